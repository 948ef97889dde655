"""What the launching process knows of the sweep it runs: its folder.

A Hydra callback (``conf/config.yaml``: ``hydra.callbacks.sweep_state``) records it
when the multirun starts, in the launching process, where no job's ``HydraConfig``
exists (joblib runs the jobs in other processes); ``train.py`` reads it to stop a
sweep cleanly on Ctrl-C.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback

SWEEP: dict[str, Path | None] = {"dir": None}


class RecordSweep(Callback):
    """Keeps the sweep folder in :data:`SWEEP` when a multirun starts."""

    def on_multirun_start(self, config: Any, **kwargs: Any) -> None:
        SWEEP["dir"] = Path(str(config.hydra.sweep.dir))
