"""``comparison.png``: per robot/task, each row's rolling mean of the task's measure per
training episode (mean and min-max spread over seeds, with the threshold), and beside
it each row's IQM of the score with its 95% confidence interval."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from runs.metrics_files import rolling_field


def _curve(run: dict) -> np.ndarray | None:
    """A finished run's rolling mean of its measure per episode (None if metrics.csv is unreadable)."""
    try:
        with open(Path(run["run_dir"]) / "metrics.csv", newline="") as f:
            column = rolling_field(run["measure"], run["window"])
            return np.array([float(r[column]) for r in csv.DictReader(f)])
    except (OSError, KeyError, TypeError, ValueError, csv.Error):
        return None


def _label(row: dict, n: int) -> str:
    swept = "" if row["swept"] == "-" else f" {row['swept']}"
    return f"{row['learner']}{swept} ({n} seed{'s' * (n != 1)})"


def _curves(ax, rows: list[dict]) -> set[float]:
    """Each row's mean curve and min-max band, in colour ``C<i>``; the thresholds seen."""
    thresholds, ylabel = set(), "rolling mean"
    for i, row in enumerate(rows):
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
        ax.plot(x, padded.mean(0), color=f"C{i}", label=_label(row, len(curves)))
        ax.fill_between(x, padded.min(0), padded.max(0), color=f"C{i}", alpha=0.2)
    ax.set_xlabel("episode")
    ax.set_ylabel(ylabel)
    return {t for t in thresholds if np.isfinite(t)}


def _iqms(ax, rows: list[dict], thresholds: set[float]) -> None:
    """Each row's IQM of the score as a point with its 95% CI as an error bar, in colour ``C<i>``."""
    for i, row in enumerate(rows):
        if math.isnan(row["iqm"]):
            continue
        has_ci = not math.isnan(row["ci_low"])
        err = [[row["iqm"] - row["ci_low"]], [row["ci_high"] - row["iqm"]]] if has_ci else None
        ax.errorbar([i], [row["iqm"]], yerr=err, fmt="o", ms=7, capsize=6, lw=2, color=f"C{i}")
    ax.set_xticks(range(len(rows)), [_label(r, r["finished"]) for r in rows], rotation=20, ha="right")
    ax.set_xlim(-0.6, len(rows) - 0.4)
    units = sorted({run["unit"] for r in rows for run in r["_runs"] if run["status"] == "ok"})
    unit = f" ({units[0]})" if len(units) == 1 else ""
    ax.set_ylabel(f"score: {'; '.join(sorted({r['score'] for r in rows}))}{unit}")
    # The threshold is only named: drawn, it would squash the intervals of runs far from it.
    shown = "; ".join(f"{t:g}" for t in sorted(thresholds))
    ax.set_title(f"IQM over seeds, 95% bootstrap CI{f' (threshold {shown})' if shown else ''}", fontsize=10)


def plot(sweep_dir: Path, rows: list[dict]) -> None:
    """Draws ``sweep_dir/comparison.png`` from the table's ``rows``: one line of panels per robot/task."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pairs = sorted({r["robot/task"] for r in rows})
    fig, axes = plt.subplots(len(pairs), 2, figsize=(14, 4.5 * len(pairs)), squeeze=False,
                             gridspec_kw={"width_ratios": [2, 1]})
    for (left, right), pair in zip(axes, pairs):
        mine = [r for r in rows if r["robot/task"] == pair]
        thresholds = _curves(left, mine)
        _iqms(right, mine, thresholds)
        for t in sorted(thresholds):
            left.axhline(t, color="k", ls="--", lw=1, label=f"threshold {t:g}")
        left.set_title(pair)
        if left.get_legend_handles_labels()[0]:
            left.legend(loc="upper left")
    fig.tight_layout()
    fig.savefig(sweep_dir / "comparison.png", dpi=100)
    plt.close(fig)
