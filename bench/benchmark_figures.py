"""The benchmark page's figures: per task, each learner x setting's final greedy measure (IQM
over seeds with its 95% bootstrap interval) and its sample efficiency (the greedy evaluations
against env steps: IQM across seeds with its interval band, :func:`sweeps.comparison_plot.greedy_points`),
the task's threshold dashed; a learner keeps its colour in both panels, its published
settings drawn dashed and hollow, its tuned ones solid. Drawn from the seeds' rows (``evaluations``: each run's
``evals.csv``, kept in the pair's record when its folders are gone).
"""

from __future__ import annotations

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
    """Writes ``path`` (a PNG) for ``task``'s rows; None when no row has a greedy measure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [p for p in pairs if p["task"] == task and p["greedy_iqm"] is not None]
    if not rows:
        return None
    rows.sort(key=lambda p: p["greedy_iqm"])
    threshold = next((s["threshold"] for s in seeds if s["task"] == task and s["threshold"] is not None), None)
    measure = rows[0]["measure"] or "measure"
    style = styles(task, pairs)
    fig, (curves, bars) = plt.subplots(1, 2, figsize=(13, 0.35 * len(rows) + 3.5), width_ratios=(1.6, 1))
    for p in reversed(rows):
        label = f"{p['learner']} ({p['setting']})"
        mine = [s for s in seeds if s["task"] == task and s["learner"] == p["learner"] and s["setting"] == p["setting"]
                and s["status"] == "ok"]
        x, centre, low, high = greedy_points([[tuple(point) for point in s.get("evaluations", [])] for s in mine])
        if len(x):
            colour, dashes = style[p["learner"], p["setting"]]
            curves.plot(x, centre, label=label, color=colour, lw=1.5, ls=dashes)
            curves.fill_between(x, low, high, color=colour, alpha=0.12)
    for y, p in enumerate(rows):
        low, high = p["ci_low"], p["ci_high"]
        centre = p["greedy_iqm"]
        err = [[centre - low], [high - centre]] if low is not None and high is not None else None
        colour, dashes = style[p["learner"], p["setting"]]
        bars.errorbar([centre], [y], xerr=err, fmt="o", color=colour, capsize=3,
                      mfc="white" if dashes == "--" else colour)
    bars.set_yticks(range(len(rows)), [f"{p['learner']} ({p['setting']}) {p['success']}/{p['seeds']}"
                                       for p in rows], fontsize=8)
    for axis in (curves, bars):
        if threshold is not None:
            (axis.axhline if axis is curves else axis.axvline)(threshold, ls="--", color="0.4", lw=1)
        axis.grid(alpha=0.3)
    curves.set(xlabel="env steps (all copies)", ylabel=f"greedy {measure} (IQM over seeds, 95% CI)",
               title=f"{task}: sample efficiency")
    curves.legend(fontsize=7, loc="best")
    bars.set(xlabel=f"final greedy {measure}: IQM, 95% CI", title="at the end (success: seeds over the threshold)")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
