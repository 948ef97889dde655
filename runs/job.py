"""One run to make, composed and checked from Hydra's config before anything is written.

    job = compose_job(cfg, run_dir, overrides, hydra_cfg)   # checked; loads no torch

A job is fresh, resumed (``resume=<run folder>``: the folder's config, the command's
changes applied) or an evaluation (``mode=eval checkpoint=...``). Every key is checked
by :func:`compose_job` (:func:`runs.settings.check_run_config`), before the folder is
locked, written or torch is imported, so a refusal is one line and leaves nothing behind.
A single run is made by :func:`runs.lifecycle.train_alone`; the seeds launcher composes its
batch's jobs with :func:`compose_job` itself and trains them with
:func:`runs.lifecycle.run_jobs` together.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import TYPE_CHECKING, Mapping, Sequence

from omegaconf import DictConfig

from params import CheckpointError, ConfigError
from runs.console import tuned_changes
from runs.folder import eval_config, held_elsewhere, resumed_config, run_folder_of
from runs.settings import check_fit, check_no_empty_mappings, check_run_config
from tasks.catalog import locate_model, run_choices, use_config_dirs

if TYPE_CHECKING:
    from runs.run import Progress

# Settings a batched job may not have: each makes a run that is not a fresh training run.
NOT_BATCHED = ("resume", "checkpoint")


def refusals() -> tuple[type[BaseException], ...]:
    """The errors that refuse a job in one line (exit 2), leaving its folder as it was: a
    value, a checkpoint, a config Hydra cannot instantiate."""
    from hydra.errors import InstantiationException

    return ConfigError, CheckpointError, InstantiationException


def keep_failure(run_dir: Path, message: str) -> None:
    """A sweep's job that failed: ``message`` printed (to stdout: the sweep's end says on
    stderr how many failed) and kept in its folder's ``error.txt`` (:func:`keep_error`); the
    sweep goes on."""
    print(message, flush=True)
    keep_error(run_dir, message)


def keep_error(run_dir: Path, message: str) -> None:
    """``message`` in ``run_dir/error.txt``, unless another live run holds that folder (a
    refusal for being in use by it: nothing of this process is written there) or it cannot
    be written (a full disk: the console has it)."""
    if held_elsewhere(run_dir):
        return
    try:
        (run_dir / "error.txt").write_text(message + "\n")
    except OSError:
        pass


@dataclasses.dataclass
class Job:
    """One run to make: its checked config, folder, choices (for the banner and run.json),
    command-line overrides and what its tuned file changed; ``resume``: it continues the
    stopped run in ``run_dir`` (its cfg: the folder's, resume= set); ``progress``: a tuning
    trial's report; ``held``: its caller holds the folder's lock and tees its console (a
    single run of train.py), else the batch that trains it does."""

    cfg: DictConfig
    run_dir: Path
    choices: Mapping[str, str | None]
    overrides: Sequence[str] = ()
    changes: Sequence[str] | None = None
    resume: bool = False
    progress: Progress | None = None
    held: bool = False


def batchable(cfg: DictConfig) -> bool:
    """Whether a job with ``cfg`` can train in a batch (a fresh training run, a tuning
    trial's included)."""
    return cfg.mode == "train" and not any(cfg.get(key) not in (None, "", False) for key in NOT_BATCHED)


def compose_job(cfg: DictConfig, run_dir: Path, overrides: Sequence[str], hydra_cfg: DictConfig) -> Job:
    """The job Hydra's ``cfg`` asks for in ``run_dir``, every key checked; writes nothing.

    Args:
        cfg: the composed config (a run folder's, for ``resume=``, is read here).
        run_dir: the folder Hydra gave the job.
        overrides: the command line's ``key=value`` words.
        hydra_cfg: Hydra's own config of the job (its choices and config sources).

    Returns:
        The job: its config, folder (a resumed run's own), choices and tuned changes.

    Raises:
        ConfigError: a key, value or path the job cannot take (one line).
        CheckpointError: a resumed folder or a checkpoint that cannot be used.
    """
    choices = run_choices(hydra_cfg.runtime.choices)  # tuned: None where no file applies
    sources = hydra_cfg.runtime.config_sources  # conf/, then any --config-dir
    use_config_dirs([s.path for s in sources if s.schema == "file" and s.provider != "main"])
    cfg = locate_model(cfg, choices.get("robot"), sources)
    resume = bool(cfg.get("resume"))
    if resume:
        if not isinstance(cfg.resume, str):
            raise ConfigError(f"resume must be the path of a run folder; got {cfg.resume!r}")
        from runs.training_state import read_run_json

        cfg, run_dir = resumed_config(cfg, list(overrides))
        choices = read_run_json(run_dir)
    elif cfg.mode == "eval" and run_folder_of(cfg.get("checkpoint")) is not None:
        cfg = eval_config(cfg, list(overrides))
    check_run_config(cfg)
    check_fit(cfg, choices)
    check_no_empty_mappings(cfg, overrides)
    changes = None if resume or cfg.mode == "eval" else tuned_changes(cfg, choices, overrides)
    return Job(cfg, run_dir, choices, overrides, changes, resume)
