"""One meaning for each number: every number a run reports is named for what it is
(``train_return_mean``, ``train_<measure>_last<window>``, ``greedy_<measure>``, ...), the
same in summary.json, the verdict and its VERDICT line, the loggers' ``run/*`` scalars and
the Optuna objective; no user-facing file says a bare "score"."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from params import ConfigError
from runs.loggers import finish_log, make_logger, run_scalar_names
from runs.run import Run
from runs.summary import measure_keys
from runs.summary import verdict_lines
from tasks.base import Success

ROOT = Path(__file__).resolve().parents[1]
# A task measure other than the length, judged over a window other than 100: both must show in the names.
WALK = Success("distance_walked", "m", "distance walked towards +y", 1.0, judge="greedy", window=4, min_episodes=1)
NUMBERS = {"judged_distance_walked", "train_return_mean", "train_return_last100",
           "train_distance_walked_best_rolling4", "train_distance_walked_last4",
           "train_distance_walked_best100_mean", "greedy_distance_walked", "greedy_return"}
GENERIC = {"solved", "decided_by", "episodes", "solved_at", "measure", "unit", "description", "threshold",
           "judge", "window", "min_episodes", "evaluations", "env_steps", "wall_s", "process_s", "divergences",
           "first_step_s", "rate", "greedy_rate", "eval_episodes", "start_level", "stuck_steps", "stuck"}


def feed(run: Run, episodes: list[tuple[int, float, float]]) -> None:
    """One-copy episodes ``(length, reward per step, distance walked)``, as the env reports them."""
    for length, reward, walked in episodes:
        for t in range(1, length + 1):
            end = np.array([t == length])
            run.record(np.array([reward]), end, end, ended_info={"distance_walked": np.array([walked])})


EPISODES = [(10, 1.0, 0.1), (20, 0.5, 0.4), (5, 2.0, 0.2), (8, 1.0, 0.9), (12, -1.0, 0.3), (6, 3.0, 0.5)]


def walked_run(tmp_path: Path) -> Run:
    """Six episodes of known returns and distances, then a greedy evaluation (2.5 m, return 7)
    and its confirmation (the same)."""
    run = Run(tmp_path, 1, 100, WALK, quiet=True)
    feed(run, EPISODES)
    for _ in range(2):
        run.record_evaluation({"episodes": 3, "mean_length": 30.0, "mean_return": 7.0,
                               "info_mean": {"distance_walked": 2.5}, "info": {"distance_walked": [2.0, 2.5, 3.0]}})
    return run


def test_summary_json_names_every_number_for_what_it_is(tmp_path):
    run = walked_run(tmp_path)
    s = run.close()
    assert set(s) == NUMBERS | GENERIC
    assert not [key for key in s if "score" in key]
    returns = [length * reward for length, reward, _ in EPISODES]
    walked = [w for _, _, w in EPISODES]
    assert s["train_return_mean"] == pytest.approx(np.mean(returns))
    assert s["train_return_last100"] == pytest.approx(np.mean(returns))  # fewer than 100 episodes: all
    assert s["train_distance_walked_last4"] == pytest.approx(np.mean(walked[-4:]))
    assert s["train_distance_walked_best_rolling4"] == pytest.approx(
        max(np.mean(walked[i:i + 4]) for i in range(3)))
    assert s["train_distance_walked_best100_mean"] == pytest.approx(np.mean(walked))
    assert (s["greedy_distance_walked"], s["greedy_return"]) == (2.5, 7.0)
    assert s["judged_distance_walked"] == 2.5 and s["solved"]  # the greedy judge: 2.5 m >= 1 m
    assert set(measure_keys("distance_walked", 4).numbers()) == NUMBERS


def test_the_verdict_and_its_verdict_line_use_the_same_names(tmp_path):
    s = walked_run(tmp_path).close()
    lines = verdict_lines(s, tmp_path)
    fields = dict(field.split("=", 1) for field in lines[-1].split()[1:])
    assert lines[-1].startswith("VERDICT ")
    assert set(fields) == {"solved", "episodes", "solved_at", "measure", "judge", "judged_distance_walked",
                           "threshold", "train_distance_walked_best_rolling4", "train_distance_walked_last4",
                           "greedy_distance_walked", "train_return_mean", "greedy_return", "greedy_rate", "rate",
                           "wall_s", "process_s", "run_dir"}
    assert set(fields) - {"run_dir"} <= set(s)  # every field is summary.json's, by the same name
    assert fields["greedy_distance_walked"] == "2.5" and fields["solved_at"] == "6"
    text = "\n".join(lines)
    for name in NUMBERS:  # the human lines name every number too
        assert f"{name} " in text or f"{name}=" in text, name
    assert not re.search(r"\bscores?\b", text, re.I)


def test_the_loggers_run_scalars_are_the_summarys_names(tmp_path):
    """The CSV logger's run/* files: one per summary number (by its summary.json name), the counts."""
    s = walked_run(tmp_path).close()
    logger = make_logger("csv", tmp_path, exp_name="run")
    finish_log(logger, s)
    logged = {p.stem for p in (tmp_path / "logs" / "run" / "scalars" / "run").glob("*.csv")}
    assert logged == {n.split("/", 1)[1] for n in run_scalar_names("distance_walked", 4)}
    assert logged == (NUMBERS - {"judged_distance_walked"}) | {"env_steps", "episodes", "wall_s", "divergences",
                                                                 "solved"}
    value = (tmp_path / "logs" / "run" / "scalars" / "run" / "greedy_distance_walked.csv").read_text()
    assert value.strip().split(",")[-1] == "2.5"


def test_a_run_without_a_greedy_evaluation_logs_no_greedy_number(tmp_path):
    run = Run(tmp_path, 1, 100, WALK, quiet=True)
    feed(run, EPISODES)
    s = run.close()
    assert s["greedy_distance_walked"] is None and s["greedy_return"] is None
    logger = make_logger("csv", tmp_path, exp_name="run")
    finish_log(logger, s)
    logged = {p.stem for p in (tmp_path / "logs" / "run" / "scalars" / "run").glob("*.csv")}
    assert "greedy_return" not in logged and "train_return_mean" in logged
    assert "greedy_distance_walked -" in "\n".join(verdict_lines(s, tmp_path))


def test_a_checkpoint_saved_before_the_returns_were_kept_reads_them_from_metrics_csv(tmp_path):
    run = walked_run(tmp_path)
    state = run.state_dict()
    run.files.close()
    del state["returns"]  # as an older version saved it
    resumed = Run(tmp_path, 1, 100, WALK, quiet=True, resume=True)
    resumed.load_state_dict(state)
    assert list(resumed.returns) == [length * reward for length, reward, _ in EPISODES]
    resumed.files.close()
    short = Run(tmp_path / "other", 1, 100, WALK, quiet=True, resume=True)
    with pytest.raises(ValueError, match="metrics.csv is unreadable|episode rows"):
        short.load_state_dict(state)


# -- the Optuna objective -------------------------------------------------------------------
# Its value per job is runs.summary.success_and_speed (tests/test_tune.py); its name is the
# study's metric name, and a study of another is refused.
def test_the_study_is_named_for_its_objective_and_refuses_another(tmp_path):
    from sweeps.optuna_sweep import TuningSweep
    from sweeps.tuning import Plan

    def opened(measure: str, objective: str):
        sweep = TuningSweep(study="s", storage=f"sqlite:///{tmp_path / 's.db'}", pruner=None)
        sweep._check_settings()
        plan = Plan("cube", "one_disk_walk", "qlearn", [], [], Path("space.yaml"), {}, measure, objective)
        return sweep._open_study(plan)

    assert opened("distance_walked", "greedy_distance_walked").metric_names == ["greedy_distance_walked"]
    assert opened("distance_walked", "greedy_distance_walked").user_attrs["measure"] == "distance_walked"
    with pytest.raises(ConfigError, match="maximizes greedy_distance_walked, this run's objective is "
                                          "train_distance_walked_last100: name another study"):
        opened("distance_walked", "train_distance_walked_last100")


# -- no bare "score" where a user reads ---------------------------------------------------------
USER_FACING = ["README.md", "docs/**/*.md", "train.py", "compare.py", "runs/**/*.py", "sweeps/**/*.py", "hydra_plugins/**/*.py",
               "conf/hydra/**/*.yaml", "conf/config.yaml"]
# (file, text on the line): where "score" names something else, and why.
ALLOWED = [
    ("runs/summary.py", "``score``) read the same"),  # the old summary.json key, mapped on read
    ("docs/solved.md", "also one written before these names (`score`,"),  # the same
]
SCORE = re.compile(r"\bscor(e|es|ed|ing)\b", re.I)


def test_no_user_facing_file_says_score():
    files = sorted({p for pattern in USER_FACING for p in ROOT.glob(pattern) if p.is_file()})
    assert len(files) > 20  # the globs found the project
    found = []
    for path in files:
        rel = path.relative_to(ROOT).as_posix()
        for n, line in enumerate(path.read_text().splitlines(), 1):
            if SCORE.search(line) and not any(rel == f and text in line for f, text in ALLOWED):
                found.append(f"{rel}:{n}: {line.strip()}")
    assert not found, "\n".join(found)


def test_the_docs_name_what_the_code_logs():
    """The docs' loggers table lists the run/* scalars by their patterns, and their verdict
    example's VERDICT line has the code's field names."""
    row = next(line for line in (ROOT / "docs" / "loggers.md").read_text().splitlines()
               if line.startswith("| `run/*`"))
    for name in ("train_return_mean", "train_return_last100", "train_<measure>_best_rolling<window>",
                 "train_<measure>_last<window>", "train_<measure>_best100_mean", "greedy_<measure>",
                 "greedy_return"):
        assert f"`{name}`" in row, name
    example = next(line for line in (ROOT / "docs" / "solved.md").read_text().splitlines()
                   if line.strip().startswith("VERDICT "))
    fields = [field.split("=", 1)[0] for field in example.split()[1:]]
    k = measure_keys("length", 100)
    assert fields == ["solved", "episodes", "solved_at", "measure", "judge", k.judged, "threshold",
                      k.train_best_rolling, k.train_last, k.greedy, k.train_return_mean, k.greedy_return,
                      "greedy_rate", "rate", "wall_s", "process_s", "run_dir"]
    assert not math.isnan(float(dict(f.split("=", 1) for f in example.split()[1:])[k.greedy]))
