"""Gymnasium registration: every robot's default task makes, passes check_env, seeds, steps."""

import os
import subprocess
import sys
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra

from tasks import factory
from tasks.gym_env import MujocoRLEnv, default_tasks, env_id, register_envs

ROOT = Path(__file__).resolve().parents[1]
EXPECTED = {  # id: robot, observation size, actions, time limit
    "MujocoRL/CartPoleStayUp-v0": ("cartpole", 4, 2, 1000),
    "MujocoRL/MovingCubeOneDiskWalk-v0": ("cube", 6, 5, 1000),
    "MujocoRL/TurtleBot2Maze-v0": ("turtlebot", 6, 3, 500),
}


@pytest.fixture
def make():
    envs = []

    def _make(env_name: str, **kwargs):
        env = gym.make(env_name, **kwargs)
        envs.append(env)
        return env

    yield _make
    for env in envs:
        env.close()


def test_every_robot_is_registered_with_its_default_task():
    ids = register_envs()
    assert sorted(ids) == sorted(EXPECTED)
    assert register_envs() == ids  # idempotent
    robots = sorted(p.stem for p in (ROOT / "conf" / "robot").glob("*.yaml"))
    assert sorted(default_tasks()) == robots
    for name in ids:
        assert name in gym.registry and gym.spec(name).namespace == "MujocoRL"
        assert gym.spec(name).max_episode_steps == EXPECTED[name][3]
    assert env_id("cartpole", "stay_up") == "MujocoRL/CartPoleStayUp-v0"


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_make_and_check_env(make, name):
    robot, n_obs, n_actions, _ = EXPECTED[name]
    env = make(name, render_mode="rgb_array", width=64, height=48)
    assert env.unwrapped.config.robot._target_.startswith(f"robots.{robot}")
    assert env.observation_space == gym.spaces.Box(-np.inf, np.inf, (n_obs,), np.float32)
    assert env.action_space == gym.spaces.Discrete(n_actions)
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message=".*Box observation space m.*infinity")
        check_env(env.unwrapped)
    obs, info = env.reset(seed=0)
    assert obs.dtype == np.float32 and obs.shape == (n_obs,) and isinstance(info, dict)
    frame = env.render()
    assert frame.shape == (48, 64, 3) and frame.dtype == np.uint8 and frame.std() > 0


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_seeded_reset_reproduces_trajectories(make, name):
    env = make(name)

    def rollout(seed):
        obs, _ = env.reset(seed=seed)
        start = env.unwrapped.torchrl_env.physics.qpos[0].copy()  # observations may be rounded
        out = [obs]
        rng = np.random.default_rng(0)
        for _ in range(5):
            obs, reward, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
            assert obs in env.observation_space and isinstance(reward, float)
            assert isinstance(terminated, bool) and isinstance(truncated, bool)
            out.append(obs)
            if terminated or truncated:
                break
        return start, np.stack(out)

    (s1, a), (s2, b), (s3, c) = rollout(11), rollout(11), rollout(12)
    assert np.array_equal(s1, s2) and np.array_equal(a, b)
    assert not np.array_equal(s1, s3)


def test_cartpole_steps_follow_the_task(make):
    env = make("MujocoRL/CartPoleStayUp-v0", max_episode_steps=400)
    env.reset(seed=0)
    for t in range(1, 401):  # always push right: the pole or the cart leaves its range
        obs, reward, terminated, truncated, _ = env.step(1)
        assert reward == 1.0
        if terminated:
            break
    assert terminated and not truncated and t < 100
    assert abs(obs[0]) >= 1.0 or abs(obs[2]) >= 0.7
    with pytest.raises(ValueError, match="action"):
        env.step(2)


def test_time_limit_and_episode_info(make):
    env = make("MujocoRL/MovingCubeOneDiskWalk-v0", max_episode_steps=3)
    env.reset(seed=0)
    steps = [env.step(2)[2:] for _ in range(3)]  # action 2: wheel stopped, the cube rests
    assert [s[:2] for s in steps] == [(False, False), (False, False), (False, True)]
    assert all(set(info) == {"y_displacement", "distance_walked"} for *_, info in steps)
    direct = MujocoRLEnv("cube", max_episode_steps=2)  # no make(): the task's own limit
    try:
        direct.reset(seed=0)
        assert [direct.step(2)[2:4] for _ in range(2)] == [(False, False), (False, True)]
    finally:
        direct.close()


def test_make_kwargs_override_task_and_robot_parameters(make):
    env = make("MujocoRL/CartPoleStayUp-v0", pos_step=0.5, n_actions=4,
               robot_params={"velocity_gain": 500.0})
    assert env.unwrapped.task.pos_step == 0.5 and env.action_space.n == 4
    assert env.unwrapped.config.robot.velocity_gain == 500.0
    with pytest.raises(TypeError, match="pos_stepp"):
        gym.make("MujocoRL/CartPoleStayUp-v0", pos_stepp=0.5)


def test_composing_inside_a_running_hydra_app_keeps_its_state():
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        app = GlobalHydra.instance().hydra
        cfg = factory.compose("cube")
        assert cfg.task._target_ == "tasks.one_disk_walk.OneDiskWalk"
        assert GlobalHydra.instance().hydra is app
        assert compose(config_name="config").robot._target_ == "robots.cartpole.CartPole"


def test_plain_gymnasium_user_makes_it_with_the_module_prefix():
    code = ("import gymnasium as gym\n"
            "env = gym.make('tasks.gym_env:MujocoRL/TurtleBot2Maze-v0')\n"
            "obs, _ = env.reset(seed=1)\n"
            "print(env.spec.id, obs.shape)\n")
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    proc = subprocess.run([sys.executable, "-c", code], cwd="/", env=env, capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-1500:]
    assert proc.stdout.strip().splitlines()[-1] == "MujocoRL/TurtleBot2Maze-v0 (6,)"
