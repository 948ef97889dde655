"""The benchmark page's figures: per task, each learner's sample efficiency in a panel of its
own (the greedy evaluations against env steps: IQM across seeds with its interval band,
:func:`sweeps.comparison_plot.greedy_points`; a dozen curves on one axis could not be read)
and every row's final greedy measure (IQM over seeds with its 95% bootstrap interval)
beside them, the task's threshold dashed; a learner keeps its colour throughout, its
published settings drawn dashed and hollow, its tuned ones solid. Drawn from the seeds' rows (``evaluations``: each run's
``evals.csv``, kept in the pair's record when its folders are gone).
"""

from __future__ import annotations

import math
from pathlib import Path

from sweeps.comparison_plot import greedy_points


def styles(task: str, pairs: list[dict]) -> dict[tuple[str, str], tuple[str, str]]:
    """Per learner x setting of ``task``: (colour, line style). A learner's colour is its
    place on the page (up to ten learners apart); published dashed, tuned solid."""
    learners = list(dict.fromkeys(p["learner"] for p in pairs if p["task"] == task))
    return {(p["learner"], p["setting"]): (f"C{learners.index(p['learner']) % 10}",
                                           "--" if p["setting"] == "published" else "-")
            for p in pairs if p["task"] == task}


def draw(task: str, pairs: list[dict], seeds: list[dict], path: Path) -> Path | None:
    """Writes ``path`` (a PNG) for ``task``'s rows: one sample-efficiency panel per learner
    (its settings, published dashed and tuned solid, on shared axes), and the final measures
    of every row beside them; None when no row has a greedy measure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker  # noqa: F401 - matplotlib.ticker below

    rows = [p for p in pairs if p["task"] == task and p["greedy_iqm"] is not None
            and math.isfinite(p["greedy_iqm"])]  # not a pair not run, nor one whose seeds are all still running
    if not rows:
        return None
    rows.sort(key=lambda p: p["greedy_iqm"])
    threshold = next((s["threshold"] for s in seeds if s["task"] == task and s["threshold"] is not None), None)
    measure = rows[0]["measure"] or "measure"
    style = styles(task, pairs)
    learners = list(dict.fromkeys(p["learner"] for p in rows))
    columns = min(3, len(learners))
    lines = -(-len(learners) // columns)
    fig = plt.figure(figsize=(5 * columns + 6, 3.6 * lines + 1.2))
    grid = fig.add_gridspec(lines, columns + 1, width_ratios=[1] * columns + [1.25])
    panels = {}
    for i, learner in enumerate(learners):
        share = next(iter(panels.values()), None)
        panels[learner] = fig.add_subplot(grid[i // columns, i % columns], sharex=share, sharey=share)
    bars = fig.add_subplot(grid[:, columns])
    for p in rows:
        mine = [s for s in seeds if s["task"] == task and s["learner"] == p["learner"] and s["setting"] == p["setting"]
                and s["status"] == "ok"]
        x, centre, low, high = greedy_points([[tuple(point) for point in s.get("evaluations", [])] for s in mine])
        if len(x):
            colour, dashes = style[p["learner"], p["setting"]]
            axis = panels[p["learner"]]
            axis.plot(x, centre, label=f"{p['setting']} {p['success']}/{p['seeds']}", color=colour, lw=1.8, ls=dashes)
            axis.fill_between(x, low, high, color=colour, alpha=0.15)
    thousands = matplotlib.ticker.FuncFormatter(lambda v, _: f"{v / 1000:g}k" if v else "0")
    for learner, axis in panels.items():
        axis.xaxis.set_major_formatter(thousands)
        if threshold is not None:
            axis.axhline(threshold, ls="--", color="0.4", lw=1)
        axis.grid(alpha=0.3)
        axis.set_title(learner, fontsize=12)
        axis.legend(fontsize=9, loc="best")
        axis.set_xlabel("env steps (all copies)", fontsize=9)
        axis.set_ylabel(f"greedy {measure}", fontsize=9)
    for y, p in enumerate(rows):
        low, high = p["ci_low"], p["ci_high"]
        centre = p["greedy_iqm"]
        err = [[centre - low], [high - centre]] if low is not None and high is not None else None
        colour, dashes = style[p["learner"], p["setting"]]
        bars.errorbar([centre], [y], xerr=err, fmt="o", color=colour, capsize=3,
                      mfc="white" if dashes == "--" else colour)
    bars.set_yticks(range(len(rows)), [f"{p['learner']} ({p['setting']}) {p['success']}/{p['seeds']}"
                                       for p in rows], fontsize=10)
    if threshold is not None:
        bars.axvline(threshold, ls="--", color="0.4", lw=1)
    bars.grid(alpha=0.3)
    bars.set(xlabel=f"final greedy {measure}: IQM, 95% CI", title="at the end (seeds over the threshold)")
    fig.suptitle(f"{task}: greedy {measure} against env steps (IQM over seeds, 95% CI band; dashed: the threshold)",
                 fontsize=13)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path
