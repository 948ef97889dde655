"""The reward curve (runs/plot.py): its panels and labels drawn inside the figure."""

from __future__ import annotations

from pathlib import Path

from runs.plot import reward_curve
from tasks.base import Success


def test_a_long_measure_label_wraps_within_its_panel(tmp_path: Path):
    """A task's long description (the pendulum's held share: 97 characters) labels its
    panel on lines that stay beside the panel, not over the one below."""
    rows = ["episode,env_index,reward,length,terminated,env_steps,held,held_mean100"]
    rows += [f"{e},0,{1 + e / 100},100,0,{100 * e},{e % 2},{0.5}" for e in range(1, 41)]
    (tmp_path / "metrics.csv").write_text("\n".join(rows) + "\n")
    (tmp_path / "evals.csv").write_text("episode,env_steps,held,episodes,length,return,rate\n"
                                        "20,2000,0.5,20,100.0,1.2,0.5\n")
    success = Success("held", "", "share of episodes ending with the pole within 15 degrees of vertical "
                                  "(90 % of the last 2 s)", 0.9, judge="greedy", min_episodes=0)
    fig = reward_curve(tmp_path / "metrics.csv", success, tmp_path / "evals.csv", "run")
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig).draw()  # as savefig draws a PNG
    axes = fig.axes
    assert [ax.get_ylabel().split("\n")[0] for ax in axes] == [
        "share of episodes ending with the", "episode length (steps)", "episode return"]
    renderer = fig.canvas.get_renderer()
    for ax in axes:
        label, panel = ax.yaxis.label.get_window_extent(renderer), ax.get_window_extent(renderer)
        assert label.y0 >= panel.y0 - 1 and label.y1 <= panel.y1 + 1, ax.get_ylabel()
        assert label.x0 >= 0
