"""A write that fails (a full disk) is one line, exit 3, and loses nothing: the last good
checkpoint stays intact and resumes to the uninterrupted run's files once there is room; a
seed of a batch whose folder cannot be written ends alone, its siblings go on."""

from __future__ import annotations

import errno
import subprocess
import sys
import time
from pathlib import Path

import pytest

from inprocess import run_train
import torch

from runs import checkpoint as checkpoint_module
from runs import training_state
from runs.lifecycle import Job, run_jobs
from runs.settings import check_run_config
from tasks.catalog import compose

ROOT = Path(__file__).resolve().parents[1]
RUN = ["num_envs=1", "max_episodes=100", "checkpoint_every=50", "eval_episodes=0", "quiet=true", "seed=3"]


def train(*args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(ROOT / "train.py"), *args], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)


def disk_full(payload, f) -> None:
    raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 43648 vs 43544")


def table(run_dir: Path) -> torch.Tensor:
    return torch.load(run_dir / "model.pt", weights_only=True)["table"]


@pytest.fixture
def small_disk(tmp_path):
    """A 2 MiB filesystem of its own (tmpfs), unmounted after the test."""
    disk = tmp_path / "disk"
    disk.mkdir()
    made = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(disk)], capture_output=True)
    if made.returncode != 0:
        pytest.skip(f"cannot mount a small filesystem here ({made.stderr.decode().strip()}); "
                    "test_a_seed_whose_folder_cannot_be_written_ends_alone fails a write instead")
    yield disk
    subprocess.run(["umount", "-l", str(disk)], check=False)


def test_a_run_whose_disk_fills_is_one_line_and_resumes_once_there_is_room(tmp_path, small_disk):
    reference = tmp_path / "reference"
    done = run_train(f"hydra.run.dir={reference}", *RUN)  # in this process: only the run whose disk fills needs its own
    assert done.returncode == 0, done.stderr[-2000:]
    run_dir = small_disk / "run"
    proc = train(f"hydra.run.dir={run_dir}", *RUN)
    deadline = time.time() + 240
    while not (run_dir / "checkpoint.pt").is_file():  # the first checkpoint: the disk fills before the second
        assert time.time() < deadline and proc.poll() is None, proc.communicate()[1][-2000:]
        time.sleep(0.01)
    filler = small_disk / "filler"
    with open(filler, "wb", buffering=0) as f:
        try:
            while True:
                f.write(b"\0" * 4096)
        except OSError as err:
            assert err.errno == errno.ENOSPC
    out, err = proc.communicate(timeout=240)
    assert proc.returncode == 3, err[-2000:]
    assert err.strip().splitlines() == [
        f"error: cannot write {err.split('error: cannot write ')[1].split(':')[0]}: No space left on device; "
        f"the last checkpoint is intact: once there is room, resume with: python train.py resume={run_dir}"], err
    assert str(run_dir) in err and "Traceback" not in out
    filler.unlink()
    resumed = run_train(f"resume={run_dir}")
    assert resumed.returncode == 0, resumed.stderr[-2000:]
    assert (run_dir / "metrics.csv").read_bytes() == (reference / "metrics.csv").read_bytes()
    assert torch.equal(table(run_dir), table(reference))


def test_a_seed_whose_folder_cannot_be_written_ends_alone(tmp_path, monkeypatch):
    """Seed 9's second checkpoint fails to write (as on a full disk): it ends with one line in
    its error.txt, its first checkpoint intact; seed 4 trains on to its end."""
    jobs = []
    for seed in (4, 9):
        cfg = compose("cartpole", learner="qlearn", overrides=[f"seed={seed}", "quiet=true", "max_episodes=120",
                                                                "checkpoint_every=20", "eval_episodes=0"])
        check_run_config(cfg)
        jobs.append(Job(cfg, tmp_path / f"seed{seed}", {"robot": "cartpole", "task": "stay_up", "learner": "qlearn"}))
    real, saved = training_state.save_checkpoint, []

    def save(path, payload):  # seed 9's second checkpoint: torch's writer fails as on a full disk
        if Path(path).parent.name == "seed9":
            saved.append(path)
            if len(saved) == 2:
                with monkeypatch.context() as m:
                    m.setattr(checkpoint_module.torch, "save", disk_full)
                    return real(path, payload)
        return real(path, payload)

    monkeypatch.setattr(training_state, "save_checkpoint", save)
    first = (tmp_path / "seed9" / "checkpoint.pt")
    summaries = run_jobs(jobs)
    assert "failed" not in summaries[0] and summaries[0]["episodes"] == 120, summaries[0]
    line = (tmp_path / "seed9" / "error.txt").read_text().strip()
    assert line.startswith(f"error: cannot write {first}: ") and "resume with: python train.py resume=" in line, line
    assert summaries[1]["failed"] == line
    assert torch.load(first, weights_only=False)["run"] is not None  # the first checkpoint, loadable
