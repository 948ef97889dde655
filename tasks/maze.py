"""TurtleBot ``maze``: drive around a looped maze without hitting its walls.

The maze is a round loop (``ring``) or a grid of wall cells (``layout``); see
tasks/maze_arena.py.

Actions (the original's three): 0 forward (``linear_forward_speed``, no
turning), 1 turn left (``linear_turn_speed``, +``angular_speed``), 2 turn right
(``linear_turn_speed``, -``angular_speed``). Each holds for ``running_step``
seconds of simulated time. The continuous form (SAC and its kind): two actions in
[-1, 1], the turn rate (x ``angular_speed``, left positive) and the speed (from
``linear_turn_speed`` at -1 to ``linear_forward_speed`` at 1); the three discrete
actions are corners and an edge's middle of that square.

Observation: the laser fan cut into ``n_observations`` equal sectors, right to
left (``laser_0`` is the rightmost); each sector reports its nearest reading, no
hit counting as the laser's maximum range, rounded to one decimal.

The episode terminates on a collision: any laser reading below ``min_range``, or
the base touching a wall. Reward: ``forwards_reward`` for a forward step,
``turn_reward`` for a turn, -``end_episode_points`` on the colliding step; a
continuous step earns between the two by how straight and fast it drives
(``turn_reward + (forwards_reward - turn_reward) * (1 - |turn|) * speed share``). The
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
from dataclasses import dataclass
from typing import ClassVar, Mapping, Sequence

import numpy as np
from dm_control import mjcf

from params import require
from params.declare import param
from robots.physics import BatchedPhysics
from robots.turtlebot import TurtleBot
from tasks.base import ActionRange, Bounds, PerCopy, Success, Task, common, setup
from tasks.maze_arena import Maze, maze_arena

SUCCESS = Success("laps", "laps", "laps round the maze without a collision", 2.0, "greedy", 100, 0)
MEASURES = {
    "laps": ("laps", "laps round the maze without a collision"),
    "loop_distance": ("m", "distance along the loop without a collision"),
    "distance": ("m", "path length driven without a collision"),
}
# The laser's rays at most this far apart: a flat wall's nearest point then lies within 5 deg
# of a ray, which reads at most 1/cos(5 deg) = 1.004 times its distance, so "a reading below
# min_range" is "a wall within min_range" (one ray, or a narrow fan, lets a side wall come to
# the base unseen: robot.laser_rays=1 drove "laps" a centimetre from the outer wall).
MAX_RAY_GAP = math.radians(10.0)
RING_KEYS = ("inner_radius", "outer_radius", "segments", "starts", "wall_thickness")

FORWARD, LEFT, RIGHT = 0, 1, 2


@dataclass(eq=False)
class MazeTask(Task):
    """The maze-driving task; it has a :class:`TurtleBot`."""

    ROBOT = TurtleBot  # the robot it needs (read from params/declared.json before anything loads)

    name: ClassVar[str] = "maze"

    robot: TurtleBot
    ring: Mapping[str, float] | None = param(None, "a round loop: " + ", ".join(RING_KEYS)
                                                   + " (or give layout)")
    layout: Sequence[str] | None = param(None, "a grid of wall cells, rows north to south: "
                                               "'#' wall, '.' floor, '> ^ < v' starts (or give ring)")
    cell_size: float = param(0.5, "edge of a layout cell, m", gt=0)
    wall_height: float = param(0.5, "height of the walls, m", gt=0)
    n_actions: int = param(3, "actions: forward, turn left, turn right", choices=(3,))
    n_observations: int = param(6, "laser sectors in the observation", ge=1, le=1024)
    linear_forward_speed: float = param(0.5, "speed of the forward action, m/s", gt=0)
    linear_turn_speed: float = param(0.1, "speed while turning, m/s")
    angular_speed: float = param(0.3, "turn rate of the turn actions, rad/s", gt=0)
    min_range: float = param(0.5, "a laser reading below it ends the episode, m", gt=0)
    forwards_reward: float = param(5.0, "reward of a forward step")
    turn_reward: float = param(1.0, "reward of a turning step")
    end_episode_points: float = param(200.0, "the colliding step's reward is minus this", ge=0)
    running_step: float = common.running_step(0.5)
    max_episode_steps: int = common.max_episode_steps(500)
    physics_timestep: float = common.physics_timestep(0.02)
    start_position_noise: float = param(0.2, "uniform start offset in x and y, m", ge=0)
    start_yaw_noise: float = param(0.3, "uniform start heading offset, rad", ge=0)
    tabular_state: Mapping[str, Sequence[float]] | None = common.tabular_state(
        "every sector over [min_range, laser range]")
    win: Mapping[str, object] | None = common.win("2 greedy laps")

    def __post_init__(self) -> None:
        setup(self, SUCCESS, MEASURES)
        self._check_speeds()
        self._check_laser()
        self.maze = self._build_maze()
        self.rewards = np.array([self.forwards_reward, self.turn_reward, self.turn_reward])
        # Action -> (linear, angular) velocity command.
        self.speeds = np.array([[self.linear_forward_speed, 0.0],
                                [self.linear_turn_speed, self.angular_speed],
                                [self.linear_turn_speed, -self.angular_speed]], dtype=float)
        self._sectors = self._laser_sectors()
        self.observation_names = tuple(f"laser_{k}" for k in range(self.n_observations))
        self.tabular_bounds = Bounds.from_config(
            self.tabular_state or {name: [self.min_range, self.robot.laser_max_range]
                                   for name in self.observation_names},
            self.observation_names)
        # The last action, and the odometer and loop progress of the episode.
        self.per_copy = PerCopy(action=((), np.int64), prev_xy=(2,), distance=(), winding=(),
                                along=())
        # The continuous form: a turn rate in [-1, 1] x angular_speed and a speed from
        # linear_turn_speed (-1) to linear_forward_speed (1).
        slow, fast = sorted((self.linear_turn_speed, self.linear_forward_speed))
        slow = slow if fast - slow > 1e-9 else min(0.0, fast - 1.0)
        self.action_range = ActionRange.of({"turn": [-self.angular_speed, self.angular_speed],
                                            "speed": [slow, fast]})

    def _check_laser(self) -> None:
        """A fan that sees every wall the base can reach: both sides (``laser_fov`` >= pi) and
        rays at most :data:`MAX_RAY_GAP` apart; else a collision (a reading below min_range)
        could go unseen and the task's measure could be faked."""
        robot = self.robot
        require(robot.laser_fov >= math.pi - 1e-6, "task maze judges a collision by the laser, so it "
                "needs robot.laser_fov >= pi (3.1416: both sides seen)", robot.laser_fov)
        full = robot.laser_fov >= 2 * math.pi - 1e-6
        need = math.ceil(robot.laser_fov / MAX_RAY_GAP - 1e-6) + (0 if full else 1)
        require(robot.laser_rays >= need, f"task maze judges a collision by the laser, so it needs rays at "
                f"most 10 deg apart: robot.laser_rays >= {need} for robot.laser_fov={robot.laser_fov!r}",
                robot.laser_rays)

    def _check_speeds(self) -> None:
        """A range the laser can see, speeds the robot can drive (its servos clip to its limits)."""
        robot = self.robot
        require(self.min_range < robot.laser_max_range,
                f"task.min_range must be below the laser's range ({robot.laser_max_range})",
                self.min_range)
        v_max, w_max = robot.max_linear_speed, robot.max_angular_speed
        require(self.linear_forward_speed <= v_max,
                f"task.linear_forward_speed must be in (0, {v_max}] m/s (robot.max_linear_speed)",
                self.linear_forward_speed)
        require(abs(self.linear_turn_speed) <= v_max,
                f"task.linear_turn_speed must be in [-{v_max}, {v_max}] m/s (robot.max_linear_speed)",
                self.linear_turn_speed)
        require(self.angular_speed <= w_max,
                f"task.angular_speed must be in (0, {w_max}] rad/s (robot.max_angular_speed)",
                self.angular_speed)

    def _build_maze(self) -> Maze:
        """The maze of ``ring`` or of ``layout``: exactly one of them."""
        ring, layout = self.ring, self.layout
        require((ring is None) != (layout is None),
                "task maze needs exactly one of task.ring and task.layout",
                "neither" if ring is None else "both")
        if layout is not None:
            require(all(isinstance(row, str) for row in layout),
                    "task.layout must be a list of strings (rows of the grid)", layout)
            return Maze.grid(layout, self.cell_size)
        unknown = sorted(set(ring) - set(RING_KEYS))
        require(not unknown, f"task.ring entries must be among {', '.join(RING_KEYS)}",
                ", ".join(map(str, unknown)))
        return Maze.ring(**ring)

    def _laser_sectors(self) -> np.ndarray:
        """``(n_observations, rays)``: sector k covers the closed angle interval k of
        n_observations equal ones, so a ray on a boundary counts in both neighbours."""
        angles = self.robot.laser_angles
        edges = np.linspace(angles[0], angles[-1], self.n_observations + 1)
        eps = 1e-9
        sectors = (angles[None, :] >= edges[:-1, None] - eps) & (angles[None, :] <= edges[1:, None] + eps)
        require(bool(sectors.any(1).all()),
                f"task.n_observations must leave at least one laser ray per sector "
                f"(robot.laser_rays = {self.robot.n_rays})", self.n_observations)
        return sectors

    def build_arena(self) -> mjcf.RootElement:
        arena = maze_arena("turtlebot_maze", self.maze, self.physics_timestep, self.wall_height)
        arena.attach(self.robot.mjcf_model)
        return arena

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
        self.robot.stop(physics, mask)  # the other copies keep their commands
        c = self.per_copy
        c.prev_xy[mask] = pose[:, :2]
        c.distance[mask] = c.winding[mask] = c.along[mask] = 0.0

    def apply_action(self, physics: BatchedPhysics, action: np.ndarray) -> None:
        if self.continuous(action):  # the share of a forward step's reward: straight and fast
            angular, linear = self.action_range.command(action).T
            slow, fast = self.action_range.low[1], self.action_range.high[1]
            straight = 1.0 - np.abs(angular) / self.angular_speed
            self._forward = straight * (linear - slow) / (fast - slow)
            self._continuous = True
        else:
            self.per_copy.action = np.asarray(action, dtype=np.int64).copy()
            linear, angular = self.speeds[self.per_copy.action].T
            self._continuous = False
        self.robot.command_velocity(physics, linear, angular)

    def scan(self, physics: BatchedPhysics) -> np.ndarray:
        """Nearest laser reading in each sector, unrounded ``(num_envs, n_observations)``."""
        ranges = self.robot.laser(physics)
        return np.where(self._sectors[None], ranges[:, None, :], np.inf).min(-1)

    def observation(self, physics: BatchedPhysics) -> np.ndarray:
        self._track(physics)
        return np.round(self.scan(physics), 1)

    def observation_range(self) -> tuple[np.ndarray, np.ndarray]:
        """Every sector reads in [0, the laser's range], rounded as observed."""
        n = self.n_observations
        return np.zeros(n), np.full(n, np.round(self.robot.laser_max_range, 1))

    def terminated(self, physics: BatchedPhysics, observation: np.ndarray) -> np.ndarray:
        too_close = self.robot.laser(physics).min(-1) < self.min_range
        return too_close | self.robot.bumper(physics)

    def reward(
        self, physics: BatchedPhysics, observation: np.ndarray, terminated: np.ndarray
    ) -> np.ndarray:
        if getattr(self, "_continuous", False):
            step = self.turn_reward + (self.forwards_reward - self.turn_reward) * self._forward
        else:
            step = self.rewards[self.per_copy.action]
        return np.where(terminated, -self.end_episode_points, step)

    def episode_info(self, physics: BatchedPhysics) -> dict[str, np.ndarray]:
        """Per copy, since the episode began: ``distance``, the path length driven (m);
        ``loop_distance``, the net distance driven around the maze centre (m, either
        way round); ``laps``, the net number of times round it."""
        self._track(physics)
        c = self.per_copy
        return {"distance": c.distance.copy(), "loop_distance": np.abs(c.along),
                "laps": np.abs(c.winding) / (2 * math.pi)}

    def _track(self, physics: BatchedPhysics) -> None:
        """Adds the motion since the last call to each copy's path length and its
        progress around the maze centre (angle, and arc length r * d(angle))."""
        c = self.per_copy
        odom = self.robot.odometry(physics)
        xy = np.stack([odom.x, odom.y], axis=1)
        c.distance += np.linalg.norm(xy - c.prev_xy, axis=1)
        now, before = xy[:, 0] + 1j * xy[:, 1], c.prev_xy[:, 0] + 1j * c.prev_xy[:, 1]
        turned = np.angle(now * np.conj(before))
        radius = (np.abs(now) + np.abs(before)) / 2
        c.winding += turned
        c.along += radius * turned
        c.prev_xy = xy
