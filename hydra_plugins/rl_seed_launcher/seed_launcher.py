"""``hydra/launcher=seeds`` (the default for multirun): jobs that differ only in ``seed`` train
together in this process, one batch per group (:mod:`sweeps.seed_batch`).
``hydra/launcher=seeds_submitit_slurm`` (``seeds_slurm``: its settings written out) and
``seeds_submitit_local``: Hydra's submitit launchers, one submitit job per batch of seeds.

    python train.py -m seed='range(10)'                      # one batch of ten seeds
    python train.py -m learner=qlearn,dqn seed='range(10)'   # two batches
    python train.py -m hydra/launcher=seeds_slurm seed='range(20)' hydra.launcher.max_seeds=10  # two Slurm jobs
    python train.py -m hydra/launcher=basic seed=0,1         # one process per job, in turn

Hydra imports this module whenever any app starts (to find plugins), so it stays a thin
shell: the work is imported when a sweep launches.
"""

from dataclasses import dataclass, fields
from typing import Any, Sequence

from hydra.core.config_store import ConfigStore
from hydra.core.utils import JobReturn
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from hydra_plugins.hydra_submitit_launcher.config import BaseQueueConf, LocalQueueConf, SlurmQueueConf
from hydra_plugins.hydra_submitit_launcher.submitit_launcher import LocalLauncher, SlurmLauncher
from omegaconf import DictConfig
from params.private_api import basic_sweeper


class SeedBatchLauncher(Launcher):
    """Hydra's face of :class:`sweeps.seed_batch.SeedBatchLaunch`."""

    def __init__(self, **settings: Any) -> None:
        self.settings = settings
        self.launch_impl = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        from sweeps.seed_batch import SeedBatchLaunch

        self.launch_impl = SeedBatchLaunch(hydra_context, task_function, config, **self.settings)

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        assert self.launch_impl is not None, "setup() first"
        return self.launch_impl.launch(job_overrides, initial_job_idx)

    def launch_fed(self, jobs: Sequence[Any], more: Any) -> dict:
        """Jobs (index, overrides) launched with each batch's freed members given the jobs
        ``more`` hands in (:meth:`sweeps.seed_batch.SeedBatchLaunch.launch_fed`)."""
        assert self.launch_impl is not None, "setup() first"
        return self.launch_impl.launch_fed(jobs, more)


class SeedBatchSweeper(basic_sweeper()):
    """``hydra/sweeper=seeds`` (the default for multirun): Hydra's basic sweeper, which before
    launching a batch composes each of its jobs to find a bad override early. The seeds
    launcher composes every job of its batch before any starts (:func:`sweeps.seed_batch.
    compose_jobs`, the jobs that differ only in values as copies of one), so with it the
    sweeper's own pass is skipped: it cost ~0.3 s a job, 3 s before a ten-seed batch began."""

    def validate_batch_is_legal(self, batch: Sequence[Sequence[str]]) -> None:
        if not isinstance(self.launcher, SeedBatchLauncher):
            super().validate_batch_is_legal(batch)


class _SubmititBatches:
    """Hydra's submitit launcher with one submitit job per batch of seeds, not per seed
    (:func:`sweeps.seed_batch.submit_batches`); ``max_seeds`` seeds a job at most."""

    QUEUE_KEYS = frozenset(f.name for f in fields(BaseQueueConf))

    def __init__(self, max_seeds: int = 64, **params: Any) -> None:
        self.max_seeds = max_seeds
        super().__init__(**params)

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        from sweeps.seed_batch import check_max_seeds

        check_max_seeds(self.max_seeds)  # before the sweep writes anything
        super().setup(hydra_context=hydra_context, task_function=task_function, config=config)

    def launch(self, job_overrides: Sequence[Sequence[str]], initial_job_idx: int) -> Sequence[JobReturn]:
        from sweeps.seed_batch import submit_batches

        return submit_batches(self, job_overrides, initial_job_idx)

    def __call__(self, chunk: list, singleton_state: dict) -> dict[int, JobReturn]:
        from sweeps.seed_batch import run_batch_job

        return run_batch_job(self, chunk, singleton_state)

    def checkpoint(self, *args: Any, **kwargs: Any) -> None:
        """Not requeued when preempted: its seeds' folders resume, each with resume=<job folder>."""
        return None


class SeedBatchSlurmLauncher(_SubmititBatches, SlurmLauncher):
    """``hydra/launcher=seeds_submitit_slurm``: one Slurm job per batch of seeds."""


class SeedBatchLocalLauncher(_SubmititBatches, LocalLauncher):
    """``hydra/launcher=seeds_submitit_local``: one local submitit process per batch of seeds."""


@dataclass
class SeedBatchSlurmConf(SlurmQueueConf):
    _target_: str = "hydra_plugins.rl_seed_launcher.seed_launcher.SeedBatchSlurmLauncher"
    max_seeds: int = 64


@dataclass
class SeedBatchLocalConf(LocalQueueConf):
    _target_: str = "hydra_plugins.rl_seed_launcher.seed_launcher.SeedBatchLocalLauncher"
    max_seeds: int = 64


ConfigStore.instance().store(group="hydra/launcher", name="seeds_submitit_slurm", node=SeedBatchSlurmConf(),
                             provider="rl_seed_launcher")
ConfigStore.instance().store(group="hydra/launcher", name="seeds_submitit_local", node=SeedBatchLocalConf(),
                             provider="rl_seed_launcher")
