"""Metrics through TorchRL's loggers, chosen by ``logger=csv|tensorboard|wandb|mlflow|none``.

The heavy backends are optional extras (``pip install -e '.[tensorboard]'``
and so on); choosing one that is not installed is a one-line error.
W&B runs offline by default (no network needed); MLflow writes a local SQLite
store (``logs/mlflow.db``). Everything lands in the run folder under ``logs/``.

What a training run sends: ``episode/<name>`` scalars per finished episode
(:func:`log_episode`), ``eval/<name>`` per greedy evaluation
(:func:`log_evaluation`) and ``run/<name>`` at the end (:func:`finish_log`),
each at the step of the episode count; with no logger (``None``) they do
nothing.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import Any

from learners.episode import Episode
from learners.metrics_files import rolling_field
from params import ConfigError
from tasks.base import Success

# logger kind -> the package it needs (None: nothing beyond the base install)
NEEDS = {"csv": None, "tensorboard": "tensorboard", "wandb": "wandb", "mlflow": "mlflow"}
# the summary's numbers logged as run/<name> at the end
RUN_SCALARS = ("best_rolling", "mean_of_100_best_episodes", "score", "env_steps", "wall_s", "divergences")


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


def log_episode(logger, ep: Episode, success: Success) -> None:
    """``episode/<name>``: return, length, the measure and its rolling mean, env steps, the learner's."""
    if logger is None:
        return
    scalars = {"reward": ep.reward, "length": ep.length, success.measure: ep.value,
               rolling_field(success.measure, success.window): ep.rolling,
               "env_steps": ep.env_steps, **ep.extra}
    for key, value in scalars.items():
        logger.log_scalar(f"episode/{key}", float(value), step=ep.episode)


def log_evaluation(logger, row: dict, success: Success) -> None:
    """``eval/<name>``: a greedy evaluation's measure, mean length and return (``row`` as ``Run.evals``)."""
    if logger is None:
        return
    for key, value in ((success.measure, row["value"]), ("length", row["length"]), ("return", row["return"])):
        logger.log_scalar(f"eval/{key}", float(value), step=row["episode"])


def finish_log(logger, summary: dict) -> None:
    """``run/<name>``: the summary's headline numbers and whether it solved; then closes ``logger``."""
    if logger is None:
        return
    for key in RUN_SCALARS:
        logger.log_scalar(f"run/{key}", float(summary[key]), step=summary["episodes"])
    logger.log_scalar("run/solved", float(summary["solved"]), step=summary["episodes"])
    logger.close()
