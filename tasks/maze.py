"""TurtleBot ``maze``: drive around a looped maze without hitting its walls.

The maze is a round loop (``ring``) or a grid of wall cells (``layout``); see
tasks/maze_arena.py.

Actions (the original's three): 0 forward (``linear_forward_speed``, no
turning), 1 turn left (``linear_turn_speed``, +``angular_speed``), 2 turn right
(``linear_turn_speed``, -``angular_speed``). Each holds for ``running_step``
seconds of simulated time.

Observation: the laser fan cut into ``n_observations`` equal sectors, right to
left (``laser_0`` is the rightmost); each sector reports its nearest reading, no
hit counting as the laser's maximum range, rounded to one decimal.

The episode terminates on a collision: any laser reading below ``min_range``, or
the base touching a wall. Reward: ``forwards_reward`` for a forward step,
``turn_reward`` for a turn, -``end_episode_points`` on the colliding step. The
environment truncates after ``max_episode_steps``.

Episodes start at one of the maze's start poses (chosen by the environment's
seeded generator), shifted by up to ``start_position_noise`` metres in x and y
and ``start_yaw_noise`` radians in heading. ``episode_info`` reports the path
length driven and the progress made around the maze centre.

Solved (``success``, overridable as ``task.win``): the greedy policy drives at
least 2 laps round the maze centre before its episode ends (a collision ends
it), the mean ``laps`` of a greedy evaluation's episodes; 500 forward steps
would make about 6.6 laps of the ring's centre line. Turning in place, or
shuttling back and forth, makes no laps. A maze without a loop (``layout``)
can be judged by ``distance`` (path length, m) instead.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np
from dm_control import mjcf

from robots.physics import BatchedPhysics
from robots.turtlebot import TurtleBot
from params import finite, require, whole
from tasks.base import Bounds, Success, substeps_for
from tasks.maze_arena import Maze, maze_arena

SUCCESS = Success("laps", "laps", "laps round the maze without a collision", 2.0, "greedy", 100, 100)
MEASURES = {
    "laps": ("laps", "laps round the maze without a collision"),
    "loop_distance": ("m", "distance along the loop without a collision"),
    "distance": ("m", "path length driven without a collision"),
}

FORWARD, LEFT, RIGHT = 0, 1, 2


class MazeTask:
    """The maze-driving task; it has a :class:`TurtleBot`."""

    def __init__(
        self,
        robot: TurtleBot,
        ring: Mapping[str, float] | None = None,
        layout: Sequence[str] | None = None,
        cell_size: float = 0.5,
        wall_height: float = 0.5,
        n_actions: int = 3,
        n_observations: int = 6,
        linear_forward_speed: float = 0.5,
        linear_turn_speed: float = 0.1,
        angular_speed: float = 0.3,
        min_range: float = 0.5,
        forwards_reward: float = 5.0,
        turn_reward: float = 1.0,
        end_episode_points: float = 200.0,
        running_step: float = 0.5,
        max_episode_steps: int = 500,
        physics_timestep: float = 0.02,
        start_position_noise: float = 0.2,
        start_yaw_noise: float = 0.3,
        tabular_state: Mapping[str, Sequence[float]] | None = None,
        win: Mapping[str, object] | None = None,
    ) -> None:
        require(isinstance(robot, TurtleBot), "task maze needs robot=turtlebot",
                type(robot).__name__)
        require(n_actions == 3, "task.n_actions must be 3 (forward, left, right)", n_actions)
        require(whole(n_observations) and n_observations >= 1,
                "task.n_observations must be an integer >= 1", n_observations)
        require(finite(min_range) and min_range > 0, "task.min_range must be a finite number > 0",
                min_range)
        require(min_range < robot.laser_max_range,
                f"task.min_range must be below the laser's range ({robot.laser_max_range})",
                min_range)
        # Speeds the robot can drive: its servos clip commands to its limits.
        v_max, w_max = robot.max_linear_speed, robot.max_angular_speed
        require(finite(linear_forward_speed) and 0 < linear_forward_speed <= v_max,
                f"task.linear_forward_speed must be in (0, {v_max}] m/s (robot.max_linear_speed)",
                linear_forward_speed)
        require(finite(linear_turn_speed) and abs(linear_turn_speed) <= v_max,
                f"task.linear_turn_speed must be in [-{v_max}, {v_max}] m/s (robot.max_linear_speed)",
                linear_turn_speed)
        require(finite(angular_speed) and 0 < angular_speed <= w_max,
                f"task.angular_speed must be in (0, {w_max}] rad/s (robot.max_angular_speed)",
                angular_speed)
        for name, value in (("forwards_reward", forwards_reward), ("turn_reward", turn_reward)):
            require(finite(value), f"task.{name} must be a finite number", value)
        require(finite(end_episode_points) and end_episode_points >= 0,
                "task.end_episode_points must be a finite number >= 0 (it is subtracted)",
                end_episode_points)
        require(finite(start_position_noise) and start_position_noise >= 0,
                "task.start_position_noise must be a finite number >= 0", start_position_noise)
        require(finite(start_yaw_noise) and start_yaw_noise >= 0,
                "task.start_yaw_noise must be a finite number >= 0", start_yaw_noise)
        require(whole(max_episode_steps) and max_episode_steps >= 1,
                "task.max_episode_steps must be an integer >= 1", max_episode_steps)
        require(finite(wall_height) and wall_height > 0, "task.wall_height must be a finite number > 0",
                wall_height)
        require((ring is None) != (layout is None),
                "task maze needs exactly one of task.ring and task.layout",
                "neither" if ring is None else "both")
        ring_keys = ("inner_radius", "outer_radius", "segments", "starts", "wall_thickness")
        require(ring is None or isinstance(ring, Mapping),
                f"task.ring must be a mapping of {', '.join(ring_keys)}", ring)
        unknown = sorted(set(ring or ()) - set(ring_keys))
        require(not unknown, f"task.ring entries must be among {', '.join(ring_keys)}",
                ", ".join(map(str, unknown)))
        require(layout is None or (isinstance(layout, Sequence) and not isinstance(layout, str)
                                   and all(isinstance(row, str) for row in layout)),
                "task.layout must be a list of strings (rows of the grid)", layout)
        self.success = Success.from_config(win, SUCCESS, MEASURES)
        self.robot = robot
        self.maze = Maze.ring(**ring) if ring is not None else Maze.grid(layout, cell_size)
        self.wall_height = float(wall_height)
        self.n_actions = 3
        self.n_observations = int(n_observations)
        self.min_range = float(min_range)
        self.rewards = np.array([forwards_reward, turn_reward, turn_reward], dtype=float)
        self.end_episode_points = float(end_episode_points)
        self.running_step = float(running_step)
        self.max_episode_steps = int(max_episode_steps)
        self.physics_timestep = float(physics_timestep)
        self.n_substeps = substeps_for(running_step, physics_timestep)
        self.start_position_noise = float(start_position_noise)
        self.start_yaw_noise = float(start_yaw_noise)
        # Action -> (linear, angular) velocity command.
        self.speeds = np.array([[linear_forward_speed, 0.0],
                                [linear_turn_speed, angular_speed],
                                [linear_turn_speed, -angular_speed]], dtype=float)
        # Sector k covers the closed angle interval k of n_observations equal ones, so a ray
        # on a boundary counts in both neighbours.
        angles = robot.laser_angles
        edges = np.linspace(angles[0], angles[-1], self.n_observations + 1)
        eps = 1e-9
        self._sectors = (angles[None, :] >= edges[:-1, None] - eps) & (
            angles[None, :] <= edges[1:, None] + eps)
        require(bool(self._sectors.any(1).all()),
                f"task.n_observations must leave at least one laser ray per sector "
                f"(robot.laser_rays = {robot.n_rays})", n_observations)
        self.observation_names = tuple(f"laser_{k}" for k in range(self.n_observations))
        self.tabular_state = Bounds.from_config(
            tabular_state or {name: [self.min_range, robot.laser_max_range]
                              for name in self.observation_names},
            self.observation_names,
        )
        self._allocate(0)

    def build_arena(self) -> mjcf.RootElement:
        arena = maze_arena("turtlebot_maze", self.maze, self.physics_timestep, self.wall_height)
        arena.attach(self.robot.mjcf_model)
        return arena

    def bind(self, physics: BatchedPhysics) -> None:
        self.robot.bind(physics)
        self._allocate(physics.num_envs)

    def _allocate(self, n: int) -> None:
        """Per-copy state: last action, and the odometer and loop progress of the episode."""
        self._action = np.zeros(n, dtype=np.int64)
        self._prev_xy = np.zeros((n, 2))
        self._distance = np.zeros(n)
        self._winding = np.zeros(n)
        self._along = np.zeros(n)

    def initialize_episode(
        self, physics: BatchedPhysics, mask: np.ndarray, rng: np.random.Generator
    ) -> None:
        """A random start pose of the maze, uniformly perturbed, at rest."""
        n = int(mask.sum())
        starts = self.maze.starts[rng.integers(len(self.maze.starts), size=n)]
        noise = rng.uniform(-1.0, 1.0, size=(n, 3)) * [
            self.start_position_noise, self.start_position_noise, self.start_yaw_noise]
        pose = starts + noise
        self.robot.set_pose(physics, mask, pose[:, 0], pose[:, 1], pose[:, 2])
        linear, angular = self.speeds[self._action].T
        self.robot.command_velocity(physics, np.where(mask, 0.0, linear),
                                    np.where(mask, 0.0, angular))
        self._prev_xy[mask] = pose[:, :2]
        self._distance[mask] = 0.0
        self._winding[mask] = 0.0
        self._along[mask] = 0.0

    def apply_action(self, physics: BatchedPhysics, action: np.ndarray) -> None:
        self._action = np.asarray(action, dtype=np.int64).copy()
        linear, angular = self.speeds[self._action].T
        self.robot.command_velocity(physics, linear, angular)

    def scan(self, physics: BatchedPhysics) -> np.ndarray:
        """Nearest laser reading in each sector, unrounded ``(num_envs, n_observations)``."""
        ranges = self.robot.laser(physics)
        return np.where(self._sectors[None], ranges[:, None, :], np.inf).min(-1)

    def observation(self, physics: BatchedPhysics) -> np.ndarray:
        self._track(physics)
        return np.round(self.scan(physics), 1)

    def terminated(self, physics: BatchedPhysics, observation: np.ndarray) -> np.ndarray:
        too_close = self.robot.laser(physics).min(-1) < self.min_range
        return too_close | self.robot.bumper(physics)

    def reward(
        self, physics: BatchedPhysics, observation: np.ndarray, terminated: np.ndarray
    ) -> np.ndarray:
        return np.where(terminated, -self.end_episode_points, self.rewards[self._action])

    def episode_info(self, physics: BatchedPhysics) -> dict[str, np.ndarray]:
        """Per copy, since the episode began: ``distance``, the path length driven (m);
        ``loop_distance``, the net distance driven around the maze centre (m, either
        way round); ``laps``, the net number of times round it."""
        self._track(physics)
        return {"distance": self._distance.copy(), "loop_distance": np.abs(self._along),
                "laps": np.abs(self._winding) / (2 * math.pi)}

    def _track(self, physics: BatchedPhysics) -> None:
        """Adds the motion since the last call to each copy's path length and its
        progress around the maze centre (angle, and arc length r * d(angle))."""
        odom = self.robot.odometry(physics)
        xy = np.stack([odom.x, odom.y], axis=1)
        self._distance += np.linalg.norm(xy - self._prev_xy, axis=1)
        now, before = xy[:, 0] + 1j * xy[:, 1], self._prev_xy[:, 0] + 1j * self._prev_xy[:, 1]
        turned = np.angle(now * np.conj(before))
        radius = (np.abs(now) + np.abs(before)) / 2
        self._winding += turned
        self._along += radius * turned
        self._prev_xy = xy
