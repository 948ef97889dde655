"""comparison.png a person can read: learning curves against env steps (or wall time), the
greedy evaluations across seeds with their CI band, the threshold, rows ranked by the
task's own headline, and an Optuna sweep's many trials faded behind its best one.

The figure is inspected as matplotlib objects (axes, lines, legend), never as pixels; the
sweeps are fake job folders as train.py writes them."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import matplotlib
import numpy as np
import pytest

import compare
from sweeps import comparison
from sweeps.comparison_plot import BEST_COLOUR, FADED, figure, greedy_points

matplotlib.use("Agg")
EPISODES = 40
EVAL_EVERY = 10


def write_job(sweep: Path, num: int, learner: str, seed: int, final: float, swept: list[str] = ()) -> Path:
    """A finished cart-pole job: episodes of 25 to 50 env steps, its rolling mean rising to
    ``final``, a greedy evaluation every ``EVAL_EVERY`` episodes (measure ``2 * rolling``)."""
    job = sweep / f"{num}_cartpole_{learner}_seed{seed}"
    job.mkdir(parents=True)
    overrides = [f"learner={learner}", f"seed={seed}", *swept]
    (job / "run.json").write_text(json.dumps({"robot": "cartpole", "task": "stay_up", "learner": learner,
                                              "seed": seed, "overrides": overrides}))
    steps = np.cumsum([25 + 25 * ((i * (seed + 1)) % 2) for i in range(1, EPISODES + 1)])
    rolling = [final * i / EPISODES for i in range(1, EPISODES + 1)]
    with open(job / "metrics.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["episode", "env_index", "reward", "length", "terminated", "env_steps", "length_mean100"])
        w.writerows([i, 0, r, r, 1, s, r] for i, (s, r) in enumerate(zip(steps, rolling), 1))
    with open(job / "timing.csv", "w", newline="") as f:
        csv.writer(f).writerows([["episode", "wall_s"], *([i, 0.5 * i] for i in range(1, EPISODES + 1))])
    with open(job / "evals.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["episode", "env_steps", "episodes", "length", "return"])
        w.writerows([e, steps[e - 1], 5, 2 * rolling[e - 1], 2 * rolling[e - 1]]
                    for e in range(EVAL_EVERY, EPISODES + 1, EVAL_EVERY))
    (job / "summary.json").write_text(json.dumps({
        "solved": False, "decided_by": "training", "episodes": EPISODES, "solved_at": None, "measure": "length",
        "unit": "steps", "description": "steps balanced", "threshold": 250.0, "judge": "training", "window": 100,
        "min_episodes": 100, "judged_length": final, "train_return_mean": final / 2, "train_return_last100": final,
        "train_length_best_rolling100": final, "train_length_last100": final, "train_length_best100_mean": final,
        "greedy_length": 2 * final, "greedy_return": 2 * final, "evaluations": 4,
        "env_steps": int(steps[-1]), "wall_s": 0.5 * EPISODES, "divergences": 0}))
    return job


def rows_of(sweep: Path) -> list[dict]:
    rows, _ = comparison.compare(sweep)
    return rows


@pytest.fixture
def two_learners(tmp_path) -> list[dict]:
    """qlearn (seeds ending at 100, 110, 120) and dqn (150, 160, 170): dqn is the better."""
    num = 0
    for learner, base in (("qlearn", 100.0), ("dqn", 150.0)):
        for seed in range(3):
            write_job(tmp_path, num, learner, seed, base + 10 * seed)
            num += 1
    return rows_of(tmp_path)


def by_gid(ax, prefix: str) -> list:
    return [a for a in [*ax.lines, *ax.collections] if (a.get_gid() or "").startswith(prefix)]


def test_curves_are_against_env_steps_with_greedy_points_and_the_threshold(two_learners):
    fig = figure(two_learners)
    left, right = fig.axes
    assert left.get_xlabel().startswith("env steps")
    assert left.get_ylabel() == "length (steps)"
    training = by_gid(left, "training:")
    assert len(training) == 2
    longest = max(np.cumsum([25 + 25 * ((i * (s + 1)) % 2) for i in range(1, EPISODES + 1)])[-1] for s in range(3))
    assert max(line.get_xdata().max() for line in training) == pytest.approx(longest)
    greedy = by_gid(left, "greedy:")
    assert len(greedy) == 2 and all(len(line.get_xdata()) == EPISODES // EVAL_EVERY for line in greedy)
    dqn = next(line for line in greedy if "dqn" in line.get_gid())
    assert dqn.get_ydata()[-1] == pytest.approx(2 * 160.0)  # the IQM of the seeds' final evaluations
    assert len(by_gid(left, "greedy_ci:")) == 2  # the CI bands
    assert any(list(line.get_ydata()) == [250, 250] for line in left.lines)  # the threshold
    texts = [t.get_text() for t in left.get_legend().get_texts()]
    assert texts[:2] == ["dqn (3 seeds)", "qlearn (3 seeds)"]  # best first
    assert "greedy evaluation (IQM over seeds, band 95% CI)" in texts and "threshold 250" in texts
    assert [t.get_text() for t in right.get_yticklabels()] == ["dqn", "qlearn"]
    assert right.get_xlabel() == "train_length_last100 (steps)"


def test_wall_time_is_the_other_x_axis(two_learners, tmp_path):
    fig = figure(two_learners, x="wall_s")
    left = fig.axes[0]
    assert left.get_xlabel() == "wall time (s)"
    assert max(line.get_xdata().max() for line in by_gid(left, "training:")) == pytest.approx(0.5 * EPISODES)
    greedy = by_gid(left, "greedy:")[0]
    assert greedy.get_xdata()[0] == pytest.approx(0.5 * EVAL_EVERY)  # the wall time of its episode


def test_an_unknown_x_axis_is_one_line(two_learners, tmp_path, capsys):
    with pytest.raises(ValueError, match=r"^the comparison plot's x-axis must be one of env_steps, wall_s; "
                                         r"got 'steps'$"):
        figure(two_learners, x="steps")
    with pytest.raises(SystemExit) as stop:
        compare.main([str(tmp_path), "--x", "steps"])
    assert stop.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "invalid choice: 'steps'" in err[0]
    assert compare.main([str(tmp_path), "--x", "wall_s"]) == 0 and (tmp_path / "comparison.png").is_file()


def test_many_trials_fade_behind_the_best_and_the_legend_stays_short(tmp_path):
    """Nine trials of an Optuna sweep, two seeds each: trial 4 is the best."""
    finals = [60, 80, 40, 90, 150, 70, 50, 30, 100]
    num = 0
    for trial, final in enumerate(finals):
        for seed in range(2):
            write_job(tmp_path, num, "qlearn", seed, float(final + seed),
                      [f"learner.alpha=0.{trial + 1}", f"trial={trial}"])
            num += 1
    fig = figure(rows_of(tmp_path))
    left, right = fig.axes
    training = by_gid(left, "training:")
    assert len(training) == 9
    coloured = [line for line in training if line.get_color() != FADED["color"]]
    assert len(coloured) == 1 and "trial=4" in coloured[0].get_gid() and coloured[0].get_color() == BEST_COLOUR
    faded = [line for line in training if line.get_color() == FADED["color"]]
    assert len(faded) == 8 and all(line.get_linewidth() < coloured[0].get_linewidth() for line in faded)
    assert len(by_gid(left, "greedy:")) == 1  # the best trial's evaluations only
    texts = [t.get_text() for t in left.get_legend().get_texts()]
    assert "8 other trials" in texts
    assert sum("trial=" in t for t in texts) == 1 and "trial=4" in texts[0]
    ticks = [t.get_text() for t in right.get_yticklabels()]
    assert ticks == [f"qlearn trial {t}" for t in np.argsort(finals)[::-1]]  # best first
    assert right.get_yticklabels()[0].get_color() == BEST_COLOUR


def test_greedy_points_take_every_seed_at_the_same_env_steps():
    """Seeds evaluate at different env steps: at the mean x of the k-th evaluations (the last
    at the last one's x), each seed counts with its measure interpolated there, held after its
    last evaluation, not before its first."""
    x, centre, low, high = greedy_points([[(100, 1.0), (200, 2.0), (300, 3.0)], [(120, 2.0), (260, 4.0)],
                                          [(90, 0.0)]])
    assert list(x) == pytest.approx([(100 + 120 + 90) / 3, 230.0, 300.0])
    b_at_230 = 2.0 + 2.0 * (230 - 120) / (260 - 120)
    assert list(centre) == pytest.approx([(1 + 1 / 30) / 2, (2.3 + b_at_230 + 0.0) / 3, (3.0 + 4.0 + 0.0) / 3])
    assert all(lo <= c <= hi for lo, c, hi in zip(low, centre, high))
    x, centre, low, high = greedy_points([[(100, 5.0)]])
    assert list(centre) == [5.0] and np.isnan(low[0]) and np.isnan(high[0])  # one seed: no interval
    assert all(len(a) == 0 for a in greedy_points([[], []]))
