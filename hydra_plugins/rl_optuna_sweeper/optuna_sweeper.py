"""``hydra/sweeper=optuna``: tunes the run's learner on its robot/task with Optuna.

    python train.py -m hydra/sweeper=optuna hydra/launcher=joblib robot=cube learner=qlearn

Each trial samples the learner's search space (``conf/search/<learner>.yaml``, or
``<robot>_<learner>.yaml`` where a robot has its own), runs one job per seed through
Hydra's launcher (basic, joblib, submitit: Slurm) with the same budget (``budget_steps``
env steps, each seed stopping when solved, as a plain run), and tells the study the mean
over the jobs of its objective, ``success_and_speed`` (:func:`runs.summary.success_and_speed`:
success first, then env steps to success, as the benchmark ranks; the study's metric name). With the ``seeds`` launcher, trials asked
together (``trials_per_batch``) train side by side wherever only member-wise settings
differ. Jobs report their rolling measure every ``report_every`` env steps, and the
``pruner`` (median, successive halving or Hyperband; settings in ``pruners``) stops
hopeless trials. The study lives in ``storage`` (an SQLite file by default, any SQL
database by URL, or a journal file), so sweeps started on several machines share it, and
the next sweep of a study takes over the trials a stopped one left running. With ``value_defaults``
the learner's own values of the searched settings are valued too, once per study. The best
(a trial, or those values where they beat every trial) ends as a tuned file:
``tuned_<robot>_<learner>.yaml`` in the sweep folder, and with ``write_tuned=true``
``conf/tuned/<robot>_<learner>.yaml``, which the next plain run uses (for a task other
than the robot's default: ``<robot>_<task>_<learner>``, applied on top of the robot's).

Why not ``hydra-optuna-sweeper``: it pins optuna < 3, whose SQLite storage fails with
SQLAlchemy 2 (what pip resolves today), and its jobs cannot report intermediate values,
so there is no pruning.

Hydra imports this module whenever any app starts (to find plugins), so it stays a thin
shell: the work is :mod:`sweeps.optuna_sweep`, imported when a sweep is set up.
"""

from typing import Any, List

from hydra.plugins.sweeper import Sweeper
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig


class OptunaSweeper(Sweeper):
    """Hydra's face of :class:`sweeps.optuna_sweep.TuningSweep` (settings:
    ``conf/hydra/sweeper/optuna.yaml``)."""

    def __init__(self, **settings: Any) -> None:
        self.settings = settings
        self.sweep_impl = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        from sweeps.optuna_sweep import TuningSweep

        self.sweep_impl = TuningSweep(**self.settings)
        self.sweep_impl.setup(hydra_context=hydra_context, task_function=task_function, config=config)

    def sweep(self, arguments: List[str]) -> Any:
        assert self.sweep_impl is not None, "setup() first"
        return self.sweep_impl.sweep(arguments)
