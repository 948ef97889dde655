"""A declared task's start state (``task.reset``): where each hinge and slide joint starts and
how fast, drawn per episode from the env's seeded stream.

::

    reset:
      joints:
        shoulder: 3.14159                                  # a position; the noise below is added
        elbow: {position: [-0.5, 0.5], velocity: [-1, 1]}  # its own uniform ranges, no other noise
        spinner: {position: [-3.14159, 3.14159], within_limits: false}
      disc: {joints: [target_x, target_y], radius: 0.2}    # two slides, uniform over a disc
      position_noise: 0.1                                  # uniform +-, on every other joint
      velocity_noise: 0.1

A joint given a number starts there plus ``position_noise``, moving at a uniform
+-``velocity_noise`` (as does every joint not named, from the model's ``qpos0``). A joint given
a mapping takes only its own ``position`` (a number or ``[low, high]``, uniform; default the
model's) and ``velocity`` (a number or ``[low, high]``; default 0, at rest). A ``disc`` places
two joints uniformly over a disc of ``radius`` around ``center`` (default: their start
positions), at rest unless the joints say otherwise (Gymnasium's reacher target). Positions are
clipped to a limited joint's range unless its ``within_limits`` is false.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from params import finite, require
from robots.mjcf_robot import MjcfRobot, Reader
from robots.physics import BatchedPhysics

RESET_KEYS = ("joints", "disc", "position_noise", "velocity_noise")
JOINT_KEYS = ("position", "velocity", "within_limits")
DISC_KEYS = ("joints", "radius", "center")


@dataclass
class JointStart:
    """One joint's start: its reader, its position (a number, a ``(low, high)`` range, or
    None: the model's) and velocity (likewise; None: the shared noise's), whether the shared
    noise applies, and the range its positions are clipped to (None: none)."""

    reader: Reader
    position: float | tuple[float, float] | None = None
    velocity: float | tuple[float, float] | None = None
    noisy: bool = True
    limits: tuple[float, float] | None = None


def _number_or_range(value: Any, where: str) -> float | tuple[float, float]:
    if isinstance(value, (list, tuple)):
        require(len(value) == 2 and all(finite(v) for v in value) and value[0] <= value[1],
                f"{where} must be a number or [low, high] with low <= high", value)
        return float(value[0]), float(value[1])
    require(finite(value), f"{where} must be a number or [low, high]", value)
    return float(value)


def _draw(value: float | tuple[float, float], n: int, rng: np.random.Generator) -> np.ndarray | float:
    return rng.uniform(value[0], value[1], n) if isinstance(value, tuple) else value


class StartState:
    """The start state ``task.reset`` declares over a robot's hinge and slide joints."""

    def __init__(self, robot: MjcfRobot, spec: Mapping | None) -> None:
        spec = dict(spec or {})
        unknown = sorted(set(spec) - set(RESET_KEYS))
        require(not unknown, f"task.reset takes {', '.join(RESET_KEYS)}", unknown)
        self.position_noise, self.velocity_noise = (self._noise(spec, k) for k in RESET_KEYS[2:])
        ranges = robot.joint_ranges()
        self.joints = {name: JointStart(robot.reader("joint_pos", name, "task.reset"), limits=ranges.get(name))
                       for name in robot.hinges_and_slides()}
        given = spec.get("joints") or {}
        require(isinstance(given, Mapping), "task.reset.joints must map joint names to positions or "
                "{position, velocity, within_limits}", given)
        for name, value in given.items():
            self._joint(robot, str(name), value)
        self.disc = self._disc(robot, spec.get("disc"))

    @staticmethod
    def _noise(spec: Mapping, key: str) -> float:
        value = spec.get(key, 0.0)
        require(finite(value) and value >= 0, f"task.reset.{key} must be a number >= 0", value)
        return float(value)

    def _joint(self, robot: MjcfRobot, name: str, value: Any) -> None:
        where = f"task.reset.joints.{name}"
        if name not in self.joints:
            robot.element("joint", name, "task.reset.joints")  # one line if missing
            require(False, f"{where} must be a hinge or slide joint", name)
        joint = self.joints[name]
        if not isinstance(value, Mapping):
            require(finite(value), f"{where} must be a position or {{position, velocity, within_limits}}", value)
            joint.position = float(value)
            return
        unknown = sorted(set(value) - set(JOINT_KEYS))
        require(not unknown, f"{where} takes {', '.join(JOINT_KEYS)}", unknown)
        joint.noisy = False
        if value.get("position") is not None:
            joint.position = _number_or_range(value["position"], f"{where}.position")
        joint.velocity = _number_or_range(value.get("velocity", 0.0), f"{where}.velocity")
        within = value.get("within_limits", True)
        require(isinstance(within, bool), f"{where}.within_limits must be true or false", within)
        if not within:
            joint.limits = None

    def _disc(self, robot: MjcfRobot, spec: Any) -> dict | None:
        if spec is None:
            return None
        where = "task.reset.disc"
        require(isinstance(spec, Mapping) and set(spec) <= set(DISC_KEYS) and {"joints", "radius"} <= set(spec),
                f"{where} must be {{joints: [joint, joint], radius, center: [x, y]}}", spec)
        pair = spec["joints"]
        require(isinstance(pair, (list, tuple)) and len(pair) == 2 and pair[0] != pair[1],
                f"{where}.joints must name two joints", pair)
        for name in pair:
            if str(name) not in self.joints:
                self._joint(robot, str(name), 0.0)  # one line naming it
        require(finite(spec["radius"]) and spec["radius"] > 0, f"{where}.radius must be a number > 0", spec["radius"])
        center = spec.get("center")
        require(center is None or (isinstance(center, (list, tuple)) and len(center) == 2
                                   and all(finite(v) for v in center)), f"{where}.center must be [x, y]", center)
        for name in pair:
            self.joints[str(name)].noisy = False
        return {"joints": [str(n) for n in pair], "radius": float(spec["radius"]),
                "center": None if center is None else [float(v) for v in center]}

    def start(self, robot: MjcfRobot, physics: BatchedPhysics, mask: np.ndarray, rng: np.random.Generator) -> None:
        """Places the ``mask`` copies' joints (just reset to the model's ``qpos0``), in the model's
        order, then the disc's pair."""
        n = int(mask.sum())
        disc = set(self.disc["joints"]) if self.disc else set()
        for name, joint in self.joints.items():
            if name in disc:
                continue
            pos, vel = self._drawn(joint, physics, mask, n, rng)
            robot.set_joint(physics, joint.reader, mask, self._clipped(joint, pos), vel)
        if self.disc:
            self._on_disc(robot, physics, mask, n, rng)

    def _drawn(self, joint: JointStart, physics: BatchedPhysics, mask: np.ndarray, n: int,
               rng: np.random.Generator) -> tuple[Any, Any]:
        base = joint.reader.read(physics)[mask, 0] if joint.position is None else _draw(joint.position, n, rng)
        if joint.noisy:  # the shared noise (the draws a number or an unnamed joint always made)
            return (base + rng.uniform(-self.position_noise, self.position_noise, n),
                    rng.uniform(-self.velocity_noise, self.velocity_noise, n))
        return base, _draw(0.0 if joint.velocity is None else joint.velocity, n, rng)

    def _on_disc(self, robot: MjcfRobot, physics: BatchedPhysics, mask: np.ndarray, n: int,
                 rng: np.random.Generator) -> None:
        first, second = (self.joints[name] for name in self.disc["joints"])
        center = self.disc["center"] or [j.reader.read(physics)[mask, 0] if j.position is None
                                         else _draw(j.position, n, rng) for j in (first, second)]
        angle = rng.uniform(0.0, 2 * np.pi, n)
        radius = self.disc["radius"] * np.sqrt(rng.uniform(0.0, 1.0, n))
        for joint, offset, c in ((first, np.cos(angle), center[0]), (second, np.sin(angle), center[1])):
            vel = _draw(0.0 if joint.velocity is None else joint.velocity, n, rng)
            robot.set_joint(physics, joint.reader, mask, self._clipped(joint, c + radius * offset), vel)

    @staticmethod
    def _clipped(joint: JointStart, pos: Any) -> Any:
        return pos if joint.limits is None else np.clip(pos, *joint.limits)
