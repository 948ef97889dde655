"""Name-to-address lookups: how robots reach their joints in a compiled model."""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from robots.physics import BatchedPhysics


def _full_name(element) -> str:
    return element.full_identifier


def actuator_id(model: mujoco.MjModel, element) -> int:
    """Index of an MJCF actuator element in the compiled ``model``."""
    index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, _full_name(element))
    if index < 0:
        raise KeyError(f"actuator {_full_name(element)!r} is not in the compiled model")
    return index


def sensor_slice(model: mujoco.MjModel, element) -> slice:
    """Where an MJCF sensor element's values sit in ``sensordata``."""
    index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SENSOR, _full_name(element))
    if index < 0:
        raise KeyError(f"sensor {_full_name(element)!r} is not in the compiled model")
    start = int(model.sensor_adr[index])
    return slice(start, start + int(model.sensor_dim[index]))


@dataclass(frozen=True)
class JointHandle:
    """Addresses of one 1-dof joint (hinge or slide) in ``qpos`` and ``qvel``."""

    name: str
    qpos_adr: int
    dof_adr: int

    @classmethod
    def of(cls, model: mujoco.MjModel, element) -> "JointHandle":
        name = _full_name(element)
        index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if index < 0:
            raise KeyError(f"joint {name!r} is not in the compiled model")
        return cls(name, int(model.jnt_qposadr[index]), int(model.jnt_dofadr[index]))

    def pos(self, physics: BatchedPhysics) -> np.ndarray:
        return physics.qpos[:, self.qpos_adr].copy()

    def vel(self, physics: BatchedPhysics) -> np.ndarray:
        return physics.qvel[:, self.dof_adr].copy()

    def set(self, physics: BatchedPhysics, mask: np.ndarray, pos, vel) -> None:
        physics.qpos[mask, self.qpos_adr] = pos
        physics.qvel[mask, self.dof_adr] = vel
