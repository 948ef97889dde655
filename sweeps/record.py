"""The Hydra callback of ``conf/config.yaml`` (``hydra.callbacks.sweep_state``). Hydra builds
it for every run, a single one included, so it imports the sweep's state
(:class:`sweeps.state.RecordSweep`) only when a multirun starts or ends: a single run
loads nothing more of ``sweeps/`` than this file."""

from __future__ import annotations

from typing import Any

from hydra.experimental.callback import Callback


class RecordSweep(Callback):
    """:class:`sweeps.state.RecordSweep`, loaded when a multirun needs it."""

    def on_multirun_start(self, config: Any, **kwargs: Any) -> None:
        from sweeps.state import RecordSweep as Record

        Record().on_multirun_start(config, **kwargs)

    def on_multirun_end(self, config: Any, **kwargs: Any) -> None:
        from sweeps.state import RecordSweep as Record

        Record().on_multirun_end(config, **kwargs)
