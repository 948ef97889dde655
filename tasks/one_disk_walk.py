"""Moving cube ``one_disk_walk``: walk along +y by tipping over edges with the wheel.

Actions are ``Discrete(5)`` on a persistent wheel-speed command: 0 sets it to
``+roll_speed_fixed_value``, 1 to ``-roll_speed_fixed_value``, 2 to 0, 3 adds
``roll_speed_increment_value``, 4 subtracts it; the command is then clipped to
+-``roll_speed_fixed_value``.

Observation (the original's, rounded as it did): wheel speed (0 decimals),
y distance from the episode's start, roll, pitch, y linear speed, yaw
(1 decimal each).

Reward, on a step that does not end the episode::

    round(dy * move_distance_reward_weight)
    + round(y_speed * y_linear_speed_reward_weight)
    + round(-|sin(yaw)| * y_axis_angle_reward_weight)

with ``dy`` the change of y since the previous step; on the step that ends it,
``-end_episode_points``. The episode terminates when |pitch| >
``max_pitch_angle`` or |yaw| > ``max_yaw_angle``; the environment truncates
it after ``max_episode_steps``. Summed over an episode the speed term is about
``y_linear_speed_reward_weight / running_step`` times the net displacement, so
a negative weight makes walking towards -y pay (the course's exercise).

The original's defects are fixed: a pitch failure is no longer cleared by the
yaw check; the unused roll reward term is gone; ``n_actions`` must be 5; the
ending step costs ``-end_episode_points`` (so ``end_episode_points`` >= 0).
Reward and termination use the exact pose and velocity, not the rounded
observation (rounding is only what the learner sees). ``max_distance`` and
``max_y_linear_speed`` are, as in the original, only the declared observation
bounds (:attr:`OneDiskWalk.observation_high`).

Reset: the cube at rest on its face at ``init_cube_pose`` (x, y, height of its
bottom above the floor) with the wheel at ``init_roll_vel``, turned about z by
a seeded uniform yaw in +-``reset_noise`` rad so the copies do not all repeat
one trajectory. Parameter names are the course YAML's.

Solved (``success``, overridable as ``task.win``): the greedy policy walks at
least 1 m in the rewarded direction (the sign of
``y_linear_speed_reward_weight``), the mean ``distance_walked`` of a greedy
evaluation's episodes. One tip over an edge moves the cube 0.2 m, so 1 m is
five edges in a row: a gait, not a lucky fall. Surviving is not success: a
cube that never moves lasts every episode to its time limit and walks 0 m.
"""

from __future__ import annotations

import math
from typing import Sequence

import numpy as np
from dm_control import mjcf

from robots.cube import Cube
from robots.physics import BatchedPhysics
from tasks.arena import floor_arena
from params import finite, require, whole
from tasks.base import Bounds, Success, substeps_for

SUCCESS = Success("distance_walked", "m", "distance walked", 1.0, "greedy", 100, 100)

# The five actions on the wheel-speed command.
WHEEL_FORWARD, WHEEL_BACKWARD, WHEEL_STOP, SPEED_UP, SPEED_DOWN = range(5)


class OneDiskWalk:
    """The cube walking task; it has a :class:`Cube`."""

    observation_names = ("wheel_speed", "y_distance", "roll", "pitch", "y_speed", "yaw")

    def __init__(
        self,
        robot: Cube,
        running_step: float = 0.06,
        n_actions: int = 5,
        init_roll_vel: float = 0.0,
        roll_speed_fixed_value: float = 100.0,
        roll_speed_increment_value: float = 10.0,
        max_distance: float = 2.0,
        max_pitch_angle: float = 0.2,
        max_yaw_angle: float = 0.1,
        max_y_linear_speed: float = 100.0,
        init_cube_pose: Sequence[float] = (0.0, 0.0, 0.0),
        end_episode_points: float = 1000.0,
        move_distance_reward_weight: float = 1000.0,
        y_linear_speed_reward_weight: float = 1000.0,
        y_axis_angle_reward_weight: float = 1000.0,
        reset_noise: float = 0.005,
        max_episode_steps: int = 1000,
        physics_timestep: float = 0.001,
        tabular_state: dict | None = None,
        win: dict | None = None,
    ) -> None:
        require(isinstance(robot, Cube), "task one_disk_walk needs robot=cube",
                type(robot).__name__)
        require(n_actions == 5, "task.n_actions must be 5 (the five wheel actions)", n_actions)
        require(finite(roll_speed_fixed_value) and roll_speed_fixed_value > 0,
                "task.roll_speed_fixed_value must be a finite number > 0", roll_speed_fixed_value)
        require(roll_speed_fixed_value <= robot.speed_limit,
                f"task.roll_speed_fixed_value must be <= robot.speed_limit ({robot.speed_limit})",
                roll_speed_fixed_value)
        require(finite(roll_speed_increment_value) and roll_speed_increment_value > 0,
                "task.roll_speed_increment_value must be a finite number > 0",
                roll_speed_increment_value)
        require(finite(init_roll_vel) and abs(init_roll_vel) <= roll_speed_fixed_value,
                f"task.init_roll_vel must be within +-roll_speed_fixed_value "
                f"({roll_speed_fixed_value})", init_roll_vel)
        for name, value in (("max_pitch_angle", max_pitch_angle), ("max_yaw_angle", max_yaw_angle),
                            ("max_distance", max_distance),
                            ("max_y_linear_speed", max_y_linear_speed)):
            require(finite(value) and value > 0, f"task.{name} must be a finite number > 0", value)
        require(isinstance(init_cube_pose, (Sequence, np.ndarray)) and not isinstance(init_cube_pose, str)
                and len(init_cube_pose) == 3 and all(finite(v) for v in init_cube_pose),
                "task.init_cube_pose must be [x, y, z], three finite numbers", init_cube_pose)
        require(finite(end_episode_points) and end_episode_points >= 0,
                "task.end_episode_points must be a finite number >= 0 (it is subtracted)",
                end_episode_points)
        for name, value in (("move_distance_reward_weight", move_distance_reward_weight),
                            ("y_linear_speed_reward_weight", y_linear_speed_reward_weight),
                            ("y_axis_angle_reward_weight", y_axis_angle_reward_weight)):
            require(finite(value), f"task.{name} must be a finite number", value)
        require(finite(reset_noise) and reset_noise >= 0,
                "task.reset_noise must be a finite number >= 0", reset_noise)
        require(whole(max_episode_steps) and max_episode_steps >= 1,
                "task.max_episode_steps must be an integer >= 1", max_episode_steps)
        # The rewarded walking direction along y: the speed weight's sign (else the distance's).
        self.direction = float(np.sign(y_linear_speed_reward_weight)
                               or np.sign(move_distance_reward_weight) or 1.0)
        towards = "+y" if self.direction > 0 else "-y"
        self.success = Success.from_config(
            win, SUCCESS, {"distance_walked": ("m", f"distance walked towards {towards}")})
        self.robot = robot
        self.n_actions = int(n_actions)
        self.running_step = float(running_step)
        self.physics_timestep = float(physics_timestep)
        self.n_substeps = substeps_for(running_step, physics_timestep)
        self.init_roll_vel = float(init_roll_vel)
        self.roll_speed_fixed_value = float(roll_speed_fixed_value)
        self.roll_speed_increment_value = float(roll_speed_increment_value)
        self.max_pitch_angle = float(max_pitch_angle)
        self.max_yaw_angle = float(max_yaw_angle)
        self.init_cube_pose = np.asarray(init_cube_pose, dtype=float)
        self.end_episode_points = float(end_episode_points)
        self.move_distance_reward_weight = float(move_distance_reward_weight)
        self.y_linear_speed_reward_weight = float(y_linear_speed_reward_weight)
        self.y_axis_angle_reward_weight = float(y_axis_angle_reward_weight)
        self.reset_noise = float(reset_noise)
        self.max_episode_steps = int(max_episode_steps)
        # The original's observation Box (informational: the env spec is unbounded).
        self.observation_high = np.array([
            roll_speed_fixed_value, max_distance, 2 * math.pi, max_pitch_angle,
            max_y_linear_speed, max_y_linear_speed,
        ])
        self.tabular_state = Bounds.from_config(
            tabular_state
            or {"wheel_speed": [-105.0, 105.0], "y_speed": [-0.75, 0.75], "yaw": [-0.15, 0.15]},
            self.observation_names,
        )
        self._command = np.zeros(0)
        self._start_y = np.zeros(0)
        self._prev_y = np.zeros(0)

    def build_arena(self) -> mjcf.RootElement:
        arena = floor_arena("cube_one_disk_walk", self.physics_timestep)
        # Elliptic friction cones: with pyramidal ones the cube rests ten times
        # less level and yaws more when thrown over several edges at once.
        arena.option.cone = "elliptic"
        # Looking along -x at the walking line: +y is to the right of the image.
        arena.worldbody.add("camera", name="side", pos=[1.3, 0.25, 0.45],
                            xyaxes=[0, 1, 0, -0.35, 0, 1.3])
        arena.attach(self.robot.mjcf_model).add("freejoint")
        return arena

    def bind(self, physics: BatchedPhysics) -> None:
        self.robot.bind(physics)
        n = physics.num_envs
        self._command = np.zeros(n)
        self._start_y = np.zeros(n)
        self._prev_y = np.zeros(n)

    def initialize_episode(
        self, physics: BatchedPhysics, mask: np.ndarray, rng: np.random.Generator
    ) -> None:
        """The cube at rest at ``init_cube_pose``, yawed by a small seeded angle."""
        n = int(np.count_nonzero(mask))
        yaw = rng.uniform(-self.reset_noise, self.reset_noise, size=n)
        x, y, z = self.init_cube_pose
        rpy = np.stack([np.zeros(n), np.zeros(n), yaw], axis=1)
        self.robot.set_state(physics, mask, [x, y, z + self.robot.half_edge], rpy,
                             wheel_speed=self.init_roll_vel)
        self._command[mask] = self.init_roll_vel
        self._start_y[mask] = y

    def apply_action(self, physics: BatchedPhysics, action: np.ndarray) -> None:
        fixed, inc = self.roll_speed_fixed_value, self.roll_speed_increment_value
        cmd = self._command
        cmd[action == WHEEL_FORWARD] = fixed
        cmd[action == WHEEL_BACKWARD] = -fixed
        cmd[action == WHEEL_STOP] = 0.0
        cmd[action == SPEED_UP] += inc
        cmd[action == SPEED_DOWN] -= inc
        np.clip(cmd, -fixed, fixed, out=cmd)
        self.robot.command_wheel_speed(physics, cmd)
        self._prev_y = self.robot.odometry(physics).position[:, 1]

    def observation(self, physics: BatchedPhysics) -> np.ndarray:
        odom = self.robot.odometry(physics)
        roll, pitch, yaw = odom.rpy.T
        return np.stack([
            np.round(self.robot.wheel_speed(physics), 0),
            np.round(odom.position[:, 1] - self._start_y, 1),
            np.round(roll, 1),
            np.round(pitch, 1),
            np.round(odom.linear_velocity[:, 1], 1),
            np.round(yaw, 1),
        ], axis=1)

    def terminated(self, physics: BatchedPhysics, observation: np.ndarray) -> np.ndarray:
        _, pitch, yaw = self.robot.odometry(physics).rpy.T
        return (np.abs(pitch) > self.max_pitch_angle) | (np.abs(yaw) > self.max_yaw_angle)

    def reward(
        self, physics: BatchedPhysics, observation: np.ndarray, terminated: np.ndarray
    ) -> np.ndarray:
        odom = self.robot.odometry(physics)
        running = (
            np.round((odom.position[:, 1] - self._prev_y) * self.move_distance_reward_weight)
            + np.round(odom.linear_velocity[:, 1] * self.y_linear_speed_reward_weight)
            + np.round(-np.abs(np.sin(odom.rpy[:, 2])) * self.y_axis_angle_reward_weight)
        )
        return np.where(terminated, -self.end_episode_points, running)

    def episode_info(self, physics: BatchedPhysics) -> dict[str, np.ndarray]:
        """Per copy: ``y_displacement``, how far along y the cube is from where its
        episode started (m); ``distance_walked``, the same in the rewarded direction."""
        dy = self.robot.odometry(physics).position[:, 1] - self._start_y
        return {"y_displacement": dy, "distance_walked": dy * self.direction}
