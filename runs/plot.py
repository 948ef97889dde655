"""The reward curve of a run folder (``reward_curve.png``), drawn from its CSV files."""

from __future__ import annotations

import csv
import textwrap
from pathlib import Path

import numpy as np

from runs.metrics_files import rolling_field
from tasks.base import Success


def _read(path: Path) -> list[dict]:
    with open(path) as f:
        return list(csv.DictReader(f))


def _column(rows: list[dict], key: str) -> np.ndarray:
    return np.array([float(r[key]) for r in rows])


def _panels(rows: list[dict], success: Success) -> list[tuple[str, str]]:
    """(column, y label) per panel: the measure, the length unless it is the measure,
    the return unless it is the length (+1 a step: the same curve)."""
    unit = f" ({success.unit})" if success.unit else ""  # a share or a count has none
    panels = [(success.measure, f"{success.description}{unit}")]
    if success.measure != "length":
        panels.append(("length", "episode length (steps)"))
    if not rows or not np.array_equal(_column(rows, "reward"), _column(rows, "length")):
        panels.append(("reward", "episode return"))
    return panels


def _mark_success(ax, rows: list[dict], evals: list[dict], success: Success) -> None:
    """On the measure's panel: its rolling mean, the greedy evaluations and the threshold."""
    if rows:
        ax.plot(_column(rows, "episode"), _column(rows, rolling_field(success.measure, success.window)),
                lw=2, label=f"mean of last {success.window}")
    if evals:
        ax.plot(_column(evals, "episode"), _column(evals, success.measure), "o-", ms=4, lw=1,
                color="C3", label="greedy evaluation")
    if np.isfinite(success.threshold):
        ax.axhline(success.threshold, color="k", ls="--", lw=1,
                   label=f"solved: {success.judge} >= {success.threshold:g}")
    if ax.get_legend_handles_labels()[0]:  # an empty run with no threshold has nothing to label
        ax.legend(loc="upper left", fontsize=8)


def plot_reward_curve(metrics_csv: Path, out_png: Path, success: Success,
                      evals_csv: Path | None = None) -> None:
    """Draws :func:`reward_curve` into ``out_png``."""
    reward_curve(metrics_csv, success, evals_csv, Path(out_png).parent.name).savefig(out_png, dpi=100)


def reward_curve(metrics_csv: Path, success: Success, evals_csv: Path | None = None, title: str = ""):
    """The task's measure per episode, its rolling mean, the threshold and the greedy
    evaluations; the episode length (if it is not the measure) and return (if it is
    not the length) below; a matplotlib ``Figure``."""
    from matplotlib.figure import Figure  # not pyplot: no GUI backend to load, nothing to close

    rows = _read(metrics_csv)
    evals = _read(evals_csv) if evals_csv is not None and Path(evals_csv).is_file() else []
    panels = _panels(rows, success)
    fig = Figure(figsize=(8, 2.6 * len(panels) + 0.6))
    axes = fig.subplots(len(panels), 1, squeeze=False, sharex=True)
    for ax, (key, label) in zip(axes[:, 0], panels):
        if rows:
            ax.plot(_column(rows, "episode"), _column(rows, key), lw=0.6, alpha=0.5,
                    label="training episode")
        ax.set_ylabel(textwrap.fill(label, 34), fontsize=9 if len(label) > 34 else None)  # a panel is 2.6 in high
    _mark_success(axes[0, 0], rows, evals, success)
    axes[-1, 0].set_xlabel("episode")
    from runs.console import solved_when  # the console's words for the rule

    rule = textwrap.fill(f"solved when {solved_when(success)}", 120)
    fig.suptitle(f"{title}\n{rule}", fontsize=8)
    fig.tight_layout()
    return fig
