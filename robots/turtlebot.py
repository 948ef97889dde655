"""A TurtleBot2-like differential-drive base with a planar laser scanner.

The base (robots/turtlebot.xml: Kobuki-sized, 0.355 m across, about 6 kg) moves
in the plane on slide x / slide y / hinge yaw joints. It is commanded like the
original's ``cmd_vel``: a linear velocity along its heading and an angular
velocity about the vertical, held by velocity servos that act at the base centre
in the body frame (a third servo holds the sideways velocity at 0, the wheels'
no-slip constraint). This stands in for two driven wheels on casters: the same
kinematics, no wheel-floor friction to tune, and a few cheap joints to step.

Sensors:

- odometry: pose (x, y, yaw) and velocities, read exactly from the joint state;
- laser: ``laser_rays`` MuJoCo rangefinders in a horizontal fan over
  ``laser_fov`` centred on the heading, ordered right to left like a ROS
  ``LaserScan``; no hit (MuJoCo's -1) or a hit beyond ``laser_max_range`` reads
  ``laser_max_range``;
- bumper: whether the base touches anything (a MuJoCo ``contact`` sensor).

Sensor readings are those of :class:`~robots.physics.BatchedPhysics`: one
physics timestep old after a step, exact after a reset. No rewards here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from dm_control import mjcf

from params.declare import check_fields, param
from robots.base import Robot
from robots.binding import JointHandle, actuator_id, sensor_slice
from robots.physics import BatchedPhysics

_XML = Path(__file__).with_suffix(".xml")


@dataclass
class Odometry:
    """Pose and velocities of a batch of bases, each of shape ``(num_envs,)``.

    ``yaw`` is wrapped to [-pi, pi); ``linear`` is the velocity along the
    heading, ``angular`` the yaw rate.
    """

    x: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    linear: np.ndarray
    angular: np.ndarray


@dataclass(eq=False)
class TurtleBot(Robot):
    """A TurtleBot2-like robot; ``mjcf_model`` is attached to an arena by its task."""

    laser_rays: int = param(31, "rangefinders in the laser fan, right to left", ge=1, le=1024)
    laser_fov: float = param(math.pi, "angle the fan covers, centred on the heading, rad",
                             gt=0, le=2 * math.pi)
    laser_max_range: float = param(6.0, "laser range, m; no hit reads this (original max_laser_value)",
                                   gt=0)
    laser_height: float = param(0.3, "height of the laser above the floor, m", gt=0)
    linear_gain: float = param(200.0, "velocity servo gain, N per m/s (about 0.03 s to settle)", gt=0)
    angular_gain: float = param(3.0, "yaw-rate servo gain, N m per rad/s (about 0.03 s to settle)",
                                gt=0)
    max_linear_speed: float = param(0.7, "linear speed limit, m/s (Kobuki); commands are clipped",
                                    gt=0)
    max_angular_speed: float = param(math.pi, "yaw rate limit, rad/s (Kobuki); commands are clipped",
                                     gt=0)

    def __post_init__(self) -> None:
        check_fields(self, "robot")
        self.laser_angles = self._fan_angles(self.laser_rays, self.laser_fov)
        self.mjcf_model = mjcf.from_path(str(_XML))
        self._linear = self.mjcf_model.find("actuator", "linear")
        self._angular = self.mjcf_model.find("actuator", "angular")
        self._linear.kv = self.linear_gain
        self._angular.kv = self.angular_gain
        self._rays = [self._add_ray(i, angle) for i, angle in enumerate(self.laser_angles)]
        self._x: JointHandle | None = None
        self._y: JointHandle | None = None
        self._yaw: JointHandle | None = None
        self._act = np.zeros(2, dtype=np.int64)
        self._laser_idx = np.zeros(self.laser_rays, dtype=np.int64)
        self._bumper_idx = -1

    @staticmethod
    def _fan_angles(n: int, fov: float) -> np.ndarray:
        """Ray headings, right to left; a full circle has no duplicate ray at +-pi."""
        if n == 1:
            return np.zeros(1)
        if fov >= 2 * math.pi - 1e-9:
            return -math.pi + 2 * math.pi * np.arange(n) / n
        return np.linspace(-fov / 2, fov / 2, n)

    def _add_ray(self, i: int, angle: float):
        """A rangefinder on a site of the base, looking along ``angle``."""
        site = self.mjcf_model.find("body", "base").add(
            "site", name=f"laser_{i:03d}", pos=[0, 0, self.laser_height],
            zaxis=[math.cos(angle), math.sin(angle), 0], size=[0.005], rgba=[1, 0, 0, 0])
        return self.mjcf_model.sensor.add("rangefinder", name=f"laser_{i:03d}", site=site)

    @property
    def n_rays(self) -> int:
        return len(self.laser_angles)

    @property
    def radius(self) -> float:
        """Radius of the base's footprint, in metres."""
        return float(self.mjcf_model.find("geom", "kobuki").size[0])

    def bind(self, physics: BatchedPhysics) -> None:
        """Resolves this robot's joints, actuators and sensors in the compiled model."""
        model = physics.model
        find = self.mjcf_model.find
        self._x = JointHandle.of(model, find("joint", "x"))
        self._y = JointHandle.of(model, find("joint", "y"))
        self._yaw = JointHandle.of(model, find("joint", "yaw"))
        self._act = np.array([actuator_id(model, self._linear), actuator_id(model, self._angular)])
        self._laser_idx = np.array([sensor_slice(model, s).start for s in self._rays])
        self._bumper_idx = sensor_slice(model, find("sensor", "bumper")).start

    def command_velocity(self, physics: BatchedPhysics, linear: np.ndarray | float,
                         angular: np.ndarray | float) -> None:
        """Sets every copy's linear (m/s) and angular (rad/s) velocity command.

        Commands are clipped to ``max_linear_speed`` and ``max_angular_speed``.
        """
        physics.ctrl[:, self._act[0]] = np.clip(linear, -self.max_linear_speed,
                                                self.max_linear_speed)
        physics.ctrl[:, self._act[1]] = np.clip(angular, -self.max_angular_speed,
                                                self.max_angular_speed)

    def stop(self, physics: BatchedPhysics, mask: np.ndarray) -> None:
        """Zero linear and angular velocity commands for the ``mask`` copies (the others keep theirs)."""
        physics.ctrl[np.ix_(mask, self._act)] = 0.0

    def odometry(self, physics: BatchedPhysics) -> Odometry:
        """Pose and velocities of every copy."""
        yaw = self._yaw.pos(physics)
        vx, vy = self._x.vel(physics), self._y.vel(physics)
        return Odometry(
            x=self._x.pos(physics),
            y=self._y.pos(physics),
            yaw=np.mod(yaw + math.pi, 2 * math.pi) - math.pi,
            linear=vx * np.cos(yaw) + vy * np.sin(yaw),
            angular=self._yaw.vel(physics),
        )

    def laser(self, physics: BatchedPhysics) -> np.ndarray:
        """Ranges ``(num_envs, laser_rays)`` in metres, right to left; no hit = max range."""
        ranges = physics.sensordata[:, self._laser_idx].copy()
        ranges[(ranges < 0) | (ranges > self.laser_max_range)] = self.laser_max_range
        return ranges

    def bumper(self, physics: BatchedPhysics) -> np.ndarray:
        """Whether each copy's base is in contact with anything (bool ``(num_envs,)``)."""
        return physics.sensordata[:, self._bumper_idx] > 0

    def set_pose(self, physics: BatchedPhysics, mask: np.ndarray, x: np.ndarray | float,
                 y: np.ndarray | float, yaw: np.ndarray | float) -> None:
        """Places the masked copies at (x, y) heading ``yaw``, at rest."""
        self._x.set(physics, mask, x, 0.0)
        self._y.set(physics, mask, y, 0.0)
        self._yaw.set(physics, mask, yaw, 0.0)
