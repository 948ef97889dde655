"""Turn a Hydra sweep folder into a comparison of learners on each robot/task.

    python compare.py multirun/2026-11-21/12-00-00

Prints a table, one row per robot/task, learner and setting of the swept
hyperparameters (column ``swept``: every override whose value differs between
the sweep's jobs, the seed aside), judged by the task's own success measure:
seeds solved and by which judge, episodes and env steps to solve, the greedy
policy's measure, the best rolling 100-episode mean of the training episodes,
final mean return, wall time; mean +- std over the finished seeds. Each row
counts its jobs (``seeds``) by how they ended: finished, failed, interrupted,
never started; only finished jobs enter the numbers.

The jobs are those the sweep's ``multirun.yaml`` launches (expanded by Hydra's
own BasicSweeper), so a job that never started is listed too; without a usable
multirun.yaml, the job folders found. Every job that did not finish gets one
line saying why: a failed job's error, the damaged file, or the command that
resumes an interrupted one. A damaged job never stops the others' table.

Saves the table as ``comparison.csv`` and ``comparison.md`` (with those lines)
in the sweep folder, and draws ``comparison.png``: each row's rolling mean of
the task's measure per episode, mean and min-max spread over seeds, with the
threshold.
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections import Counter, defaultdict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from hydra._internal.core_plugins.basic_sweeper import BasicSweeper
from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import OmegaConf

from learners.metrics_files import rolling_field
from learners.summary import summarize_run

PICKS = ("robot", "task", "learner")  # config groups with their own columns, never in ``swept``
COLUMNS = ("robot/task", "learner", "swept", "measure", "seeds", "finished", "solved", "failed",
           "interrupted", "never_started", "episodes_to_solve", "steps_to_solve", "greedy",
           "best_rolling", "final_mean_return", "wall_s")


def _mean_std(values: list) -> str:
    values = [v for v in values if v is not None]
    if not values:
        return "-"
    return f"{np.mean(values):.3g} +- {np.std(values):.2g}"


def overrides_dict(overrides: list[str] | None) -> dict[str, str]:
    """``["learner.alpha=0.05", ...]`` (as Hydra hands them to a job) -> ``{"learner.alpha": "0.05"}``."""
    return dict(o.partition("=")[::2] for o in overrides or [])


@dataclass
class Plan:
    """The jobs a sweep launches: each one's overrides, in job order (``None`` where
    multirun.yaml cannot tell, and ``note`` says why), and the sweep's own robot, task
    and learner (those of jobs that do not override them)."""

    jobs: list[list[str]] | None
    defaults: dict = field(default_factory=dict)
    note: str | None = None


def planned_jobs(sweep_dir: Path) -> Plan:
    """The jobs of ``sweep_dir/multirun.yaml``, expanded as Hydra's BasicSweeper does."""
    path = sweep_dir / "multirun.yaml"
    if not path.is_file():
        return Plan(None, note=f"{path} is missing: jobs that never started cannot be listed")
    try:  # whatever is wrong with the file, the job folders still tell the rest
        cfg = OmegaConf.load(path)
        sweeper = cfg.hydra.sweeper
        if not str(sweeper.get("_target_")).endswith(".BasicSweeper"):
            return Plan(None, note=f"{path}: sweeper {sweeper.get('_target_')} is not Hydra's basic "
                                   "sweeper: jobs that never started cannot be listed")
        params = [f"{k}={v}" for k, v in (sweeper.get("params") or {}).items()]
        overrides = OverridesParser.create().parse_overrides([*params, *cfg.hydra.overrides.task])
        jobs = [job for batch in BasicSweeper.split_arguments(overrides, None) for job in batch]
        defaults = {k: cfg.hydra.runtime.choices.get(k) for k in PICKS}
    except Exception as err:
        return Plan(None, note=f"{path} is unreadable ({type(err).__name__}): "
                               "jobs that never started cannot be listed")
    return Plan(jobs, defaults)


def job_number(folder: Path) -> int | None:
    """The job number a job folder's name starts with (hydra.sweep.subdir ``<num>_...``)."""
    head = folder.name.split("_")[0]
    return int(head) if head.isdigit() else None


def job_folders(sweep_dir: Path) -> list[Path]:
    """The sweep's job folders: named after their job number, or holding run.json or .hydra."""
    found = [p for p in sweep_dir.iterdir() if p.is_dir() and not p.name.startswith(".")
             and (job_number(p) is not None or (p / "run.json").exists() or (p / ".hydra").exists())]
    return sorted(found, key=lambda p: (job_number(p) is None, job_number(p) or 0, p.name))


def sweep_jobs(sweep_dir: Path) -> tuple[list[dict], list[str]]:
    """Every job of the sweep, in job order, each a :func:`summarize_run` summary with its
    ``job`` number and ``overrides``; and notes on the sweep as a whole."""
    plan = planned_jobs(sweep_dir)
    runs = [summarize_run(d) | {"job": job_number(d)} for d in job_folders(sweep_dir)]
    jobs = runs if plan.jobs is None else _match(plan.jobs, runs, sweep_dir)
    _fill_picks(jobs, plan.defaults)
    return jobs, [plan.note] if plan.note else []


def _match(planned: list[list[str]], runs: list[dict], sweep_dir: Path) -> list[dict]:
    """Each planned job with the summary of its folder (same job number, or none in the
    folder's name, and the same overrides where the folder recorded them) or as never
    started; then the folders no planned job claims."""
    def fits(run: dict, num: int, want: dict) -> bool:
        if run["overrides"] is None:
            return run["job"] == num
        return run["job"] in (num, None) and overrides_dict(run["overrides"]) == want

    free, jobs = list(runs), []
    for num, overrides in enumerate(planned):
        want = overrides_dict(overrides)
        mine = next((r for r in free if fits(r, num, want)), None)
        if mine is None:
            mine = {"run_dir": None, "status": "never started", "error": f"no folder {num}_* in {sweep_dir}"}
        else:
            free.remove(mine)
        jobs.append(mine | {"job": num, "overrides": overrides})
    stray = "not one of multirun.yaml's jobs (its overrides differ): tabulated under its own"
    return jobs + [r | {"warning": "; ".join(filter(None, (r.get("warning"), stray)))} for r in free]


def _fill_picks(jobs: list[dict], defaults: dict) -> None:
    """robot, task and learner of the jobs that left no run.json: those of a job with the
    same robot/task/learner overrides, else the overrides' or the sweep's (``?`` if unknown)."""
    def picks(job: dict) -> tuple:
        return tuple(overrides_dict(job["overrides"]).get(k) for k in PICKS)

    known = {picks(j): j for j in jobs if j.get("robot") and j["overrides"] is not None}
    for job in (j for j in jobs if not j.get("robot")):
        if job["overrides"] is None:
            job.update(dict.fromkeys(PICKS, "?"))
            continue
        given, like = overrides_dict(job["overrides"]), known.get(picks(job))
        for k in PICKS:  # a robot's own default task is known only from its jobs
            guess = given.get(k) or (None if k == "task" and "robot" in given else defaults.get(k))
            job[k] = like[k] if like else guess or "?"


def swept_keys(jobs: list[dict]) -> list[str]:
    """The override keys whose value differs between jobs (the seed, and robot, task and
    learner, which have their own columns, aside), in the sweep's order."""
    known = [overrides_dict(j["overrides"]) for j in jobs if j["overrides"] is not None]
    keys = dict.fromkeys(k for given in known for k in given)
    return [k for k in keys if k not in ("seed", *PICKS) and len({g.get(k) for g in known}) > 1]


def swept_label(job: dict, keys: list[str]) -> str:
    """``learner.alpha=0.05 learner.gamma=0.9``: the job's values of the swept ``keys``."""
    if not keys:
        return "-"
    if job["overrides"] is None:
        return "? (overrides unknown)"
    given = overrides_dict(job["overrides"])
    return " ".join(f"{k}={given[k]}" if k in given else f"{k}=(default)" for k in keys)


def job_line(job: dict) -> str | None:
    """One line on a job that did not finish, or whose files are damaged; None otherwise."""
    where = job["run_dir"] or f"job {job['job']} ({' '.join(job['overrides'] or [])})"
    if job["status"] == "ok":
        return f"warning: {where}: {job['warning']}" if job.get("warning") else None
    return f"{job['status']}: {where}: {job.get('error', 'no verdict')}"


def table_row(key: tuple[str, str, str], jobs: list[dict]) -> dict:
    """One row of the table: the jobs of one robot/task, learner and swept setting."""
    pair, learner, swept = key
    ok = [j for j in jobs if j["status"] == "ok"]
    won = [j for j in ok if j["solved"]]
    count = Counter(j["status"] for j in jobs)
    measures = sorted({f"{j['measure']} ({j['unit']}, {j['judge']} >= {j['threshold']:g})" for j in ok})
    return {
        "robot/task": pair, "learner": learner, "swept": swept,
        "measure": "; ".join(measures) or "-", "seeds": len(jobs), "finished": len(ok),
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
    """comparison.csv (the table), comparison.md (the table and ``lines``), comparison.png."""
    with open(sweep_dir / "comparison.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    md = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    md += ["| " + " | ".join(str(r[c]) for c in COLUMNS) + " |" for r in rows]
    if lines:
        md += ["", "Jobs that did not finish, and damaged files:", "", *(f"- {line}" for line in lines)]
    (sweep_dir / "comparison.md").write_text("\n".join(md) + "\n")
    plot(sweep_dir, rows)


def _curve(run: dict) -> np.ndarray | None:
    """A finished run's rolling mean of its measure per episode (None if metrics.csv is unreadable)."""
    try:
        with open(Path(run["run_dir"]) / "metrics.csv", newline="") as f:
            column = rolling_field(run["measure"], run["window"])
            return np.array([float(r[column]) for r in csv.DictReader(f)])
    except (OSError, KeyError, TypeError, ValueError, csv.Error):
        return None


def plot(sweep_dir: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pairs = sorted({r["robot/task"] for r in rows})
    fig, axes = plt.subplots(len(pairs), 1, figsize=(9, 4 * len(pairs)), squeeze=False)
    for ax, pair in zip(axes[:, 0], pairs):
        thresholds, ylabel = set(), "rolling mean"
        for row in (r for r in rows if r["robot/task"] == pair):
            finished = [run for run in row["_runs"] if run["status"] == "ok"]
            curves = [c for c in map(_curve, finished) if c is not None and len(c)]
            thresholds.update(run["threshold"] for run in finished)
            if not curves:
                continue
            run = finished[0]
            ylabel = f"{rolling_field(run['measure'], run['window'])} ({run['unit']}), training episodes"
            n = max(len(c) for c in curves)
            # A run that stopped early (solved) keeps its last value.
            padded = np.stack([np.pad(c, (0, n - len(c)), mode="edge") for c in curves])
            x = np.arange(1, n + 1)
            swept = "" if row["swept"] == "-" else f" {row['swept']}"
            line, = ax.plot(x, padded.mean(0), label=f"{row['learner']}{swept} ({len(curves)} seeds)")
            ax.fill_between(x, padded.min(0), padded.max(0), color=line.get_color(), alpha=0.2)
        for t in sorted(v for v in thresholds if np.isfinite(v)):
            ax.axhline(t, color="k", ls="--", lw=1, label=f"threshold {t:g}")
        ax.set_title(pair)
        ax.set_xlabel("episode")
        ax.set_ylabel(ylabel)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(sweep_dir / "comparison.png", dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep_dir", type=Path)
    args = parser.parse_args(argv)
    if not args.sweep_dir.is_dir():
        print(f"error: {args.sweep_dir} is not a folder (give a Hydra multirun sweep folder)",
              file=sys.stderr)
        return 2
    rows, lines = compare(args.sweep_dir)
    if not rows:
        print(f"error: {args.sweep_dir} holds no run folders of train.py", file=sys.stderr)
        return 2
    write_outputs(args.sweep_dir, rows, lines)
    widths = {c: max(len(c), *(len(str(r[c])) for r in rows)) for c in COLUMNS}
    print("  ".join(c.ljust(widths[c]) for c in COLUMNS))
    for r in rows:
        print("  ".join(str(r[c]).ljust(widths[c]) for c in COLUMNS))
    if lines:
        print("\njobs that did not finish, and damaged files:")
        print("\n".join(lines))
    print(f"\nwrote {args.sweep_dir / 'comparison.csv'}, comparison.md and comparison.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
