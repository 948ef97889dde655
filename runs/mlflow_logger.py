"""TorchRL's MLflow logger for runs that share a process or a store: each run its own
MLflow run, addressed by id.

TorchRL's ``MLFlowLogger`` logs through MLflow's fluent API, whose one active run is
the process's: a second run in the same process (the seeds of a batch train side by
side) is refused ("Run ... is already active"). :class:`JobLogger` is that logger with
every call made through an ``MlflowClient`` and the run's own id, so any number of runs
log from one process, into one store; and a resumed run goes on logging into the MLflow
run it began (its id kept in ``logs/mlflow_run_id``).
"""

from __future__ import annotations

import fcntl
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Iterator, Mapping

from torchrl.record.loggers.mlflow import MLFlowLogger


@contextmanager
def _locked(store: Path) -> Iterator[None]:
    """Held while a process opens or creates the store and its experiment: jobs of a sweep
    in several processes (joblib) would otherwise race to create the SQLite schema."""
    with open(store.with_name(store.name + ".lock"), "a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


class JobLogger(MLFlowLogger):
    """One MLflow run of experiment ``experiment`` in the SQLite store ``store``, named
    ``run_name`` and tagged with ``tags``; its id in ``run_dir/logs/mlflow_run_id``."""

    def __init__(self, experiment: str, run_name: str, store: Path, run_dir: Path,
                 tags: Mapping[str, Any] | None = None) -> None:
        self._run_name, self._store, self._id_file = run_name, Path(store), Path(run_dir) / "logs" / "mlflow_run_id"
        self._tags = {k: str(v) for k, v in (tags or {}).items() if v is not None}
        super().__init__(exp_name=experiment, tracking_uri=f"sqlite:///{self._store}")

    def _create_experiment(self):
        from mlflow import MlflowClient
        from mlflow.exceptions import MlflowException

        with _locked(self._store):
            self.client = MlflowClient(tracking_uri=f"sqlite:///{self._store}")
            found = self.client.get_experiment_by_name(self.exp_name)
            self.id = found.experiment_id if found is not None else self.client.create_experiment(self.exp_name)
        if self._id_file.is_file():  # a resumed run: its MLflow run goes on
            try:
                run = self.client.get_run(self._id_file.read_text().strip())
                self.client.update_run(run.info.run_id, status="RUNNING")
                return run
            except MlflowException:
                pass  # a store that lost it: a new run
        run = self.client.create_run(self.id, run_name=self._run_name, tags=self._tags)
        self._id_file.write_text(run.info.run_id)
        return run

    @property
    def run_id(self) -> str:
        return self.experiment.info.run_id

    def log_scalar(self, name: str, value: float, step: int | None = None) -> None:
        self.client.log_metric(self.run_id, name, float(value), step=step or 0)

    def log_metrics(self, metrics: Mapping[str, Any], step: int | None = None, **_: Any) -> None:
        from mlflow.entities import Metric
        from mlflow.utils.time import get_current_time_millis

        now = get_current_time_millis()
        self.client.log_batch(self.run_id, metrics=[Metric(k, float(v), now, step or 0) for k, v in metrics.items()])

    def log_hparams(self, cfg: Mapping[str, Any]) -> None:
        from mlflow.entities import Param

        params = [Param(k, str(v)) for k, v in cfg.items()]
        for i in range(0, len(params), 100):  # MLflow's limit per batch
            self.client.log_batch(self.run_id, params=params[i:i + 100])

    def log_video(self, name: str, video: Any, **kwargs: Any) -> None:
        raise NotImplementedError("the run's video is policy.mp4 in its folder")

    def close(self, timeout: float | None = None) -> None:
        self.client.set_terminated(self.run_id)
