"""Every bad command line is one ``error:`` line and exit 2, with nothing written (not even
the run folder Hydra makes before the job starts).

The table holds what a skeptical user tried (values of the wrong type, integers with
no upper bound, removed keys, unknown keys with and without ``+``, Hydra grammar and
interpolation errors, unknown config choices, a task that does not fit the robot,
folders that cannot be created) plus every case of tests/test_validation.py (its line
names the key and the value given), run through the real entry point (``train.cli``) in
this process: a case costs a fraction of a second.
"""

from __future__ import annotations

import sys

import pytest
import torch
from hydra.core.global_hydra import GlobalHydra

import train
from runs import lifecycle as session
from test_validation import CASES

TRIED = [
    ["seed=abc"], ["seed=null"], ["seed=nan"], ["seed=[1,2]"], ["seed=-1"], ["seed=1e30"],
    ["resume=5"], ["resume=true"], ["resume=/nonexistent/run"], ["seed=${oops}"], ["~seed"],
    ["~num_envs"], ["num_envs=1e308"], ["torch_threads=1099511627776"], ["eval_episodes=1e308"],
    ["learner=dqn", "learner.hidden=[1e10]"], ["learner=dqn", "learner.hidden=[]"],
    ["learner=dqn", "learner.buffer_size=1e12"], ["learner.number_splits=65536"],
    ["learner.number_splits=[1000,1000,1000,1000]"], ["task.physics_timestep=1e-9"],
    ["video=true", "video_steps=1e308"], ["robot=turtlebot", "robot.laser_rays=1e9"],
    ["robot=turtlebot", "task.n_observations=1e6"], ["task.max_episode_steps=1e300"],
    ["learner.alpah=0.1"], ["+learner.alpah=0.1"], ["learner.gama=0.9"], ["robot=submarine"],
    ["learner=bogus"], ["task=bogus"], ["logger=bogus"], ["~robot"], ["~learner"],
    ["seed=[1,2"], ["learner.alpha="], ["=5"], ["seed==3"], ["+foo=1"], ["foo=1"],
    ["robot=cartpole", "task=maze"], ["robot=turtlebot", "task=stay_up"],
    ["checkpoint=/nonexistent/model.pt"], ["mode=eval"], ["hydra.run.dir=/proc/nope"],
    ["learner=dqn", "learner.epsilon._target_=os.system"],
    # issue 28
    ["hydra.run.dir=/"], ["learner.number_splits=1e308"], ["learner.number_splits=0"],
    ["learner.number_splits=[10,10,10,1e308]"], ["learner.number_splits.pole_vel=-2"],
    # issues 35 and 36: old keys name their new place; an override that would change nothing
    ["learner.nepisodes=5"], ["+learner.nsteps=5"], ["max_episodes=0", "max_env_steps=0"], ["win.min_episodes=5"],
    ["+win.threshold=3"], ["learner.number_splits={}"], ["task.tabular_state={}"], ["~logger"],
    ["checkpoint=/dev/null"], ["learner=dqn", "learner.epsilon._target_=nosuch.Thing"],
    ["learner=dqn", "learner.epsilon._target_=learners.schedules.Nope"], ["learner.epsilon.steps=3"],
    ["robot=cartpole", "task=wall"], ["robot=turtlebot", "robot.laser_rays=1"],
]
ALL = [(args, "", "") for args in TRIED] + CASES  # (overrides, the key its line names, the value shown)


def cli(args: list[str], tmp_path, monkeypatch) -> int:
    """``python train.py <args>`` in this process; its exit code."""
    GlobalHydra.instance().clear()
    monkeypatch.setattr(train, "_IN_JOB", False)
    run_dir = [] if any(a.startswith("hydra.run.dir=") for a in args) else [f"hydra.run.dir={tmp_path / 'run'}"]
    # Hydra's logging set-up would hold on to pytest's captured streams: none here.
    quiet = [*(["quiet=true"] if not any(a.startswith("quiet=") for a in args) else []),
             "hydra/job_logging=none", "hydra/hydra_logging=none"]
    monkeypatch.setattr(sys, "argv", ["train.py", *args, *run_dir, *quiet])
    with pytest.raises(SystemExit) as stop:
        train.cli()
    return stop.value.code


@pytest.mark.parametrize("args, key, shown", ALL, ids=[" ".join(a) for a, _, _ in ALL])
def test_a_bad_command_line_is_one_error_line_and_exit_2(args, key, shown, tmp_path, monkeypatch, capsys):
    code = cli(args, tmp_path, monkeypatch)
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip() and not ln.startswith("[")]
    assert code == 2 and len(err) == 1 and err[0].startswith("error: "), err
    assert key in err[0], err[0]
    assert not shown or shown in err[0].rpartition("; got ")[2], err[0]
    left = sorted(str(p.relative_to(tmp_path)) for p in tmp_path.rglob("*"))
    assert left == [], f"a refused command left {left}"  # not even the folder Hydra made


def test_the_table_covers_what_was_tried():
    assert len(ALL) >= 134


def test_a_full_disk_mid_run_is_one_line_and_the_last_checkpoint_survives(tmp_path, monkeypatch,
                                                                          capsys):
    """The second checkpoint write fails as on a full disk: one line, exit 3, and the first
    checkpoint still loads (saves are atomic: write a temporary file, then rename)."""
    saves = []

    def save(path, *args):
        saves.append(path)
        if len(saves) == 2:
            raise OSError(28, "No space left on device", str(path))
        real_save(path, *args)

    real_save = session.save_training_state
    monkeypatch.setattr(session, "save_training_state", save)
    code = cli(["max_episodes=200", "checkpoint_every=20", "eval_episodes=0"], tmp_path,
               monkeypatch)
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip() and not ln.startswith("[")]
    run_dir = tmp_path / "run"
    assert code == 3 and err == [f"error: cannot write {saves[-1]}: No space left on device; the last checkpoint "
                                 f"is intact: once there is room, resume with: python train.py resume={run_dir}"]
    state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    assert state["run"]["n_episodes"] == 20


@pytest.mark.parametrize("args, suggestion", [
    (["learner.gama=0.9"], "did you mean learner.gamma?"),
    (["+learner.gama=0.9"], "did you mean learner.gamma?"),
    (["learner=dqn", "learner.lrr=0.1"], "did you mean learner.lr?"),
    (["sed=3"], "did you mean seed?"),
    (["+sed=3"], "did you mean seed?"),
    (["robot=cube", "task.rol_speed_fixed_value=3"], "did you mean task.roll_speed_fixed_value?"),
])
def test_a_mistyped_key_gets_the_closest_one(args, suggestion, tmp_path, monkeypatch, capsys):
    assert cli(args, tmp_path, monkeypatch) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip() and not ln.startswith("[")]
    assert len(err) == 1 and suggestion in err[0], err


# -- inputs that need files: a finished run, damaged models, folders that are not ours --------
@pytest.fixture(scope="module")
def made(tmp_path_factory) -> dict[str, str]:
    """A finished run and the damaged or foreign files the cases below point at."""
    import subprocess
    from pathlib import Path

    from runs.checkpoint import save_checkpoint

    base = tmp_path_factory.mktemp("made")
    finished = base / "finished"
    done = subprocess.run([sys.executable, "train.py", "max_episodes=10", "eval_episodes=2", "quiet=true",
                           f"hydra.run.dir={finished}"], cwd=Path(__file__).resolve().parents[1],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-1500:]
    model = torch.load(finished / "model.pt", weights_only=True)
    unchecked = {k: v for k, v in model.items() if k != "checksum"}
    torch.save(unchecked, base / "unchecked.pt")
    table = unchecked["table"].clone()
    table[0, 0] = float("nan")
    save_checkpoint(base / "nan.pt", {**unchecked, "table": table})
    save_checkpoint(base / "reshaped.pt", {**unchecked, "table": unchecked["table"].reshape(-1, 1)})
    (base / "foreign").mkdir()
    (base / "foreign" / "notes.txt").write_text("not a run\n")
    (base / "link").symlink_to(finished)
    torch.jit.save(torch.jit.script(torch.nn.Sequential()), str(base / "script.pt"))  # a TorchScript archive
    (base / "conf" / "tuned").mkdir(parents=True)
    (base / "conf" / "tuned" / "latin1.yaml").write_bytes(b"# @package _global_\nlearner:\n  alpha: 0.\xe93\n")
    return {"finished": str(finished), "base": str(base), "foreign": str(base / "foreign")}


MADE = [  # (arguments, what the one line must say); {name} is made[name]
    (["mode=eval", "checkpoint={base}/unchecked.pt"], "unchecked.pt has no checksum"),
    (["mode=eval", "checkpoint={base}/nan.pt"], "holds values that are not finite (NaN or infinite) in table"),
    (["resume={finished}"], "resume={finished}: it is finished"),
    (["hydra.run.dir={foreign}"], "hydra.run.dir={foreign} is a folder that holds other files (notes.txt)"),
    (["-m", "hydra.sweep.dir={foreign}"], "hydra.sweep.dir={foreign} is a folder that holds other files"),
    # issue 63: never a run inside another run's folder, through a symlink or '..' either
    (["hydra.run.dir={finished}/sub2"], "hydra.run.dir={finished}/sub2 is inside the run folder {finished}"),
    (["hydra.run.dir={base}/link/sub2"], "hydra.run.dir={base}/link/sub2 is inside the run folder {finished}"),
    (["hydra.run.dir={finished}/x/../sub"], "is inside the run folder {finished}"),
    (["hydra.run.dir={finished}/x/../../finished"], "hydra.run.dir={finished} already holds a run"),
    (["mode=eval", "checkpoint={finished}", "eval_episodes=0"], "mode=eval with eval_episodes=0 would evaluate nothing"),
    (["-m", "hydra.sweep.dir={finished}/sweep"], "hydra.sweep.dir={finished}/sweep is inside the run folder"),
    # issue 63: library warnings inside the line, values as given, no cut message, +hydra.<unknown>
    (["mode=eval", "checkpoint={base}/reshaped.pt"], "checkpoint {base}/reshaped.pt does not fit this run: table is"),
    (["checkpoint={base}/reshaped.pt"], "checkpoint {base}/reshaped.pt does not fit this run: table is"),
    (["mode=eval", "checkpoint={base}/script.pt"], "checkpoint {base}/script.pt cannot be read"),
    (["learner.alpha=1e-320"], "learner.alpha must be a finite number in (0, 1]; got 1e-320, below the smallest"),
    (["learner=dqn", "learner.epsilon._target_=subprocess.Popen"],
     "learner.epsilon._target_='subprocess.Popen' is not allowed: a run builds only classes of the project's "
     "own packages (robots., tasks., learners.)"),
    (["+hydra.foo=1"], "hydra.foo is not a setting of Hydra; allowed under hydra: defaults, mode,"),
    (["++hydra.job.foo=1"], "hydra.job.foo is not a setting of Hydra; allowed under hydra.job: name, chdir,"),
    (["resume={base}/link/../nowhere"], "resume={base}/link/../nowhere is not a run folder"),
    (["hydra.searchpath=[file://{base}/conf]", "tuned=latin1"],
     "conf/tuned/latin1.yaml is not valid UTF-8 (byte 0xe9 at position 40)"),
    (["-m", "seed=-1,-2"], "every job of the sweep failed (2); the first, 0_cartpole_qlearn_seed-1: seed must be "
                           "an integer in [0, 9223372036854775808); got -1"),
    (["-m", "hydra/sweeper=optuna", "robot=cartpole", "task=maze"], "task maze needs robot=turtlebot"),
    (["-m", "hydra/sweeper=optuna", "robot=cartpole", "hydra.sweeper.budget_steps=5"],
     "hydra.sweeper.budget_steps must be at least one episode of cartpole/stay_up (task.max_episode_steps = 1000 "
     "env steps); got 5"),
    *((["-m", "hydra/sweeper=optuna", f"hydra.sweeper.{key}={value}"], f"hydra.sweeper.{key} must be {allowed}")
      for key, value, allowed in (
          ("write_tuned", "maybe", "true or false; got 'maybe'"), ("start_from_current", "1", "true or false"),
          ("value_defaults", "yes", "true or false"),
          ("n_trials", "1.5", "an integer >= 0"), ("budget_steps", "1e308", "an integer >= 1"),
          ("startup_trials", "-1", "an integer >= 0"), ("study", "''", "a non-empty name"),
          ("seeds", "[-1]", "distinct seeds"), ("pruners.median.n_warmup_steps", "-5", "an integer >= 0"),
          ("pruner", "asha", "null or one of median, successive_halving, hyperband"))),
]


@pytest.mark.parametrize("args, words", MADE, ids=[" ".join(a) for a, _ in MADE])
def test_a_bad_input_that_needs_files_is_one_line_and_writes_nowhere(args, words, made, tmp_path, monkeypatch,
                                                                    capsys):
    args = [a.format(**made) for a in args]
    sweep = ["hydra.sweep.dir=" + str(tmp_path / "run")]
    if "hydra/sweeper=optuna" in args:
        sweep.append(f"hydra.sweeper.storage=sqlite:///{tmp_path / 's.db'}")
    if "-m" in args:
        args += [a for a in sweep if a.split("=", 1)[0] not in {x.split("=", 1)[0] for x in args}]
        args += [] if "hydra/sweeper=optuna" in args else ["max_episodes=1"]
    before = _listing(made["base"])
    assert cli(args, tmp_path, monkeypatch) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and err[0].startswith("error: ") and words.format(**made) in err[0], err
    assert _listing(made["base"]) == before, "a refused command wrote into a folder not its own"
    assert not (tmp_path / "s.db").exists() and not (tmp_path / "run" / "config.yaml").exists()


def test_resume_through_a_symlink_and_dotdot_goes_where_the_file_system_goes(made, tmp_path, monkeypatch, capsys):
    """``resume=L/../K`` with L a link to ``deep/sub``: the run ``deep/K`` (the text alone would
    say ``K`` beside L)."""
    import shutil
    from pathlib import Path

    run = tmp_path / "deep" / "K"
    shutil.copytree(made["finished"], run, ignore=shutil.ignore_patterns(".lock"))
    (run / "summary.json").unlink()  # a run stopped after its last checkpoint
    (tmp_path / "deep" / "sub").mkdir()
    (tmp_path / "L").symlink_to(tmp_path / "deep" / "sub")
    monkeypatch.chdir(tmp_path)
    GlobalHydra.instance().clear()
    monkeypatch.setattr(train, "_IN_JOB", False)
    monkeypatch.setattr(sys, "argv", ["train.py", "resume=L/../K", "hydra/job_logging=none", "hydra/hydra_logging=none"])
    train.cli()  # returns: the run finished
    assert (run / "summary.json").is_file() and not Path("K").exists()


def _listing(folder: str) -> dict[str, int]:
    """Every file below ``folder`` with its size (train.log aside: Hydra's log of the refusal)."""
    from pathlib import Path

    return {str(p): p.stat().st_size for p in Path(folder).rglob("*") if p.is_file() and p.name != "train.log"}


def test_a_typo_is_one_line_whatever_hydra_full_error_says(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("HYDRA_FULL_ERROR", "0")
    assert cli(["learner.alpah=0.1"], tmp_path, monkeypatch) == 2
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert len(err) == 1 and "did you mean learner.alpha?" in err[0], err


def test_a_sweep_where_some_jobs_failed_says_how_many(tmp_path, monkeypatch, capsys):
    GlobalHydra.instance().clear()
    monkeypatch.setattr(train, "_IN_JOB", False)
    monkeypatch.setattr(sys, "argv", ["train.py", "-m", "seed=-1,3", "max_episodes=2", "eval_episodes=0",
                                      "quiet=true", f"hydra.sweep.dir={tmp_path / 'sweep'}",
                                      "hydra/job_logging=none", "hydra/hydra_logging=none"])
    with pytest.raises(SystemExit) as stop:  # the sweep ran, and one of its jobs failed
        train.cli()
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip()]
    assert stop.value.code == 1
    assert err == ["error: 1 of 2 jobs failed or never started (listed above); the first, 0_cartpole_qlearn_seed-1: "
                   "seed must be an integer in [0, 9223372036854775808); got -1: the sweep exits 1"], err


def test_an_earlier_sweeps_stop_does_not_skip_the_next_sweeps_jobs(tmp_path, monkeypatch, capsys):
    """Two sweeps in one process: the first stopped by Ctrl-C (its signal kept for its exit
    status) does not make the second skip its jobs."""
    import signal

    from sweeps.state import SWEEP

    GlobalHydra.instance().clear()
    monkeypatch.setattr(train, "_IN_JOB", False)
    monkeypatch.setitem(SWEEP, "signal", signal.SIGINT)  # what the stopped first sweep left
    sweep = tmp_path / "sweep"
    monkeypatch.setattr(sys, "argv", ["train.py", "-m", "seed=3,4", "max_episodes=2", "eval_episodes=0",
                                      "quiet=true", f"hydra.sweep.dir={sweep}",
                                      "hydra/job_logging=none", "hydra/hydra_logging=none"])
    try:
        train.cli()
    except SystemExit as stop:
        assert stop.code in (0, None), capsys.readouterr().err
    assert len(list(sweep.glob("*/summary.json"))) == 2


@pytest.mark.parametrize("argv", [[], ["a", "b"], ["--bogus", "x"]])
def test_compare_usage_mistakes_are_one_line(argv, capsys):
    import compare

    with pytest.raises(SystemExit) as stop:
        compare.main(argv)
    err = capsys.readouterr().err.splitlines()
    assert stop.value.code == 2 and len(err) == 1 and err[0].startswith("error: "), err
    assert err[0].endswith("; see python compare.py --help")
