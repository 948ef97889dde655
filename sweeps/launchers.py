"""Checks of a sweep's Hydra launcher, made in the launching process before any job starts.

Hydra types the launcher's settings (``hydra.launcher.timeout_min=abc`` is refused when the
config is composed); what a type cannot say is checked here: Slurm's settings that must be
positive, and that Slurm itself is there (``sbatch`` and ``srun`` on PATH) for the
``submitit_slurm`` launcher (``hydra/launcher=slurm`` is that launcher with the settings a
user edits, ``conf/hydra/launcher/slurm.yaml``).
"""

from __future__ import annotations

import shutil
from typing import Any

from params import ConfigError

# Slurm settings that must be integers >= 1 where they are set (null: the cluster's default).
SLURM_POSITIVE = ("timeout_min", "cpus_per_task", "mem_gb", "nodes", "tasks_per_node", "array_parallelism")
SLURM_TOOLS = ("sbatch", "srun")


def check_launcher(launcher: Any) -> None:
    """Refuses, in one line, a Slurm launcher (``launcher``: the ``hydra.launcher`` node)
    with a setting below 1 or on a machine without Slurm; other launchers pass."""
    target = str(launcher.get("_target_", "")) if launcher is not None else ""
    if not target.endswith("SlurmLauncher"):
        return
    for key in SLURM_POSITIVE:
        value = launcher.get(key)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < 1):
            raise ConfigError(f"hydra.launcher.{key} must be an integer >= 1 (or null where Slurm "
                              f"has a default); got {value!r}")
    missing = [tool for tool in SLURM_TOOLS if shutil.which(tool) is None]
    if missing:
        raise ConfigError(f"the Slurm launcher needs Slurm's {' and '.join(missing)} on PATH, not found "
                          "here: start the sweep on the cluster's login node (hydra/launcher=submitit_local "
                          "runs the same jobs on this machine)")
