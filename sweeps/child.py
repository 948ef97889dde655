"""Child commands (``train.py``) that a Ctrl-C of their caller stops as each would stop alone.

``subprocess.call`` gives a child a quarter of a second after Ctrl-C, then kills it: a
sweep killed mid-step loses what it would have saved, and the killed process leaves
"leaked semaphore" warnings behind. A child left running by a caller that was signalled
alone (``kill -INT <pid>``) goes on training unseen. Here each child runs in its own
session, so the caller passes each SIGINT on exactly once to every child running: the
first asks ``train.py`` to stop after its step and save a checkpoint, a second to abort
without saving; the caller starts no more children, waits for those running to exit,
then stops too. A SIGTERM of the caller is passed on the same way (:class:`Stopped` says
which signal it was).
"""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import IO


#: a child's exit codes when Ctrl-C or SIGTERM stopped it (train.py saved its checkpoints), or the signal itself.
STOPPED = {128 + signal.SIGINT, 128 + signal.SIGTERM, -signal.SIGINT, -signal.SIGTERM}


class Stopped(KeyboardInterrupt):
    """The caller was signalled (``signum``: SIGINT or SIGTERM); every child, passed the
    signal, has exited."""

    def __init__(self, signum: int = signal.SIGINT) -> None:
        super().__init__(signum)
        self.signum = signum


@contextlib.contextmanager
def _sigterm_as_stop() -> Iterator[None]:
    """Inside, a SIGTERM raises :class:`Stopped` (where this is the main thread)."""
    def stop(signum, frame):
        raise Stopped(signum)

    try:
        before = signal.signal(signal.SIGTERM, stop)
    except ValueError:  # not the main thread: the caller's handler stays
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, before)


def cores() -> int:
    """The CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


def call(cmd: Sequence[str], cwd: Path, stdout: IO | None = None, poll: Callable[[], None] | None = None,
         every: float = 1.0) -> int:
    """Runs ``cmd`` to its end and returns its exit code.

    Args:
        cmd: the command line.
        cwd: its working folder.
        stdout: a file for its stdout and stderr together; None: the caller's.
        poll: called every ``every`` seconds while the child runs (a progress bar's update).
        every: seconds between polls.

    Returns:
        The child's exit code.

    Raises:
        Stopped: after the child, passed the caller's SIGINT or SIGTERM, has exited.
    """
    return call_all([cmd], cwd, 1, [stdout], poll=poll, every=every)[0]


def call_all(cmds: Sequence[Sequence[str]], cwd: Path, jobs: int, stdouts: Sequence[IO | Path | None] | None = None,
             started: Callable[[int], None] | None = None, ended: Callable[[int, int], None] | None = None,
             poll: Callable[[], None] | None = None, every: float = 1.0) -> list[int | None]:
    """Runs ``cmds`` in order, up to ``jobs`` at once, and returns their exit codes.

    A child that a signal ended (a kill, a machine out of memory: exit code below 0 or 128
    and above) starts no more of them; those running go on to their end.

    Args:
        cmds: the command lines.
        cwd: their working folder.
        jobs: children running at once (at least 1).
        stdouts: per command, a file for its stdout and stderr together (a path: appended to,
            opened when the command starts); None: the caller's.
        started: called with a command's index when it starts.
        ended: called with a command's index and exit code when it exits.
        poll: called every ``every`` seconds while children run.
        every: seconds between polls.

    Returns:
        Each command's exit code; None for one never started.

    Raises:
        Stopped: after every child, passed the caller's SIGINT or SIGTERM, has exited.
    """
    with _sigterm_as_stop():
        return _call_all(cmds, cwd, jobs, stdouts, started, ended, poll, every)


def _call_all(cmds, cwd, jobs, stdouts, started, ended, poll, every) -> list[int | None]:
    stdouts = list(stdouts or [None] * len(cmds))
    codes: list[int | None] = [None] * len(cmds)
    running: dict[int, subprocess.Popen] = {}
    following, interrupted, halted = 0, False, False
    while True:
        while not (interrupted or halted) and following < len(cmds) and len(running) < max(jobs, 1):
            with contextlib.ExitStack() as stack:
                out = stdouts[following]
                if isinstance(out, Path):  # the child keeps its own copy of the open file
                    out.parent.mkdir(parents=True, exist_ok=True)
                    out = stack.enter_context(out.open("a"))
                running[following] = subprocess.Popen(cmds[following], cwd=cwd, stdout=out,
                                                      stderr=subprocess.STDOUT if out else None,
                                                      start_new_session=True)
            if started is not None:
                started(following)
            following += 1
        for i, proc in list(running.items()):
            if proc.poll() is not None:
                del running[i]
                codes[i] = proc.returncode
                halted = halted or proc.returncode < 0 or proc.returncode >= 128
                if ended is not None:
                    ended(i, proc.returncode)
        if not running and (interrupted or halted or following == len(cmds)):
            break
        try:
            time.sleep(every)
            if poll is not None:
                poll()
        except KeyboardInterrupt as stop:
            interrupted = getattr(stop, "signum", signal.SIGINT)
            for proc in running.values():
                if proc.poll() is None:
                    proc.send_signal(interrupted)
    if interrupted:
        raise Stopped(interrupted)
    return codes
