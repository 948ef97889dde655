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

from robots.binding import JointHandle, actuator_id, sensor_slice
from robots.physics import BatchedPhysics
from params import finite, require, whole

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


class TurtleBot:
    """A TurtleBot2-like robot; ``mjcf_model`` is attached to an arena by its task."""

    def __init__(
        self,
        laser_rays: int = 31,
        laser_fov: float = math.pi,
        laser_max_range: float = 6.0,
        laser_height: float = 0.3,
        linear_gain: float = 200.0,
        angular_gain: float = 3.0,
        max_linear_speed: float = 0.7,
        max_angular_speed: float = math.pi,
    ) -> None:
        require(whole(laser_rays) and laser_rays >= 1, "robot.laser_rays must be an integer >= 1",
                laser_rays)
        require(finite(laser_fov) and 0 < laser_fov <= 2 * math.pi,
                "robot.laser_fov must be in (0, 2 pi] radians", laser_fov)
        for name, value in (("laser_max_range", laser_max_range), ("laser_height", laser_height),
                            ("linear_gain", linear_gain), ("angular_gain", angular_gain),
                            ("max_linear_speed", max_linear_speed),
                            ("max_angular_speed", max_angular_speed)):
            require(finite(value) and value > 0, f"robot.{name} must be a finite number > 0", value)
        self.laser_max_range = float(laser_max_range)
        self.max_linear_speed = float(max_linear_speed)
        self.max_angular_speed = float(max_angular_speed)
        n = int(laser_rays)
        if n == 1:
            self.laser_angles = np.zeros(1)
        elif laser_fov >= 2 * math.pi - 1e-9:  # a full circle: no duplicate ray at +-pi
            self.laser_angles = -math.pi + 2 * math.pi * np.arange(n) / n
        else:
            self.laser_angles = np.linspace(-laser_fov / 2, laser_fov / 2, n)
        self.mjcf_model = mjcf.from_path(str(_XML))
        model = self.mjcf_model
        self._linear = model.find("actuator", "linear")
        self._angular = model.find("actuator", "angular")
        self._linear.kv = float(linear_gain)
        self._angular.kv = float(angular_gain)
        base = model.find("body", "base")
        self._rays = []
        for i, angle in enumerate(self.laser_angles):
            site = base.add("site", name=f"laser_{i:03d}", pos=[0, 0, laser_height],
                            zaxis=[math.cos(angle), math.sin(angle), 0], size=[0.005],
                            rgba=[1, 0, 0, 0])
            self._rays.append(model.sensor.add("rangefinder", name=f"laser_{i:03d}", site=site))
        self._x: JointHandle | None = None
        self._y: JointHandle | None = None
        self._yaw: JointHandle | None = None
        self._act = np.zeros(2, dtype=np.int64)
        self._laser_idx = np.zeros(n, dtype=np.int64)
        self._bumper_idx = -1

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
