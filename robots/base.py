"""What a task needs from a robot: the contract every robot fulfils.

A robot is an MJCF model with named accessors (dm_control's ``suite``
physics style): the task attaches ``mjcf_model`` to its arena, the env
compiles it, ``bind`` resolves the robot's joints, actuators and sensors in
the compiled model, and from then on the robot reads and commands a whole
batch of copies (:class:`~robots.physics.BatchedPhysics`). A robot never
computes a reward and knows nothing of episodes.
"""

from __future__ import annotations

import abc
from typing import Any, Mapping

import numpy as np

from params import ConfigError
from robots.physics import BatchedPhysics


class Robot(abc.ABC):
    """The robot contract. Its parameters are dataclass fields made with
    :func:`params.declare.param` (checked in ``__post_init__``)."""

    #: The robot's MJCF model (``dm_control.mjcf``), attached to an arena by the task.
    mjcf_model: Any

    @abc.abstractmethod
    def bind(self, physics: BatchedPhysics) -> None:
        """Resolves this robot's joints, actuators and sensors in ``physics.model``.

        Args:
            physics: the batch of copies of the compiled arena (the robot attached); from then on the
                robot reads and commands every copy through it.
        """

    def state_dict(self) -> dict[str, np.ndarray]:
        """Per-copy state kept outside the physics (saved with a training checkpoint).

        The robots here keep none: their commands live in ``physics.ctrl``.

        Returns:
            Named arrays with one row per copy; ``{}`` for the robots here.
        """
        return {}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restores what :meth:`state_dict` returned.

        Args:
            state: named arrays, as :meth:`state_dict` returns them.

        Raises:
            ConfigError: if ``state`` is not empty (this default keeps no state).
        """
        if state:
            raise ConfigError(f"{type(self).__name__} keeps no per-copy state; got {sorted(state)}")


#: Every member a robot provides.
CONTRACT = ("mjcf_model", "bind", "state_dict", "load_state_dict")


def check_robot(robot: Any) -> None:
    """Raises ``TypeError`` naming the contract members ``robot`` lacks.

    Args:
        robot: the object to check.

    Raises:
        TypeError: if ``robot`` lacks a member of :data:`CONTRACT` or does not derive from :class:`Robot`.
    """
    missing = [m for m in CONTRACT if not hasattr(robot, m)]
    if missing or not isinstance(robot, Robot):
        raise TypeError(f"{type(robot).__name__} is not a robot (robots.base.Robot): "
                        f"missing {', '.join(missing) or 'the Robot base class'}")
