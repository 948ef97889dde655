"""One Ctrl-C stops a sweep with every launcher the docs name: the jobs under way save, no job
starts after the signal, the console prints the one command that finishes the sweep, and that
command leaves every job's files as an uninterrupted sweep's."""

from __future__ import annotations

import io
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from inprocess import run_train
from runs.console import Tee

ROOT = Path(__file__).resolve().parents[1]
JOBS = ["max_episodes=150", "eval_episodes=0", "quiet=true"]
SEEDS = 4  # the sweep's seeds 0..3 (a launcher's case may take fewer)
LAUNCHERS = {
    "seeds": [],  # the default: the four seeds in one batch
    "basic": ["hydra/launcher=basic"],
    "joblib": ["hydra/launcher=joblib", "hydra.launcher.n_jobs=2"],
    # every job at once, each a process under its controller: two seeds (each costs a fresh
    # interpreter's imports on CI's two cores) stop and finish as four do
    "submitit_local": ["hydra/launcher=submitit_local"],
}
CASE_SEEDS = {"submitit_local": 2}


def seeds(count: int = SEEDS) -> str:
    """The sweep's ``seed=`` override for seeds 0..count-1."""
    return "seed=" + ",".join(map(str, range(count)))


def train(*args: str, **kw) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(ROOT / "train.py"), *args], cwd=ROOT, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, **kw)


def ends(sweep: Path) -> dict[str, tuple[bytes, torch.Tensor]]:
    """Each job's metrics and Q-table, by job folder."""
    return {job.name: ((job / "metrics.csv").read_bytes(), torch.load(job / "model.pt", weights_only=True)["table"])
            for job in sorted(sweep.glob("*_seed*"))}


@pytest.fixture(scope="module")
def uninterrupted(tmp_path_factory) -> dict:
    sweep = tmp_path_factory.mktemp("uninterrupted") / "sweep"
    done = run_train("-m", seeds(), *JOBS, f"hydra.sweep.dir={sweep}")  # in this process: only the stopped sweeps need their own
    assert done.returncode == 0, done.stderr[-2000:]
    return ends(sweep)


# basic runs its jobs in turn in the launching process, as joblib does in its workers (no job
# starts after the signal: the joblib case); its own bug, a Tee that closed stderr, is tested
# below: slow (30 s), run with pytest -m slow.
@pytest.mark.parametrize("launcher", [pytest.param(name, marks=pytest.mark.slow) if name == "basic" else name
                                      for name in LAUNCHERS])
def test_one_ctrl_c_stops_the_sweep_and_one_command_finishes_it(tmp_path, launcher, uninterrupted):
    sweep = tmp_path / "sweep"
    count = CASE_SEEDS.get(launcher, SEEDS)
    proc = train("-m", *LAUNCHERS[launcher], seeds(count), *JOBS, f"hydra.sweep.dir={sweep}", start_new_session=True)
    deadline = time.time() + 240
    while not any(len(p.read_bytes().splitlines()) > 5 for p in sweep.glob("1_*/metrics.csv")):
        assert time.time() < deadline and proc.poll() is None, proc.communicate()[1][-2000:]
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGINT)  # Ctrl-C reaches the whole process group
    out, err = proc.communicate(timeout=240)
    assert proc.returncode == 130, err[-3000:]
    assert "Traceback" not in err and "lost sys.stderr" not in err, err[-3000:]
    assert "the sweep was stopped (SIGINT)" in out
    if launcher in ("basic", "joblib"):  # jobs run in turn (two at once): the last one never began
        assert not (sweep / "3_cartpole_qlearn_seed3" / "run.json").exists()
    finish = re.search(r"^or the whole rest of the sweep in one command .*: (python train\.py resume=\S+)$", out, re.M)
    assert finish is not None and finish.group(1) == f"python train.py resume={sweep}", out[-3000:]
    done = run_train(f"resume={sweep}")  # the printed command, in this process (its never-started jobs too)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-2000:]
    unended = {job.name: (sorted(p.name for p in job.iterdir()), (job / "train.log").read_text()[-600:])
               for job in sweep.glob("*_seed*") if not (job / "model.pt").is_file()}
    assert not unended, (unended, err[-2000:], done.stdout[-2000:])  # (once in a suite under load: seed 1, no checkpoint)
    got = ends(sweep)
    assert got.keys() == {job for job in uninterrupted if int(job.rsplit("seed", 1)[1]) < count}
    for job, (metrics, table) in got.items():
        assert metrics == uninterrupted[job][0] and torch.equal(table, uninterrupted[job][1]), job


def test_closing_a_tee_closes_neither_the_terminal_nor_the_log():
    """A library that kept the stream it found (absl's log handler, imported inside a run)
    closes it when logging is configured again: that must not close the process's stderr."""
    terminal, log = io.StringIO(), io.StringIO()
    tee = Tee(terminal, log)
    tee.write("a\n")
    tee.close()
    assert not terminal.closed and not log.closed
    log.close()  # the run is over: its log closed, the terminal still written
    tee.write("b\n")
    tee.flush()
    assert terminal.getvalue() == "a\nb\n"
