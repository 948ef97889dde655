"""Gymnasium environments: every robot with its default task, built from conf/.

Importing this module registers one id per robot in ``conf/robot/`` (with the
task that robot's config picks), in the ``MujocoRL`` namespace:

- ``MujocoRL/CartPoleStayUp-v0`` (cartpole / stay_up)
- ``MujocoRL/MovingCubeOneDiskWalk-v0`` (cube / one_disk_walk)
- ``MujocoRL/TurtleBot2Maze-v0`` (turtlebot / maze)

Gymnasium 1.x has no plugin discovery, so users make them with the module
prefix, which imports (and so registers) first::

    gymnasium.make("tasks.gym_env:MujocoRL/CartPoleStayUp-v0", pos_step=0.5)

Keyword arguments to ``gymnasium.make`` override the task's parameters
(``robot_params={...}`` the robot's); everything else comes from the Hydra
configs. ``gymnasium.make`` truncates episodes with a ``TimeLimit`` at the task's
``max_episode_steps`` (its own ``max_episode_steps=`` changes that). ``info``
holds the task's ``episode_info`` values (such as the cube's y displacement).
"""

from __future__ import annotations

import re
from typing import Any, Mapping

import numpy as np

import gymnasium as gym
import torch
from gymnasium import spaces
from omegaconf import DictConfig, OmegaConf

from tasks import factory
from tasks.env import RobotTaskEnv

NAMESPACE = "MujocoRL"
# Display names of robots in env ids; a robot not listed gets its name camel-cased.
ROBOT_NAMES = {"cartpole": "CartPole", "cube": "MovingCube", "turtlebot": "TurtleBot2"}
_NO_LIMIT = 2**62


def _camel(name: str) -> str:
    return "".join(part.capitalize() for part in re.split(r"[_\-]", name) if part)


def default_tasks() -> dict[str, str]:
    """Robot name (one per ``conf/robot/*.yaml``) -> the task its config picks."""
    return {robot: factory.default_task(robot) for robot in factory.robot_names()}


def env_id(robot: str, task: str) -> str:
    """``MujocoRL/<Robot><Task>-v0``."""
    return f"{NAMESPACE}/{ROBOT_NAMES.get(robot, _camel(robot))}{_camel(task)}-v0"


def _override(node: DictConfig, params: Mapping[str, Any], what: str) -> DictConfig:
    known = sorted(k for k in node.keys() if k != "_target_")
    unknown = sorted(set(params) - set(known))
    if unknown:
        raise TypeError(f"unknown parameter(s) {unknown} for {what}; known: {known}")
    return OmegaConf.merge(node, dict(params))


class MujocoRLEnv(gym.Env):
    """One copy of a robot's task as a ``gymnasium.Env`` (discrete actions)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(
        self,
        robot: str = "cartpole",
        render_mode: str | None = None,
        width: int = 480,
        height: int = 360,
        camera: str | int | None = None,
        robot_params: Mapping[str, Any] | None = None,
        **task_params: Any,
    ) -> None:
        """``task_params`` override ``task.*`` and ``robot_params`` ``robot.*`` of the config;
        ``camera`` defaults to the task's first camera (else MuJoCo's free camera)."""
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None; "
                             f"got {render_mode!r}")
        cfg = factory.compose(robot)
        robot_cfg = _override(cfg.robot, robot_params or {}, f"robot {robot}")
        task_cfg = _override(cfg.task, task_params, f"the task of robot {robot}")
        self.config = OmegaConf.create({"robot": robot_cfg, "task": task_cfg})
        task = factory.build_task(self.config)
        if "max_episode_steps" not in task_params:
            task.max_episode_steps = _NO_LIMIT  # gymnasium.make's TimeLimit truncates
        self.torchrl_env = RobotTaskEnv(task, num_envs=1, seed=0)  # the one copy underneath
        self.task = task
        self.render_mode = render_mode
        self.width, self.height = int(width), int(height)
        self.camera = camera if camera is not None else (0 if self.torchrl_env.model.ncam else -1)
        self.metadata = {**self.metadata, "render_fps": 1.0 / float(task.running_step)}
        self.observation_space = spaces.Box(
            -np.inf, np.inf, shape=(len(task.observation_names),), dtype=np.float32)
        self.action_space = spaces.Discrete(int(task.n_actions))
        self._td = None
        self._seeded = False

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None or not self._seeded:
            # The task's randomness follows Gymnasium's seeded generator.
            self.torchrl_env.set_seed(int(self.np_random.integers(2**31 - 1)))
            self._seeded = True
        self._td = self.torchrl_env.reset()
        return self._obs(self._td), {}

    def step(self, action):
        if self._td is None:
            raise RuntimeError("call reset() before step()")
        if not self.action_space.contains(action):
            raise ValueError(f"action must be in {self.action_space}; got {action!r}")
        self._td.set("action", torch.tensor([int(action)], dtype=torch.int64))
        nxt = self.torchrl_env.step(self._td).get("next")
        self._td = nxt.exclude("reward", "done", "terminated", "truncated")
        terminated = bool(nxt.get("terminated").item())
        truncated = bool(nxt.get("truncated").item())
        info = {k: float(np.asarray(v)[0])
                for k, v in self.task.episode_info(self.torchrl_env.physics).items()}
        return self._obs(nxt), float(nxt.get("reward").item()), terminated, truncated, info

    def render(self) -> np.ndarray | None:
        """An RGB frame (``height x width x 3``, uint8) when ``render_mode="rgb_array"``."""
        if self.render_mode != "rgb_array":
            return None
        return self.torchrl_env.render(self.width, self.height, self.camera, 0).copy()

    def close(self) -> None:
        self.torchrl_env.close(raise_if_closed=False)

    @staticmethod
    def _obs(td) -> np.ndarray:
        return td.get("observation")[0].numpy().astype(np.float32, copy=True)


def register_envs() -> list[str]:
    """Registers (idempotently) one id per robot with its default task; returns the ids.

    Each id's ``max_episode_steps`` (Gymnasium's ``TimeLimit``) is the task's
    ``max_episode_steps`` from the config; ``gymnasium.make(id, max_episode_steps=N)``
    changes it.
    """
    ids = []
    for robot in factory.robot_names():
        name = env_id(robot, factory.default_task(robot))
        if name not in gym.registry:
            gym.register(id=name, entry_point=f"{__name__}:MujocoRLEnv", kwargs={"robot": robot},
                         max_episode_steps=int(factory.compose(robot).task.max_episode_steps))
        ids.append(name)
    return ids


register_envs()
