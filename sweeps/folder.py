"""Reading a Hydra sweep folder back: the jobs it planned and what became of each.

The jobs are those the sweep's ``multirun.yaml`` launches (expanded by Hydra's own
BasicSweeper), so a job that never started is known too; without a usable
multirun.yaml, the job folders found. Each job is a
:func:`runs.summary.summarize_run` summary with its ``job`` number and
``overrides``; a damaged job folder is a status and an ``error``, never an exception.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from hydra.core.override_parser.overrides_parser import OverridesParser
from omegaconf import OmegaConf

from runs.summary import summarize_run
from tasks.catalog import GROUPS

PICKS = GROUPS  # config groups with their own columns, never in ``swept``


def overrides_dict(overrides: list[str] | None) -> dict[str, str]:
    """``["learner.alpha=0.05", ...]`` (as Hydra hands them to a job) -> ``{"learner.alpha": "0.05"}``."""
    return dict(o.partition("=")[::2] for o in overrides or [])


@dataclass
class Plan:
    """The jobs a sweep launches: each one's overrides, in job order (``None`` where
    multirun.yaml cannot tell, and ``note`` says why), and the sweep's own robot, task
    and learner (those of jobs that do not override them)."""

    jobs: list[list[str]] | None
    defaults: dict = field(default_factory=dict)
    note: str | None = None


def planned_jobs(sweep_dir: Path) -> Plan:
    """The jobs of ``sweep_dir/multirun.yaml``, expanded as Hydra's BasicSweeper does."""
    path = sweep_dir / "multirun.yaml"
    if not path.is_file():
        return Plan(None, note=f"{path} is missing: jobs that never started cannot be listed")
    try:  # whatever is wrong with the file, the job folders still tell the rest
        cfg = OmegaConf.load(path)
        sweeper = cfg.hydra.sweeper
        if str(sweeper.get("_target_")).endswith(".OptunaSweeper"):  # hydra/sweeper=optuna
            # It asks its study for one batch of trials at a time: no job is planned ahead.
            return Plan(None, {k: cfg.hydra.runtime.choices.get(k) for k in PICKS})
        if not str(sweeper.get("_target_")).endswith((".BasicSweeper", ".SeedBatchSweeper")):  # seeds: basic's own
            return Plan(None, note=f"{path}: sweeper {sweeper.get('_target_')} is not Hydra's basic "
                                   "sweeper: jobs that never started cannot be listed")
        params = [f"{k}={v}" for k, v in (sweeper.get("params") or {}).items()]
        overrides = OverridesParser.create().parse_overrides([*params, *cfg.hydra.overrides.task])
        from params.private_api import basic_sweeper  # (it imports torch: only here)

        jobs = [job for batch in basic_sweeper().split_arguments(overrides, None) for job in batch]
        defaults = {k: cfg.hydra.runtime.choices.get(k) for k in PICKS}
    except Exception as err:
        return Plan(None, note=f"{path} is unreadable ({type(err).__name__}): "
                               "jobs that never started cannot be listed")
    return Plan(jobs, defaults)


def job_number(folder: Path) -> int | None:
    """The job number a job folder's name starts with (hydra.sweep.subdir ``<num>_...``)."""
    head = folder.name.split("_")[0]
    return int(head) if head.isdigit() else None


def job_folders(sweep_dir: Path) -> list[Path]:
    """The sweep's job folders: named after their job number, or holding run.json or .hydra."""
    found = [p for p in sweep_dir.iterdir() if p.is_dir() and not p.name.startswith(".")
             and (job_number(p) is not None or (p / "run.json").exists() or (p / ".hydra").exists())]
    return sorted(found, key=lambda p: (job_number(p) is None, job_number(p) or 0, p.name))


def sweep_jobs(sweep_dir: Path) -> tuple[list[dict], list[str]]:
    """Every job of the sweep, in job order, each a :func:`summarize_run` summary with its
    ``job`` number and ``overrides``; and notes on the sweep as a whole."""
    plan = planned_jobs(sweep_dir)
    runs = [summarize_run(d) | {"job": job_number(d)} for d in job_folders(sweep_dir)]
    jobs = runs if plan.jobs is None else _match(plan.jobs, runs, sweep_dir)
    _fill_picks(jobs, plan.defaults)
    return jobs, [plan.note] if plan.note else []


def _match(planned: list[list[str]], runs: list[dict], sweep_dir: Path) -> list[dict]:
    """Each planned job with the summary of its folder (same job number, or none in the
    folder's name, and the same overrides where the folder recorded them) or as never
    started; then the folders no planned job claims."""
    def fits(run: dict, num: int, want: dict) -> bool:
        if run["overrides"] is None:
            return run["job"] == num
        return run["job"] in (num, None) and overrides_dict(run["overrides"]) == want

    free, jobs = list(runs), []
    for num, overrides in enumerate(planned):
        want = overrides_dict(overrides)
        mine = next((r for r in free if fits(r, num, want)), None)
        if mine is None:
            mine = {"run_dir": None, "status": "never started", "error": f"no folder {num}_* in {sweep_dir}"}
        else:
            free.remove(mine)
        jobs.append(mine | {"job": num, "overrides": overrides})
    stray = "not one of multirun.yaml's jobs (its overrides differ): tabulated under its own"
    return jobs + [r | {"warning": "; ".join(filter(None, (r.get("warning"), stray)))} for r in free]


def _fill_picks(jobs: list[dict], defaults: dict) -> None:
    """robot, task and learner of the jobs that left no run.json: those of a job with the
    same robot/task/learner overrides, else the overrides' or the sweep's (``?`` if unknown)."""
    def picks(job: dict) -> tuple:
        return tuple(overrides_dict(job["overrides"]).get(k) for k in PICKS)

    known = {picks(j): j for j in jobs if j.get("robot") and j["overrides"] is not None}
    for job in (j for j in jobs if not j.get("robot")):
        if job["overrides"] is None:
            job.update(dict.fromkeys(PICKS, "?"))
            continue
        given, like = overrides_dict(job["overrides"]), known.get(picks(job))
        for k in PICKS:  # a robot's own default task is known only from its jobs
            guess = given.get(k) or (None if k == "task" and "robot" in given else defaults.get(k))
            job[k] = like[k] if like else guess or "?"


def swept_keys(jobs: list[dict]) -> list[str]:
    """The override keys whose value differs between jobs (the seed, and robot, task and
    learner, which have their own columns, aside), in the sweep's order."""
    known = [overrides_dict(j["overrides"]) for j in jobs if j["overrides"] is not None]
    keys = dict.fromkeys(k for given in known for k in given)
    return [k for k in keys if k not in ("seed", *PICKS) and len({g.get(k) for g in known}) > 1]


def swept_label(job: dict, keys: list[str]) -> str:
    """``learner.alpha=0.05 learner.gamma=0.9``: the job's values of the swept ``keys`` it set
    (those it left at their defaults are left out: ``(defaults)`` where it set none)."""
    if not keys:
        return "-"
    if job["overrides"] is None:
        return "? (overrides unknown)"
    given = overrides_dict(job["overrides"])
    return " ".join(f"{k}={given[k]}" for k in keys if k in given) or "(defaults)"
