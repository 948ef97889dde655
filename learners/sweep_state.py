"""What the launching process knows of the sweep it runs: its folder, and whether
its comparison is printed yet.

A Hydra callback (``conf/config.yaml``: ``hydra.callbacks.sweep_state``) records the
folder when the multirun starts, in the launching process, where no job's
``HydraConfig`` exists (joblib runs the jobs in other processes); ``train.py`` reads
it to stop a sweep cleanly on Ctrl-C. When the multirun ends, the same callback
prints the comparison of the sweep's learners and writes its files into the folder
(:func:`learners.comparison.report`), whatever the launcher.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback

from learners.comparison import NotASweep, report

SWEEP: dict[str, Any] = {"dir": None, "compared": False}


class RecordSweep(Callback):
    """Keeps the sweep folder in :data:`SWEEP` when a multirun starts; compares its jobs
    when it ends."""

    def on_multirun_start(self, config: Any, **kwargs: Any) -> None:
        SWEEP["dir"] = Path(str(config.hydra.sweep.dir))
        SWEEP["compared"] = False

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
    try:
        report(folder, stopped)
    except (Exception, KeyboardInterrupt) as err:  # noqa: BLE001 - the sweep itself is done
        text = " ".join(str(err).split())
        reason = text if isinstance(err, NotASweep) else f"{type(err).__name__}: {text}".rstrip(": ")
        print(f"comparison failed: {reason}", file=sys.stderr, flush=True)
    sys.stdout.flush()
