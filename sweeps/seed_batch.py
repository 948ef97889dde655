"""The ``seeds`` launcher's work: a sweep's jobs grouped by their configs but the seed, a
tuning trial and the learner's member-wise settings (:func:`runs.lifecycle.same_batch`:
a study's trials side by side), each group of fresh training runs trained as one batch
(:func:`runs.lifecycle.run_jobs`).

Every job still goes through Hydra's ``run_job`` (its folder, logging, callbacks). A
batch's job is composed and checked there by the launcher itself (:meth:`SeedBatchLaunch.check`:
:func:`runs.job.compose_job`, as ``train.py`` checks a single run), and the launcher trains
the batch of them (:func:`runs.lifecycle.run_jobs`) once all of its group has been checked.
A group of one, and jobs that are not fresh training runs (``resume=``, ``mode=eval``), run
alone through the app's own task, as with ``hydra/launcher=basic``. The submitit
launchers group by the overrides but ``seed``.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path
from typing import Callable, Sequence

from hydra.core.utils import JobReturn, configure_log, filter_overrides, run_job, setup_globals
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf, open_dict

from hydra.core.hydra_config import HydraConfig

from params import ConfigError
from params.private_api import apply_value_overrides, overrides_dirname
from runs.command import one_line
from runs.folder import cannot_write, write_hydra_record
from runs.job import batchable, compose_job, keep_error, keep_failure, refusals
from runs.lifecycle import Job, batch_key, run_jobs, same_batch

log = logging.getLogger(__name__)
# ``launch_fed``'s source of jobs: (the jobs that ended: index and folder, members free
# beyond those waiting) -> the next jobs (index, overrides).
Feed = Callable[[Sequence[tuple[int, Path]], int], Sequence[tuple[int, Sequence[str]]]]


def _key(override: str) -> str:
    return override.split("=", 1)[0].lstrip("+~")


def group_jobs(job_overrides: Sequence[Sequence[str]]) -> list[list[int]]:
    """Job indices grouped by every override except ``seed`` (in first-seen order); a seed
    given twice in one group is refused with one line."""
    groups: dict[tuple, list[int]] = {}
    for i, overrides in enumerate(job_overrides):
        rest = tuple(sorted(o for o in overrides if _key(o) != "seed"))
        groups.setdefault(rest, []).append(i)
    for members in groups.values():
        seeds = [o for i in members for o in job_overrides[i] if _key(o) == "seed"]
        twice = sorted({s for s in seeds if seeds.count(s) > 1})
        if twice:
            raise ConfigError(f"{twice[0]} is given twice in one sweep; give each seed once")
    return list(groups.values())


def batches(job_overrides: Sequence[Sequence[str]], initial_job_idx: int, max_seeds: int,
            groups: list[list[int]] | None = None) -> list[list[tuple[int, list[str]]]]:
    """The sweep's jobs (job index, overrides) in batches: each group (default: of
    :func:`group_jobs`, which refuses a seed given twice) cut into batches of ``max_seeds``
    at most."""
    checked = group_jobs(job_overrides)
    return [[(initial_job_idx + i, list(job_overrides[i])) for i in members[start:start + max_seeds]]
            for members in (checked if groups is None else groups) for start in range(0, len(members), max_seeds)]


def check_max_seeds(max_seeds) -> None:
    """One line unless ``max_seeds`` (seeds a batch at most) is an integer >= 1."""
    if type(max_seeds) is not int or max_seeds < 1:
        raise ConfigError(f"hydra.launcher.max_seeds must be an integer >= 1; got {max_seeds!r}")


class SeedBatchLaunch:
    """Launches a sweep's jobs, a group of seeds as one batch (``max_seeds`` at most each)."""

    def __init__(self, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig,
                 max_seeds: int = 64) -> None:
        check_max_seeds(max_seeds)
        self.hydra_context, self.task_function, self.config = hydra_context, task_function, config
        self.max_seeds = max_seeds
        self.composed: dict[int, DictConfig] = {}  # each job's composed config, by job index

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> list[JobReturn]:
        setup_globals()
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        composed = compose_jobs(self.hydra_context.config_loader, self.config, job_overrides)  # each job's, once
        self.composed = {initial_job_idx + i: cfg for i, cfg in enumerate(composed)}
        groups = same_batch([_without_hydra(self.composed[initial_job_idx + i]) for i in range(len(job_overrides))])
        chunks = batches(job_overrides, initial_job_idx, self.max_seeds, groups)  # refused before any job starts
        Path(str(self.config.hydra.sweep.dir)).mkdir(parents=True, exist_ok=True)
        log.info(f"Launching {len(job_overrides)} jobs in this process, seeds of the same "
                 f"settings together ({len(chunks)} batch{'es' * (len(chunks) != 1)})")
        returns: dict[int, JobReturn] = {}
        for chunk in chunks:
            returns.update(self.run_chunk(chunk))
        return [returns[initial_job_idx + i] for i in range(len(job_overrides))]

    def launch_fed(self, jobs: Sequence[tuple[int, Sequence[str]]], more: Feed) -> dict[int, JobReturn]:
        """Launches ``jobs`` (job index, overrides) as :meth:`launch` does, each batch's freed
        members given the jobs ``more(ended, room)`` hands in (:func:`runs.lifecycle.run_jobs`):
        ``ended`` the jobs that ended at a step (index, folder), ``room`` the members free
        beyond the jobs already waiting. A job handed in that does not fit the running batch
        (another shape) waits for a batch of its own after it. Returns every job's return by
        index."""
        setup_globals()
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        Path(str(self.config.hydra.sweep.dir)).mkdir(parents=True, exist_ok=True)
        waiting = [(idx, list(overrides)) for idx, overrides in jobs]
        returns: dict[int, JobReturn] = {}
        while waiting:
            keys = self._keys(waiting)
            batch = [job for job in waiting if keys[job[0]] == keys[waiting[0][0]]][:self.max_seeds]
            waiting[:] = [job for job in waiting if job not in batch]
            returns.update(self._fed_batch(batch, keys[batch[0][0]], waiting, more))
        return returns

    def _keys(self, jobs: Sequence[tuple[int, list[str]]]) -> dict[int, str]:
        """Each job's batch key by index (:func:`runs.lifecycle.batch_key`: jobs of one key
        may share a batch), its config composed once and kept for its run."""
        new = [(idx, overrides) for idx, overrides in jobs if idx not in self.composed]
        if new:
            composed = compose_jobs(self.hydra_context.config_loader, self.config, [o for _, o in new])
            self.composed.update({idx: cfg for (idx, _), cfg in zip(new, composed)})
        return {idx: repr(batch_key(_without_hydra(self.composed[idx]))) for idx, _ in jobs}

    def _fed_batch(self, chunk: list[tuple[int, list[str]]], key: str, waiting: list, more: Feed
                   ) -> dict[int, JobReturn]:
        """One batch of ``chunk`` trained with its freed members fed (:meth:`launch_fed`);
        jobs handed in go to ``waiting`` first, and those of this batch's ``key`` take freed
        members in order."""
        returns = {idx: self._run(idx, overrides, collect=True) for idx, overrides in chunk}
        index = {id(ret.return_value): idx for idx, ret in returns.items() if isinstance(_value(ret), Job)}
        jobs = [ret.return_value for ret in returns.values() if isinstance(_value(ret), Job)]

        def feed(ended: Sequence[Job], free: int) -> list[Job]:
            handed = more([(index[id(job)], job.run_dir) for job in ended], free - len(waiting))
            waiting.extend((idx, list(overrides)) for idx, overrides in handed)
            given, keys = [], self._keys(waiting)
            for idx, overrides in list(waiting):
                if len(given) == free:
                    break
                if keys[idx] != key:
                    continue  # another shape: a batch of its own later
                waiting.remove((idx, overrides))
                returns[idx] = ret = self._run(idx, overrides, collect=True)
                if isinstance(_value(ret), Job):  # (a job that failed its checks has its return)
                    index[id(ret.return_value)] = idx
                    given.append(ret.return_value)
            return given

        if jobs:
            log.info(f"Training {len(jobs)} runs together, freed members taking the next ones: " + ", ".join(
                f"trial {j.cfg.get('trial')} seed {j.cfg.seed}" for j in jobs))
        _batch(jobs, feed)
        return returns

    def run_chunk(self, chunk: list[tuple[int, list[str]]]) -> dict[int, JobReturn]:
        """One batch's jobs (job index, overrides): trained together, or alone if one."""
        return self._launch_batch(chunk) if len(chunk) > 1 else {chunk[0][0]: self._run(*chunk[0])}

    def _run(self, idx: int, overrides: Sequence[str], collect: bool = False) -> JobReturn:
        """One job through Hydra's ``run_job``, as the basic launcher runs it; ``collect``: the
        job's task is :meth:`check` (a batchable job returns its checked :class:`~runs.job.Job`
        instead of training)."""
        log.info(f"\t#{idx} : {' '.join(filter_overrides(overrides))}")
        composed = self.composed.pop(idx, None)  # launch composed it to group the jobs
        sweep_config = composed if composed is not None else \
            self.hydra_context.config_loader.load_sweep_config(self.config, list(overrides))
        with open_dict(sweep_config):
            sweep_config.hydra.job.id = idx
            sweep_config.hydra.job.num = idx
        ret = run_job(hydra_context=self.hydra_context, task_function=self.check if collect else self.task_function,
                      config=sweep_config, job_dir_key="hydra.sweep.dir", job_subdir_key="hydra.sweep.subdir")
        configure_log(self.config.hydra.hydra_logging, self.config.hydra.verbose)
        return ret

    def check(self, cfg: DictConfig) -> Job | None:
        """A batch's job, inside Hydra's ``run_job`` (its folder and config set):
        :func:`checked_job`, to train with the others (None: refused, or the sweep was stopped
        before it began); a job that is not a fresh training run is the app's own task's."""
        if not batchable(cfg):
            return self.task_function(cfg)
        from sweeps.state import sweep_stopped

        if sweep_stopped():
            return None  # the sweep was stopped before this job began: it never starts
        hydra_cfg = HydraConfig.get()
        return checked_job(cfg, Path(hydra_cfg.runtime.output_dir), hydra_cfg)

    def _launch_batch(self, chunk: list[tuple[int, Sequence[str]]]) -> dict[int, JobReturn]:
        """The chunk's jobs checked and handed over, then trained as one batch."""
        returns = {idx: self._run(idx, overrides, collect=True) for idx, overrides in chunk}
        jobs = [ret.return_value for ret in returns.values() if isinstance(_value(ret), Job)]
        if jobs:  # (fewer than the chunk where a job failed its checks)
            trials = any(j.cfg.get("trial") is not None for j in jobs)
            log.info(f"Training {len(jobs)} {'runs' if trials else 'seeds'} together: " + ", ".join(
                f"trial {j.cfg.trial} seed {j.cfg.seed}" if j.cfg.get("trial") is not None
                else f"seed {j.cfg.seed}" if trials else str(j.cfg.seed) for j in jobs))
        _batch(jobs)
        return returns


def checked_job(cfg: DictConfig, run_dir: Path, hydra_cfg: DictConfig) -> Job | None:
    """A sweep's job to train in a batch: Hydra's record of it written in ``run_dir``, composed
    and checked (:func:`runs.job.compose_job`), a tuning trial linked to its study. A refused
    job's line is kept in its ``error.txt`` (None)."""
    write_hydra_record(run_dir, ".hydra", cfg, hydra_cfg, hydra_cfg.overrides.task)
    try:
        job = compose_job(cfg, run_dir, list(OmegaConf.to_container(hydra_cfg.overrides.task, resolve=False)),
                          hydra_cfg)
        job.run_dir.mkdir(parents=True, exist_ok=True)
        if job.cfg.get("trial") is not None:
            from sweeps.tuning import trial_link

            job.progress = trial_link(job.cfg, job.run_dir, hydra_cfg.sweeper)
    except refusals() as err:
        return keep_failure(run_dir, f"error: {one_line(err)}")
    except OSError as err:  # its folder: read-only, full
        return keep_failure(run_dir, cannot_write(err, run_dir))
    return job


def compose_jobs(loader, master: DictConfig, job_overrides: Sequence[Sequence[str]]) -> list[DictConfig]:
    """Each job's config as ``loader.load_sweep_config(master, overrides)`` composes it.
    Jobs whose overrides differ only in plain values (``key=value`` of a scalar or a list of
    them, not a config group) of the same kinds (a list where the first had a list) share one
    composition: the first of each robot, task, learner, ... is composed by Hydra, each
    other is a copy of it given its own values by Hydra's override step
    (:func:`params.private_api.apply_value_overrides`), its ``hydra.overrides.task`` and
    ``override_dirname``. A sweep's jobs differ in their seed, trial and searched values, and
    Hydra's whole composition took ~0.25 s a job, a copy ~0.04 s (one process, this machine)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parser = OverridesParser.create()
    groups = set(master.hydra.runtime.choices)
    firsts: dict[tuple, tuple[DictConfig, list]] = {}  # shape -> (composed config, its parsed overrides)
    configs = []
    for overrides in job_overrides:
        parsed = parser.parse_overrides(list(overrides))
        shape = tuple((o.key_or_group, isinstance(o.value(), list)) if _plain(o) and o.key_or_group not in groups
                      else o.input_line for o in parsed)
        first = firsts.get(shape)
        if first is None or not _no_group_changed(first[1], parsed, first[0]):
            cfg = loader.load_sweep_config(master, list(overrides))
            firsts.setdefault(shape, (cfg.copy(), parsed))
            configs.append(cfg)
            continue
        cfg = first[0].copy()
        changed = [o for o, was in zip(parsed, first[1]) if o.input_line != was.input_line]
        with open_dict(cfg):
            apply_value_overrides(changed, cfg)
            cfg.hydra.overrides.task = [o.input_line for o in parsed if not o.is_hydra_override()]
            cfg.hydra.job.override_dirname = overrides_dirname([o for o in parsed if not o.is_hydra_override()], cfg)
        OmegaConf.copy_cache(from_config=master, to_config=cfg)
        configs.append(cfg)
    return configs


def _plain(override) -> bool:
    """A ``key=value`` override of a scalar or a list of scalars (not a group, package,
    addition, deletion or ``hydra.*`` setting), which a copy of a composed config can take."""
    from hydra.core.override_parser.types import OverrideType

    if (override.type != OverrideType.CHANGE or override.package is not None or override.is_sweep_override()
            or override.is_hydra_override()):  # (a hydra.* override is kept in hydra.overrides.hydra)
        return False
    value = override.value()
    return isinstance(value, (int, float, str, bool, type(None))) or (
        isinstance(value, list) and all(isinstance(v, (int, float, str, bool, type(None))) for v in value))


def _no_group_changed(first: list, parsed: list, cfg: DictConfig) -> bool:
    """Whether ``parsed`` changes none of the config groups of ``cfg`` (``first``'s
    composition, which may have groups its master had not): its values can be set on a copy."""
    groups = set(cfg.hydra.runtime.choices)
    return all(o.input_line == was.input_line or o.key_or_group not in groups for o, was in zip(parsed, first))


def _without_hydra(cfg: DictConfig) -> DictConfig:
    """A copy of a job's composed config without its ``hydra`` node (what the job sees)."""
    cfg = cfg.copy()
    with open_dict(cfg):
        del cfg["hydra"]
    return cfg


def _value(ret: JobReturn):
    """A job's return value (None where the job failed: reading it would raise)."""
    try:
        return ret.return_value
    except Exception:  # noqa: BLE001 - Hydra re-raises a failed job's exception here
        return None


def _batch(jobs: list[Job], more=None) -> None:
    """Trains ``jobs`` (if any) as one batch (``more``: the source of jobs for its freed
    members); a refusal is one line, kept in each job's ``error.txt``. A batch stopped by
    Ctrl-C stops the sweep (train.cli prints what finished and how to resume)."""
    if not jobs:  # (every job of the chunk failed its checks)
        return
    try:
        summaries = run_jobs(jobs, more=more)
    except ConfigError as err:
        message = f"error: {err}"
        print(message, file=sys.stderr)
        for job in jobs:
            keep_error(job.run_dir, message)
        return
    stopped = [s for s in summaries if s.get("interrupted")]
    if stopped:
        raise SystemExit(128 + int(stopped[0].get("signal", 2)))


# -- submitit: one submitit job per batch ----------------------------------------------
def submit_batches(launcher, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> list[JobReturn]:
    """``hydra/launcher=seeds_submitit_slurm`` (or ``_local``): the sweep's batches
    (:func:`batches`) as one submitit job array, each job training one batch of seeds
    (:func:`run_batch_job`); ``launcher`` is the plugin's (Hydra's submitit launcher with
    ``max_seeds``; ``params`` its queue settings, ``QUEUE_KEYS`` those submitit names
    without the cluster's prefix)."""
    import submitit
    from hydra.core.singleton import Singleton

    chunks = batches(job_overrides, initial_job_idx, launcher.max_seeds)  # refused before any submission
    cluster, params = launcher._EXECUTOR, dict(launcher.params)
    executor = submitit.AutoExecutor(folder=params.pop("submitit_folder"), cluster=cluster,
                                     **{f"{cluster}_max_num_timeout": params.pop("max_num_timeout")}
                                     if "max_num_timeout" in params else {})
    shared = launcher.QUEUE_KEYS  # submitit's own parameter names; the others are the cluster's
    executor.update_parameters(**{k if k in shared else f"{cluster}_{k}": v for k, v in params.items()})
    sweep_dir = Path(str(launcher.config.hydra.sweep.dir))
    sweep_dir.mkdir(parents=True, exist_ok=True)
    log.info(f"Submitting {len(job_overrides)} jobs as {len(chunks)} submitit '{cluster}' job"
             f"{'s' * (len(chunks) != 1)}, one per batch of seeds; output under {sweep_dir}")
    for chunk in chunks:
        log.info("\t" + ", ".join(f"#{idx}" for idx, _ in chunk) + f" : {' '.join(filter_overrides(chunk[0][1]))}")
    state = Singleton.get_state()
    returns: dict[int, JobReturn] = {}
    for job in executor.map_array(launcher, chunks, [state] * len(chunks)):
        returns.update(job.results()[0])
    return [returns[initial_job_idx + i] for i in range(len(job_overrides))]


def run_batch_job(launcher, chunk: list[tuple[int, list[str]]], singleton_state: dict) -> dict[int, JobReturn]:
    """Inside a submitit job: one batch of seeds, trained as the ``seeds`` launcher trains it."""
    from hydra.core.singleton import Singleton

    Singleton.set_state(singleton_state)
    setup_globals()
    launch = SeedBatchLaunch(launcher.hydra_context, launcher.task_function, launcher.config, launcher.max_seeds)
    configure_log(launcher.config.hydra.hydra_logging, launcher.config.hydra.verbose)
    return launch.run_chunk(chunk)
