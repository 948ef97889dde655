"""What kind of folder a path is, told by the files in it: a run of this project or a
Hydra multirun sweep. Imports nothing of the project, so the loggers and the folder
code can both ask."""

from __future__ import annotations

import sys
from pathlib import Path

def compare_command() -> str:
    """How to run the comparison, in the form :func:`train_command` was run: the installed
    ``mujoco-rl-compare``, else ``python compare.py``."""
    return "mujoco-rl-compare" if train_command().startswith("mujoco-rl-train") else "python compare.py"


def train_command() -> str:
    """How a printed command starts: the command the user ran, ``mujoco-rl-train`` where the
    installed command started this process, else ``python train.py``."""
    name = Path(sys.argv[0]).name if sys.argv and sys.argv[0] else ""
    return name if name.startswith("mujoco-rl-train") else "python train.py"


def is_run_folder(path) -> bool:
    """Whether ``path`` holds a run of this project (its ``run.json`` and ``config.yaml``)."""
    return bool(path) and all((Path(str(path)) / name).is_file() for name in ("run.json", "config.yaml"))


def is_sweep_folder(path) -> bool:
    """Whether ``path`` is a Hydra multirun sweep folder (Hydra's ``multirun.yaml`` in it): a
    run folder's parent when the run is a sweep's job."""
    return bool(path) and (Path(str(path)) / "multirun.yaml").is_file()
