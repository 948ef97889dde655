"""What the launching process knows of the sweep it runs: its folder, whether its
comparison is printed yet, and whether it was asked to stop.

A Hydra callback (``conf/config.yaml``: ``hydra.callbacks.sweep_state``) records the
folder when the multirun starts, in the launching process, where no job's
``HydraConfig`` exists (joblib runs the jobs in other processes); :func:`stop_sweep`
reads it to stop a sweep cleanly on Ctrl-C (a ``.stop`` file that jobs not started
yet see through :func:`sweep_stopped`). When the multirun ends, the same callback
prints the comparison of the sweep's learners and writes its files into the folder
(:func:`sweeps.comparison.report`), whatever the launcher.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback

from params import ConfigError
from runs.layout import train_command
from runs.signals import HELD, say
from runs.summary import summarize_run
from sweeps.folder import job_folders, sweep_jobs
from sweeps.comparison import NotASweep, report
from sweeps.launchers import check_launcher

# The sweep's folder, whether it is compared yet, the signal that stopped it (if any), and its
# jobs as the comparison counted them: all, and those that failed or never started.
SWEEP: dict[str, Any] = {"dir": None, "compared": False, "signal": None, "jobs": 0, "unfinished": 0}


class SweepRefused(BaseException):
    """A sweep refused before any job started (Hydra turns a callback's ``Exception`` into
    a warning and launches anyway; this one reaches ``train.cli``, which prints it)."""


class RecordSweep(Callback):
    """Checks the launcher and keeps the sweep folder in :data:`SWEEP` when a multirun
    starts; compares its jobs when it ends."""

    def on_multirun_start(self, config: Any, **kwargs: Any) -> None:
        try:
            check_launcher(config.hydra.get("launcher"))
        except ConfigError as err:
            raise SweepRefused(str(err)) from None
        launcher = config.hydra.get("launcher")
        if launcher is not None and str(launcher.get("_target_", "")).endswith("LocalLauncher"):  # submitit_local's
            keep_controllers_through_ctrl_c()
        # Resolved here, once, in the launching process: ${now:} and ${pid:} are cached
        # resolvers, and Hydra copies their cached values into every job's config.
        SWEEP["dir"] = Path(str(config.hydra.sweep.dir))
        SWEEP.update(compared=False, jobs=0, unfinished=0)

    def on_multirun_end(self, config: Any, **kwargs: Any) -> None:
        # The folder as resolved at the start (its name holds the time: ${now:...}).
        compare_sweep(SWEEP["dir"] or Path(str(config.hydra.sweep.dir)))


def compare_sweep(folder: Path | None, stopped: str | None = None) -> None:
    """Prints the comparison of the sweep in ``folder`` and writes its files there, once
    per sweep (a stopped sweep's launcher asks again: Hydra skips ``on_multirun_end``
    when the launcher raises; ``stopped``: the signal's name). Never raises: a failure
    is one line, ``comparison failed: <reason>``, and the sweep's exit status stays its own."""
    if SWEEP["compared"] or folder is None:
        return
    SWEEP["compared"] = True
    print(flush=True)
    if folder.is_dir() and not job_folders(folder):
        print("no job of this sweep ran: nothing to compare", flush=True)  # (a study's sweep of no new trials)
        return
    try:
        rows = report(folder, stopped)
        SWEEP["jobs"] = sum(int(r["seeds"]) for r in rows)
        SWEEP["unfinished"] = sum(int(r["failed"]) + int(r["never_started"]) for r in rows)
    except (Exception, KeyboardInterrupt) as err:  # noqa: BLE001 - the sweep itself is done
        text = " ".join(str(err).split())
        reason = text if isinstance(err, NotASweep) else f"{type(err).__name__}: {text}".rstrip(": ")
        print(f"comparison failed: {reason}", file=sys.stderr, flush=True)
    sys.stdout.flush()


def sweep_dir() -> Path | None:
    """The running sweep's folder: a job's own, else what the launcher recorded."""
    try:
        return Path(str(HydraConfig.get().sweep.dir))
    except Exception:  # noqa: BLE001 - the launching process has no job config
        return SWEEP["dir"]


def stop_sweep(signum, frame) -> None:
    """The launcher's Ctrl-C / SIGTERM during a sweep: running jobs (which get the signal
    too) stop after their step and save; jobs not started yet are skipped (``.stop``)."""
    if SWEEP["signal"] is not None and signum == signal.SIGINT:
        raise KeyboardInterrupt
    SWEEP["signal"] = signum
    folder = sweep_dir()
    if folder is not None and folder.is_dir():
        (folder / ".stop").write_text(signal.Signals(signum).name + "\n")
    say(f"\n{signal.Signals(signum).name}: the sweep's running jobs stop after their step and "
        "save a checkpoint; jobs not started are skipped (Ctrl-C again aborts)")


def sweep_stopped() -> bool:
    """Inside a job: whether its sweep was asked to stop before the job began (in the
    launching process, even before the sweep's folder existed to hold ``.stop``)."""
    if SWEEP["signal"] is not None or HELD["signal"] is not None:
        return True
    folder = sweep_dir()
    return folder is not None and (folder / ".stop").exists()


def report_stopped_sweep(folder: Path) -> None:
    """One resume command per job the stop left unfinished, each job not started named, and
    the one command that finishes the sweep."""
    resumable = not_started = 0
    for job in sweep_jobs(folder)[0]:  # planned jobs too: a launcher stopped before their folders
        if job.get("resume"):
            print(f"resume with: {job['resume']}")
            resumable += 1
        elif job["status"] == "never started":
            where = Path(job["run_dir"]).name if job.get("run_dir") else f"job {job['job']}"
            print(f"not started: {where}")
            not_started += 1
    if resumable > 1 or not_started:
        print(f"or the whole rest of the sweep in one command (stopped jobs resumed, then jobs not started "
              f"begun, seeds of one setting together): {train_command()} resume={folder}")
    record = folder / "multirun.yaml"
    if record.is_file() and "rl_optuna_sweeper" in record.read_text(errors="replace"):
        print("or the same tuning command again: the next sweep of the study resumes the trials this "
              "one left running, tells the study their values and goes on")


def end_stopped_sweep() -> int | None:
    """After a stopped sweep: the comparison of what finished and how to resume the rest;
    the exit status (128 + the signal), or None if the sweep was not stopped."""
    if SWEEP["signal"] is None:
        return None
    folder = sweep_dir()
    if folder is not None and folder.is_dir():
        # What finished; done already unless a job's exit skipped on_multirun_end.
        compare_sweep(folder, stopped=signal.Signals(int(SWEEP["signal"])).name)
        report_stopped_sweep(folder)
    return 128 + int(SWEEP["signal"])


def end_failed_sweep() -> bool:
    """After a sweep whose launcher failed (e.g. a joblib worker killed from outside): the
    comparison and the resume commands, if the sweep's folder exists; whether it did."""
    folder = sweep_dir()
    if folder is None or not folder.is_dir():
        return False
    compare_sweep(folder)  # Hydra skips on_multirun_end when the launcher raises
    report_stopped_sweep(folder)
    return True


def end_sweep() -> int:
    """After a sweep that was not stopped: 0 when every job finished; else one line on stderr
    and a non-zero status. Every job failed: the first job's reason (:func:`sweep_failures`),
    2 where it is an input error, else 1. Some failed or never started: how many, and 1."""
    failures = sweep_failures(SWEEP["dir"] or sweep_dir())
    if failures is not None and failures[0]:
        print(failures[1], file=sys.stderr, flush=True)
        return failures[0]
    if not SWEEP["unfinished"]:
        return 0
    first = f"; {failures[1].split('; ', 1)[1]}" if failures is not None else ""
    print(f"error: {SWEEP['unfinished']} of {SWEEP['jobs']} jobs failed or never started "
          f"(listed above){first}: the sweep exits 1", file=sys.stderr, flush=True)
    return 1


def sweep_failures(folder: Path | None) -> tuple[int, str] | None:
    """After a sweep: None if no job failed; else the exit status and one line. Every job
    failed: ``error: every job of the sweep failed (N); the first, <job>: <its reason>``, status
    2 where that reason is a one-line input error (``error: ...``), else 1. Some failed:
    ``K of N jobs failed; the first, ...``, status 0 (:func:`end_sweep` makes it 1)."""
    if folder is None or not folder.is_dir():
        return None
    jobs = sorted((p for p in folder.iterdir()
                   if p.is_dir() and ((p / "run.json").exists() or (p / "error.txt").exists())), key=_job_number)
    failed = [(job, summarize_run(job)) for job in jobs]
    failed = [(job, state) for job, state in failed if state["status"] == "failed"]
    if not failed:
        return None
    job, state = failed[0]
    reason = str(state.get("error") or "failed")
    first = f"the first, {job.name}: {reason.removeprefix('error: ')}"
    if len(failed) < len(jobs):
        return 0, f"{len(failed)} of {len(jobs)} jobs failed; {first}"
    return (2 if reason.startswith("error: ") else 1), f"error: every job of the sweep failed ({len(jobs)}); {first}"


def _job_number(job: Path) -> tuple[int, str]:
    number = job.name.split("_", 1)[0]
    return (int(number) if number.isdigit() else 1 << 62, job.name)


BROKEN = ".broken"  # in the sweep folder: the launcher is ending its workers (one of them died)
GRACE_S = 60.0  # how long the siblings of a dead worker get to save before they are killed


def let_siblings_save(grace_s: float = GRACE_S) -> None:
    """In the launching process of a joblib sweep: when one worker dies, loky kills the others
    at once (SIGKILL), losing what they trained since their last checkpoint. Patched here to
    ask them first (SIGTERM: each stops after its step and saves, see :func:`sibling_should_exit`)
    and to wait up to ``grace_s`` seconds before loky's SIGKILL. Idempotent; a no-op without loky."""
    try:
        from joblib.externals.loky.process_executor import _ExecutorManagerThread
    except ImportError:
        return
    kill = _ExecutorManagerThread.kill_workers
    if getattr(kill, "lets_siblings_save", False):
        return

    def gentle(self, reason: str = "") -> None:
        if reason == "broken executor":
            folder = sweep_dir()
            workers = list(self.processes.values())
            if folder is not None and folder.is_dir():
                (folder / BROKEN).write_text("a worker died\n")
                for worker in workers:
                    try:
                        os.kill(worker.pid, signal.SIGTERM)
                    except (ProcessLookupError, TypeError):
                        pass
                deadline = time.monotonic() + grace_s
                for worker in workers:
                    worker.join(max(0.0, deadline - time.monotonic()))
        kill(self, reason)

    gentle.lets_siblings_save = True
    _ExecutorManagerThread.kill_workers = gentle


def sibling_should_exit() -> bool:
    """Inside a job: whether its launcher is ending the workers (:func:`let_siblings_save`), so a
    job stopped by its SIGTERM, saved, ends its worker process (else the launcher would wait)."""
    folder = sweep_dir()
    return folder is not None and (folder / BROKEN).exists()


def keep_controllers_through_ctrl_c() -> None:
    """In the launching process of a submitit_local sweep: submitit starts each job under a
    controller process of its own, in the terminal's process group, which dies on Ctrl-C with a
    traceback and sends its job a second SIGINT (abort, nothing saved) and then SIGKILL.
    Patched here to start each controller with SIGINT ignored (inherited by its job, whose
    training handles the signal itself: :mod:`runs.signals`), so the job stops after its step,
    saves, and the controller ends with it. Idempotent; a no-op without submitit."""
    try:
        from submitit.local import local
    except ImportError:
        return
    start = local.start_controller
    if getattr(start, "keeps_through_ctrl_c", False):
        return

    def start_ignoring_ctrl_c(*args, **kwargs):
        previous = signal.signal(signal.SIGINT, signal.SIG_IGN)
        try:
            return start(*args, **kwargs)
        finally:
            signal.signal(signal.SIGINT, previous)

    start_ignoring_ctrl_c.keeps_through_ctrl_c = True
    local.start_controller = start_ignoring_ctrl_c
