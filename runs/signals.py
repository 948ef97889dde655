"""Ctrl-C and SIGTERM during training: each run stops after its current step and saves; a
second Ctrl-C aborts at once.

A sweep's job in a process of its own (a joblib or submitit worker) may be signalled before
its training has started (while it imports or builds): :func:`hold_early` keeps that signal,
and :func:`stop_on_signals` then stops the runs after their first step, as if it had come
then. Light on purpose: ``train.py`` installs the hold before torch or MuJoCo load.
"""

from __future__ import annotations

import signal
import sys
import threading
from contextlib import contextmanager
from typing import Iterator, Protocol

SIGNALS = (signal.SIGINT, signal.SIGTERM)
HELD: dict = {"signal": None}  # a signal that came before the training's handler was in place


class Stoppable(Protocol):
    stop_requested: bool

    def request_stop(self) -> None: ...


def say(line: str) -> None:
    """``line`` on stderr from a signal handler: a console that cannot be written to (closed,
    a full pipe) must not turn the stop into an exception."""
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def hold_early() -> None:
    """Until training starts, a Ctrl-C or SIGTERM is kept (:data:`HELD`), not raised."""
    if threading.current_thread() is not threading.main_thread():
        return  # signal handlers live in the main thread only

    def keep(signum, frame):
        HELD["signal"] = signum

    for sig in SIGNALS:
        signal.signal(sig, keep)


@contextmanager
def stop_on_signals(records: list[Stoppable]) -> Iterator[dict]:
    """Ctrl-C / SIGTERM ask each of ``records`` (those in it at the time) to stop after the
    current step; a second Ctrl-C aborts. A signal held since before (:func:`hold_early`)
    asks at once. Yields ``{"signal": None}``, where the stopping signal's number is put."""
    stopped: dict = {"signal": None}
    if threading.current_thread() is not threading.main_thread():
        yield stopped  # signal handlers live in the main thread only (e.g. joblib's threads)
        return

    def handler(signum, frame):
        if any(r.stop_requested for r in records) and signum == signal.SIGINT:
            raise KeyboardInterrupt
        stopped["signal"] = signum
        for record in records:
            record.request_stop()
        say(f"\n{signal.Signals(signum).name}: stopping after this step and saving a checkpoint "
            "(Ctrl-C again aborts without saving)")

    previous = {sig: signal.signal(sig, handler) for sig in SIGNALS}
    if HELD["signal"] is not None:
        signum, HELD["signal"] = HELD["signal"], None
        handler(signum, None)
    try:
        yield stopped
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
