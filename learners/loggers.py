"""Metrics through TorchRL's loggers, chosen by ``logger=csv|tensorboard|wandb|mlflow|none``.

The heavy backends are optional extras (``pip install -e '.[tensorboard]'``
and so on); choosing one that is not installed is a one-line error.
W&B runs offline by default (no network needed); MLflow writes a local SQLite
store (``logs/mlflow.db``). Everything lands in the run folder under ``logs/``.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import Any

from params import ConfigError

# logger kind -> the package it needs (None: nothing beyond the base install)
NEEDS = {"csv": None, "tensorboard": "tensorboard", "wandb": "wandb", "mlflow": "mlflow"}


def make_logger(kind: str | None, run_dir: Path, exp_name: str, offline: bool = True,
                project: str = "mujoco-rl-toolkit") -> Any:
    """A TorchRL ``Logger`` writing below ``run_dir/logs``, or ``None`` for ``none``."""
    if kind in (None, "", "none"):
        return None
    if kind not in NEEDS:
        raise ConfigError(f"logger must be one of {', '.join([*NEEDS, 'none'])}; got {kind!r}")
    package = NEEDS[kind]
    if package is not None and importlib.util.find_spec(package) is None:
        raise ConfigError(
            f"logger={kind} needs the {package} package, which is not installed; "
            f"install it with: pip install -e '.[{kind}]'")
    from torchrl.record.loggers import get_logger

    log_dir = Path(run_dir) / "logs"
    log_dir.mkdir(parents=True, exist_ok=True)
    kwargs: dict = {}
    if kind == "wandb":
        if offline:
            os.environ.setdefault("WANDB_MODE", "offline")
        kwargs["wandb_kwargs"] = {"offline": offline, "project": project}
    if kind == "mlflow":
        # MLflow 3 retired the plain directory store; a SQLite file is its local store.
        from torchrl.record.loggers.mlflow import MLFlowLogger

        return MLFlowLogger(exp_name=exp_name, tracking_uri=f"sqlite:///{log_dir / 'mlflow.db'}")
    return get_logger(kind, logger_name=str(log_dir), experiment_name=exp_name, **kwargs)
