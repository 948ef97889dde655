"""What a run prints: the banner, summary lines every ``log_every`` episodes, per-episode
lines only when ``verbose``, the console copied into train.log; ``mode=eval`` from a run folder."""

from __future__ import annotations

import io
import json
import re
import sys

import pytest
from hydra.core.global_hydra import GlobalHydra
from omegaconf import OmegaConf

import train
from runs.console import Console, Tee, summary_line, tee_console
from runs.metrics_files import Episode
from tasks.base import Success

SUCCESS = Success(measure="length", unit="steps", description="steps balanced", threshold=250,
                  judge="training", window=100, min_episodes=100)


def episode(n: int) -> Episode:
    return Episode(episode=n, env_index=0, reward=float(n), length=n, terminated=True,
                   env_steps=10 * n, wall_s=0.5 * n, value=float(n), rolling=float(n),
                   extra={"epsilon": 0.5})


@pytest.mark.parametrize("quiet, verbose, log_every, lines", [
    (False, False, 0, 20),     # about 20 summary lines per run by default
    (False, False, 50, 8),
    (False, True, 50, 400 + 8),
    (True, True, 50, 0),       # quiet wins
])
def test_lines_per_run(capsys, quiet, verbose, log_every, lines):
    console = Console(400, SUCCESS, quiet=quiet, verbose=verbose, log_every=log_every)
    asked = []
    for n in range(1, 401):
        console.episode(episode(n), None, lambda: asked.append(1) or {"loss": 0.25})
    console.close()
    out = capsys.readouterr().out.splitlines()
    assert len(out) == lines
    if lines and not verbose:
        assert out[0].startswith(f"episode {log_every or 20}/400 | steps balanced: mean100")
        assert "eps 0.5 | loss 0.25" in out[0]
    # the learner's numbers are asked for only when shown (no bar off a terminal)
    assert len(asked) == (0 if quiet else lines - (400 if verbose else 0))


class Terminal(io.StringIO):
    """What a terminal shows of what is written to it (stdout and stderr alike): ``\\r``
    returns to the line's start, later characters overwrite earlier ones."""

    def isatty(self) -> bool:
        return True

    def screen(self) -> list[str]:
        text = re.sub(r"\x1b\[[0-9;]*[A-Za-z]", "", self.getvalue())  # tqdm's cursor moves (none at position 0)
        rows = []
        for physical in text.split("\n"):
            row: list[str] = []
            col = 0
            for char in physical:
                if char == "\r":
                    col = 0
                    continue
                row[col:col + 1] = [char]
                col += 1
            rows.append("".join(row).rstrip())
        return [r for r in rows if r]


def test_on_a_terminal_the_bar_is_cleared_before_each_line_and_at_the_end(monkeypatch):
    """The bar (stderr) and the summary lines (stdout) share the terminal: each line starts
    on a clean line, and once the run ends the bar is gone (the verdict follows the lines)."""
    terminal, log = Terminal(), io.StringIO()
    monkeypatch.setattr(sys, "stdout", Tee(terminal, log))  # as in a run: stdout also goes to train.log
    console = Console(100, SUCCESS, log_every=25, bar_file=terminal)
    for n in range(1, 101):
        console.episode(episode(n))
    console.close()
    print("VERDICT", file=terminal)
    screen = terminal.screen()
    assert "%|" in terminal.getvalue()  # a bar was drawn
    assert [row.split(" |")[0] for row in screen] == [f"episode {n}/100" for n in (25, 50, 75, 100)] + ["VERDICT"]
    assert [line.split(" |")[0] for line in log.getvalue().splitlines()] == [f"episode {n}/100" for n in (25, 50, 75, 100)]


def test_summary_line_names_the_measure_the_evaluation_and_the_rate():
    line = summary_line(episode(200), 4000, SUCCESS, best=210.0,
                        last_eval={"episode": 100, "value": 80.2}, live={"loss": 0.012})
    assert line == ("episode 200/4000 | steps balanced: mean100 200 steps, best 210 | greedy 80.2 "
                    "at 100 | eps 0.5 | loss 0.012 | 2000 env steps, 20 steps/s, 100.0s")


def test_tee_copies_stdout_and_stderr_into_the_log(tmp_path, capsys):
    with tee_console(tmp_path / "train.log"):
        print("one")
        print("two", file=sys.stderr)
        assert isinstance(sys.stdout, Tee)
    print("after")
    assert (tmp_path / "train.log").read_text() == "one\ntwo\n"
    captured = capsys.readouterr()
    assert captured.out == "one\nafter\n" and captured.err == "two\n"


def test_the_banner_names_a_tuned_file_only_where_one_exists(tmp_path, monkeypatch, capsys):
    """acrobot x mbalunovic has no conf/tuned file (the benchmark's studies do not tune the
    acrobot): no "tuned:" line, and run.json says none."""
    from tasks.catalog import conf_dir, run_choices

    assert not (conf_dir() / "tuned" / "acrobot_mbalunovic.yaml").exists()
    assert run_choices({"robot": "acrobot", "learner": "mbalunovic", "tuned": "acrobot_mbalunovic"})["tuned"] is None
    assert run_choices({"robot": "cartpole", "learner": "qlearn", "tuned": "cartpole_qlearn"})["tuned"] == "cartpole_qlearn"
    code = cli(["robot=acrobot", "learner=mbalunovic", "max_episodes=1", "eval_episodes=0", "quiet=true",
                f"hydra.run.dir={tmp_path}"], monkeypatch)
    out = capsys.readouterr().out.splitlines()
    assert code == 0 and out[0].startswith("acrobot / swingup / mbalunovic")
    assert out[1].startswith("solved when: ") and not any(line.startswith("tuned:") for line in out)
    assert json.loads((tmp_path / "run.json").read_text())["tuned"] is None



# The cube's dqn file changes the run (the cart-pole's holds the dqn's own values since 2026-11-29).
CUBE_DQN = {"robot": "cube", "task": "one_disk_walk", "learner": "dqn", "tuned": "cube_dqn", "tuned_task": None}


@pytest.mark.parametrize("overrides", [
    [], ["learner.lr=0.01", "seed=3"], ["learner.hidden=[32,32]", "trial=2"], ["num_envs=2", "learner.gamma=0.9"],
    ["learner.epsilon.steps=100"], ["learner=rainbow", "learner.lr=0.01"], ["+note=1", "~learner.grad_clip"],
])
def test_what_the_tuned_file_changed_is_the_command_against_itself_without_it(overrides):
    """The banner's changes are those of the same command composed with and without
    ``~tuned``, though a value override is left out of the cached composition."""
    from params import dotted
    from runs.console import tuned_changes
    from tasks.catalog import compose

    learner = next((o.split("=")[1] for o in overrides if o.startswith("learner=")), "dqn")
    rest = [o for o in overrides if not o.startswith("learner=")]
    choices = {**CUBE_DQN, "learner": learner, "tuned": f"cube_{learner}"}
    cfg = compose("cube", None, learner, rest)
    before = dotted(OmegaConf.to_container(compose("cube", None, learner, [*rest, "~tuned"]), resolve=True))
    after = dotted(OmegaConf.to_container(cfg, resolve=True))
    expected = [f"{key} {before.get(key)} -> {value}" for key, value in after.items() if before.get(key) != value]
    assert expected and tuned_changes(cfg, choices, overrides) == expected


def test_jobs_that_differ_in_values_only_share_one_composition_without_the_tuned_file(monkeypatch):
    """A sweep's jobs (seeds, trials' learning rates) compose the command without its tuned
    file once, not once each."""
    import runs.console as console
    from tasks.catalog import compose

    calls = []
    monkeypatch.setattr(console, "compose", lambda *a, **k: calls.append(a) or compose(*a, **k))
    console._without_tuned.cache_clear()
    seen = set()
    for seed, lr in [(0, 0.01), (1, 0.01), (0, 0.002), (1, 0.002)]:
        overrides = [f"learner.lr={lr}", f"seed={seed}", f"trial={int(lr * 1000)}"]
        changes = console.tuned_changes(compose("cube", None, "dqn", overrides), CUBE_DQN, overrides)
        assert changes and not any(line.startswith(("learner.lr ", "seed ", "trial ")) for line in changes)
        seen.add(tuple(changes))
    assert len(calls) == 1 and len(seen) == 1


def test_the_banner_names_a_task_tuned_file_on_top_of_the_robot_one(tmp_path, monkeypatch, capsys):
    """conf/tuned/<robot>_<task>_<learner>.yaml (here from a --config-dir) is named after the
    robot's file, its values among what they changed; '~tuned' leaves out both."""
    from tasks.catalog import use_config_dirs

    layer = tmp_path / "conf"
    (layer / "tuned").mkdir(parents=True)
    (layer / "tuned" / "cartpole_stay_up_qlearn.yaml").write_text("# @package _global_\nnum_envs: 4\n")
    try:
        args = ["--config-dir", str(layer), "learner=qlearn", "max_episodes=1", "eval_episodes=0", "quiet=true"]
        code = cli([*args, f"hydra.run.dir={tmp_path / 'both'}"], monkeypatch)
        out = capsys.readouterr().out.splitlines()
        # The task's file over the robot's: num_envs 8 (cartpole_qlearn) -> 4.
        assert code == 0 and out[1].startswith(
            "tuned: conf/tuned/cartpole_qlearn.yaml + conf/tuned/cartpole_stay_up_qlearn.yaml changed num_envs 1 -> 4")
        assert out[1].endswith("('~tuned' leaves them out)")
        saved = json.loads((tmp_path / "both" / "run.json").read_text())
        assert (saved["tuned"], saved["tuned_task"]) == ("cartpole_qlearn", "cartpole_stay_up_qlearn")
        code = cli([*args, "~tuned", f"hydra.run.dir={tmp_path / 'none'}"], monkeypatch)
        out = capsys.readouterr().out.splitlines()
        assert code == 0 and not any(line.startswith("tuned:") for line in out)
        saved = json.loads((tmp_path / "none" / "run.json").read_text())
        assert (saved["tuned"], saved["tuned_task"]) == (None, None)
    finally:
        use_config_dirs([])

# -- mode=eval from a run folder --------------------------------------------------------
def cli(args: list[str], monkeypatch) -> int:
    """``python train.py <args>`` in this process; its exit code (0 when it returns)."""
    GlobalHydra.instance().clear()
    monkeypatch.setattr(train, "_IN_JOB", False)
    monkeypatch.setattr(sys, "argv", ["train.py", *args, "hydra/job_logging=none",
                                      "hydra/hydra_logging=none"])
    try:
        train.cli()
    except SystemExit as stop:
        return int(stop.code or 0)
    return 0


@pytest.fixture(scope="module")
def dqn_run(tmp_path_factory):
    """A short dqn cart-pole run's folder (its model.pt is what the evaluations load)."""
    folder = tmp_path_factory.mktemp("dqn_run")
    mp = pytest.MonkeyPatch()
    try:
        code = cli(["learner=dqn", "max_episodes=10", "learner.learning_starts=16",
                    "eval_episodes=0", "quiet=true", f"hydra.run.dir={folder}"], mp)
    finally:
        mp.undo()
    assert code == 0 and (folder / "model.pt").is_file()
    return folder


@pytest.mark.parametrize("target", ["folder", "model.pt"])
def test_eval_from_a_run_folder_needs_no_other_override(dqn_run, tmp_path, monkeypatch, capsys,
                                                        target):
    checkpoint = dqn_run if target == "folder" else dqn_run / "model.pt"
    code = cli(["mode=eval", f"checkpoint={checkpoint}", f"hydra.run.dir={tmp_path}"], monkeypatch)
    out = capsys.readouterr().out
    assert code == 0, out
    copies = OmegaConf.load(dqn_run / "config.yaml").num_envs  # the run's (its tuned file's)
    assert out.splitlines()[0] == f"evaluate cartpole / stay_up / dqn, seed 0, {copies} cop{'y' if copies == 1 else 'ies'}"
    result = json.loads((tmp_path / "eval.json").read_text())
    assert result["episodes"] == 20 and result["measure"] == "length"
    assert "greedy evaluation over 20 episodes: steps balanced" in out
    saved = (tmp_path / "config.yaml").read_text()
    assert "_target_: learners.dqn.DQN" in saved and f"checkpoint: {dqn_run / 'model.pt'}" in saved


def test_eval_from_a_run_folder_applies_the_other_overrides(dqn_run, tmp_path, monkeypatch, capsys):
    """A robustness test: a longer pole-angle limit and 7 evaluation episodes."""
    code = cli(["mode=eval", f"checkpoint={dqn_run}", "eval_episodes=7", "task.max_pole_angle=0.5",
                f"hydra.run.dir={tmp_path}"], monkeypatch)
    assert code == 0, capsys.readouterr()
    assert json.loads((tmp_path / "eval.json").read_text())["episodes"] == 7
    saved = (tmp_path / "config.yaml").read_text()
    assert "max_pole_angle: 0.5" in saved and "eval_episodes: 7" in saved


def test_eval_from_a_run_folder_refuses_another_robot(dqn_run, tmp_path, monkeypatch, capsys):
    code = cli(["mode=eval", f"checkpoint={dqn_run}", "robot=cube", f"hydra.run.dir={tmp_path}"],
               monkeypatch)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1
    assert err[0] == (f"error: checkpoint={dqn_run} is a cartpole/stay_up/dqn run, evaluated with "
                      "its own robot, task and learner; drop robot=cube")


def test_eval_of_a_folder_without_model_is_one_line(tmp_path, monkeypatch, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    code = cli(["mode=eval", f"checkpoint={empty}", f"hydra.run.dir={tmp_path / 'run'}"], monkeypatch)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "is a folder without model.pt" in err[0]


def test_a_ticker_speaks_every_few_seconds_of_a_long_piece_of_work(capsys, monkeypatch):
    """Issue 67: an evaluation sat silent for 52 s, a video for 175 s. A Ticker prints a line
    every ``every`` seconds while the work goes on, and nothing for work shorter than that."""
    from runs import console

    clock = iter([0.0, 1.0, 5.5, 6.0, 11.0])
    monkeypatch.setattr(console.time, "monotonic", lambda: next(clock))
    tick = console.Ticker("greedy evaluation", 20, "episodes ended")
    for done in (3, 8, 9, 15):
        tick(done)
    assert capsys.readouterr().out.splitlines() == ["greedy evaluation: 8/20 episodes ended, 6 s",
                                                    "greedy evaluation: 15/20 episodes ended, 11 s"]
