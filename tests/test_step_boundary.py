"""A step boundary with nothing due is ended quietly (``Run.end_quiet_step``), and only then:
what a run does at its boundaries is the same whether the loop took the quiet way or not."""

from __future__ import annotations

import numpy as np
import pytest

from runs.run import TRAIN_LOG_STEPS, Hooks, Run
from tasks.base import Success

SUCCESS = Success(measure="length", unit="steps", description="steps balanced", threshold=1e9, window=5,
                  min_episodes=5)
RESULT = {"episodes": 2, "mean_length": 3.0, "std_length": 0.0, "mean_return": 3.0, "std_return": 0.0,
          "lengths": [3, 3], "returns": [3.0, 3.0], "info": {}, "info_mean": {}}


class Logger:
    """Keeps every batch of scalars with its step."""

    def __init__(self, calls: list) -> None:
        self.calls = calls

    def log_metrics(self, scalars: dict, step: int) -> None:
        self.calls.append(("log", step, tuple(sorted(scalars))))

    def close(self) -> None:
        pass


class Report:
    """A tuning trial's link: keeps each report; prunes the run at ``prune_at`` env steps
    (another seed's report, seen at any step)."""

    def __init__(self, calls: list, every: int, prune_at: int) -> None:
        self.calls, self.every, self.prune_at, self.steps = calls, every, prune_at, 0

    @property
    def pruned(self) -> bool:
        return self.steps >= self.prune_at

    def __call__(self, env_steps: int, rolling: float) -> bool:
        self.calls.append(("report", env_steps))
        return False

    def solved(self, env_steps: int, value: float) -> None:
        self.calls.append(("solved", env_steps))


def drive(folder, quiet: bool, seed: int, prune_at: int, stop_at: int) -> list:
    """A run of two copies whose episodes end at random steps, every boundary hook recorded;
    ``quiet``: a step that finished no episode ends as the training loop ends it."""
    calls: list = []
    report = Report(calls, every=70, prune_at=prune_at)
    run = Run(folder, 2, 0, SUCCESS, quiet=True, logger=Logger(calls), eval_every=7, eval_every_steps=90,
              checkpoint_every=3, max_env_steps=2 * 1500, stop_when_solved=False,
              hooks=Hooks(checkpoint=lambda r, td: calls.append(("checkpoint", r.env_steps)),
                          greedy_eval=lambda k: calls.append(("eval", k)) or RESULT,
                          train_stats=lambda reset=True: calls.append(("stats", reset)) or {"loss": 1.0},
                          progress=report))
    rng = np.random.default_rng(seed)
    td = None  # the next step's input: no env here
    while not run.done:
        done = rng.random(2) < (0.04 if run.env_steps < 300 else 0.0005)  # then long stretches
        report.steps = run.env_steps
        if run.env_steps >= stop_at:
            run.request_stop()
        if done.any():
            run.record(np.ones(2), done, done)
        else:
            run.episodes.step(np.ones(2))
        if not (quiet and not done.any() and run.end_quiet_step(td)):
            run.end_step(td)
    calls.append(("end", run.env_steps, run.n_episodes, len(run.evals), run.pruned_at))
    run.close()
    return calls


@pytest.mark.parametrize("prune_at, stop_at", [(10**9, 10**9), (2 * 1233, 10**9), (10**9, 2 * 1311)])
def test_a_quiet_boundary_does_what_a_full_one_would(tmp_path, prune_at, stop_at):
    """Every log point (train/* at least every TRAIN_LOG_STEPS env steps and after each
    finished episode), progress report, evaluation (by episodes and by env steps),
    checkpoint, prune and stop falls at the same step either way."""
    assert TRAIN_LOG_STEPS < 2 * 1500  # the budget spans train/* points made by env steps alone
    for seed in range(3):
        full = drive(tmp_path / f"full{seed}", False, seed, prune_at, stop_at)
        quiet = drive(tmp_path / f"quiet{seed}", True, seed, prune_at, stop_at)
        assert quiet == full
        assert {c[0] for c in full} >= {"log", "report", "eval", "checkpoint", "stats", "end"}
        steps = [c[1] for c in full if c[0] == "log" and c[2] == ("train/loss",)]
        assert any(b - a >= TRAIN_LOG_STEPS for a, b in zip(steps, steps[1:]))  # a point by env steps alone
