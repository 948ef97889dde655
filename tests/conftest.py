import os

os.environ.setdefault("MUJOCO_GL", "egl")

import pytest  # noqa: E402
import torch  # noqa: E402

torch.set_num_threads(1)

from robots.cartpole import CartPole  # noqa: E402
from tasks.env import RobotTaskEnv  # noqa: E402
from tasks.stay_up import StayUp  # noqa: E402


@pytest.fixture
def make_cartpole_env():
    envs = []

    def make(num_envs: int = 1, seed: int = 0, **task_kwargs) -> RobotTaskEnv:
        robot_kwargs = {k: task_kwargs.pop(k) for k in ("velocity_gain", "force_limit") if k in task_kwargs}
        env = RobotTaskEnv(StayUp(CartPole(**robot_kwargs), **task_kwargs), num_envs=num_envs, seed=seed)
        envs.append(env)
        return env

    yield make
    for env in envs:
        env.close(raise_if_closed=False)
