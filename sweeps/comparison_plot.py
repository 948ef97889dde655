"""``comparison.png``: per robot/task, on the left each row's learning curve (the rolling
mean of the task's measure over training episodes: mean over seeds, min-max band) and its
greedy evaluations (IQM over seeds with a 95% bootstrap CI band) against env steps (or
wall seconds), with the threshold; on the right each row's headline (its IQM over seeds
with its 95% CI), best first.

Rows are ranked by the IQM of their headline, the task's own measure as its judge sees
it, best first, in the right-hand panel and in the legend. With more than
``MANY_ROWS`` rows for a task (an Optuna sweep's trials), the best row is drawn in
colour and the others thin and grey, left out of the legend but for one entry
``N other trials``.

:func:`figure` draws it (a matplotlib figure, for inspection), :func:`plot` saves it.
"""

from __future__ import annotations

import csv
import math
import textwrap
import warnings
from pathlib import Path

import numpy as np

from runs.metrics_files import rolling_field
from sweeps.stats import iqm_ci

X_AXES = ("env_steps", "wall_s")  # what the learning curves are drawn against
X_LABELS = {"env_steps": "env steps (transitions of all copies)", "wall_s": "wall time (s)"}
MANY_ROWS = 6  # more rows than this for one task: the best in colour, the others faded
GRID = 200  # points of the common x grid the seeds' curves are averaged on
CI_RESAMPLES = 2000  # bootstrap resamples per greedy evaluation point (a plot, not the table)
FADED = {"color": "0.6", "lw": 0.8, "alpha": 0.5}
BEST_COLOUR = "C0"
LABEL_WIDTH = 70  # the legend's row names wrap at this many characters
SHORT_WIDTH = 40  # the right panel's row names are cut to this many


def _read(path: Path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _wall_at(run_dir: Path) -> np.ndarray:
    """Seconds since the run started at the end of each training episode (timing.csv)."""
    return np.array([float(r["wall_s"]) for r in _read(run_dir / "timing.csv")])


def _curve(run: dict, x: str) -> tuple[np.ndarray, np.ndarray] | None:
    """A finished run's rolling mean of its measure per training episode, against ``x``
    (None where its files are unreadable)."""
    run_dir = Path(run["run_dir"])
    try:
        rows = _read(run_dir / "metrics.csv")
        ys = np.array([float(r[rolling_field(run["measure"], run["window"])]) for r in rows])
        xs = (np.array([float(r["env_steps"]) for r in rows]) if x == "env_steps"
              else _wall_at(run_dir)[: len(rows)])
    except (OSError, KeyError, TypeError, ValueError, csv.Error):
        return None
    return (xs, ys) if len(xs) == len(ys) and len(ys) else None


def run_evaluations(run: dict, x: str) -> list[tuple[float, float]]:
    """A finished run's greedy evaluations (evals.csv) as ``(x, measure)`` points; wall
    seconds are those at the end of the training episode before each evaluation."""
    run_dir = Path(run["run_dir"])
    try:
        rows = _read(run_dir / "evals.csv")
        values = [float(r[run["measure"]]) for r in rows]
        if x == "env_steps":
            xs = [float(r["env_steps"]) for r in rows]
        else:
            wall = _wall_at(run_dir)
            xs = [float(wall[int(r["episode"]) - 1]) if int(r["episode"]) > 0 else 0.0 for r in rows]
    except (OSError, KeyError, TypeError, ValueError, IndexError, csv.Error):
        return []
    return list(zip(xs, values))


def mean_curve(curves: list[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, ...]:
    """``(x, mean, low, high)`` of the seeds' ``curves`` on a common grid up to the longest:
    each seed interpolated where it ran and holding its last value after it stopped (a seed
    that solved early keeps its end), none before its first episode ended."""
    end = max(float(xs[-1]) for xs, _ in curves)
    grid = np.linspace(0.0, end, GRID)
    stack = np.stack([np.where(grid < xs[0], np.nan, np.interp(grid, xs, ys)) for xs, ys in curves])
    keep = ~np.all(np.isnan(stack), axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # columns where only some seeds ran
        return grid[keep], np.nanmean(stack[:, keep], 0), np.nanmin(stack[:, keep], 0), np.nanmax(stack[:, keep], 0)


def greedy_points(evaluations: list[list[tuple[float, float]]]) -> tuple[np.ndarray, ...]:
    """``(x, iqm, low, high)`` of the seeds' greedy ``evaluations`` (per seed, ``(x, measure)``
    points in order): at the mean x of the seeds' k-th evaluations, for each k but the last,
    and at the last evaluation's x, the IQM over seeds of each seed's evaluated measure there,
    with its 95% bootstrap interval (one seed: none). Seeds evaluate at different env steps
    (their episodes differ): a seed counts with its measure interpolated between its
    evaluations, after its last with that one (as its training curve holds its end: the last
    point is the IQM of every seed's final evaluation), and not before its first."""
    evaluations = [e for e in evaluations if e]
    if not evaluations:
        return tuple(np.array([]) for _ in range(4))
    seeds = [(np.array([x for x, _ in e]), np.array([v for _, v in e])) for e in evaluations]
    most = max(len(xs) for xs, _ in seeds)
    grid = sorted({*(float(np.mean([xs[k] for xs, _ in seeds if k < len(xs)])) for k in range(most - 1)),
                   max(float(xs[-1]) for xs, _ in seeds)})
    out = []
    for x in grid:
        values = [float(np.interp(x, xs, vs)) for xs, vs in seeds if x >= xs[0]]
        out.append((x, *iqm_ci(values, n_resamples=CI_RESAMPLES)))
    return tuple(np.array(column) for column in zip(*out))


def ranked(rows: list[dict]) -> list[dict]:
    """``rows`` best first by the IQM of their headline (rows without one last, in order)."""
    return sorted(rows, key=lambda r: -r["iqm"] if not math.isnan(r["iqm"]) else math.inf)


def label(row: dict, n: int | None = None) -> str:
    """``dqn learner.lr=0.001 (3 seeds)``: the row's learner, swept setting and finished seeds
    (the legend's, wrapped to lines of ``LABEL_WIDTH``)."""
    n = row["finished"] if n is None else n
    swept = "" if row["swept"] == "-" else f" {row['swept']}"
    return textwrap.fill(f"{row['learner']}{swept} ({n} seed{'s' * (n != 1)})", LABEL_WIDTH)


def short_label(row: dict) -> str:
    """The right panel's name of a row: ``dqn trial 3`` for an Optuna trial, else the learner
    and the swept values by their last key part (``dqn lr=0.001``), at most ``SHORT_WIDTH``
    characters."""
    swept = [] if row["swept"] == "-" else row["swept"].split()
    trial = [t.split("=", 1)[1] for t in swept if t.startswith("trial=")]
    parts = [f"trial {trial[0]}"] if trial else [t.split("=", 1)[0].rsplit(".", 1)[-1] + "=" + t.split("=", 1)[-1]
                                                 for t in swept]
    text = " ".join([row["learner"], *parts])
    return text if len(text) <= SHORT_WIDTH else text[: SHORT_WIDTH - 3] + "..."


def _style(rank: int, many: bool) -> dict:
    """The drawing style of the row ranked ``rank``: its colour, or faded grey when many."""
    if many:
        return {"color": BEST_COLOUR, "lw": 2.2} if rank == 0 else dict(FADED)
    return {"color": f"C{rank}", "lw": 1.8}


def _others(rows: list[dict]) -> str:
    """``N other trials`` (an Optuna sweep's rows) or ``N other settings``."""
    trials = all("trial=" in r["swept"] for r in rows[1:])
    return f"{len(rows) - 1} other {'trials' if trials else 'settings'}"


def _learning(ax, rows: list[dict], x: str) -> tuple[set[float], list]:
    """The left panel: each row's training curve and band, and its greedy evaluations with
    their CI band (highlighted rows only); returns the thresholds seen and the legend's
    handles, best row first."""
    from matplotlib.lines import Line2D

    many, handles, thresholds = len(rows) > MANY_ROWS, [], set()
    measure = unit = window = None
    for rank, row in enumerate(rows):
        finished = [run for run in row["_runs"] if run["status"] == "ok"]
        thresholds.update(run["threshold"] for run in finished)
        curves = [c for c in (_curve(run, x) for run in finished) if c is not None]
        style, shown = _style(rank, many), not many or rank == 0
        if finished:
            measure, unit, window = (finished[0][k] for k in ("measure", "unit", "window"))
        if curves:
            grid, mean, low, high = mean_curve(curves)
            line, = ax.plot(grid, mean, gid=f"training:{label(row)}", zorder=3 if shown else 1, **style)
            if shown:
                ax.fill_between(grid, low, high, color=style["color"], alpha=0.12, lw=0)
                handles.append((line, label(row, len(curves))))
        if not shown:  # a faded row's evaluations are not drawn (its curve says enough)
            continue
        ex, centre, low, high = greedy_points([run_evaluations(run, x) for run in finished])
        if len(ex):
            ax.plot(ex, centre, "o--", ms=5, lw=1, color=style["color"], gid=f"greedy:{label(row)}", zorder=4)
            has_ci = ~np.isnan(low)
            ax.fill_between(ex, np.where(has_ci, low, centre), np.where(has_ci, high, centre),
                            color=style["color"], alpha=0.25, lw=0, gid=f"greedy_ci:{label(row)}")
    if many:
        handles.append((Line2D([], [], **FADED), _others(rows)))
    handles.append((Line2D([], [], color="k", lw=1.8),
                    f"training: mean of the last {window or 'window of'} episodes (mean over seeds, band min-max)"))
    handles.append((Line2D([], [], color="k", ls="--", marker="o", ms=5, lw=1),
                    "greedy evaluation (IQM over seeds, band 95% CI)"))
    ax.set_xlabel(X_LABELS[x])
    ax.set_ylabel(f"{measure} ({unit})" if measure and unit else (measure or "measure"))
    return {t for t in thresholds if np.isfinite(t)}, handles


def _headlines(ax, rows: list[dict], thresholds: set[float]) -> None:
    """The right panel: each row's headline IQM with its 95% CI, best at the top."""
    many = len(rows) > MANY_ROWS
    for rank, row in enumerate(rows):
        if math.isnan(row["iqm"]):
            continue
        colour = _style(rank, many)["color"]
        has_ci = not math.isnan(row["ci_low"])
        err = [[row["iqm"] - row["ci_low"]], [row["ci_high"] - row["iqm"]]] if has_ci else None
        ax.errorbar([row["iqm"]], [rank], xerr=err, fmt="o", ms=6 if rank == 0 or not many else 4,
                    capsize=4, lw=2 if rank == 0 or not many else 1, color=colour, gid=f"headline:{label(row)}")
    ax.set_yticks(range(len(rows)), [short_label(r) for r in rows], fontsize=8 if len(rows) <= 12 else 6)
    if many:
        ax.get_yticklabels()[0].set_color(BEST_COLOUR)
        ax.get_yticklabels()[0].set_fontweight("bold")
    ax.set_ylim(len(rows) - 0.4, -0.6)  # best at the top
    units = sorted({run["unit"] for r in rows for run in r["_runs"] if run["status"] == "ok"})
    unit = f" ({units[0]})" if len(units) == 1 and units[0] else ""
    ax.set_xlabel(f"{'; '.join(sorted({r['headline'] for r in rows if r['headline'] != '-'})) or 'headline'}{unit}")
    # The threshold is only named: drawn, it would squash the intervals of rows far from it.
    shown = "; ".join(f"{t:g}" for t in sorted(thresholds))
    ax.set_title(f"headline: IQM over seeds, 95% CI, best first"
                 f"{f' (threshold {shown})' if shown else ''}", fontsize=9)


def figure(rows: list[dict], x: str = "env_steps"):
    """The comparison's figure for the table's ``rows`` (one line of two panels per
    robot/task), the learning curves against ``x`` (``env_steps`` or ``wall_s``)."""
    if x not in X_AXES:
        raise ValueError(f"the comparison plot's x-axis must be one of {', '.join(X_AXES)}; got {x!r}")
    from matplotlib.figure import Figure  # not pyplot: no GUI backend, a tenth of a second less to the table

    pairs = sorted({r["robot/task"] for r in rows})
    heights = [max(5.5, 0.2 * len([r for r in rows if r["robot/task"] == p]) + 2.5) for p in pairs]
    fig = Figure(figsize=(15, sum(heights)))
    axes = fig.subplots(len(pairs), 2, squeeze=False,
                        gridspec_kw={"width_ratios": [2, 1], "height_ratios": heights})
    for (left, right), pair in zip(axes, pairs):
        mine = ranked([r for r in rows if r["robot/task"] == pair])
        thresholds, handles = _learning(left, mine, x)
        _headlines(right, mine, thresholds)
        for t in sorted(thresholds):
            handles.append((left.axhline(t, color="k", ls=":", lw=1.2), f"threshold {t:g}"))
        left.set_title(pair)
        # Below the panel: over it, a legend would hide the curves it names.
        left.legend(*zip(*handles), loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, fontsize=8,
                    frameon=False)
    fig.tight_layout()
    return fig


def plot(sweep_dir: Path, rows: list[dict], x: str = "env_steps") -> Path:
    """Draws ``sweep_dir/comparison.png`` from the table's ``rows`` (:func:`figure`); returns its path."""
    fig = figure(rows, x)
    out = Path(sweep_dir) / "comparison.png"
    fig.savefig(out, dpi=100)
    return out
