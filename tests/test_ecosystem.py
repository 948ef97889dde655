"""Loggers chosen from Hydra, sweeps through Hydra launchers, and the sweep comparison."""

import csv
import os
import subprocess
import sys
from pathlib import Path

import pytest

from inprocess import run_train

ROOT = Path(__file__).resolve().parents[1]


def run(args: list[str], timeout: int = 600) -> subprocess.CompletedProcess:
    if args[0] == "train.py" and "-m" not in args:  # a single run: in this process (tests/inprocess.py)
        return run_train(*args[1:])
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    return subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=timeout, env=env)


def test_tensorboard_logger_writes_event_files_with_the_episode_scalars(tmp_path):
    proc = run(["train.py", f"hydra.run.dir={tmp_path}", "quiet=true", "logger=tensorboard",
                "max_episodes=12", "eval_episodes=0"])
    assert proc.returncode == 0, proc.stderr[-2000:]
    events = list((tmp_path / "logs").rglob("events.out.tfevents.*"))
    assert events
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    acc = EventAccumulator(str(events[0].parent))
    acc.Reload()
    lengths = acc.Scalars("episode/length")
    rows = list(csv.DictReader(open(tmp_path / "metrics.csv")))
    assert [e.step for e in lengths] == [int(r["env_steps"]) for r in rows]  # against env steps
    assert [e.value for e in lengths] == [float(r["length"]) for r in rows]
    assert [e.value for e in acc.Scalars("episode/index")] == list(range(1, 13))
    assert [e.step for e in acc.Scalars("train/visited_fraction")][-1] == int(rows[-1]["env_steps"])


def test_csv_logger_is_the_default(tmp_path):
    proc = run(["train.py", f"hydra.run.dir={tmp_path}", "quiet=true", "max_episodes=3",
                "eval_episodes=0"])
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert list((tmp_path / "logs").rglob("episode/length.csv")) or \
        list((tmp_path / "logs").rglob("*length*.csv"))


def test_missing_logger_backend_is_a_one_line_error(tmp_path, monkeypatch):
    from runs.loggers import make_logger
    from params import ConfigError
    import importlib.util
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "mlflow" else real(name, *a))
    with pytest.raises(ConfigError, match=r"logger=mlflow needs the mlflow package.*\[mlflow\]"):
        make_logger("mlflow", tmp_path, "x")
    with pytest.raises(ConfigError, match="logger must be one of"):
        make_logger("papyrus", tmp_path, "x")


def only_sweep_folder(parent: Path) -> Path:
    """The one folder ``sweep_<pid>`` under ``parent`` (every job must write under it)."""
    folders = sorted(p for p in parent.iterdir() if p.name.startswith("sweep_"))
    assert len(folders) == 1, f"the sweep's jobs scattered over {[p.name for p in folders]}"
    return folders[0]


# joblib's wiring stays in CI through test_run_folders (Ctrl-C on a joblib sweep); both here: -m slow.
@pytest.mark.slow
@pytest.mark.parametrize("launcher", ["joblib", "submitit_local"])
def test_two_job_sweep_through_a_launcher_compares_itself_and_compare_reruns(tmp_path, launcher):
    # ${pid:} as in the default sweep folder: it must resolve to the launching process's id in every job.
    proc = run(["train.py", "-m", f"hydra/launcher={launcher}", f"hydra.sweep.dir={tmp_path}/sweep_${{pid:}}",
                "learner=qlearn", "seed=0,1", "max_episodes=8", "eval_episodes=0",
                "quiet=true"], timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    sweep = only_sweep_folder(tmp_path)
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir() and (p / "metrics.csv").exists())
    assert len(jobs) == 2
    # The launching process compares the jobs when the launcher returns (Hydra's on_multirun_end).
    assert "IQM [95% CI]" in proc.stdout and f"wrote {sweep / 'comparison.csv'}" in proc.stdout
    (sweep / "comparison.csv").unlink()
    proc = run(["compare.py", str(sweep)])
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "cartpole/stay_up" in proc.stdout and "qlearn" in proc.stdout
    rows = list(csv.DictReader(open(sweep / "comparison.csv")))
    assert len(rows) == 1 and rows[0]["seeds"] == "2" and rows[0]["solved"] == "0/2"
    assert rows[0]["measure"] == "length (steps, training >= 250)"  # the task's own rule, named
    assert (sweep / "comparison.png").read_bytes()[:4] == b"\x89PNG"
    assert "| cartpole/stay_up | qlearn |" in (sweep / "comparison.md").read_text()


def test_a_submitit_sweep_keeps_its_jobs_in_one_folder_and_a_failed_job_fails_it(tmp_path):
    """A real submitit_local sweep (each job a process of its own) of two tiny jobs, one of
    them refused: both jobs write under the launching process's ${pid:} folder, the
    comparison counts one finished and one failed job, and the sweep exits 1."""
    proc = run(["train.py", "-m", "hydra/launcher=submitit_local", f"hydra.sweep.dir={tmp_path}/sweep_${{pid:}}",
                "learner=qlearn", "learner.alpha=-1,0.5", "max_episodes=4", "eval_episodes=0",
                "quiet=true"], timeout=900)
    assert proc.returncode == 1, proc.stdout[-2000:] + proc.stderr[-3000:]
    sweep = only_sweep_folder(tmp_path)
    jobs = sorted(p.name for p in sweep.iterdir() if p.is_dir() and not p.name.startswith("."))
    assert jobs == ["0_cartpole_qlearn_seed0", "1_cartpole_qlearn_seed0"]
    assert "learner.alpha must be a finite number in (0, 1]" in (sweep / jobs[0] / "error.txt").read_text()
    assert (sweep / jobs[1] / "metrics.csv").is_file()
    rows = list(csv.DictReader(open(sweep / "comparison.csv")))
    counts = {r["swept"]: (r["finished"], r["failed"], r["never_started"]) for r in rows}
    assert counts == {"learner.alpha=-1": ("0", "1", "0"), "learner.alpha=0.5": ("1", "0", "0")}
    assert proc.stderr.strip().splitlines()[-1] == (
        "error: 1 of 2 jobs failed or never started (listed above); the first, 0_cartpole_qlearn_seed0: "
        "learner.alpha must be a finite number in (0, 1]; got -1: the sweep exits 1")


def test_a_submitit_job_holds_a_batch_of_seeds(tmp_path):
    """hydra/launcher=seeds_submitit_local (seeds_slurm's local twin): seeds of one setting
    go to submitit as batches of max_seeds, each batch one job that trains its seeds
    together; every seed still gets its folder and the launching process compares them."""
    proc = run(["train.py", "-m", "hydra/launcher=seeds_submitit_local", f"hydra.sweep.dir={tmp_path}/sweep",
                "hydra.launcher.max_seeds=2", "seed=0,1,2", "learner=qlearn", "max_episodes=4",
                "eval_episodes=0", "quiet=true"], timeout=900)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    sweep = tmp_path / "sweep"
    assert "Submitting 3 jobs as 2 submitit 'local' jobs, one per batch of seeds" in proc.stderr + proc.stdout
    logs = sorted((sweep / ".submitit").glob("*/*_log.out"))
    batched = [log for log in logs if "Training 2 seeds together: 0, 1" in log.read_text()]
    assert len(logs) == 2 and len(batched) == 1, [log.read_text()[-500:] for log in logs]
    jobs = sorted(p.name for p in sweep.iterdir() if p.is_dir() and (p / "metrics.csv").exists())
    assert jobs == ["0_cartpole_qlearn_seed0", "1_cartpole_qlearn_seed1", "2_cartpole_qlearn_seed2"]
    rows = list(csv.DictReader(open(sweep / "comparison.csv")))
    assert len(rows) == 1 and rows[0]["finished"] == "3"


def test_a_failing_job_does_not_cost_the_sweep_its_other_jobs_but_fails_it(tmp_path):
    sweep = tmp_path / "sweep"
    proc = run_train("-m", f"hydra.sweep.dir={sweep}", "learner=qlearn",  # in this process: the sweep's end,
                     "learner.alpha=-1,0.5", "max_episodes=5", "eval_episodes=0", "quiet=true")  # not a process's
    assert proc.returncode == 1, proc.stderr[-2000:]
    assert "error: 1 of 2 jobs failed or never started" in proc.stderr
    jobs = sorted(p for p in sweep.iterdir() if p.is_dir())
    assert len(jobs) == 2
    assert "learner.alpha must be a finite number in (0, 1]" in (jobs[0] / "error.txt").read_text()
    assert (jobs[1] / "metrics.csv").exists() and (jobs[1] / "model.pt").exists()
    proc = run(["compare.py", str(sweep)])
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = list(csv.DictReader(open(sweep / "comparison.csv")))
    assert sum(int(r["failed"]) for r in rows) == 1
    assert "failed:" in proc.stdout and "learner.alpha" in proc.stdout


def test_compare_rejects_a_folder_that_is_not_a_sweep(tmp_path):
    proc = run(["compare.py", str(tmp_path / "nope")])
    assert proc.returncode == 2 and "is not a folder" in proc.stderr


@pytest.mark.parametrize("kind", ["wandb", "mlflow"])
def test_optional_loggers_record_episode_lengths(tmp_path, kind):
    pytest.importorskip(kind)  # extras: pip install -e ".[wandb]" / ".[mlflow]"
    proc = run(["train.py", f"hydra.run.dir={tmp_path}", "quiet=true", f"logger={kind}",
                "max_episodes=6", "eval_episodes=0"])
    assert proc.returncode == 0, proc.stderr[-2000:]
    lengths = [float(r["length"]) for r in csv.DictReader(open(tmp_path / "metrics.csv"))]
    if kind == "wandb":
        assert list((tmp_path / "logs" / "wandb").glob("offline-run-*/run-*.wandb"))
    else:
        import mlflow
        mlflow.set_tracking_uri(f"sqlite:///{tmp_path / 'logs' / 'mlflow.db'}")
        run_id = mlflow.search_runs(search_all_experiments=True).run_id[0]
        history = mlflow.MlflowClient().get_metric_history(run_id, "episode/length")
        assert [m.value for m in history] == lengths
