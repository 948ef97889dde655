"""Cart-pole ``stay_up``: keep the pole up by nudging the cart's command.

Actions are ``Discrete(n_actions)``: action 1 adds ``pos_step`` to the cart
command and action 0 subtracts it; with 4 actions, 3 and 2 do the same with
10 x ``pos_step``. The command persists between steps (it accumulates) and, in
velocity control, is clipped to +-``max_base_velocity``.

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

from dm_control import mjcf
import numpy as np

from robots.cartpole import CONTROL_TYPES, CartPole
from robots.physics import BatchedPhysics
from tasks.arena import floor_arena
from params import finite, require, whole
from tasks.base import Bounds, Success, substeps_for

# The seeds' win rule: judged on the training episodes, as they did.
SUCCESS = Success("length", "steps", "steps balanced", 250.0, "training", 100, 100)


class StayUp:
    """The cart-pole balancing task; it has a :class:`CartPole`."""

    observation_names = ("cart_pos", "cart_vel", "pole_angle", "pole_vel")

    def __init__(
        self,
        robot: CartPole,
        n_actions: int = 2,
        min_pole_angle: float = -0.7,
        max_pole_angle: float = 0.7,
        max_base_velocity: float = 50.0,
        min_base_pose_x: float = -1.0,
        max_base_pose_x: float = 1.0,
        pos_step: float = 1.0,
        running_step: float = 0.04,
        init_pos: float = 0.0,
        control_type: str = "velocity",
        reset_noise: float = 0.05,
        max_episode_steps: int = 1000,
        physics_timestep: float = 0.002,
        tabular_state: dict | None = None,
        win: dict | None = None,
    ) -> None:
        require(isinstance(robot, CartPole), "task stay_up needs robot=cartpole",
                type(robot).__name__)
        require(n_actions in (2, 4), "task.n_actions must be 2 or 4", n_actions)
        # Limits the robot can reach: within the hinge's and the rail's travel.
        hinge = float(robot.mjcf_model.find("joint", "hinge").range[1])
        rail = robot.rail_limit
        for key, low, high, limit, what in (
            ("pole_angle", min_pole_angle, max_pole_angle, hinge, "the hinge's limit"),
            ("base_pose_x", min_base_pose_x, max_base_pose_x, rail, "the rail's end"),
        ):
            require(finite(low) and low >= -limit,
                    f"task.min_{key} must be a number >= -{limit} ({what})", low)
            require(finite(high) and high <= limit,
                    f"task.max_{key} must be a number <= {limit} ({what})", high)
            require(low < high, f"task.min_{key} must be < task.max_{key} ({high})", low)
        require(finite(init_pos) and min_base_pose_x < init_pos < max_base_pose_x,
                f"task.init_pos must be within (min_base_pose_x, max_base_pose_x) = "
                f"({min_base_pose_x}, {max_base_pose_x})", init_pos)
        require(finite(pos_step) and pos_step > 0, "task.pos_step must be a finite number > 0",
                pos_step)
        require(finite(max_base_velocity) and max_base_velocity > 0,
                "task.max_base_velocity must be a finite number > 0", max_base_velocity)
        require(control_type in CONTROL_TYPES,
                f"task.control_type must be one of {', '.join(CONTROL_TYPES)}", control_type)
        require(finite(reset_noise) and reset_noise >= 0,
                "task.reset_noise must be a finite number >= 0", reset_noise)
        require(whole(max_episode_steps) and max_episode_steps >= 1,
                "task.max_episode_steps must be an integer >= 1", max_episode_steps)
        self.success = Success.from_config(win, SUCCESS, {"length": ("steps", "steps balanced")})
        self.robot = robot
        self.n_actions = int(n_actions)
        self.pole_angle_limits = (float(min_pole_angle), float(max_pole_angle))
        self.base_x_limits = (float(min_base_pose_x), float(max_base_pose_x))
        self.max_base_velocity = float(max_base_velocity)
        self.pos_step = float(pos_step)
        self.running_step = float(running_step)
        self.init_pos = float(init_pos)
        self.reset_noise = float(reset_noise)
        self.max_episode_steps = int(max_episode_steps)
        self.physics_timestep = float(physics_timestep)
        self.n_substeps = substeps_for(running_step, physics_timestep)
        robot.use_controller(control_type)
        self.control_type = control_type
        # Action -> change of the cart command.
        steps = [-self.pos_step, self.pos_step, -10 * self.pos_step, 10 * self.pos_step]
        self._deltas = np.asarray(steps[: self.n_actions])
        self._command = np.zeros(0)
        self.tabular_state = Bounds.from_config(
            tabular_state
            or {"cart_pos": [min_base_pose_x, max_base_pose_x], "cart_vel": [-2.0, 2.0],
                "pole_angle": [min_pole_angle, max_pole_angle], "pole_vel": [-3.0, 3.0]},
            self.observation_names,
        )

    def build_arena(self) -> mjcf.RootElement:
        arena = floor_arena("cartpole_stay_up", self.physics_timestep)
        arena.worldbody.add("camera", name="side", pos=[0, -3.0, 1.2], xyaxes=[1, 0, 0, 0, 0.12, 1])
        arena.attach(self.robot.mjcf_model)
        return arena

    def bind(self, physics: BatchedPhysics) -> None:
        self.robot.bind(physics)
        self._command = np.zeros(physics.num_envs)

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
        self._command[mask] = 0.0
        self.robot.command(physics, self._command)

    def apply_action(self, physics: BatchedPhysics, action: np.ndarray) -> None:
        self._command += self._deltas[action]
        if self.control_type == "velocity":
            np.clip(self._command, -self.max_base_velocity, self.max_base_velocity,
                    out=self._command)
        self.robot.command(physics, self._command)

    def observation(self, physics: BatchedPhysics) -> np.ndarray:
        s = self.robot.joint_states(physics)
        return np.stack([s.cart_pos, s.cart_vel, s.pole_angle, s.pole_vel], axis=1)

    def terminated(self, physics: BatchedPhysics, observation: np.ndarray) -> np.ndarray:
        x, angle = observation[:, 0], observation[:, 2]
        lo_x, hi_x = self.base_x_limits
        lo_a, hi_a = self.pole_angle_limits
        return (x <= lo_x) | (x >= hi_x) | (angle <= lo_a) | (angle >= hi_a)

    def reward(
        self, physics: BatchedPhysics, observation: np.ndarray, terminated: np.ndarray
    ) -> np.ndarray:
        return np.ones(physics.num_envs)
