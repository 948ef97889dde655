"""The comparison of a Hydra sweep's learners on each robot/task: a table, saved
next to the jobs (``comparison.csv``, ``comparison.md``, ``comparison.png``).

One row per robot/task, learner and setting of the swept hyperparameters (column
``swept``: every override whose value differs between the sweep's jobs, the seed
aside). The headline is each row's ``score``, the task's own measure per seed as its
judge sees it (the final greedy evaluation for greedily judged tasks, the mean of the
last ``window`` training episodes otherwise), summarized over the finished seeds by
its interquartile mean with a 95% bootstrap confidence interval (``IQM [95% CI]``).
Also: seeds solved and by which judge, episodes and env steps to solve, the greedy
policy's measure, the best rolling training mean, final mean return, wall time
(mean +- std). Each row counts its jobs (``seeds``) by how they ended: finished,
failed, interrupted, never started; only finished jobs enter the numbers, and
every job that did not finish gets one line saying why. Rows of different
robot/task (other measures, other units) are never pooled.
"""

from __future__ import annotations

import csv
import math
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from runs.loggers import write_sweep_hparams
from sweeps.comparison_plot import plot
from sweeps.stats import format_iqm_ci, iqm_ci
from sweeps.folder import sweep_jobs, swept_keys, swept_label

IQM = "IQM [95% CI]"
COLUMNS = ("robot/task", "learner", "swept", "measure", "score", IQM, "mean +- std", "seeds", "finished",
           "solved", "failed", "interrupted", "never_started", "episodes_to_solve", "steps_to_solve",
           "greedy", "best_rolling", "final_mean_return", "wall_s")
NUMBERS = ("iqm", "ci_low", "ci_high")  # the headline as numbers, in comparison.csv only
LEGEND = (f"{IQM}: interquartile mean of the score over the finished seeds, 95% percentile bootstrap "
          "interval (seeds resampled); rows of different tasks are never pooled")


class NotASweep(Exception):
    """The folder is missing or holds no job of train.py; the message says which."""


def score(job: dict) -> tuple[float | None, str]:
    """A finished job's headline number and what it is: the final greedy evaluation's
    measure for a greedily judged task, else (or without one) the mean of the last
    ``window`` training episodes."""
    if job["judge"] == "greedy" and job.get("greedy") is not None:
        return job["greedy"], "greedy policy"
    kind = f"last-{job['window']} training mean"
    return job.get("last_rolling"), kind if job["judge"] != "greedy" else f"{kind} (no greedy evaluation)"


def _mean_std(values: list) -> str:
    values = [v for v in values if v is not None]
    if not values:
        return "-"
    return f"{np.mean(values):.3g} +- {np.std(values):.2g}"


def _headline(ok: list[dict]) -> dict:
    """The score's kind, IQM with its interval (text and numbers) and mean +- std."""
    scored = [score(j) for j in ok]
    values = [v for v, _ in scored if v is not None and math.isfinite(v)]
    centre, low, high = iqm_ci(values)
    return {"score": "; ".join(sorted({kind for _, kind in scored})) or "-",
            IQM: format_iqm_ci(centre, low, high, len(values)), "mean +- std": _mean_std(values),
            "iqm": centre, "ci_low": low, "ci_high": high}


def table_row(key: tuple[str, str, str], jobs: list[dict]) -> dict:
    """One row of the table: the jobs of one robot/task, learner and swept setting."""
    pair, learner, swept = key
    ok = [j for j in jobs if j["status"] == "ok"]
    won = [j for j in ok if j["solved"]]
    count = Counter(j["status"] for j in jobs)
    measures = sorted({f"{j['measure']} ({j['unit'] + ', ' if j['unit'] else ''}{j['judge']} >= "
                       f"{j['threshold']:g})" for j in ok})
    return {
        "robot/task": pair, "learner": learner, "swept": swept, "measure": "; ".join(measures) or "-",
        **_headline(ok), "seeds": len(jobs), "finished": len(ok),
        "solved": f"{len(won)}/{len(ok)}", "failed": count["failed"],
        "interrupted": count["interrupted"], "never_started": count["never started"],
        "episodes_to_solve": _mean_std([j["episodes_to_solve"] for j in won]),
        "steps_to_solve": _mean_std([j["steps_to_solve"] for j in won]),
        "greedy": _mean_std([j["greedy"] for j in ok]),
        "best_rolling": _mean_std([j["best_rolling"] for j in ok]),
        "final_mean_return": _mean_std([j["final_mean_return"] for j in ok]),
        "wall_s": _mean_std([j["wall_s"] for j in ok]),
        "_runs": jobs,
    }


def job_line(job: dict) -> str | None:
    """One line on a job that did not finish, or whose files are damaged; None otherwise."""
    where = job["run_dir"] or f"job {job['job']} ({' '.join(job['overrides'] or [])})"
    if job["status"] == "ok":
        return f"warning: {where}: {job['warning']}" if job.get("warning") else None
    return f"{job['status']}: {where}: {job.get('error', 'no verdict')}"


def compare(sweep_dir: Path) -> tuple[list[dict], list[str]]:
    """The table's rows, in robot/task and learner order (swept settings in the sweep's
    order), and one line per job that did not finish (after notes on the sweep)."""
    jobs, notes = sweep_jobs(sweep_dir)
    keys = swept_keys(jobs)
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for job in jobs:
        pair = f"{job.get('robot')}/{job.get('task')}"
        groups[(pair, str(job.get("learner")), swept_label(job, keys))].append(job)
    rows = [table_row(key, js) for key, js in sorted(groups.items(), key=lambda kv: kv[0][:2])]
    return rows, notes + [line for line in map(job_line, jobs) if line]


def write_outputs(sweep_dir: Path, rows: list[dict], lines: list[str]) -> None:
    """comparison.csv (the table, and the IQM as numbers), comparison.md (the table and
    ``lines``), comparison.png."""
    with open(sweep_dir / "comparison.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS + NUMBERS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    md = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    md += ["| " + " | ".join(str(r[c]) for c in COLUMNS) + " |" for r in rows]
    md += ["", LEGEND]
    if lines:
        md += ["", "Jobs that did not finish, and damaged files:", "", *(f"- {line}" for line in lines)]
    (sweep_dir / "comparison.md").write_text("\n".join(md) + "\n")
    plot(sweep_dir, rows)


def table_text(rows: list[dict]) -> str:
    """The rows as aligned columns under a header line, then the IQM's legend."""
    shown = [dict(zip(COLUMNS, COLUMNS)), *rows]
    widths = {c: max(len(str(r[c])) for r in shown) for c in COLUMNS}
    lines = ["  ".join(str(r[c]).ljust(widths[c]) for c in COLUMNS).rstrip() for r in shown]
    return "\n".join([*lines, LEGEND])


def report(sweep_dir: Path, stopped: str | None = None) -> list[dict]:
    """Prints the comparison of the sweep in ``sweep_dir``, writes its files there and
    returns its rows; :class:`NotASweep` if the folder is missing or holds no job.
    ``stopped``: the signal that stopped the sweep (else its ``.stop`` file tells), said first."""
    if not sweep_dir.is_dir():
        raise NotASweep(f"{sweep_dir} is not a folder (give a Hydra multirun sweep folder)")
    rows, lines = compare(sweep_dir)
    if not rows:
        raise NotASweep(f"{sweep_dir} holds no run folders of train.py")
    stop = sweep_dir / ".stop"
    if stopped or stop.is_file():
        signal = stopped or stop.read_text(errors="replace").strip() or "a signal"
        print(f"the sweep was stopped ({signal}): the numbers are those of the jobs that finished")
    print(table_text(rows))
    if lines:
        print("\njobs that did not finish, and damaged files:")
        print("\n".join(lines))
    write_outputs(sweep_dir, rows, lines)
    print(f"\nwrote {sweep_dir / 'comparison.csv'}, comparison.md and comparison.png")
    hparams_for_tensorboard(sweep_dir)
    return rows


def hparams_for_tensorboard(sweep_dir: Path) -> None:
    """Where the sweep's jobs logged to TensorBoard, its experiment (every job's settings, the
    final measures as metrics) in ``<sweep>/hparams`` for the HParams tab."""
    logged = sorted({p.parents[2] for p in sweep_dir.glob("*/logs/*/events.out.tfevents.*")})
    configs = [OmegaConf.to_container(OmegaConf.load(job / "config.yaml")) for job in logged
               if (job / "config.yaml").is_file()]
    if configs:
        write_sweep_hparams(sweep_dir, configs)
        print(f"TensorBoard: tensorboard --logdir {sweep_dir} compares the jobs in its HParams tab")
