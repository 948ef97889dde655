"""Metrics through TorchRL's loggers, chosen by ``logger=csv|tensorboard|wandb|mlflow|none``.

The heavy backends are optional extras (``pip install -e '.[tensorboard]'``
and so on); choosing one that is not installed is a one-line error.
W&B runs offline by default (no network needed); MLflow writes a local SQLite
store (``logs/mlflow.db``). Everything lands in the run folder under ``logs/``, but for a
job of a sweep (its folder's parent holds Hydra's ``multirun.yaml``) MLflow writes one
store for the sweep, ``<sweep>/mlflow.db``, one experiment named after the sweep folder
with one MLflow run per job (named after its folder, tagged with robot, task, learner
and seed), and W&B puts the sweep's runs in one group (the sweep folder's name), so
either UI shows a sweep's runs side by side.

What a training run sends, every scalar at the step of the run's env steps
(all copies' transitions so far): ``episode/<name>`` per finished episode
(:func:`log_episode`, ``episode/index`` its number), ``eval/<name>`` per
greedy evaluation (:func:`log_evaluation`), ``train/<name>`` the learner's
``train_stats()`` (:func:`log_train`; when, :class:`~runs.run.Run` says),
``run/<name>`` at the end (:func:`finish_log`: the summary's numbers under their
summary.json names, :func:`run_scalar_names`) and the resolved config once at
the start (:func:`log_hparams`). With no logger (``None``) they do nothing.
W&B: TorchRL gives each group its own step metric (``episode/step``, ...),
which holds these env steps.

The CSV logger (:class:`runs.csv_logger.BufferedCSVLogger`) keeps no scalar in memory
(TorchRL's keeps every one it writes: about 1 KB per episode, for ever) and writes through a
buffer that a checkpoint flushes (:func:`csv_sizes`); a resumed run cuts its files back to
the checkpoint's rows (:func:`cut_csv_files`), as it does metrics.csv.
"""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Mapping, Sequence

from omegaconf import DictConfig, OmegaConf

from runs.layout import is_sweep_folder
from runs.metrics_files import Episode
from runs.metrics_files import rolling_field
from runs.summary import measure_keys
from params import ConfigError

if TYPE_CHECKING:
    from tasks.base import Success

# logger kind -> the package it needs (None: nothing beyond the base install)
NEEDS = {"csv": None, "tensorboard": "tensorboard", "wandb": "wandb", "mlflow": "mlflow"}
# the summary's counts logged as run/<name> at the end, after its named numbers (run_scalar_names)
RUN_COUNTS = ("env_steps", "episodes", "wall_s", "divergences", "solved")


def sweep_of(run_dir: Path) -> Path | None:
    """The sweep folder ``run_dir`` is a job of (Hydra's ``multirun.yaml`` beside it), or None."""
    parent = Path(run_dir).resolve().parent
    return parent if is_sweep_folder(parent) else None


def make_logger(kind: str | None, run_dir: Path, exp_name: str, offline: bool = True,
                project: str = "mujoco-rl-toolkit", tags: Mapping[str, Any] | None = None) -> Any:
    """A TorchRL ``Logger`` writing below ``run_dir/logs``, or ``None`` for ``none``; a
    sweep's job logs into its sweep's MLflow experiment or W&B group (:func:`sweep_of`).
    ``tags``: the run's robot, task, learner and seed, as MLflow tags."""
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
    sweep = sweep_of(run_dir)
    if kind == "wandb":
        if offline:
            os.environ.setdefault("WANDB_MODE", "offline")
        # reinit="create_new": the seeds of a batch are runs of one process, each its own
        # (W&B's default finishes the process's run when the next one starts).
        kwargs["wandb_kwargs"] = {"offline": offline, "project": project, "name": Path(run_dir).name,
                                  "reinit": "create_new", **({"group": sweep.name} if sweep is not None else {})}
    if kind == "mlflow":
        from runs.mlflow_logger import JobLogger

        # MLflow 3 retired the plain directory store; a SQLite file is its local store.
        store = (sweep / "mlflow.db") if sweep is not None else (log_dir / "mlflow.db")
        return JobLogger(experiment=sweep.name if sweep is not None else exp_name, run_name=Path(run_dir).name,
                         store=store, run_dir=Path(run_dir), tags=tags)
    if kind == "csv":
        from runs.csv_logger import BufferedCSVLogger

        return BufferedCSVLogger(exp_name=exp_name, log_dir=str(log_dir))
    return get_logger(kind, logger_name=str(log_dir), experiment_name=exp_name, **kwargs)


def csv_sizes(run_dir: Path, logger=None) -> dict[str, int]:
    """The CSV logger's scalar files below ``run_dir/logs`` and their sizes in bytes, once
    ``logger`` (the run's, if any) has flushed them (empty without that logger): what a
    checkpoint records, so a resume can cut them back (a stat per file, however long the run)."""
    if logger is not None:
        logger.flush()
    return {path.relative_to(run_dir).as_posix(): path.stat().st_size
            for path in sorted((Path(run_dir) / "logs").glob("*/scalars/**/*.csv"))}


def cut_csv_files(run_dir: Path, sizes: Mapping[str, int]) -> None:
    """Cuts each CSV logger scalar file back to ``sizes[file]`` bytes and removes the files
    ``sizes`` does not name (written after the checkpoint)."""
    for path in (Path(run_dir) / "logs").glob("*/scalars/**/*.csv"):
        size = sizes.get(path.relative_to(run_dir).as_posix())
        if size is None:
            path.unlink()
        elif path.stat().st_size > size:
            os.truncate(path, size)


def log_episode(logger, ep: Episode, success: Success) -> None:
    """``episode/<name>``: return, length, the measure and its rolling mean, env steps, the
    learner's, and ``episode/index`` (the episode's number, to plot against episodes)."""
    if logger is None:
        return
    scalars = {"reward": ep.reward, "length": ep.length, success.measure: ep.value,
               rolling_field(success.measure, success.window): ep.rolling,
               "env_steps": ep.env_steps, "index": ep.episode, **ep.extra}
    _log(logger, "episode", scalars, ep.env_steps)


def log_evaluation(logger, row: dict, success: Success) -> None:
    """``eval/<name>``: a greedy evaluation's measure, mean length and return, and the training
    episodes before it (``eval/episode``); ``row`` as ``Run.evals``."""
    if logger is None:
        return
    scalars = {success.measure: row["value"], "length": row["length"], "return": row["return"],
               "episode": row["episode"]}
    _log(logger, "eval", scalars, row["env_steps"])


def log_train(logger, stats: Mapping[str, float], env_steps: int) -> None:
    """``train/<name>``: the learner's ``train_stats()`` (loss, epsilon, ...) at ``env_steps``."""
    if logger is not None and stats:
        _log(logger, "train", stats, env_steps)


def run_scalar_names(measure: str, window: int) -> tuple[str, ...]:
    """The ``run/<name>`` scalars of a run of the task measure ``measure`` judged over
    ``window`` episodes: its summary's numbers under their summary.json names
    (``train_return_mean``, ..., ``greedy_<measure>``, ``greedy_return``), then
    ``RUN_COUNTS``."""
    return tuple(f"run/{name}" for name in (*measure_keys(measure, window).logged(), *RUN_COUNTS))


def finish_log(logger, summary: dict) -> None:
    """``run/<name>`` (:func:`run_scalar_names`): the summary's numbers, each under its
    summary.json name (a number the run lacks, such as the greedy one without an
    evaluation, is left out), its counts and whether it solved; then closes ``logger``."""
    if logger is None:
        return
    names = [n.split("/", 1)[1] for n in run_scalar_names(summary["measure"], summary["window"])]
    scalars = {key: summary[key] for key in names if summary.get(key) is not None}
    _log(logger, "run", scalars, summary["env_steps"])
    logger.close()


def _log(logger, group: str, scalars: Mapping[str, Any], step: int) -> None:
    """``<group>/<name>`` for each of ``scalars`` at ``step``, as one batch (one MLflow call,
    one W&B row)."""
    logger.log_metrics({f"{group}/{key}": float(value) for key, value in scalars.items()},
                       step=int(step))


def flat_config(cfg: DictConfig | Mapping) -> dict[str, int | float | str | bool]:
    """``cfg`` resolved, as ``{"learner.lr": 0.001, ...}``: nested keys joined by dots, lists
    as their text (``"[64, 64]"``), unset (``null``) values left out."""
    tree = OmegaConf.to_container(cfg, resolve=True) if isinstance(cfg, DictConfig) else cfg
    flat: dict[str, int | float | str | bool] = {}

    def walk(node: Mapping, prefix: str) -> None:
        for key, value in node.items():
            if isinstance(value, Mapping):
                walk(value, f"{prefix}{key}.")
            elif value is not None:
                scalar = isinstance(value, (bool, int, float, str))
                flat[f"{prefix}{key}"] = value if scalar else str(value)

    walk(tree, "")
    return flat


def log_hparams(logger, cfg: DictConfig | Mapping, metrics: Sequence[str] = ()) -> None:
    """The resolved run config (:func:`flat_config`), once, at the start: TensorBoard's
    HParams tab (the run's session in its own event file; its metrics, ``metrics``, are the
    ``run/*`` scalars logged at the end: :func:`run_scalar_names`), W&B's config, MLflow's
    params, the CSV logger's ``texts/hparams0.txt``."""
    if logger is None:
        return
    flat = flat_config(cfg)
    from torchrl.record.loggers.tensorboard import TensorboardLogger

    if not isinstance(logger, TensorboardLogger):
        logger.log_hparams(flat)
        return
    # TorchRL's (SummaryWriter.add_hparams) writes them to a new run in a subfolder, away
    # from this run's scalars; these summaries are the same, in this run's event file. No
    # experiment summary: TensorBoard would show every run of a folder with the settings of
    # the first run that has one; without, it shows the settings of all (a sweep writes one
    # of its own, :func:`write_sweep_hparams`).
    from torch.utils.tensorboard.summary import hparams

    _, session_start, session_end = hparams(flat, dict.fromkeys(metrics, 0.0))
    writer = logger.experiment._get_file_writer()
    for summary in (session_start, session_end):
        writer.add_summary(summary)


def write_sweep_hparams(folder: Path, configs: list[Mapping], metrics: Sequence[str]) -> Path:
    """TensorBoard's experiment for a sweep's runs, in ``folder/hparams``: every setting any
    of ``configs`` (the runs' resolved configs) has, and ``metrics`` (the runs' ``run/*``
    scalars, :func:`run_scalar_names`) as its metrics, so ``tensorboard --logdir <sweep>``
    compares the runs in its HParams tab."""
    from torch.utils.tensorboard import SummaryWriter
    from torch.utils.tensorboard.summary import hparams

    examples: dict = {}
    for cfg in configs:
        for key, value in flat_config(cfg).items():
            examples.setdefault(key, value)
    experiment, _, _ = hparams(dict(sorted(examples.items())), dict.fromkeys(dict.fromkeys(metrics), 0.0))
    out = Path(folder) / "hparams"
    for old in out.glob("events.out.tfevents.*"):
        old.unlink()  # compare.py again: one experiment
    writer = SummaryWriter(str(out))
    writer._get_file_writer().add_summary(experiment)
    writer.close()
    return out
