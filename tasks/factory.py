"""A composed config -> robot -> task -> env: the one place that builds them.

Everything that needs an environment comes here: the run, the Gymnasium ids,
the video tool, evaluation and the benches::

    cfg = tasks.catalog.compose("cartpole", learner="dqn")
    env = build_env(cfg, 4, seed=0)

Composing the config from ``conf/`` is :mod:`tasks.catalog`'s. (Robots and tasks
are dataclasses, which Hydra's ``instantiate`` would turn back into configs when
one is passed to another as a keyword: build them here.)
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

from omegaconf import DictConfig, OmegaConf

from params import ConfigError, locate
from robots.base import Robot
from tasks.base import Task, action_forms, check_action_form
from tasks.env import RobotTaskEnv


def _build(node: Mapping[str, Any], key: str, kind: type, **extra: Any) -> Any:
    """``node``'s ``_target_`` class, checked to be a ``kind``, built from the node's values."""
    values = OmegaConf.to_container(node, resolve=True) if isinstance(node, DictConfig) else dict(node)
    target = values.pop("_target_", None)
    try:
        cls = locate(target) if isinstance(target, str) else None
    except Exception:  # noqa: BLE001 - any import failure is the same config mistake
        cls = None
    if not (isinstance(cls, type) and issubclass(cls, kind)):
        raise ConfigError(f"{key}._target_ must name a {kind.__module__}.{kind.__name__} class; "
                          f"got {target!r}")
    return cls(**extra, **values)


def build_robot(cfg: DictConfig) -> Robot:
    """The robot of a composed config.

    Args:
        cfg: a composed config (:mod:`tasks.catalog`); its ``robot`` node names the class in ``_target_``
            and holds its parameters.

    Returns:
        A new robot.

    Raises:
        ConfigError: if ``robot._target_`` does not name a :class:`~robots.base.Robot` class, or a value
            is one the robot cannot honour.
    """
    return _build(cfg.robot, "robot", Robot)


def build_task(cfg: DictConfig) -> Task:
    """A fresh task, with its robot, from a composed config.

    Args:
        cfg: a composed config (:mod:`tasks.catalog`); its ``robot`` and ``task`` nodes name the classes
            in ``_target_`` and hold their parameters.

    Returns:
        A new task, holding a new robot.

    Raises:
        ConfigError: if ``robot._target_`` or ``task._target_`` does not name a robot or task class, or a
            value is one the robot or task cannot honour.
    """
    return _build(cfg.task, "task", Task, robot=build_robot(cfg))


def action_form(cfg: DictConfig) -> str:
    """The action form a composed config's learner acts on: its class's ``ACTIONS``
    (``discrete`` unless it says ``continuous``); ``discrete`` without a learner.

    Args:
        cfg: a composed config.

    Returns:
        ``discrete`` or ``continuous``.
    """
    target = (cfg.get("learner") or {}).get("_target_") if isinstance(cfg, (DictConfig, Mapping)) else None
    try:
        cls = locate(str(target)) if target else None
    except Exception:  # noqa: BLE001 - a learner that cannot be found is refused where it is built
        cls = None
    return str(getattr(cls, "ACTIONS", "discrete"))


def learner_name(cfg: DictConfig) -> str:
    """The learner's name as a user picked it (``learner=<name>``), else its class's."""
    try:
        from hydra.core.hydra_config import HydraConfig

        return str(HydraConfig.get().runtime.choices["learner"])
    except Exception:  # noqa: BLE001 - no Hydra run: the class's name
        target = str((cfg.get("learner") or {}).get("_target_", ""))
        return target.rsplit(".", 1)[-1].lower()


def build_env(cfg: DictConfig, num_envs: int | None = None,
              seed: int | Sequence[int] | None = None) -> RobotTaskEnv:
    """The batched env of a composed config.

    Args:
        cfg: a composed config (:mod:`tasks.catalog`): its ``robot`` and ``task`` nodes, ``num_envs``
            and ``seed``.
        num_envs: the number of copies; None: ``cfg.num_envs``.
        seed: the seed, or a list of seeds that makes seed blocks (see :class:`RobotTaskEnv`);
            None: ``cfg.seed``.

    Returns:
        A new env, with a fresh task and robot, whose actions are the form the config's
        learner acts on (:func:`action_form`).

    Raises:
        ConfigError: as :func:`build_task` does, or if the task offers no actions of the learner's form.
    """
    task, form = build_task(cfg), action_form(cfg)
    if form not in action_forms(task):  # the env refuses it too; this names the learner as picked
        check_action_form(task, form, learner_name(cfg))
    return RobotTaskEnv(task, num_envs=int(cfg.num_envs if num_envs is None else num_envs),
                        seed=int(cfg.seed) if seed is None else seed, actions=form)
