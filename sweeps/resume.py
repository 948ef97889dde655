"""A stopped sweep resumed as a whole: ``python train.py resume=<sweep folder>``.

Every unfinished job folder of the sweep with a checkpoint continues from it, the jobs
alike but their seed trained together as one seed batch (:func:`runs.lifecycle.run_jobs`),
each exactly as ``resume=<job folder>`` continues it alone; then the sweep's comparison is
made again. Jobs that cannot continue (no checkpoint.pt, a damaged one) are listed with
their one-line reason and left as they are; finished jobs are not touched. Jobs of the
sweep's plan that never started (a launcher stopped before them) are composed here and
checked as the sweep's launcher checks a job, in the folder the sweep would have given each,
and train with the others (those alike but their seed in one batch): the one command
finishes the sweep.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

from hydra.core.hydra_config import HydraConfig
from omegaconf import DictConfig, OmegaConf, open_dict

from params import ConfigError
from runs.lifecycle import Job, run_jobs, same_batch
from runs.checkpoint import CheckpointError
from runs.folder import is_finished, resumed_config
from runs.layout import is_run_folder
from runs.training_state import read_run_json
from runs.settings import check_run_config
from sweeps.comparison import NotASweep, report
from sweeps.folder import job_folders, overrides_dict, sweep_jobs
from sweeps.seed_batch import checked_job
from sweeps.state import report_stopped_sweep


def never_started(folder: Path) -> list[tuple[list[str], Path]]:
    """The overrides of each job of the sweep in ``folder`` that never started, and the
    folder its sweep would have given it."""
    jobs, _ = sweep_jobs(folder)
    found = []
    for job in (j for j in jobs if j.get("status") == "never started" and j.get("overrides") is not None):
        seed = overrides_dict(job["overrides"]).get("seed", 0)
        found.append((list(job["overrides"]), folder / f"{job['job']}_{job.get('robot')}_{job.get('learner')}_seed{seed}"))
    return found


def composed(unstarted: Sequence[tuple[list[str], Path]]) -> list[tuple[DictConfig, Path, DictConfig]]:
    """Each of ``unstarted`` (:func:`never_started`) composed in this process as ``train.py``
    composes its config: ``(config, folder, Hydra's config of it)``; nothing written."""
    from hydra import compose

    found = []
    for overrides, run_dir in unstarted:
        cfg = compose(config_name=HydraConfig.get().job.config_name, overrides=overrides, return_hydra_config=True)
        with open_dict(cfg):
            hydra_cfg = cfg.pop("hydra")
        found.append((cfg, run_dir, hydra_cfg))
    return found


def _run_batches(jobs: Sequence, folder: Path, verb: str) -> tuple[list[dict], bool]:
    """``jobs`` trained in batches (those alike but their seed together); each a
    :class:`Job`, or a composed ``(config, folder, Hydra's config)`` (:func:`composed`) checked as the sweep's
    launcher checks a job (:func:`sweeps.seed_batch.checked_job`) when its batch starts.
    The summaries, and whether a batch was stopped (the stop reported; no batch starts after it)."""
    summaries = []
    for members in same_batch([job.cfg if isinstance(job, Job) else job[0] for job in jobs]):
        batch = [jobs[i] for i in members]
        print(f"{verb} {len(batch)} job{'s' * (len(batch) != 1)} of {folder} together: "
              f"{', '.join((job.run_dir if isinstance(job, Job) else job[1]).name for job in batch)}")
        batch = [job for job in (j if isinstance(j, Job) else checked_job(*j) for j in batch) if job is not None]
        summaries += run_jobs(batch) if batch else []
        if any(s.get("interrupted") for s in summaries):
            report_stopped_sweep(folder)
            return summaries, True
    return summaries, False


def resumable_jobs(cfg: DictConfig, overrides: Sequence[str]) -> tuple[list[Job], list[str]]:
    """The unfinished job folders of the sweep ``cfg.resume``, each as its resumed job, and a
    line for each that cannot continue. :class:`CheckpointError` if none can."""
    folder = Path(str(cfg.resume))
    unfinished = [d for d in job_folders(folder) if is_run_folder(d) and not is_finished(d)]
    if not unfinished:
        raise CheckpointError(f"resume={folder}: every run of this sweep is finished; nothing to continue "
                              f"(compare it with: python compare.py {folder})")
    jobs, skipped = [], []
    for run_dir in unfinished:
        job_cfg = cfg.copy()
        job_cfg.resume = str(run_dir)
        try:
            saved, run_dir = resumed_config(job_cfg, list(overrides))
            check_run_config(saved)
        except (CheckpointError, ConfigError) as err:
            skipped.append((run_dir.name, str(err).splitlines()[0]))
            continue
        jobs.append(Job(saved, run_dir, read_run_json(run_dir), resume=True))
    if not jobs:
        raise CheckpointError(f"resume={folder}: none of its {len(unfinished)} unfinished runs can continue "
                              f"(the first: {skipped[0][1]})")
    return jobs, [f"not resumed: {name}: {why}" for name, why in skipped]


def continuable(run_dir: Path) -> bool:
    """Whether ``run_dir`` is a run that is finished or has a checkpoint to continue from."""
    return is_run_folder(run_dir) and (is_finished(run_dir) or (run_dir / "checkpoint.pt").is_file())


def resume_runs(folders: Sequence[Path]) -> list[dict]:
    """Continues the unfinished runs among ``folders`` (each from its checkpoint, with its own
    config), those that may share a batch together; their summaries."""
    jobs = []
    for run_dir in folders:
        if not is_finished(run_dir):
            saved, run_dir = resumed_config(OmegaConf.create({"resume": str(run_dir)}), [])
            check_run_config(saved)
            jobs.append(Job(saved, run_dir, read_run_json(run_dir), resume=True))
    summaries = []
    for members in same_batch([job.cfg for job in jobs]):
        summaries += run_jobs([jobs[i] for i in members])
    return summaries


def resume_sweep(cfg: DictConfig, overrides: Sequence[str]) -> list[dict]:
    """Continues the sweep ``cfg.resume`` (see the module docstring); each job's summary."""
    folder = Path(str(cfg.resume))
    unstarted = never_started(folder)
    try:
        jobs, skipped = resumable_jobs(cfg, overrides)
    except CheckpointError:
        if not unstarted:
            raise
        jobs, skipped = [], []  # nothing to continue, but jobs to start
    for line in skipped:
        print(line)
    (folder / ".stop").unlink(missing_ok=True)  # the stop is over: the comparison says so no more
    summaries, stopped = _run_batches(jobs, folder, "resuming")
    if stopped:
        return summaries
    fresh, stopped = _run_batches(composed(unstarted), folder, "starting")
    if stopped:
        return summaries + fresh
    try:
        report(folder)
    except NotASweep as err:  # pragma: no cover - the folder held the jobs just resumed
        print(f"no comparison: {err}")
    return summaries + fresh
