"""train.py end to end: run folder, verdict line, loading a model, one-line errors."""

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

from inprocess import run_train

ROOT = Path(__file__).resolve().parents[1]


def train(tmp_path: Path, *overrides: str, name: str = "run") -> subprocess.CompletedProcess:
    """``train.py`` in this process (tests/inprocess.py); the run folder test starts a real one."""
    return run_train(f"hydra.run.dir={tmp_path / name}", "quiet=true", *overrides)


def train_process(tmp_path: Path, *overrides: str, name: str = "run") -> subprocess.CompletedProcess:
    """``python train.py`` in a fresh interpreter: the wiring end to end."""
    cmd = [sys.executable, "train.py", f"hydra.run.dir={tmp_path / name}", "quiet=true", *overrides]
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    return subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600, env=env)


def verdict(stdout: str) -> dict:
    last = stdout.strip().splitlines()[-1]
    assert last.startswith("VERDICT "), last
    return dict(field.split("=", 1) for field in last.split()[1:])


@pytest.fixture(scope="module")
def short_run(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("train")
    proc = train_process(tmp, "max_episodes=30", "eval_episodes=3", "seed=1")
    assert proc.returncode == 0, proc.stderr[-2000:]
    return tmp, proc


def test_run_folder_and_verdict(short_run):
    tmp, proc = short_run
    run_dir = tmp / "run"
    v = verdict(proc.stdout)
    assert v["solved"] == "false" and v["episodes"] == "30"
    assert (v["measure"], v["judge"], v["threshold"]) == ("length", "training", "250")
    assert Path(v["run_dir"]) == run_dir
    assert "not solved after 30 episodes: needs steps balanced >= 250 steps" in proc.stdout
    assert "greedy evaluation over 3 episodes: steps balanced" in proc.stdout
    for name in ("config.yaml", "metrics.csv", "timing.csv", "reward_curve.png", "model.pt",
                 "checkpoint.pt", "eval.json", "evals.csv", "success.json", "summary.json"):
        assert (run_dir / name).stat().st_size > 0, name
    rows = list(csv.DictReader(open(run_dir / "metrics.csv")))
    assert [int(r["episode"]) for r in rows] == list(range(1, 31))
    assert {"alpha", "gamma", "epsilon", "reward", "length"} <= set(rows[0])
    assert (run_dir / "reward_curve.png").read_bytes()[:4] == b"\x89PNG"
    assert "learner:" in (run_dir / "config.yaml").read_text()


def test_summary_json_and_the_verdict_line_name_every_number_alike(short_run):
    """summary.json's numbers and the VERDICT line's, by the same names (runs.summary), none a
    bare "score"; the verdict's own lines name them too."""
    import json

    from runs.summary import measure_keys

    tmp, proc = short_run
    summary = json.loads((tmp / "run" / "summary.json").read_text())
    k = measure_keys("length", 100)
    assert set(k.numbers()) <= set(summary) and not [key for key in summary if "score" in key]
    fields = verdict(proc.stdout)
    assert {k.judged, k.train_best_rolling, k.train_last, k.greedy, k.train_return_mean, k.greedy_return} <= set(fields)
    for name in (k.train_last, k.greedy, k.greedy_return, k.train_return_mean):
        assert fields[name] == f"{summary[name]:.4g}", name
    assert f"{k.train_best100_mean} " in proc.stdout and f"{k.train_return_last100} " in proc.stdout
    assert "score" not in proc.stdout


def test_saved_model_loads_for_eval_and_training(short_run):
    tmp, _ = short_run
    model = tmp / "run" / "model.pt"
    proc = train(tmp, "mode=eval", f"checkpoint={model}", "eval_episodes=2", name="eval")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "greedy evaluation over 2 episodes" in proc.stdout
    # Issue 67: an evaluation folder says what it is, with its own verdict, and compare.py lists it apart.
    fields = verdict(proc.stdout)
    assert fields["mode"] == "eval" and fields["checkpoint"] == str(model) and fields["episodes"] == "2"
    assert fields["passed"] in ("true", "false") and float(fields["greedy_rate"]) in (0.0, 0.5, 1.0)
    import json

    assert json.loads((tmp / "eval" / "run.json").read_text())["mode"] == "eval"
    assert not (tmp / "eval" / "summary.json").exists()  # not a training run
    import compare

    assert compare.main([str(tmp)]) == 0  # the folder of both: the run compared, the evaluation apart
    listed = (tmp / "comparison.md").read_text()
    assert f"evaluation (mode=eval, not a training run): {tmp / 'eval'}: " in listed
    assert f"failed: {tmp / 'eval'}" not in listed
    proc = train(tmp, f"checkpoint={model}", "max_episodes=5", "eval_episodes=0", name="more")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert verdict(proc.stdout)["episodes"] == "5"


def test_config_dir_goes_anywhere_on_the_command_line(short_run, tmp_path):
    """``--config-dir`` before, between or after the overrides, for training and evaluation."""
    tmp, _ = short_run
    mine = tmp_path / "mine"
    (mine / "learner").mkdir(parents=True)
    for i, args in enumerate((["--config-dir", str(mine), "mode=eval", f"checkpoint={tmp / 'run'}"],
                              ["mode=eval", "--config-dir", str(mine), f"checkpoint={tmp / 'run'}"],
                              ["max_episodes=2", f"--config-dir={mine}", "eval_episodes=0"])):
        proc = train(tmp_path, *args, "eval_episodes=2", name=f"cd{i}")
        assert proc.returncode == 0, (args, proc.stderr[-2000:])


def test_a_users_config_named_like_a_shipped_one_is_refused(tmp_path):
    mine = tmp_path / "mine"
    (mine / "task").mkdir(parents=True)
    (mine / "task" / "balance.yaml").write_text("threshold: 1\n")
    proc = train(tmp_path, "--config-dir", str(mine), "robot=double_pendulum")
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert proc.stderr.strip().splitlines()[-1] == (
        f"error: {mine / 'task' / 'balance.yaml'} has the name of {ROOT / 'conf' / 'task' / 'balance.yaml'}, "
        "which Hydra would use instead; allowed: another name for yours (e.g. task/my_balance.yaml)")
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("overrides, expected", [
    (["learner.alpha=-0.5"], "learner.alpha must be a finite number in (0, 1]; got -0.5"),
    (["mode=eval"], "mode=eval needs checkpoint="),
    (["checkpoint=/nonexistent/model.pt"], "checkpoint /nonexistent/model.pt does not exist"),
    (["mode=fly"], "mode must be one of train, eval; got 'fly'"),
    (["learner=dqn", "learner.lr=-1"], "learner.lr must be a finite number > 0; got -1"),
])
def test_bad_input_is_one_clear_line(tmp_path, overrides, expected):
    proc = train(tmp_path, "max_episodes=2", *overrides)
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.strip().splitlines() if line.startswith("error:")]
    assert len(lines) == 1 and expected in lines[0], proc.stderr[-1500:]
    assert "Traceback" not in proc.stderr


def test_corrupt_checkpoint_is_one_clear_line(tmp_path):
    bad = tmp_path / "model.pt"
    bad.write_bytes(b"\x00garbage")
    proc = train(tmp_path, f"checkpoint={bad}", "max_episodes=2")
    assert proc.returncode == 2 and "cannot be read" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_unknown_robot_is_hydras_clear_message(tmp_path):
    proc = train(tmp_path, "robot=submarine")
    assert proc.returncode != 0
    assert "submarine" in proc.stderr and "Available options" in proc.stderr


@pytest.mark.parametrize("overrides", [
    pytest.param(["learner=qlearn", "max_episodes=40", "num_envs=1"], marks=pytest.mark.slow),
    ["learner=qlearn", "max_episodes=40", "num_envs=6"],
    pytest.param(["learner=dqn", "max_episodes=30", "num_envs=1", "learner.learning_starts=64"],
                 marks=pytest.mark.slow),
    pytest.param(["learner=dqn", "max_episodes=30", "num_envs=4", "learner.learning_starts=64"],
                 marks=pytest.mark.slow),  # dqn's determinism in CI: tests/test_members.py, test_seed_batch.py
])
def test_same_config_and_seed_give_identical_metrics(tmp_path, overrides):
    a = train(tmp_path, *overrides, "eval_episodes=0", "seed=5", name="a")
    b = train(tmp_path, *overrides, "eval_episodes=0", "seed=5", name="b")
    c = train(tmp_path, *overrides, "eval_episodes=0", "seed=6", name="c")
    assert a.returncode == b.returncode == c.returncode == 0, a.stderr[-1500:]
    metrics = {name: (tmp_path / name / "metrics.csv").read_bytes() for name in "abc"}
    assert metrics["a"] == metrics["b"]  # bit-identical: wall-clock lives in timing.csv
    assert metrics["a"] != metrics["c"]


def test_greedy_evaluations_do_not_change_training(tmp_path):
    """Evaluations every 10 episodes draw from no training generator: the same metrics.csv as
    with none, and evals.csv holds one row per evaluation plus the final one."""
    common = ("learner=qlearn", "num_envs=1", "max_episodes=40", "eval_episodes=3", "seed=2")
    a = train(tmp_path, *common, "eval_every=10", name="a")
    b = train(tmp_path, *common, "eval_every=0", name="b")
    assert a.returncode == b.returncode == 0, a.stderr[-1500:]
    assert (tmp_path / "a" / "metrics.csv").read_bytes() == (tmp_path / "b" / "metrics.csv").read_bytes()
    evals = list(csv.DictReader(open(tmp_path / "a" / "evals.csv")))
    assert [int(r["episode"]) for r in evals] == [10, 20, 30, 40]
    assert len(list(csv.DictReader(open(tmp_path / "b" / "evals.csv")))) == 1
    # The final evaluation is the one eval.json and the verdict report.
    assert verdict(a.stdout)["greedy_length"] == f"{float(evals[-1]['length']):.4g}"
    assert verdict(a.stdout)["greedy_return"] == f"{float(evals[-1]['return']):.4g}"


def test_evaluations_every_so_many_env_steps(tmp_path):
    """``eval_every_steps``: an evaluation at the first step boundary each time that many env
    steps (all copies) have passed since the last, alone (``eval_every=0``) or with
    ``eval_every``'s episodes, whichever comes first; training is the same either way."""
    common = ("learner=qlearn", "num_envs=1", "max_episodes=40", "eval_episodes=3", "seed=2")
    a = train(tmp_path, *common, "eval_every=0", "eval_every_steps=150", name="a")
    b = train(tmp_path, *common, "eval_every=0", name="b")
    c = train(tmp_path, *common, "eval_every=10", "eval_every_steps=150", name="c")
    assert a.returncode == b.returncode == c.returncode == 0, a.stderr[-1500:]
    assert (tmp_path / "a" / "metrics.csv").read_bytes() == (tmp_path / "b" / "metrics.csv").read_bytes()
    def steps(name: str) -> list[int]:
        return [int(r["env_steps"]) for r in csv.DictReader(open(tmp_path / name / "evals.csv"))]

    [final] = steps("b")  # without a schedule, only the evaluation after training
    assert steps("a")[:-1] == list(range(150, final, 150)) and steps("a")[-1] == final
    episodes = [int(r["episode"]) for r in csv.DictReader(open(tmp_path / "c" / "evals.csv"))]
    # both schedules count from the last evaluation, whichever made it
    assert all(0 < e2 - e1 <= 10 for e1, e2 in zip([0, *episodes], episodes))
    assert all(0 < s2 - s1 <= 150 + 1 for s1, s2 in zip([0, *steps("c")], steps("c")))
    assert len(episodes) > len(steps("a")) and len(episodes) > 5


def test_a_diverging_model_keeps_training_and_says_so(tmp_path):
    """Effort control with a 1e9 N push per action: MuJoCo flags the state unstable."""
    proc = train_process(tmp_path, "task.control_type=effort", "task.pos_step=1e9", "max_episodes=40",
                         "eval_episodes=0", "num_envs=1")
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert verdict(proc.stdout)["episodes"] == "40"
    assert "warning: the physics diverged 40 times" in proc.stdout
    rows = list(csv.DictReader(open(tmp_path / "run" / "metrics.csv")))
    assert len(rows) == 40 and all(r["terminated"] == "0" for r in rows)  # truncated, not failed
    log = (tmp_path / "run" / "train.log").read_text()
    assert log.count("physics diverged in env copy 0") == 40
