"""Moving cube ``one_disk_walk``: walk along +y by tipping over edges with the wheel.

Actions are ``Discrete(5)`` on a persistent wheel-speed command: 0 sets it to
``+roll_speed_fixed_value``, 1 to ``-roll_speed_fixed_value``, 2 to 0, 3 adds
``roll_speed_increment_value``, 4 subtracts it; the command is then clipped to
+-``roll_speed_fixed_value``.

The continuous form (SAC and its kind): one action in [-1, 1], the wheel-speed command
itself, scaled to +-``roll_speed_fixed_value`` (the discrete actions 0, 1 and 2 are its
ends and its middle).

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
a seeded uniform yaw in +-``reset_noise`` rad (0.05: about 3 degrees) and its
wheel spinning a seeded uniform +-``wheel_speed_noise`` rad/s off that speed (5:
the servo brings it to its command within a few steps, rocking the cube but never
tipping it; 100 rad/s tips it), so that no two copies, and no two greedy episodes,
repeat one trajectory (with 0.005 rad and no wheel noise a greedy evaluation's 20
episodes walked 1.49532-1.49544 m: one trajectory, twenty times). Parameter names
are the course YAML's (the wheel noise is this project's).

Solved (``success``, overridable as ``task.win``): the greedy policy walks at
least 1 m in the rewarded direction (the sign of
``y_linear_speed_reward_weight``), the mean ``distance_walked`` of a greedy
evaluation's episodes. One tip over an edge moves the cube 0.2 m, so 1 m is
five edges in a row: a gait, not a lucky fall. Surviving is not success: a
cube that never moves lasts every episode to its time limit and walks 0 m.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from dm_control import mjcf

from params import require
from params.declare import param
from robots.cube import Cube
from robots.physics import BatchedPhysics
from tasks.arena import floor_arena
from tasks.base import ActionRange, Bounds, PerCopy, Success, Task, common, setup

SUCCESS = Success("distance_walked", "m", "distance walked", 1.0, "greedy", 100, 0)

# The five actions on the wheel-speed command.
WHEEL_FORWARD, WHEEL_BACKWARD, WHEEL_STOP, SPEED_UP, SPEED_DOWN = range(5)


@dataclass(eq=False)
class OneDiskWalk(Task):
    """The cube walking task; it has a :class:`Cube`."""

    ROBOT = Cube  # the robot it needs (read from params/declared.json before anything loads)

    name: ClassVar[str] = "one_disk_walk"
    observation_names: ClassVar[tuple[str, ...]] = (
        "wheel_speed", "y_distance", "roll", "pitch", "y_speed", "yaw")

    robot: Cube
    running_step: float = common.running_step(0.06)
    n_actions: int = param(5, "wheel actions: +fixed, -fixed, stop, +increment, -increment",
                           choices=(5,))
    init_roll_vel: float = param(0.0, "wheel speed at reset, rad/s (within +-roll_speed_fixed_value)")
    roll_speed_fixed_value: float = param(100.0, "wheel speed of actions 0 and 1, rad/s; "
                                                 "also the clip of the command", gt=0)
    roll_speed_increment_value: float = param(10.0, "change of the wheel command by actions 3 and 4, "
                                                    "rad/s", gt=0)
    max_distance: float = param(2.0, "observation bound only, m (as in the original)", gt=0)
    max_pitch_angle: float = param(0.2, "|pitch| beyond which the episode terminates, rad", gt=0)
    max_yaw_angle: float = param(0.1, "|yaw| beyond which the episode terminates, rad", gt=0)
    max_y_linear_speed: float = param(100.0, "observation bound only, m/s (as in the original)", gt=0)
    init_cube_pose: list[float] = param([0.0, 0.0, 0.0], "x, y of the start and z of the cube's "
                                                         "bottom, m")
    end_episode_points: float = param(1000.0, "the ending step's reward is minus this", ge=0)
    move_distance_reward_weight: float = param(1000.0, "reward per metre moved along y in a step")
    y_linear_speed_reward_weight: float = param(1000.0, "reward per m/s along y; negative walks "
                                                        "towards -y")
    y_axis_angle_reward_weight: float = param(1000.0, "penalty per |sin yaw|")
    reset_noise: float = param(0.05, "uniform start yaw perturbation, rad", ge=0)
    wheel_speed_noise: float = param(5.0, "uniform start wheel-speed perturbation, rad/s (the command "
                                          "stays init_roll_vel)", ge=0)
    max_episode_steps: int = common.max_episode_steps(1000)
    physics_timestep: float = common.physics_timestep(0.001)
    tabular_state: dict | None = common.tabular_state("the course's reduced state")
    win: dict | None = common.win("the greedy policy walks 1 m")

    def __post_init__(self) -> None:
        # The rewarded walking direction along y: the speed weight's sign (else the distance's).
        self.direction = float(np.sign(self.y_linear_speed_reward_weight)
                               or np.sign(self.move_distance_reward_weight) or 1.0)
        towards = "+y" if self.direction > 0 else "-y"
        setup(self, SUCCESS,
              {"distance_walked": ("m", f"distance walked towards {towards}")})
        self._check_wheel()
        require(len(self.init_cube_pose) == 3,
                "task.init_cube_pose must be [x, y, z], three finite numbers", self.init_cube_pose)
        # The original's observation Box (informational: walking goes past max_distance, so
        # these are no bounds; observation_range has the true ones).
        self.observation_high = np.array([
            self.roll_speed_fixed_value, self.max_distance, 2 * math.pi, self.max_pitch_angle,
            self.max_y_linear_speed, self.max_y_linear_speed])
        self.tabular_bounds = Bounds.from_config(
            self.tabular_state
            or {"wheel_speed": [-105.0, 105.0], "y_speed": [-0.75, 0.75], "yaw": [-0.15, 0.15]},
            self.observation_names)
        self.per_copy = PerCopy(command=(), start_y=(), prev_y=())
        fixed = self.roll_speed_fixed_value
        self.action_range = ActionRange.of({"wheel_speed_command": [-fixed, fixed]})

    def _check_wheel(self) -> None:
        """Wheel speeds the robot can be commanded."""
        fixed = self.roll_speed_fixed_value
        require(fixed <= self.robot.speed_limit,
                f"task.roll_speed_fixed_value must be <= robot.speed_limit ({self.robot.speed_limit})",
                fixed)
        require(abs(self.init_roll_vel) <= fixed,
                f"task.init_roll_vel must be within +-roll_speed_fixed_value ({fixed})",
                self.init_roll_vel)

    def build_arena(self) -> mjcf.RootElement:
        arena = floor_arena("cube_one_disk_walk", self.physics_timestep)
        # Elliptic friction cones: with pyramidal ones the cube rests ten times
        # less level and yaws more when thrown over several edges at once.
        arena.option.cone = "elliptic"
        # Looking along -x at the walking line: +y is to the right of the image. It keeps
        # its offset from the world's centre of mass, which only the cube moves (trackcom):
        # a cube that walks 2 m stays in the picture, the floor's squares passing behind.
        arena.worldbody.add("camera", name="side", pos=[1.3, 0.25, 0.45],
                            xyaxes=[0, 1, 0, -0.35, 0, 1.3], mode="trackcom")
        arena.attach(self.robot.mjcf_model).add("freejoint")
        return arena

    def initialize_episode(
        self, physics: BatchedPhysics, mask: np.ndarray, rng: np.random.Generator
    ) -> None:
        """The cube at rest at ``init_cube_pose``, yawed by a small seeded angle, its wheel
        at ``init_roll_vel`` plus a small seeded speed."""
        n = int(np.count_nonzero(mask))
        yaw = rng.uniform(-self.reset_noise, self.reset_noise, size=n)
        spin = rng.uniform(-self.wheel_speed_noise, self.wheel_speed_noise, size=n)
        x, y, z = self.init_cube_pose
        rpy = np.stack([np.zeros(n), np.zeros(n), yaw], axis=1)
        self.robot.set_state(physics, mask, [x, y, z + self.robot.half_edge], rpy,
                             wheel_speed=self.init_roll_vel + spin)
        self.per_copy.command[mask] = self.init_roll_vel
        self.per_copy.start_y[mask] = y

    def apply_action(self, physics: BatchedPhysics, action: np.ndarray) -> None:
        fixed, inc = self.roll_speed_fixed_value, self.roll_speed_increment_value
        cmd = self.per_copy.command
        if self.continuous(action):
            cmd[:] = self.action_range.command(action)[:, 0]
        else:
            cmd[action == WHEEL_FORWARD] = fixed
            cmd[action == WHEEL_BACKWARD] = -fixed
            cmd[action == WHEEL_STOP] = 0.0
            cmd[action == SPEED_UP] += inc
            cmd[action == SPEED_DOWN] -= inc
        np.clip(cmd, -fixed, fixed, out=cmd)
        self.robot.command_wheel_speed(physics, cmd)
        self.per_copy.prev_y = self.robot.odometry(physics).position[:, 1]

    def observation(self, physics: BatchedPhysics) -> np.ndarray:
        odom = self.robot.odometry(physics)
        roll, pitch, yaw = odom.rpy.T
        return np.stack([
            np.round(self.robot.wheel_speed(physics), 0),
            np.round(odom.position[:, 1] - self.per_copy.start_y, 1),
            np.round(roll, 1),
            np.round(pitch, 1),
            np.round(odom.linear_velocity[:, 1], 1),
            np.round(yaw, 1),
        ], axis=1)

    def observation_range(self) -> tuple[np.ndarray, np.ndarray]:
        """Roll and yaw lie in [-pi, pi] and pitch in [-pi/2, pi/2], rounded as observed;
        wheel speed, y distance and y speed have no bound."""
        roll, pitch, yaw = np.round([math.pi, math.pi / 2, math.pi], 1)
        high = np.array([np.inf, np.inf, roll, pitch, np.inf, yaw])
        return -high, high

    def terminated(self, physics: BatchedPhysics, observation: np.ndarray) -> np.ndarray:
        _, pitch, yaw = self.robot.odometry(physics).rpy.T
        return (np.abs(pitch) > self.max_pitch_angle) | (np.abs(yaw) > self.max_yaw_angle)

    def reward(
        self, physics: BatchedPhysics, observation: np.ndarray, terminated: np.ndarray
    ) -> np.ndarray:
        odom = self.robot.odometry(physics)
        running = (
            np.round((odom.position[:, 1] - self.per_copy.prev_y) * self.move_distance_reward_weight)
            + np.round(odom.linear_velocity[:, 1] * self.y_linear_speed_reward_weight)
            + np.round(-np.abs(np.sin(odom.rpy[:, 2])) * self.y_axis_angle_reward_weight)
        )
        return np.where(terminated, -self.end_episode_points, running)

    def episode_info(self, physics: BatchedPhysics) -> dict[str, np.ndarray]:
        """Per copy: ``y_displacement``, how far along y the cube is from where its
        episode started (m); ``distance_walked``, the same in the rewarded direction."""
        dy = self.robot.odometry(physics).position[:, 1] - self.per_copy.start_y
        return {"y_displacement": dy, "distance_walked": dy * self.direction}
