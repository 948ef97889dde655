"""Config -> robot -> task -> env: the one place that builds them.

Everything that needs an environment comes here: ``train.py``, the Gymnasium
ids (:mod:`tasks.gym_env`), the video tool, evaluation and the benches::

    env = make_env("cube", num_envs=8, seed=0)                  # by names
    env = make_env("turtlebot", "wall", ["task.min_range=0.4"])
    cfg = compose("cartpole", learner="dqn"); env = build_env(cfg, 4, seed=0)

The Hydra configs are found through the installed ``conf`` package, so this
works from any working directory and without an editable install. (Robots
and tasks are dataclasses, which Hydra's ``instantiate`` would turn back into
configs when one is passed to another as a keyword: build them here.)
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any, Mapping, Sequence

from hydra import compose as hydra_compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from hydra.utils import get_object
from omegaconf import DictConfig, OmegaConf, open_dict

from params import ConfigError
from robots.base import Robot
from tasks.base import Task
from tasks.env import RobotTaskEnv


# The config groups a run picks by name (``robot=cube``); everything else is a value.
GROUPS = ("robot", "task", "learner")

def conf_dir() -> Path:
    """The folder of the Hydra configs (``config.yaml``, ``robot/``, ``task/``, ...)."""
    return Path(str(resources.files("conf")))


def robot_names() -> list[str]:
    """Every robot with a config in ``conf/robot/``."""
    return sorted(p.stem for p in (conf_dir() / "robot").glob("*.yaml"))


def compose(robot: str | None = None, task: str | None = None, learner: str | None = None,
            overrides: Sequence[str] = ()) -> DictConfig:
    """The resolved run config, as ``python train.py robot=.. task=.. learner=.. <overrides>``
    composes it (the robot's default task when ``task`` is None).

    Works inside a running Hydra app too: that app's global state is restored.
    """
    picks = [f"{k}={v}" for k, v in (("robot", robot), ("task", task), ("learner", learner)) if v]
    return _resolved(_compose([*picks, *overrides]))


def default_task(robot: str) -> str:
    """The task ``robot``'s config picks."""
    return robot_default(robot)[0]


def robot_default(robot: str) -> tuple[str, DictConfig]:
    """``(task name, resolved config)`` of ``robot`` with the task its config picks, from
    one composition (``default_task`` and ``compose(robot)`` together)."""
    cfg = _compose([f"robot={robot}"])
    return str(cfg.hydra.runtime.choices.task), _resolved(cfg)


def _resolved(cfg: DictConfig) -> DictConfig:
    with open_dict(cfg):
        del cfg["hydra"]
    OmegaConf.resolve(cfg)
    return cfg


def _compose(overrides: list[str]) -> DictConfig:
    gh = GlobalHydra.instance()
    app = gh.hydra if gh.is_initialized() else None
    gh.clear()
    try:
        with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
            return hydra_compose(config_name="config", overrides=overrides, return_hydra_config=True)
    finally:
        if app is not None:
            GlobalHydra.instance().clear()
            GlobalHydra.instance().initialize(app)


def _build(node: Mapping[str, Any], key: str, kind: type, **extra: Any) -> Any:
    """``node``'s ``_target_`` class, checked to be a ``kind``, built from the node's values."""
    values = OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node)
    target = values.pop("_target_", None)
    try:
        cls = get_object(target) if isinstance(target, str) else None
    except Exception:  # noqa: BLE001 - any import failure is the same config mistake
        cls = None
    if not (isinstance(cls, type) and issubclass(cls, kind)):
        raise ConfigError(f"{key}._target_ must name a {kind.__module__}.{kind.__name__} class; "
                          f"got {target!r}")
    return cls(**extra, **values)


def build_robot(cfg: DictConfig) -> Robot:
    """The robot of a composed config (its ``robot`` node)."""
    return _build(cfg.robot, "robot", Robot)


def build_task(cfg: DictConfig) -> Task:
    """A fresh task, with its robot, from a composed config's ``robot`` and ``task`` nodes."""
    return _build(cfg.task, "task", Task, robot=build_robot(cfg))


def build_env(cfg: DictConfig, num_envs: int | None = None, seed: int | None = None,
              max_episode_steps: int | None = None) -> RobotTaskEnv:
    """The batched env of a composed config (``num_envs`` and ``seed`` default to the
    config's); ``max_episode_steps`` shortens the task's time limit (a learner's ``nsteps``)."""
    task = build_task(cfg)
    if max_episode_steps is not None:
        task.max_episode_steps = min(task.max_episode_steps, int(max_episode_steps))
    return RobotTaskEnv(task, num_envs=int(cfg.num_envs if num_envs is None else num_envs),
                        seed=int(cfg.seed if seed is None else seed))


def make_env(robot: str, task: str | None = None, overrides: Sequence[str] = (),
             num_envs: int = 1, seed: int = 0) -> RobotTaskEnv:
    """The env of ``robot`` (and ``task``, else the robot's default) with Hydra ``overrides``
    such as ``"task.pos_step=0.5"``."""
    return build_env(compose(robot, task, overrides=overrides), num_envs, seed)
