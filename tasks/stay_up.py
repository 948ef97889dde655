"""Cart-pole ``stay_up``: keep the pole up by nudging the cart's command.

Actions are ``Discrete(n_actions)``: action 1 adds ``pos_step`` to the cart
command and action 0 subtracts it; with 4 actions, 3 and 2 do the same with
10 x ``pos_step``. The command persists between steps (it accumulates) and, in
velocity control, is clipped to +-``max_base_velocity``.

The continuous form (SAC and its kind): one action in [-1, 1], the change of the cart
command scaled to the discrete actions' largest (+-``pos_step``, or +-10 x ``pos_step``
with 4 actions): the discrete actions are its ends and its middle.

Observation: cart position, cart velocity, pole angle, pole angular velocity.
Reward +1 per step. The episode terminates when the cart leaves
[``min_base_pose_x``, ``max_base_pose_x``] or the pole leaves
[``min_pole_angle``, ``max_pole_angle``]; the environment truncates it after
``max_episode_steps``. Parameter names are the original YAML's.

Solved (``success``, overridable as ``task.win``): the seeds' rule, a mean
length of the last 100 training episodes of at least 250 steps (their
``n_win_ticks``) after at least 100 episodes.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from dm_control import mjcf

from params import require
from params.declare import param
from robots.cartpole import CONTROL_TYPES, CartPole
from robots.physics import BatchedPhysics
from tasks.arena import floor_arena
from tasks.base import ActionRange, Bounds, PerCopy, Success, Task, common, setup

# The seeds' win rule: judged on the training episodes, as they did.
SUCCESS = Success("length", "steps", "steps balanced", 250.0, "training", 100, 100)


@dataclass(eq=False)
class StayUp(Task):
    """The cart-pole balancing task; it has a :class:`CartPole`."""

    ROBOT = CartPole  # the robot it needs (read from params/declared.json before anything loads)

    name: ClassVar[str] = "stay_up"
    observation_names: ClassVar[tuple[str, ...]] = ("cart_pos", "cart_vel", "pole_angle", "pole_vel")

    robot: CartPole
    n_actions: int = param(2, "actions: 1 / 0 add / subtract pos_step to the cart command; "
                              "3 / 2 ten times that", choices=(2, 4))
    min_pole_angle: float = param(-0.7, "pole angle at or below which the episode terminates, rad")
    max_pole_angle: float = param(0.7, "pole angle at or above which the episode terminates, rad")
    max_base_velocity: float = param(50.0, "clip of the velocity command, m/s", gt=0)
    min_base_pose_x: float = param(-1.0, "cart position at or below which the episode terminates, m")
    max_base_pose_x: float = param(1.0, "cart position at or above which the episode terminates, m")
    pos_step: float = param(1.0, "change of the cart command per action (m/s, m or N)", gt=0)
    running_step: float = common.running_step(0.04)
    init_pos: float = param(0.0, "cart position at reset, m")
    control_type: str = param("velocity", "cart controller", choices=CONTROL_TYPES)
    reset_noise: float = param(0.05, "uniform start perturbation of each joint position and velocity",
                               ge=0)
    max_episode_steps: int = common.max_episode_steps(1000)
    physics_timestep: float = common.physics_timestep(0.002)
    tabular_state: dict | None = common.tabular_state("all four, wide ranges")
    win: dict | None = common.win("the seeds' rule")

    def __post_init__(self) -> None:
        setup(self, SUCCESS, {"length": ("steps", "steps balanced")})
        self._check_limits()
        self.robot.use_controller(self.control_type)
        # Action -> change of the cart command.
        steps = [-self.pos_step, self.pos_step, -10 * self.pos_step, 10 * self.pos_step]
        self._deltas = np.asarray(steps[: self.n_actions])
        largest = float(np.abs(self._deltas).max())
        self.action_range = ActionRange.of({"cart_command_change": [-largest, largest]})
        self.per_copy = PerCopy(command=())
        self.tabular_bounds = Bounds.from_config(
            self.tabular_state
            or {"cart_pos": [self.min_base_pose_x, self.max_base_pose_x], "cart_vel": [-2.0, 2.0],
                "pole_angle": [self.min_pole_angle, self.max_pole_angle], "pole_vel": [-3.0, 3.0]},
            self.observation_names,
        )

    def _check_limits(self) -> None:
        """Limits the robot can reach (within the hinge's and the rail's travel), and a
        start inside them."""
        hinge = float(self.robot.mjcf_model.find("joint", "hinge").range[1])
        for key, limit, what in (("pole_angle", hinge, "the hinge's limit"),
                                 ("base_pose_x", self.robot.rail_limit, "the rail's end")):
            low, high = getattr(self, f"min_{key}"), getattr(self, f"max_{key}")
            require(low >= -limit, f"task.min_{key} must be a number >= -{limit} ({what})", low)
            require(high <= limit, f"task.max_{key} must be a number <= {limit} ({what})", high)
            require(low < high, f"task.min_{key} must be < task.max_{key} ({high})", low)
        require(self.min_base_pose_x < self.init_pos < self.max_base_pose_x,
                f"task.init_pos must be within (min_base_pose_x, max_base_pose_x) = "
                f"({self.min_base_pose_x}, {self.max_base_pose_x})", self.init_pos)

    def build_arena(self) -> mjcf.RootElement:
        arena = floor_arena("cartpole_stay_up", self.physics_timestep)
        arena.worldbody.add("camera", name="side", pos=[0, -3.0, 1.2], xyaxes=[1, 0, 0, 0, 0.12, 1])
        arena.attach(self.robot.mjcf_model)
        return arena

    def initialize_episode(
        self, physics: BatchedPhysics, mask: np.ndarray, rng: np.random.Generator
    ) -> None:
        """Cart at ``init_pos`` with command 0, plus a small uniform perturbation."""
        n = int(mask.sum())
        noise = rng.uniform(-self.reset_noise, self.reset_noise, size=(4, n))
        self.robot.set_joint_states(
            physics, mask,
            cart_pos=self.init_pos + noise[0], cart_vel=noise[1],
            pole_angle=noise[2], pole_vel=noise[3],
        )
        self.per_copy.command[mask] = 0.0
        self.robot.command(physics, self.per_copy.command)

    def apply_action(self, physics: BatchedPhysics, action: np.ndarray) -> None:
        command = self.per_copy.command
        command += self.action_range.command(action)[:, 0] if self.continuous(action) else self._deltas[action]
        if self.control_type == "velocity":
            np.clip(command, -self.max_base_velocity, self.max_base_velocity, out=command)
        self.robot.command(physics, command)

    def observation(self, physics: BatchedPhysics) -> np.ndarray:
        s = self.robot.joint_states(physics)
        return np.stack([s.cart_pos, s.cart_vel, s.pole_angle, s.pole_vel], axis=1)

    def terminated(self, physics: BatchedPhysics, observation: np.ndarray) -> np.ndarray:
        x, angle = observation[:, 0], observation[:, 2]
        return ((x <= self.min_base_pose_x) | (x >= self.max_base_pose_x)
                | (angle <= self.min_pole_angle) | (angle >= self.max_pole_angle))

    def reward(
        self, physics: BatchedPhysics, observation: np.ndarray, terminated: np.ndarray
    ) -> np.ndarray:
        return np.ones(physics.num_envs)

    def episode_info(self, physics: BatchedPhysics) -> dict[str, np.ndarray]:
        """Nothing beyond the length, which is this task's measure."""
        return {}
