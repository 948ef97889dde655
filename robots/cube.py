"""The moving cube: a free cube that walks by tipping over its edges, driven by
one reaction wheel inside it (a one-wheel Cubli).

Physical facts from the original model (SPEC.md): cube edge 0.2 m, 0.5 kg,
inertia 0.003333 I; wheel a cylinder of radius 0.08 m and length 0.01 m,
0.5 kg, on a continuous hinge about the cube's x axis. The original put the
wheel 0.1 m along x from the centre, i.e. straddling the +x face; here its
centre is at 0.09 m so the disc lies just inside the face (it only shifts the
centre of mass along x, which does not matter for rolling about x).

The wheel is velocity-controlled, as the original's velocity PID (p = 1.0,
effort limit 200, velocity limit 1000 rad/s): a MuJoCo ``velocity`` servo,
torque = ``velocity_gain`` * (command - wheel speed), clipped to
+-``torque_limit``, with the command clipped to +-``speed_limit``. Its reaction
torque acts on the cube: a sudden change of wheel speed tips it over an edge
along +-y (spinning the wheel up in +x moves the cube towards +y).

Contact choices (cube.xml; only the shell collides, and its ``priority`` makes
its parameters the contact's): friction 2. Spinning the wheel up throws the
cube about its edge with its centre moving at 45 degrees, so the pivot edge
needs a horizontal impulse about as large as the vertical one: at friction
0.3 the edge skids and a tip covers 0.08 m instead of 0.2; from about 0.8 it
holds; 2 leaves a margin. ``condim`` 3: no rolling friction to brake the tip.
``solref`` gives the contact stiffness and damping directly (1e5, 600: about
critically damped): a time-constant ``solref`` cannot be stiffer than two
timesteps, which let landings sink 4.6 mm; this one keeps them to about 1.6 mm.
The task uses elliptic friction cones and a 1 ms timestep: at 2 ms the
servo's reaction (time constant I_wheel / gain = 1.6 ms) arrives within one
step, the pivot edge sinks and the contact throws the cube up instead of
over the edge.

Measured (tests/test_cube.py): from rest, wheel 0 -> +-100 rad/s tips the cube
0.198 m along +-y, braking +-100 -> 0 tips it back 0.198 m; idle it drifts
below 1e-9 m/s; no corner goes more than 1.6 mm below the floor.

The cube has no joint of its own: whoever attaches ``mjcf_model`` to an arena
adds a free joint to the attachment frame (``arena.attach(model).add("freejoint")``,
dm_control's way for free bodies); :meth:`Cube.bind` finds it there.
Odometry and wheel speed are read exactly from the physics state. The robot
knows nothing of rewards or episodes.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np
from dm_control import mjcf
from numpy.typing import ArrayLike

from params.declare import check_fields, param
from robots.base import Robot
from robots.binding import JointHandle, actuator_id
from robots.physics import BatchedPhysics

_XML = Path(__file__).with_suffix(".xml")


@dataclass(frozen=True)
class FreeJointHandle:
    """Addresses of one free joint in ``qpos`` (xyz, quaternion) and ``qvel``."""

    name: str
    qpos_adr: int
    dof_adr: int

    @classmethod
    def of(cls, model: mujoco.MjModel, element) -> "FreeJointHandle":
        name = element.full_identifier
        index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
        if index < 0:
            raise KeyError(f"joint {name!r} is not in the compiled model")
        if model.jnt_type[index] != mujoco.mjtJoint.mjJNT_FREE:
            raise KeyError(f"joint {name!r} is not a free joint")
        return cls(name, int(model.jnt_qposadr[index]), int(model.jnt_dofadr[index]))

    def position(self, physics: BatchedPhysics) -> np.ndarray:
        return physics.qpos[:, self.qpos_adr : self.qpos_adr + 3].copy()

    def quaternion(self, physics: BatchedPhysics) -> np.ndarray:
        """Orientation as ``(w, x, y, z)``."""
        return physics.qpos[:, self.qpos_adr + 3 : self.qpos_adr + 7].copy()

    def linear_velocity(self, physics: BatchedPhysics) -> np.ndarray:
        """Velocity of the body origin in the world frame."""
        return physics.qvel[:, self.dof_adr : self.dof_adr + 3].copy()

    def angular_velocity(self, physics: BatchedPhysics) -> np.ndarray:
        """Angular velocity in the body's own frame."""
        return physics.qvel[:, self.dof_adr + 3 : self.dof_adr + 6].copy()

    def set(self, physics: BatchedPhysics, mask: np.ndarray, position: ArrayLike,
            quaternion: ArrayLike, linear_velocity: ArrayLike = 0.0,
            angular_velocity: ArrayLike = 0.0) -> None:
        """Places the masked copies at ``position`` and ``quaternion`` with the given velocities."""
        physics.qpos[mask, self.qpos_adr : self.qpos_adr + 3] = position
        physics.qpos[mask, self.qpos_adr + 3 : self.qpos_adr + 7] = quaternion
        physics.qvel[mask, self.dof_adr : self.dof_adr + 3] = linear_velocity
        physics.qvel[mask, self.dof_adr + 3 : self.dof_adr + 6] = angular_velocity


def quat_to_rpy(quat: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw (static x-y-z, as ROS ``euler_from_quaternion``) of
    ``(..., 4)`` quaternions ``(w, x, y, z)``."""
    w, x, y, z = np.moveaxis(quat, -1, 0)
    roll = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
    yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return np.stack([roll, pitch, yaw], axis=-1)


def rpy_to_quat(rpy: ArrayLike) -> np.ndarray:
    """Inverse of :func:`quat_to_rpy`: ``(..., 3)`` angles to ``(..., 4)`` quaternions."""
    half = np.asarray(rpy, dtype=float) / 2
    cr, cp, cy = np.cos(half[..., 0]), np.cos(half[..., 1]), np.cos(half[..., 2])
    sr, sp, sy = np.sin(half[..., 0]), np.sin(half[..., 1]), np.sin(half[..., 2])
    return np.stack([
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    ], axis=-1)


@dataclass
class CubeOdometry:
    """Pose and velocity of a batch of cubes (the original's ``/odom``).

    ``position`` ``(n, 3)`` of the cube centre and ``linear_velocity`` ``(n, 3)``
    in the world frame; ``rpy`` ``(n, 3)`` roll, pitch, yaw; ``quaternion``
    ``(n, 4)`` as ``(w, x, y, z)``.
    """

    position: np.ndarray
    quaternion: np.ndarray
    rpy: np.ndarray
    linear_velocity: np.ndarray


@dataclass(eq=False)
class Cube(Robot):
    """The one-wheel moving cube; ``mjcf_model`` is attached to an arena by its task."""

    velocity_gain: float = param(1.0, "wheel velocity servo gain, N m per rad/s (original PID p = 1.0)",
                                 gt=0)
    torque_limit: float = param(200.0, "largest wheel torque, N m (original effort limit)", gt=0)
    speed_limit: float = param(1000.0, "largest wheel speed command, rad/s (original velocity limit)",
                               gt=0)

    def __post_init__(self) -> None:
        check_fields(self, "robot")
        self.mjcf_model = mjcf.from_path(str(_XML))
        self._actuator = self.mjcf_model.find("actuator", "wheel")
        self._actuator.kv = self.velocity_gain
        self._actuator.forcerange = [-self.torque_limit, self.torque_limit]
        self._actuator.ctrlrange = [-self.speed_limit, self.speed_limit]
        self._root: FreeJointHandle | None = None
        self._wheel: JointHandle | None = None
        self._act_id = -1

    @property
    def half_edge(self) -> float:
        """Half the cube's edge length, in metres."""
        return float(self.mjcf_model.find("geom", "shell").size[0])

    def bind(self, physics: BatchedPhysics) -> None:
        """Resolves the free joint, the wheel joint and its servo in the compiled model."""
        frame = mjcf.get_attachment_frame(self.mjcf_model)
        if frame is None or frame.freejoint is None:
            raise ValueError("the cube must be attached with a free joint: "
                             "arena.attach(cube.mjcf_model).add('freejoint')")
        self._root = FreeJointHandle.of(physics.model, frame.freejoint)
        self._wheel = JointHandle.of(physics.model, self.mjcf_model.find("joint", "wheel"))
        self._act_id = actuator_id(physics.model, self._actuator)

    def command_wheel_speed(self, physics: BatchedPhysics, speed: ArrayLike) -> None:
        """Sets the wheel speed command (rad/s, relative to the cube) of every copy."""
        physics.ctrl[:, self._act_id] = np.clip(speed, -self.speed_limit, self.speed_limit)

    def wheel_speed(self, physics: BatchedPhysics) -> np.ndarray:
        """Wheel angular velocity relative to the cube, rad/s, ``(num_envs,)``."""
        return self._wheel.vel(physics)

    def odometry(self, physics: BatchedPhysics) -> CubeOdometry:
        """Position, orientation and linear velocity of the cube body."""
        quat = self._root.quaternion(physics)
        return CubeOdometry(
            position=self._root.position(physics),
            quaternion=quat,
            rpy=quat_to_rpy(quat),
            linear_velocity=self._root.linear_velocity(physics),
        )

    def lowest_corner_z(self, physics: BatchedPhysics) -> np.ndarray:
        """Height of each cube's lowest corner, ``(num_envs,)`` (negative: below z = 0)."""
        odom = self.odometry(physics)
        h = self.half_edge
        corners = h * np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
        w, x, y, z = odom.quaternion.T
        # Third row of each rotation matrix: world z of the body axes.
        row = np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1)
        return odom.position[:, 2] + (row @ corners.T).min(axis=1)

    def set_state(
        self,
        physics: BatchedPhysics,
        mask: np.ndarray,
        position: ArrayLike,
        rpy: ArrayLike,
        wheel_speed: ArrayLike = 0.0,
    ) -> None:
        """Places the masked copies at rest at ``position`` with orientation ``rpy``,
        the wheel spinning at ``wheel_speed`` (and commanded to keep it)."""
        n = int(np.count_nonzero(mask))
        quat = rpy_to_quat(np.broadcast_to(rpy, (n, 3)))
        self._root.set(physics, mask, np.broadcast_to(position, (n, 3)), quat)
        self._wheel.set(physics, mask, 0.0, wheel_speed)
        physics.ctrl[mask, self._act_id] = wheel_speed
