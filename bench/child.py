"""A child command (``train.py``) that a Ctrl-C of its caller stops as it would stop alone.

``subprocess.call`` gives a child a quarter of a second after Ctrl-C, then kills it: a
sweep killed mid-step loses what it would have saved, and the killed process leaves
"leaked semaphore" warnings behind. A child left running by a caller that was signalled
alone (``kill -INT <pid>``) goes on training unseen. Here the child runs in its own
session, so the caller passes each SIGINT on exactly once: the first asks ``train.py`` to
stop after its step and save a checkpoint, a second to abort without saving; the caller
waits for the child to exit, then stops too.
"""

from __future__ import annotations

import signal
import subprocess
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import IO


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
        KeyboardInterrupt: after the child, passed the caller's SIGINT, has exited.
    """
    proc = subprocess.Popen(cmd, cwd=cwd, stdout=stdout, stderr=subprocess.STDOUT if stdout else None,
                            start_new_session=True)
    interrupted = False
    while proc.poll() is None:
        try:
            time.sleep(every)
            if poll is not None:
                poll()
        except KeyboardInterrupt:
            interrupted = True
            if proc.poll() is None:
                proc.send_signal(signal.SIGINT)
    if interrupted:
        raise KeyboardInterrupt
    return proc.returncode
