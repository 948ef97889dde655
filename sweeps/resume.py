"""A stopped sweep resumed as a whole: ``python train.py resume=<sweep folder>``.

Every unfinished job folder of the sweep with a checkpoint continues from it, the jobs
alike but their seed trained together as one seed batch (:func:`runs.lifecycle.run_jobs`),
each exactly as ``resume=<job folder>`` continues it alone; then the sweep's comparison is
made again. Jobs that cannot continue (no checkpoint.pt, a damaged one) are listed with
their one-line reason and left as they are; finished jobs are not touched. Jobs of the
sweep's plan that never started (a launcher stopped before them) are listed with the
command that runs each into the sweep, and the resume then exits 1: the sweep is not
finished until they are.
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path
from typing import Sequence

from omegaconf import DictConfig, OmegaConf

from params import ConfigError
from runs.lifecycle import Job, run_jobs, same_batch
from runs.checkpoint import CheckpointError
from runs.folder import is_finished, resumed_config
from runs.layout import is_run_folder
from runs.training_state import read_run_json
from runs.settings import check_run_config
from sweeps.comparison import NotASweep, report
from sweeps.folder import job_folders, overrides_dict, sweep_jobs
from sweeps.state import report_stopped_sweep


def never_started(folder: Path) -> list[str]:
    """The command that runs each job of the sweep in ``folder`` that never started, into
    the folder its sweep would have given it."""
    jobs, _ = sweep_jobs(folder)
    commands = []
    for job in (j for j in jobs if j.get("status") == "never started" and j.get("overrides") is not None):
        seed = overrides_dict(job["overrides"]).get("seed", 0)
        name = f"{job['job']}_{job.get('robot')}_{job.get('learner')}_seed{seed}"
        commands.append(" ".join(["python train.py", *(shlex.quote(o) for o in job["overrides"]),
                                  shlex.quote(f"hydra.run.dir={folder / name}")]))
    return commands


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
    if unstarted:
        print(f"{len(unstarted)} job{'s' * (len(unstarted) != 1)} of {folder} never started; each runs with:")
        for command in unstarted:
            print(f"  {command}")
    try:
        jobs, skipped = resumable_jobs(cfg, overrides)
    except CheckpointError:
        if unstarted:  # nothing to continue, but the sweep is not finished
            raise SystemExit(1) from None
        raise
    for line in skipped:
        print(line)
    (folder / ".stop").unlink(missing_ok=True)  # the stop is over: the comparison says so no more
    summaries = []
    for members in same_batch([job.cfg for job in jobs]):
        batch = [jobs[i] for i in members]
        print(f"resuming {len(batch)} job{'s' * (len(batch) != 1)} of {folder} together: "
              f"{', '.join(job.run_dir.name for job in batch)}")
        summaries += run_jobs(batch)
    try:
        report(folder)
    except NotASweep as err:  # pragma: no cover - the folder held the jobs just resumed
        print(f"no comparison: {err}")
    if any(s.get("interrupted") for s in summaries):
        report_stopped_sweep(folder)
    elif unstarted:
        print(f"the sweep is not finished: {len(unstarted)} job{'s' * (len(unstarted) != 1)} never started "
              "(the commands above)", file=sys.stderr)
        raise SystemExit(1)
    return summaries
