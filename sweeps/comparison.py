"""The comparison of a Hydra sweep's learners on each robot/task: a table, saved
next to the jobs (``comparison.csv``, ``comparison.md``, ``comparison.png``).

One row per robot/task, learner and setting of the swept hyperparameters (column
``swept``: every override whose value differs between the sweep's jobs, the seed
aside). The ``headline`` column names the number each seed is ranked by, the task's own
measure as its judge sees it (:meth:`runs.summary.MeasureKeys.headline`):
``greedy_<measure>``, the final greedy evaluation's (a pruned trial's: its last), for greedily judged tasks,
``train_<measure>_last<window>``, the mean of the last ``window`` training episodes,
otherwise; it is summarized over the finished seeds by its interquartile mean with a 95%
bootstrap confidence interval (``IQM [95% CI]``) and ``mean +- std``. Also: seeds solved,
episodes and env steps to solve, and (mean +- std over the finished seeds) the numbers
under their summary.json names, ``greedy_<measure>``, ``greedy_return``,
``train_<measure>_best_rolling<window>``, ``train_<measure>_last<window>``,
``train_return_last100``, and wall time. Each row counts its jobs (``seeds``) by how they
ended: finished, failed, interrupted, never started; only finished jobs enter the
numbers, and every job that did not finish gets one line saying why. Rows of different
robot/task (other measures, other units) are never pooled; rows whose measures differ
are printed as tables of their own, each with its own column names.
"""

from __future__ import annotations

import csv
import math
import textwrap
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from runs.loggers import run_scalar_names, write_sweep_hparams
from runs.layout import is_run_folder, is_sweep_folder
from runs.summary import Unusable, measure_keys, read_json, summarize_run
from sweeps.comparison_plot import X_AXES, plot
from sweeps.stats import format_iqm_ci, iqm_ci
from sweeps.folder import sweep_jobs, swept_keys, swept_label

IQM = "IQM [95% CI]"
HEAD = ("robot/task", "learner", "swept", "measure", "headline", IQM, "mean +- std", "seeds", "finished",
        "solved", "failed", "interrupted", "never_started", "episodes_to_solve", "steps_to_solve")
TAIL = ("wall_s",)
# What the console shows (a terminal's width; the files hold every column).
CONSOLE = ("robot/task", "learner", "swept", "headline", IQM, "greedy_rate", "seeds", "finished", "solved",
           "steps_to_solve", "wall_s")
WIDTH = 110
NUMBERS = ("iqm", "ci_low", "ci_high")  # the headline as numbers, in comparison.csv only
LEGEND = (f"headline: the number each seed is ranked by (greedy_<measure>: the final greedy evaluation's "
          f"mean, a pruned trial's last; train_<measure>_last<window>: the mean of the last <window> training "
          f"episodes); greedy_rate: the share of the final evaluation's episodes that passed the task's threshold "
          f"(mean +- std over seeds); {IQM}: its interquartile mean over the finished seeds, 95% percentile "
          "bootstrap interval "
          "(seeds resampled; 'rough' below 5 seeds, where it spans little more than their range); rows of "
          "different tasks are never pooled")


class NotASweep(Exception):
    """The folder is missing or holds no job of train.py; the message says which."""


def named_columns(job: dict) -> tuple[str, ...]:
    """The summary.json names of the numbers a finished job's row shows (its task's measure
    and window in them): ``greedy_<measure>``, ``greedy_rate`` (the share of the final
    evaluation's episodes that passed), ``greedy_return``,
    ``train_<measure>_best_rolling<window>``, ``train_<measure>_last<window>``,
    ``train_return_last100``."""
    k = measure_keys(job["measure"], job["window"])
    return (k.greedy, "greedy_rate", k.greedy_return, k.train_best_rolling, k.train_last, k.train_return_last100)


def _num(v) -> str:
    return "-" if v is None else f"{v:.4g}"


def _mean_std(values: list) -> str:
    values = [v for v in values if v is not None]
    if not values:
        return "-"
    return f"{np.mean(values):.3g} +- {np.std(values):.2g}"


def _headline(ok: list[dict]) -> dict:
    """The headline's name (the names, where seeds differ), its IQM with its interval (text
    and numbers) and mean +- std over the finished seeds ``ok``."""
    values = [j["headline_value"] for j in ok if j["headline_value"] is not None and math.isfinite(j["headline_value"])]
    centre, low, high = iqm_ci(values)
    return {"headline": "; ".join(sorted({j["headline"] for j in ok})) or "-",
            IQM: format_iqm_ci(centre, low, high, len(values)), "mean +- std": _mean_std(values),
            "iqm": centre, "ci_low": low, "ci_high": high}


def table_row(key: tuple[str, str, str], jobs: list[dict]) -> dict:
    """One row of the table: the jobs of one robot/task, learner and swept setting
    (``_columns``: the names of its numbers' columns, :func:`named_columns`)."""
    pair, learner, swept = key
    ok = [j for j in jobs if j["status"] == "ok"]
    won = [j for j in ok if j["solved"]]
    count = Counter(j["status"] for j in jobs)
    measures = sorted({f"{j['measure']} ({j['unit'] + ', ' if j['unit'] else ''}{j['judge']} >= "
                       f"{j['threshold']:g})" for j in ok})
    names = list(dict.fromkeys(name for j in ok for name in named_columns(j)))
    return {
        "robot/task": pair, "learner": learner, "swept": swept, "measure": "; ".join(measures) or "-",
        **_headline(ok), "seeds": len(jobs), "finished": len(ok),
        "solved": f"{len(won)}/{len(ok)}", "failed": count["failed"],
        "interrupted": count["interrupted"], "never_started": count["never started"],
        "episodes_to_solve": _mean_std([j["episodes_to_solve"] for j in won]),
        "steps_to_solve": _mean_std([j["steps_to_solve"] for j in won]),
        **{name: _mean_std([j.get(name) for j in ok]) for name in names},
        "wall_s": _mean_std([j["wall_s"] for j in ok]),
        "_columns": names, "_runs": jobs,
    }


def columns(rows: list[dict]) -> tuple[str, ...]:
    """The table's columns for ``rows``: the fixed ones, the numbers' names of every row (in
    order of appearance), wall time."""
    names = dict.fromkeys(name for r in rows for name in r["_columns"])
    return (*HEAD, *names, *TAIL)


def blocks(rows: list[dict]) -> list[list[dict]]:
    """``rows`` in tables of the same column names (one table, unless the rows' measures or
    windows differ), each in the rows' order."""
    found: dict[tuple, list[dict]] = {}
    for row in rows:
        found.setdefault(tuple(row["_columns"]), []).append(row)
    return list(found.values())


def job_line(job: dict) -> str | None:
    """One line on a job that did not finish, or whose files are damaged; None otherwise."""
    where = job["run_dir"] or f"job {job['job']} ({' '.join(job['overrides'] or [])})"
    if job["status"] == "ok":
        return f"warning: {where}: {job['warning']}" if job.get("warning") else None
    return f"{job['status']}: {where}: {job.get('error', 'no verdict')}"


EVALUATION = "evaluation (mode=eval, not a training run): "  # the line of each evaluation folder


def evaluation_line(job: dict) -> str:
    """One line on an evaluation folder (``mode=eval``): its checkpoint and outcome."""
    measure = job.get("measure", "?")
    return (f"{job['run_dir']}: {'passed' if job.get('passed') else 'did not pass'}, greedy_{measure} "
            f"{_num(job.get('greedy'))}, greedy_rate {_num(job.get('greedy_rate'))} "
            f"(checkpoint {job.get('checkpoint')})")


def compare(sweep_dir: Path) -> tuple[list[dict], list[str]]:
    """The table's rows, in robot/task and learner order (swept settings in the sweep's
    order), and one line per job that did not finish (after notes on the sweep); the
    evaluation folders (``mode=eval``) are not training runs: a line each, apart."""
    jobs, notes = sweep_jobs(sweep_dir)
    evaluations = [j for j in jobs if j["status"] == "evaluation"]
    jobs = [j for j in jobs if j["status"] != "evaluation"]
    if evaluations:
        notes = notes + [f"{EVALUATION}{evaluation_line(j)}" for j in evaluations]
    keys = swept_keys(jobs)
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for job in jobs:
        pair = f"{job.get('robot')}/{job.get('task')}"
        groups[(pair, str(job.get("learner")), swept_label(job, keys))].append(job)
    rows = [table_row(key, js) for key, js in sorted(groups.items(), key=lambda kv: kv[0][:2])]
    return rows, notes + [line for line in map(job_line, jobs) if line]


def write_outputs(sweep_dir: Path, rows: list[dict], lines: list[str], x: str = "env_steps") -> None:
    """comparison.csv (one table of every row: each number under its name, empty where a
    row's task has no such number; and the IQM as numbers), comparison.md (the tables as
    printed, and ``lines``), comparison.png (its x-axis ``x``: env steps or wall seconds)."""
    with open(sweep_dir / "comparison.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns(rows) + NUMBERS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    md = []
    for block in blocks(rows):
        names = columns(block)
        md += ["| " + " | ".join(names) + " |", "|" + "---|" * len(names)]
        md += ["| " + " | ".join(str(r[c]) for c in names) + " |" for r in block]
        md += [""]
    md += [LEGEND]
    if lines:
        md += ["", "Jobs that did not finish, and damaged files:", "", *(f"- {line}" for line in lines)]
    (sweep_dir / "comparison.md").write_text("\n".join(md) + "\n")
    plot(sweep_dir, rows, x=x)


def table_text(rows: list[dict]) -> str:
    """The rows' :data:`CONSOLE` columns aligned under a header line (a table per
    :func:`blocks`; every column is in comparison.csv and comparison.md), then the
    headline's legend, wrapped to :data:`WIDTH`."""
    out = []
    for block in blocks(rows):
        names = CONSOLE
        shown = [dict(zip(names, names)), *block]
        widths = {c: max(len(str(r.get(c, ""))) for r in shown) for c in names}
        out += ["  ".join(str(r.get(c, "")).ljust(widths[c]) for c in names).rstrip() for r in shown]
    legend = textwrap.fill(f"{LEGEND}; every column: comparison.csv and comparison.md", WIDTH)
    return "\n".join([*out, legend])


def report(sweep_dir: Path, stopped: str | None = None, x: str = "env_steps") -> list[dict]:
    """Prints the comparison of the sweep in ``sweep_dir``, writes its files there and
    returns its rows; :class:`NotASweep` if the folder is missing or holds no job.
    ``stopped``: the signal that stopped the sweep (else its ``.stop`` file tells), said first.
    ``x``: comparison.png's x-axis, one of ``X_AXES`` (ValueError, one line, otherwise)."""
    if x not in X_AXES:
        raise ValueError(f"the comparison plot's x-axis must be one of {', '.join(X_AXES)}; got {x!r}")
    if not sweep_dir.is_dir():
        raise NotASweep(f"{sweep_dir} is not a folder (give a Hydra multirun sweep folder)")
    if is_run_folder(sweep_dir):  # one run: what it holds, not a comparison
        print(one_run(sweep_dir))
        return []
    rows, lines = compare(sweep_dir)
    if not rows and any(line.startswith(EVALUATION) for line in lines):  # evaluation folders alone
        print("\n".join(lines))
        return []
    if not rows:
        below = sorted(p.name for p in sweep_dir.iterdir() if p.is_dir() and is_sweep_folder(p))
        hint = f"; it holds sweeps, give one of them: {', '.join(below[:5])}{' ...' if len(below) > 5 else ''}" \
            if below else ""
        raise NotASweep(f"{sweep_dir} holds no run folders of train.py{hint}")
    stop = sweep_dir / ".stop"
    if stopped or stop.is_file():
        signal = stopped or stop.read_text(errors="replace").strip() or "a signal"
        print(f"the sweep was stopped ({signal}): the numbers are those of the jobs that finished")
    print(table_text(rows))
    if lines:
        print("\njobs that did not finish, and damaged files:")
        print("\n".join(lines))
    write_outputs(sweep_dir, rows, lines, x)
    print(f"\nwrote {sweep_dir / 'comparison.csv'}, comparison.md and comparison.png")
    hparams_for_tensorboard(sweep_dir)
    return rows


def one_run(run_dir: Path) -> str:
    """What ``compare.py`` answers for a single run's folder: its status and headline, and
    that a comparison takes a folder of runs."""
    s = summarize_run(run_dir)
    if s["status"] == "evaluation":
        what = f"an evaluation (mode=eval): {evaluation_line(s)}"
    elif s["status"] == "ok":
        what = (f"a finished run of {s.get('robot')}/{s.get('task')} x {s.get('learner')}, seed {s.get('seed')}: "
                f"solved={str(s['solved']).lower()}, {s['headline']} {_num(s['headline_value'])}")
    else:
        what = f"a run that is {s['status']}: {s.get('error', '')}"
    return (f"{run_dir} is one run's folder, {what}; compare.py compares the runs of a folder that holds "
            f"several (a sweep's, or {run_dir.parent})")


def hparams_for_tensorboard(sweep_dir: Path) -> None:
    """Where the sweep's jobs logged to TensorBoard, its experiment (every job's settings, the
    ``run/*`` numbers of every job's task as metrics) in ``<sweep>/hparams`` for the HParams tab."""
    logged = sorted({p.parents[2] for p in sweep_dir.glob("*/logs/*/events.out.tfevents.*")})
    configs = [OmegaConf.to_container(OmegaConf.load(job / "config.yaml")) for job in logged
               if (job / "config.yaml").is_file()]
    metrics: dict[str, None] = {}
    for job in logged:
        try:  # the task's rule, as the run judged it (a job that never got so far has none)
            rule = read_json(job / "success.json")
            metrics |= dict.fromkeys(run_scalar_names(rule["measure"], rule["window"]))
        except (Unusable, KeyError, TypeError, ValueError):
            pass
    if configs:
        write_sweep_hparams(sweep_dir, configs, list(metrics))
        print(f"TensorBoard: tensorboard --logdir {sweep_dir} compares the jobs in its HParams tab")
