"""Turn a Hydra sweep folder into a comparison of learners on each robot/task.

    python compare.py multirun/2026-11-21/12-00-00

Prints a table (learner x robot/task, judged by the task's own success measure:
seeds solved and by which judge, episodes and env steps to solve, the greedy
policy's measure, the best rolling 100-episode mean of the training episodes,
final mean return, wall time; mean +- std over seeds), saves it as
``comparison.csv`` and ``comparison.md`` in the sweep folder, and draws
``comparison.png``: each learner's rolling mean of the task's measure per
episode, mean and min-max spread over seeds, with the threshold. Jobs that
left no verdict are listed as failed or interrupted.
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

from learners.metrics_files import rolling_field
from learners.summary import summarize_run

COLUMNS = ("robot/task", "learner", "measure", "seeds", "solved", "failed", "episodes_to_solve",
           "steps_to_solve", "greedy", "best_rolling", "final_mean_return", "wall_s")


def _mean_std(values: list) -> str:
    values = [v for v in values if v is not None]
    if not values:
        return "-"
    return f"{np.mean(values):.3g} +- {np.std(values):.2g}"


def job_dirs(sweep_dir: Path) -> list[Path]:
    """Each job folder of a sweep (those holding a ``run.json`` or a ``.hydra`` folder)."""
    return sorted(p for p in sweep_dir.iterdir()
                  if p.is_dir() and ((p / "run.json").exists() or (p / ".hydra").exists()))


def compare(sweep_dir: Path) -> list[dict]:
    runs = [summarize_run(d) for d in job_dirs(sweep_dir)]
    groups: dict[tuple, list[dict]] = defaultdict(list)
    for r in runs:
        groups[(f"{r.get('robot')}/{r.get('task')}", str(r.get("learner")))].append(r)
    for r in runs:
        if r["status"] != "ok":
            print(f"{r['status']}: {r['run_dir']}: {r.get('error', 'no verdict')}")
    rows = []
    for (pair, learner), rs in sorted(groups.items()):
        ok = [r for r in rs if r["status"] == "ok"]
        won = [r for r in ok if r["solved"]]
        measures = sorted({f"{r['measure']} ({r['unit']}, {r['judge']} >= {r['threshold']:g})"
                           for r in ok})
        rows.append({
            "robot/task": pair, "learner": learner, "measure": "; ".join(measures) or "-",
            "seeds": len(rs),
            "solved": f"{len(won)}/{len(ok)}", "failed": len(rs) - len(ok),
            "episodes_to_solve": _mean_std([r["episodes_to_solve"] for r in won]),
            "steps_to_solve": _mean_std([r["steps_to_solve"] for r in won]),
            "greedy": _mean_std([r["greedy"] for r in ok]),
            "best_rolling": _mean_std([r["best_rolling"] for r in ok]),
            "final_mean_return": _mean_std([r["final_mean_return"] for r in ok]),
            "wall_s": _mean_std([r["wall_s"] for r in ok]),
            "_runs": rs,
        })
    return rows


def write_outputs(sweep_dir: Path, rows: list[dict]) -> None:
    with open(sweep_dir / "comparison.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=COLUMNS, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)
    lines = ["| " + " | ".join(COLUMNS) + " |", "|" + "---|" * len(COLUMNS)]
    lines += ["| " + " | ".join(str(r[c]) for c in COLUMNS) + " |" for r in rows]
    (sweep_dir / "comparison.md").write_text("\n".join(lines) + "\n")
    plot(sweep_dir, rows)


def plot(sweep_dir: Path, rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pairs = sorted({r["robot/task"] for r in rows})
    fig, axes = plt.subplots(len(pairs), 1, figsize=(9, 4 * len(pairs)), squeeze=False)
    for ax, pair in zip(axes[:, 0], pairs):
        thresholds, ylabel = set(), "rolling mean"
        for row in (r for r in rows if r["robot/task"] == pair):
            curves = []
            for run in row["_runs"]:
                if run["status"] != "ok":
                    continue
                with open(Path(run["run_dir"]) / "metrics.csv") as f:
                    column = rolling_field(run["measure"], run["window"])
                    curves.append(np.array([float(r[column]) for r in csv.DictReader(f)]))
                thresholds.add(run["threshold"])
                ylabel = f"{column} ({run['unit']}), training episodes"
            if not curves:
                continue
            n = max(len(c) for c in curves)
            # A run that stopped early (solved) keeps its last value.
            padded = np.stack([np.pad(c, (0, n - len(c)), mode="edge") for c in curves])
            x = np.arange(1, n + 1)
            line, = ax.plot(x, padded.mean(0), label=f"{row['learner']} ({len(curves)} seeds)")
            ax.fill_between(x, padded.min(0), padded.max(0), color=line.get_color(), alpha=0.2)
        for t in sorted(v for v in thresholds if np.isfinite(v)):
            ax.axhline(t, color="k", ls="--", lw=1, label=f"threshold {t:g}")
        ax.set_title(pair)
        ax.set_xlabel("episode")
        ax.set_ylabel(ylabel)
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
    rows = compare(args.sweep_dir)
    if not rows:
        print(f"error: {args.sweep_dir} holds no run folders of train.py", file=sys.stderr)
        return 2
    write_outputs(args.sweep_dir, rows)
    widths = {c: max(len(c), *(len(str(r[c])) for r in rows)) for c in COLUMNS}
    print("  ".join(c.ljust(widths[c]) for c in COLUMNS))
    for r in rows:
        print("  ".join(str(r[c]).ljust(widths[c]) for c in COLUMNS))
    print(f"\nwrote {args.sweep_dir / 'comparison.csv'}, comparison.md and comparison.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
