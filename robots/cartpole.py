"""The 3D cart-pole: a cart driven along a rail, a pole free on a hinge above it.

Physical facts from the original model (SPEC.md): cart 0.4 x 0.2 x 0.2 m, 2.5 kg,
on a prismatic joint with range +-2 m; pole 0.05 x 0.05 x 0.8 m, 1 kg, its centre
of mass 0.4 m above a hinge that sits 0.32 m above the cart centre, hinge
friction 0.1 N m (MuJoCo ``frictionloss``) and limits +-1.57 rad.

The cart's controller follows ``control_type``:

- ``velocity``: a velocity servo, force = ``velocity_gain`` * (command - velocity)
  (the original's velocity PID with p = 1000);
- ``position``: a position servo with ``position_gain`` and critical damping;
- ``effort``: the command is the force in newtons.

Joint states are read exactly from the physics state (the original's
``/joint_states`` topic). The robot knows nothing of rewards or episodes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from dm_control import mjcf

from params import require
from params.declare import check_fields, param
from robots.base import Robot
from robots.binding import JointHandle, actuator_id
from robots.physics import BatchedPhysics

CONTROL_TYPES = ("velocity", "position", "effort")
_XML = Path(__file__).with_suffix(".xml")


@dataclass
class CartPoleState:
    """Joint states of a batch of cart-poles, each of shape ``(num_envs,)``."""

    cart_pos: np.ndarray
    cart_vel: np.ndarray
    pole_angle: np.ndarray
    pole_vel: np.ndarray


@dataclass(eq=False)
class CartPole(Robot):
    """A cart-pole robot; ``mjcf_model`` is attached to an arena by its task."""

    velocity_gain: float = param(1000.0, "velocity servo gain, N per m/s (original PID p = 1000)", gt=0)
    position_gain: float = param(1000.0, "position servo gain, N per m (task.control_type=position)",
                                 gt=0)
    force_limit: float = param(0.0, "largest cart force, N", ge=0, note="0 = unlimited")

    def __post_init__(self) -> None:
        check_fields(self, "robot")
        self.mjcf_model = mjcf.from_path(str(_XML))
        self._actuator = None
        self.control_type = ""
        self.use_controller("velocity")
        self._slider: JointHandle | None = None
        self._hinge: JointHandle | None = None
        self._act_id = -1

    @property
    def rail_limit(self) -> float:
        """Half-length of the slider's travel, in metres."""
        return float(self.mjcf_model.find("joint", "slider").range[1])

    def use_controller(self, control_type: str) -> None:
        """Loads the cart controller for ``control_type`` (before compiling)."""
        require(control_type in CONTROL_TYPES,
                f"task.control_type must be one of {', '.join(CONTROL_TYPES)}", control_type)
        if self._actuator is not None:
            self._actuator.remove()
        slider = self.mjcf_model.find("joint", "slider")
        limits = {}
        if self.force_limit > 0:
            limits = dict(forcelimited="true", forcerange=[-self.force_limit, self.force_limit])
        actuators = self.mjcf_model.actuator
        if control_type == "velocity":
            self._actuator = actuators.add(
                "velocity", name="cart", joint=slider, kv=self.velocity_gain, **limits
            )
        elif control_type == "position":
            mass = 3.5  # cart + pole, for critical damping of the servo
            self._actuator = actuators.add(
                "position", name="cart", joint=slider, kp=self.position_gain,
                kv=2.0 * math.sqrt(self.position_gain * mass), **limits,
            )
        else:
            self._actuator = actuators.add("motor", name="cart", joint=slider, gear=[1], **limits)
        self.control_type = control_type

    def bind(self, physics: BatchedPhysics) -> None:
        """Resolves this robot's joints and actuator in the compiled model."""
        self._slider = JointHandle.of(physics.model, self.mjcf_model.find("joint", "slider"))
        self._hinge = JointHandle.of(physics.model, self.mjcf_model.find("joint", "hinge"))
        self._act_id = actuator_id(physics.model, self._actuator)

    def command(self, physics: BatchedPhysics, value: np.ndarray) -> None:
        """Sets the cart command (m/s, m or N by control type) of every copy."""
        physics.ctrl[:, self._act_id] = value

    def joint_states(self, physics: BatchedPhysics) -> CartPoleState:
        """Cart position and velocity, pole angle and angular velocity."""
        return CartPoleState(
            cart_pos=self._slider.pos(physics),
            cart_vel=self._slider.vel(physics),
            pole_angle=self._hinge.pos(physics),
            pole_vel=self._hinge.vel(physics),
        )

    def set_joint_states(
        self,
        physics: BatchedPhysics,
        mask: np.ndarray,
        cart_pos: np.ndarray | float,
        cart_vel: np.ndarray | float,
        pole_angle: np.ndarray | float,
        pole_vel: np.ndarray | float,
    ) -> None:
        """Places the masked copies in the given joint state."""
        self._slider.set(physics, mask, cart_pos, cart_vel)
        self._hinge.set(physics, mask, pole_angle, pole_vel)
