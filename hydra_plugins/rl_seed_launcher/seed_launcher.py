"""``hydra/launcher=seeds`` (the default for multirun): jobs that differ only in ``seed`` train
together in this process, one batch per group (:mod:`sweeps.seed_batch`).

    python train.py -m seed='range(10)'                      # one batch of ten seeds
    python train.py -m learner=qlearn,dqn seed='range(10)'   # two batches
    python train.py -m hydra/launcher=basic seed=0,1         # one process per job, in turn

Hydra imports this module whenever any app starts (to find plugins), so it stays a thin
shell: the work is imported when a sweep launches.
"""

from typing import Any, Sequence

from hydra.core.utils import JobReturn
from hydra.plugins.launcher import Launcher
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig


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
