"""``python train.py <args>`` run in the test's own process: torch, TorchRL and MuJoCo are
imported once per worker instead of once per command (about 4 s each on this machine). A few
tests keep a real subprocess to prove the wiring (signals, exit codes, a fresh interpreter)."""

from __future__ import annotations

import io
import logging
import signal
import subprocess
import sys
from contextlib import redirect_stderr, redirect_stdout

from hydra.core.global_hydra import GlobalHydra

import train

QUIET_HYDRA = ["hydra/job_logging=none", "hydra/hydra_logging=none"]  # Hydra keeps no test's stream


def run_train(*args: str) -> subprocess.CompletedProcess:
    """``train.py <args>`` in this process: its exit code, stdout and stderr, as
    :func:`subprocess.run` gives them."""
    GlobalHydra.instance().clear()
    argv, in_job = sys.argv, train._IN_JOB
    handlers = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}  # a sweep sets its own
    sys.argv = ["train.py", *args, *QUIET_HYDRA]
    train._IN_JOB = False
    out, err, code = io.StringIO(), io.StringIO(), 0
    root, level = logging.getLogger(), logging.getLogger().level
    logged = logging.StreamHandler(out)  # Hydra's default job logging: INFO and up on the console
    root.addHandler(logged)
    root.setLevel(logging.INFO)
    try:
        with redirect_stdout(out), redirect_stderr(err):
            train.cli()
    except SystemExit as stop:
        code = stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 1)
    finally:
        root.removeHandler(logged)
        root.setLevel(level)
        sys.argv, train._IN_JOB = argv, in_job
        for sig, handler in handlers.items():
            signal.signal(sig, handler)
        GlobalHydra.instance().clear()
    return subprocess.CompletedProcess(["train.py", *args], code, out.getvalue(), err.getvalue())


def train_in_process(run_dir, *args: str):
    """``train.py <args> hydra.run.dir=<run_dir>`` in this process (the product's path from the
    command line), which must succeed; the trained learner's member as its ``model.pt`` holds
    it, built from the run's ``config.yaml``."""
    from hydra.utils import instantiate

    from runs.checkpoint import load_model
    from runs.training_state import load_run_config
    from tasks.factory import build_task

    done = run_train(*args, f"hydra.run.dir={run_dir}")
    assert done.returncode == 0, done.stderr[-2000:]
    cfg = load_run_config(run_dir)
    learner = instantiate(cfg.learner, _convert_="all")
    learner.build(build_task(cfg))
    member = learner.member(0)
    load_model(run_dir / "model.pt", member)
    return member
