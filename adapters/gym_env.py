"""Gymnasium environments: every robot with its default task, built from conf/.

:func:`register_envs` (called by importing :mod:`adapters.register_gym`) registers one id
per robot in ``conf/robot/`` (with the task that robot's config picks), in the
``MujocoRL`` namespace, each with the string entry point ``adapters.gym_env:MujocoRLEnv``:

``MujocoRL/<Robot><Task>-v0``, such as ``MujocoRL/CartPoleStayUp-v0`` (cartpole /
stay_up); docs/getting-started.md "What there is" lists them. ``register_envs(config_dirs=[...])``
adds the robots of a user's config folders.

::

    import gymnasium, adapters.register_gym
    env = gymnasium.make("MujocoRL/CartPoleStayUp-v0", pos_step=0.5)
    env = gymnasium.make("adapters.register_gym:MujocoRL/CartPoleStayUp-v0")  # imports it first

Gymnasium 1.x loads no plugins, so a process knows the ids once it has imported
``adapters.register_gym`` (or called :func:`register_envs`). Subprocess workers (SB3's
``SubprocVecEnv``, ``AsyncVectorEnv``) do when the script that starts them imports
it at its top: a forked worker inherits the registry, a spawned one (TorchRL makes
spawn the default) and a forkserver one (SB3's default) import the main script
again before they run. Without a script to import again (``python -c``, a
notebook) write the id with the prefix, ``"adapters.register_gym:MujocoRL/..."``:
``gymnasium.make`` in the worker imports that module first. ``gymnasium.make_vec``
sends workers the spec itself.

Keyword arguments to ``gymnasium.make`` override the task's parameters
(``robot_params={...}`` the robot's); everything else comes from the Hydra
configs. ``gymnasium.make`` truncates episodes with a ``TimeLimit`` at the task's
``max_episode_steps`` (its own ``max_episode_steps=`` changes that). ``info``
holds the task's ``episode_info`` values (such as the cube's y displacement).
The observation space has the task's ``observation_range``; where the task knows
no bound, the largest float32 (observations are finite: the physics rolls back
a copy that diverges). ``copy.deepcopy(env)`` is a new env in the same state.
"""

from __future__ import annotations

import copy
import re
import reprlib
from typing import Any, Mapping, Sequence

import numpy as np

import gymnasium as gym
import torch
from gymnasium import spaces
from omegaconf import DictConfig, OmegaConf

from tasks import factory
from tasks import catalog
from tasks.base import Task
from tasks.env import RobotTaskEnv

NAMESPACE = "MujocoRL"
# Display names of robots in env ids; a robot not listed gets its name camel-cased.
ROBOT_NAMES = {"cartpole": "CartPole", "cube": "MovingCube", "turtlebot": "TurtleBot2"}
_NO_LIMIT = 2**62
_FLOAT32_MAX = float(np.finfo(np.float32).max)


def _camel(name: str) -> str:
    return "".join(part.capitalize() for part in re.split(r"[_\-]", name) if part)


def default_tasks() -> dict[str, str]:
    """Robot name (one per ``conf/robot/*.yaml``) -> the task its config picks."""
    return {robot: catalog.default_task(robot) for robot in catalog.robot_names()}


def env_id(robot: str, task: str) -> str:
    """``MujocoRL/<Robot><Task>-v0``."""
    return f"{NAMESPACE}/{ROBOT_NAMES.get(robot, _camel(robot))}{_camel(task)}-v0"


def _override(node: DictConfig, params: Mapping[str, Any], what: str) -> DictConfig:
    known = sorted(k for k in node.keys() if k != "_target_")
    unknown = sorted(set(params) - set(known))
    if unknown:
        # Python's own wording: TorchRL's GymEnv passes frameskip= and, told this, repeats
        # actions itself (its frame_skip).
        more = f" (and {', '.join(map(repr, unknown[1:]))})" if len(unknown) > 1 else ""
        raise TypeError(f"{what} got an unexpected keyword argument {unknown[0]!r}{more}; known: {known}")
    return OmegaConf.merge(node, dict(params))


def observation_space(task: Task) -> spaces.Box:
    """The task's ``observation_range`` as a float32 ``Box``, an unbounded side as the
    largest finite float32 (so no bound is infinite)."""
    low, high = task.observation_range()
    return spaces.Box(np.maximum(low, -_FLOAT32_MAX).astype(np.float32),
                      np.minimum(high, _FLOAT32_MAX).astype(np.float32), dtype=np.float32)


def action_index(action: Any, n: int) -> int:
    """``action`` as an ``int`` in ``[0, n)``: a Python or NumPy integer (or a float equal
    to one), alone or in a 0-d or one-element array; else a ``ValueError``."""
    try:
        a = np.asarray(action)
    except (TypeError, ValueError, OverflowError):
        a = np.asarray(None)
    if a.shape in ((), (1,)) and a.dtype.kind in "iuf":
        value = a.reshape(()).item()
        if float(value).is_integer() and 0 <= value < n:
            return int(value)
    raise ValueError(f"action must be an integer in [0, {n - 1}] (an int, a numpy integer, or an "
                     f"array of shape () or (1,) holding one); got {reprlib.repr(action)}")


def continuous_action(action: Any, dims: int) -> np.ndarray:
    """``action`` as a float ``(1, dims)`` array in [-1, 1] (values outside are clipped, as
    Gymnasium's ``ClipAction`` would): a number or a sequence of ``dims`` finite numbers;
    else a ``ValueError``."""
    try:
        a = np.asarray(action, dtype=np.float64).reshape(-1)
    except (TypeError, ValueError, OverflowError):
        a = np.asarray([np.nan])
    if a.size != dims or not np.isfinite(a).all():
        raise ValueError(f"action must be {dims} finite number(s) in [-1, 1] (a float, a list or an array "
                         f"of shape ({dims},)); got {reprlib.repr(action)}")
    return np.clip(a, -1.0, 1.0).reshape(1, dims)


class MujocoRLEnv(gym.Env):
    """One copy of a robot's task as a ``gymnasium.Env``: discrete actions, or with
    ``actions="continuous"`` the task's continuous form (a ``Box`` in [-1, 1])."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 25}

    def __init__(
        self,
        robot: str = "cartpole",
        render_mode: str | None = None,
        width: int = 480,
        height: int = 360,
        camera: str | int | None = None,
        robot_params: Mapping[str, Any] | None = None,
        config_dirs: Sequence[str] = (),
        actions: str = "discrete",
        **task_params: Any,
    ) -> None:
        """``task_params`` override ``task.*`` and ``robot_params`` ``robot.*`` of the config;
        ``actions``: ``discrete`` (``Discrete(n_actions)``) or ``continuous`` (``Box(-1, 1,
        (dims,))``, each number scaled to its command's range, as SAC and PPO take it);
        ``camera`` (a name or an index) defaults to the task's first camera (else MuJoCo's
        free camera); ``config_dirs``: config folders besides ``conf/`` (a user's robots)."""
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be one of {self.metadata['render_modes']} or None; "
                             f"got {render_mode!r}")
        self._made_with = copy.deepcopy(dict(robot=robot, render_mode=render_mode, width=width,
                                             height=height, camera=camera,
                                             robot_params=robot_params,
                                             config_dirs=list(config_dirs), actions=actions, **task_params))
        if config_dirs:
            catalog.use_config_dirs(config_dirs)
        self.config = self._config(robot, robot_params or {}, task_params)
        task = factory.build_task(self.config)
        if "max_episode_steps" not in task_params:
            task.max_episode_steps = _NO_LIMIT  # gymnasium.make's TimeLimit truncates
        self.torchrl_env = RobotTaskEnv(task, num_envs=1, seed=0, actions=actions)  # the one copy underneath
        self.task = task
        self.render_mode = render_mode
        self.width, self.height = int(width), int(height)
        self.camera = self.torchrl_env.check_camera(camera)
        self.metadata = {**self.metadata, "render_fps": 1.0 / float(task.running_step)}
        self.observation_space = observation_space(task)
        if actions == "continuous":
            self.action_space = spaces.Box(-1.0, 1.0, (task.action_range.dims,), dtype=np.float32)
        else:
            self.action_space = spaces.Discrete(int(task.n_actions))
        self._td = None
        self._seeded = False

    @staticmethod
    def _config(robot: str, robot_params: Mapping[str, Any], task_params: Mapping[str, Any]):
        cfg = catalog.compose(robot, overrides=["~tuned"])  # the task as its file says, no learner's tuning
        robot_cfg = _override(cfg.robot, robot_params, f"robot {robot}")
        task_cfg = _override(cfg.task, task_params, f"the task of robot {robot}")
        return OmegaConf.create({"robot": robot_cfg, "task": task_cfg})

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None or not self._seeded:
            # The task's randomness follows Gymnasium's seeded generator.
            self.torchrl_env.set_seed(int(self.np_random.integers(2**31 - 1)))
            self._seeded = True
        self._td = self.torchrl_env.reset()
        return self._obs(self._td), {}

    def step(self, action):
        """``action``: an integer in ``[0, n_actions)`` (see :func:`action_index`), or for the
        continuous form ``dims`` numbers in [-1, 1] (:func:`continuous_action`)."""
        if self._td is None:
            raise RuntimeError("call reset() before step()")
        if isinstance(self.action_space, spaces.Box):
            value = continuous_action(action, self.action_space.shape[0])
            self._td.set("action", torch.tensor(value, dtype=torch.float32))
        else:
            index = action_index(action, int(self.action_space.n))
            self._td.set("action", torch.tensor([index], dtype=torch.int64))
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

    def __deepcopy__(self, memo: dict) -> "MujocoRLEnv":
        """A new env from the same arguments, in this one's state (physics, task and
        robot state, randomness, the last observation); each then steps on its own."""
        new = type(self)(**copy.deepcopy(self._made_with))
        memo[id(self)] = new
        new.torchrl_env.load_state_of(self.torchrl_env)
        new._td = None if self._td is None else self._td.clone()
        new._seeded = self._seeded
        new._np_random = copy.deepcopy(self._np_random, memo)
        new._np_random_seed = self._np_random_seed
        new.spec = copy.deepcopy(self.spec, memo)
        return new

    @staticmethod
    def _obs(td) -> np.ndarray:
        return td.get("observation")[0].numpy().astype(np.float32, copy=True)


class TimeLimitRequired(gym.Wrapper, gym.utils.RecordConstructorArgs):
    """Refuses an env made without a time limit: ``gymnasium.make(id, max_episode_steps=-1)``
    drops Gymnasium's ``TimeLimit``, and the task's own limit is lifted under ``gymnasium.make``,
    so an episode that never fails would never end. (Applied by ``gymnasium.make`` after the
    ``TimeLimit``, so it sees whether there is one.)"""

    def __init__(self, env: gym.Env) -> None:
        gym.utils.RecordConstructorArgs.__init__(self)
        gym.Wrapper.__init__(self, env)
        inner = env
        while isinstance(inner, gym.Wrapper) and not isinstance(inner, gym.wrappers.TimeLimit):
            inner = inner.env
        if not isinstance(inner, gym.wrappers.TimeLimit):
            env.close()
            raise ValueError("max_episode_steps=-1 is refused: without a time limit an episode that never "
                             "fails never ends; allowed: a positive integer (default: the task's "
                             f"{int(env.unwrapped.config.task.max_episode_steps)})")


def _plain_default(robot: str) -> tuple[str, int] | None:
    """``(default task, its max_episode_steps)`` of ``robot`` as its composed config has
    them, read from conf/robot/<robot>.yaml's ``defaults`` and conf/task/<task>.yaml; None
    where the files do not say it plainly (no plain ``/task`` default, no integer limit):
    then only a composition knows."""
    entries = OmegaConf.load(catalog.config_file("robot", robot)).get("defaults") or []
    tasks = [v for e in entries if isinstance(e, DictConfig) for k, v in e.items()
             if str(k).lstrip("/") == "task"]
    path = catalog.config_file("task", str(tasks[0])) if len(tasks) == 1 else None
    if path is None:
        return None
    steps = OmegaConf.load(path).get("max_episode_steps")
    return (str(tasks[0]), steps) if type(steps) is int else None


def register_envs(config_dirs: Sequence[str] = ()) -> list[str]:
    """Registers (idempotently) one id per robot with its default task; returns the ids.

    ``config_dirs``: config folders besides ``conf/`` whose robots get ids too (a user's
    ``~/my_robots``, as ``train.py --config-dir`` reads it); their envs are made with them.

    Each id's entry point is the string ``adapters.gym_env:MujocoRLEnv`` (a process that
    makes it imports this module) and its ``max_episode_steps`` (Gymnasium's
    ``TimeLimit``) the task's from the config; ``gymnasium.make(id, max_episode_steps=N)``
    changes it. Both come from the YAML files where they say them plainly, as every
    shipped robot's do (reading them is cheaper than composing the config three times).
    """
    ids = []
    if config_dirs:
        catalog.use_config_dirs(config_dirs)
    dirs = [str(d) for d in catalog.config_dirs()[1:]]
    for robot in catalog.robot_names():
        plain = _plain_default(robot)
        if plain is None:
            cfg = catalog.compose(robot, overrides=["~tuned"])
            plain = catalog.default_task(robot), int(cfg.task.max_episode_steps)
        task, steps = plain
        name = env_id(robot, task)
        if name not in gym.registry:
            kwargs = {"robot": robot, **({"config_dirs": dirs} if dirs else {})}
            gym.register(id=name, entry_point=f"{__name__}:MujocoRLEnv", kwargs=kwargs,
                         max_episode_steps=steps, additional_wrappers=(TimeLimitRequired.wrapper_spec(),))
        ids.append(name)
    return ids
