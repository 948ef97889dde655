"""Config validation: every bad value fails before any simulation with one line naming
the key, the value and what is allowed (runs/settings.py and the constructors).

No env is built here (that compiles MuJoCo): a config is checked with
``check_run_config`` and then built as far as runs.lifecycle._build builds it before the env
(learner, robot and task, the learner's tables or networks for that task).
"""

from __future__ import annotations

import math
import os
import subprocess
import sys
from functools import lru_cache
from pathlib import Path

import pytest

from inprocess import run_train
from hydra import compose, initialize_config_dir
from hydra.errors import InstantiationException
from hydra.utils import instantiate
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from omegaconf import OmegaConf

import train
from runs.command import one_line
from tasks import factory
from runs.settings import check_run_config
from params import ConfigError

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"


@lru_cache(maxsize=None)
def _composed(overrides: tuple[str, ...]):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def compose_cfg(*overrides: str):
    return _composed(tuple(overrides)).copy()


@lru_cache(maxsize=None)
def default_task(robot: str):
    return factory.build_task(compose_cfg(f"robot={robot}"))


def build(cfg, parts: str = "all") -> None:
    """What runs.lifecycle._build does with ``cfg`` before it builds the env."""
    check_run_config(cfg)
    if parts in ("all", "task"):
        task = factory.build_task(cfg)
    if parts in ("all", "learner"):
        learner = instantiate(cfg.learner, _convert_="all")
        learner.build(task if parts == "all" else default_task(cfg.robot._target_.split(".")[1]))


def one_line_error(cfg, parts: str = "all") -> str:
    """The one-line message building ``cfg`` fails with (and that it is a config error)."""
    with pytest.raises((ConfigError, InstantiationException)) as err:
        build(cfg, parts)
    if isinstance(err.value, InstantiationException):
        assert isinstance(err.value.__cause__, ConfigError), repr(err.value.__cause__)
    message = one_line(err.value)
    assert message == str(err.value.__cause__ or err.value).strip(), "more than one line"
    return message


@pytest.mark.parametrize("task", ["wall"])
def test_other_shipped_tasks_pass(task):
    build(compose_cfg("robot=turtlebot", f"task={task}"))


def test_hydras_own_node_is_left_to_hydra():
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", return_hydra_config=True)
    check_run_config(cfg)


# (overrides, key the message must name, value it must show after "; got "): each run through
# the command line in tests/test_bad_inputs.py (one error line, exit 2, nothing written)
CASES = [
    # top level
    (["seed=-1"], "seed", "-1"),
    (["seed=1.5"], "seed", "1.5"),
    (["num_envs=-3"], "num_envs", "-3"),
    (["num_envs=0"], "num_envs", "0"),
    (["num_envs=2.5"], "num_envs", "2.5"),
    (["num_envs=abc"], "num_envs", "'abc'"),
    (["mode=fly"], "mode", "'fly'"),
    (["mode=eval"], "mode=eval needs checkpoint", ""),
    (["checkpoint=3"], "checkpoint", "3"),
    (["eval_episodes=-1"], "eval_episodes", "-1"),
    (["task.win.threshold=nan"], "task.win.threshold", "nan"),
    (["task.win.threshold=abc"], "task.win.threshold", "'abc'"),
    (["task.win.min_episodes=-1"], "task.win.min_episodes", "-1"),
    (["task.win.window=0"], "task.win.window", "0"),
    (["task.win.judge=vibes"], "task.win.judge", "'vibes'"),
    (["task.win.measure=reward"], "task.win.measure", "'reward'"),
    (["+task.win.bogus=1"], "task.win entries", "bogus"),
    (["eval_every=-1"], "eval_every", "-1"),
    (["+win.n_win_ticks=300"], "task.win", "n_win_ticks"),
    (["quiet=abc"], "quiet", "'abc'"),
    (["video=2"], "video", "2"),
    (["video_steps=-1"], "video_steps", "-1"),
    (["torch_threads=0"], "torch_threads", "0"),
    (["logger.kind=bogus"], "logger.kind", "'bogus'"),
    (["+logger.foo=1"], "logger.foo", "logger.foo=1"),
    # robots
    (["robot.velocity_gain=-1"], "robot.velocity_gain", "-1"),
    (["robot.force_limit=nan"], "robot.force_limit", "nan"),
    (["robot.position_gain=inf"], "robot.position_gain", "inf"),
    (["robot=cube", "robot.torque_limit=0"], "robot.torque_limit", "0"),
    (["robot=cube", "robot.speed_limit=abc"], "robot.speed_limit", "'abc'"),
    (["robot=turtlebot", "robot.laser_rays=0"], "robot.laser_rays", "0"),
    (["robot=turtlebot", "robot.laser_rays=2.5"], "robot.laser_rays", "2.5"),
    (["robot=turtlebot", "robot.laser_fov=7"], "robot.laser_fov", "7"),
    (["robot=turtlebot", "robot.max_linear_speed=-1"], "robot.max_linear_speed", "-1"),
    (["+robot.bogus=1"], "robot.bogus", "robot.bogus=1"),
    # tasks: stay_up
    (["task.n_actions=3"], "task.n_actions", "3"),
    (["task.n_actions=abc"], "task.n_actions", "'abc'"),
    (["task.pos_step=-1"], "task.pos_step", "-1"),
    (["task.pos_step=inf"], "task.pos_step", "inf"),
    (["task.running_step=0"], "task.running_step", "0"),
    (["task.running_step=0.041"], "task.running_step", "0.041"),
    (["task.physics_timestep=nan"], "task.physics_timestep", "nan"),
    (["task.max_pole_angle=5"], "task.max_pole_angle", "5"),
    (["task.min_pole_angle=0.9"], "task.min_pole_angle", "0.9"),
    (["task.max_base_pose_x=5"], "task.max_base_pose_x", "5"),
    (["task.init_pos=1.5"], "task.init_pos", "1.5"),
    (["task.reset_noise=-0.1"], "task.reset_noise", "-0.1"),
    (["task.max_episode_steps=0"], "task.max_episode_steps", "0"),
    (["task.max_episode_steps=2.5"], "task.max_episode_steps", "2.5"),
    (["task.control_type=torque"], "task.control_type", "'torque'"),
    (["task.tabular_state.cart_pos=[1,0]"], "task.tabular_state.cart_pos", "[1, 0]"),
    (["task.tabular_state.cart_pos=[0,1,2]"], "task.tabular_state.cart_pos", "[0, 1, 2]"),
    (["task.tabular_state.cart_pos=[0,inf]"], "task.tabular_state.cart_pos", "[0, inf]"),
    (["+task.tabular_state.bogus=[0,1]"], "task.tabular_state", "'bogus'"),
    (["+task.bogus=1"], "task.bogus", "task.bogus=1"),
    # tasks: one_disk_walk
    (["robot=cube", "task.n_actions=4"], "task.n_actions", "4"),
    (["robot=cube", "task.roll_speed_fixed_value=2000"], "task.roll_speed_fixed_value", "2000"),
    (["robot=cube", "task.init_roll_vel=500"], "task.init_roll_vel", "500"),
    (["robot=cube", "task.end_episode_points=-1"], "task.end_episode_points", "-1"),
    (["robot=cube", "task.y_linear_speed_reward_weight=nan"], "task.y_linear_speed_reward_weight", "nan"),
    (["robot=cube", "task.init_cube_pose=[0,0]"], "task.init_cube_pose", "[0, 0]"),
    (["robot=cube", "task.init_cube_pose=[0,nan,0]"], "task.init_cube_pose", "[0, nan, 0]"),
    # tasks: maze
    (["robot=turtlebot", "task.n_actions=2"], "task.n_actions", "2"),
    (["robot=turtlebot", "task.n_observations=0"], "task.n_observations", "0"),
    (["robot=turtlebot", "task.linear_forward_speed=100"], "task.linear_forward_speed", "100"),
    (["robot=turtlebot", "task.angular_speed=0"], "task.angular_speed", "0"),
    (["robot=turtlebot", "task.min_range=10"], "task.min_range", "10"),
    (["robot=turtlebot", "task.forwards_reward=inf"], "task.forwards_reward", "inf"),
    (["robot=turtlebot", "task.wall_height=0"], "task.wall_height", "0"),
    (["robot=turtlebot", "task.ring.segments=4"], "task.ring.segments", "4"),
    (["robot=turtlebot", "task.ring.starts=2.5"], "task.ring.starts", "2.5"),
    (["robot=turtlebot", "task.ring.inner_radius=nan"], "task.ring.inner_radius", "nan"),
    (["robot=turtlebot", "+task.ring.bogus=1"], "task.ring", "'bogus'"),
    (["robot=turtlebot", "task=wall", "task.cell_size=-1"], "task.cell_size", "-1"),
    # a task that does not fit the robot
    (["robot=cartpole", "task=one_disk_walk"], "needs robot=cube", "robot=cartpole"),
    (["robot=cube", "task=stay_up"], "needs robot=cartpole", "robot=cube"),
    (["robot=cartpole", "task=maze"], "needs robot=turtlebot", "robot=cartpole"),
    # learners: qlearn
    (["learner.alpha=-0.1"], "learner.alpha", "-0.1"),
    (["learner.alpha=nan"], "learner.alpha", "nan"),
    (["learner.gamma=2"], "learner.gamma", "2"),
    (["learner.epsilon=1.5"], "learner.epsilon", "1.5"),
    (["learner.epsilon_discount=0"], "learner.epsilon_discount", "0"),
    (["max_episodes=-1"], "max_episodes", "-1"),
    (["max_episodes=0", "max_env_steps=0"], "max_episodes and max_env_steps are both 0",
     "max_episodes=0, max_env_steps=0"),
    (["task.max_episode_steps=2.5"], "task.max_episode_steps", "2.5"),
    (["+learner.nepisodes=5"], "learner.nepisodes is now max_episodes", "max_episodes=5"),
    (["+learner.nsteps=300"], "learner.nsteps is now task.max_episode_steps", "task.max_episode_steps=300"),
    (["learner.initial_q=inf"], "learner.initial_q", "inf"),
    (["learner.first_visit_reward=abc"], "learner.first_visit_reward", "'abc'"),
    (["learner.number_splits.cart_pos=2.5"], "learner.number_splits.cart_pos", "2.5"),
    (["learner.number_splits.cart_pos=0"], "learner.number_splits.cart_pos", "0"),
    (["+learner.number_splits.bogus=3"], "learner.number_splits", "['bogus']"),
    (["+learner.bogus=1"], "learner.bogus", "learner.bogus=1"),
    # learners: the DQN family and its epsilon schedules
    (["learner=dqn", "learner.lr=-1"], "learner.lr", "-1"),
    (["learner=dqn", "learner.lr=inf"], "learner.lr", "inf"),
    (["learner=dqn", "learner.gamma=nan"], "learner.gamma", "nan"),
    (["learner=dqn", "learner.hidden=64"], "learner.hidden", "64"),
    (["learner=dqn", "learner.hidden=[0]"], "learner.hidden", "[0]"),
    (["learner=dqn", "learner.activation=sigmoid"], "learner.activation", "'sigmoid'"),
    (["learner=dqn", "learner.loss=l1"], "learner.loss", "'l1'"),
    (["learner=dqn", "learner.tau=1"], "learner.tau", "1"),
    (["learner=dqn", "learner.batch_size=100000"], "learner.batch_size", "100000"),
    (["learner=dqn", "learner.buffer_size=2.5"], "learner.buffer_size", "2.5"),
    (["learner=dqn", "learner.train_every=never"], "learner.train_every", "'never'"),
    (["learner=dqn", "learner.updates=0"], "learner.updates", "0"),
    (["learner=dqn", "learner.double_dqn=2"], "learner.double_dqn", "2"),
    (["learner=dqn", "learner.done_episode_reward=nan"], "learner.done_episode_reward", "nan"),
    (["learner=dqn", "learner.reward_scale=-0.5"], "learner.reward_scale", "-0.5"),
    (["learner=dqn", "learner.epsilon.epsilon=1.5"], "learner.epsilon.epsilon", "1.5"),
    (["learner=dqn", "learner.epsilon.epsilon_min=2"], "learner.epsilon.epsilon_min", "2"),
    (["learner=dqn", "learner.epsilon.steps=0"], "learner.epsilon.steps", "0"),
    (["learner=dqn", "learner.epsilon._target_=no.Such"], "learner.epsilon._target_", "'no.Such'"),
    (["learner=dqn", "+learner.epsilon.bogus=1"], "learner.epsilon.bogus", "learner.epsilon.bogus=1"),
    (["learner=mbalunovic", "learner.epsilon.decay=0"], "learner.epsilon.decay", "0"),
    (["learner=mbalunovic", "learner.epsilon.per=run"], "learner.epsilon.per", "'run'"),
    (["learner=n1try", "learner.epsilon.epsilon_decay=1.5"], "learner.epsilon.epsilon_decay", "1.5"),
    (["learner=dqn", "learner.learning_starts=100000"], "learner.learning_starts", "100000"),
    (["learner=dqn", "learner.grad_clip=-1"], "learner.grad_clip", "-1"),
    (["learner=dqn", "learner.epsilon=0.5"], "learner.epsilon", "0.5"),
    # Rainbow's parts
    (["learner=dqn", "learner.n_step=0"], "learner.n_step", "0"),
    (["learner=dqn", "learner.dueling=maybe"], "learner.dueling", "'maybe'"),
    (["learner=dqn", "learner.atoms=1"], "learner.atoms", "1"),
    (["learner=dqn", "learner.v_min=10", "learner.v_max=10"], "learner.v_max must be above learner.v_min", "10"),
    (["learner=dqn", "learner.noisy_sigma=0"], "learner.noisy_sigma", "0"),
    (["learner=qlearn", "+learner.noisy=true"], "not a parameter of learners.qlearn.QLearn", "learner.noisy=True"),
    (["learner=dqn", "learner.priority_alpha=1.5"], "learner.priority_alpha", "1.5"),
    (["learner=dqn", "learner.priority_beta=-0.1"], "learner.priority_beta", "-0.1"),
    (["learner=dqn", "learner.priority_eps=0"], "learner.priority_eps", "0"),
    (["learner=dqn", "learner.priority_beta_updates=0"], "learner.priority_beta_updates", "0"),
    # continuous-action learners
    (["learner=sac", "learner.lr=-1"], "learner.lr", "-1"),
    (["learner=sac", "learner.tau=0"], "learner.tau", "0"),
    (["learner=sac", "learner.target_entropy=nan"], "learner.target_entropy", "nan"),
    (["learner=sac", "learner.learning_starts=200000"], "learner.learning_starts", "200000"),
    (["learner=td3", "learner.policy_delay=0"], "learner.policy_delay", "0"),
    (["learner=td3", "learner.exploration_noise=-0.1"], "learner.exploration_noise", "-0.1"),
    (["learner=ppo", "learner.clip_epsilon=1.5"], "learner.clip_epsilon", "1.5"),
    (["learner=ppo", "learner.minibatches=4096"], "learner.minibatches", "4096"),
    (["learner=ppo", "learner.gae_lambda=2"], "learner.gae_lambda", "2"),
    (["learner=sac", "~task.actions", "+task.actions={values: {torque: [1.0]}}", "robot=pendulum",
      "+task.actions.continuous={torque: [1, -1]}"], "task.actions.continuous.torque", "[1, -1]"),
]


# -- hypothesis: over a key's range, valid values build and invalid ones give the line ----
def _is_int(x) -> bool:
    return not isinstance(x, bool) and isinstance(x, (int, float)) and math.isfinite(x) \
        and float(x).is_integer()


def _is_real(x) -> bool:
    """A finite number, a float 0 or of normal size (a subnormal one counts as 0 in training)."""
    return not isinstance(x, bool) and isinstance(x, (int, float)) and math.isfinite(x) \
        and (isinstance(x, int) or x == 0 or abs(x) >= sys.float_info.min)


def integer_in(low, high=math.inf):
    return lambda x: _is_int(x) and low <= x <= high


def real(test):
    return lambda x: _is_real(x) and test(x)


# key -> (robot, learner, which part to build, valid(value))
RANGES = {
    "num_envs": ("cartpole", "qlearn", "none", integer_in(1, 4096)),
    "seed": ("cartpole", "qlearn", "none", integer_in(0, 2**63 - 1)),
    "eval_episodes": ("cartpole", "qlearn", "none", integer_in(0, 4096)),
    "task.win.threshold": ("cartpole", "qlearn", "task",  # inf: never solved, whole budget
                           lambda x: not isinstance(x, (bool, str, type(None))) and not math.isnan(x)),
    "eval_every": ("cartpole", "qlearn", "none", integer_in(0)),
    "eval_every_steps": ("cartpole", "qlearn", "none", integer_in(0)),
    "torch_threads": ("cartpole", "qlearn", "none", integer_in(1, 256)),
    "robot.velocity_gain": ("cartpole", "qlearn", "task", real(lambda x: x > 0)),
    "robot.force_limit": ("cartpole", "qlearn", "task", real(lambda x: x >= 0)),
    # the maze needs both sides seen and 31 rays at most 10 deg apart (tasks.maze.MazeTask._check_laser)
    "robot.laser_fov": ("turtlebot", "qlearn", "task", real(lambda x: math.pi - 1e-6 <= x <= math.radians(300) + 1e-6)),
    "task.pos_step": ("cartpole", "qlearn", "task", real(lambda x: x > 0)),
    "task.reset_noise": ("cartpole", "qlearn", "task", real(lambda x: x >= 0)),
    "task.min_pole_angle": ("cartpole", "qlearn", "task", real(lambda x: -1.57 <= x < 0.7)),
    "task.init_pos": ("cartpole", "qlearn", "task", real(lambda x: -1 < x < 1)),
    "task.max_episode_steps": ("cartpole", "qlearn", "task", integer_in(1, 10**7)),
    "task.n_actions": ("cartpole", "qlearn", "task", lambda x: _is_int(x) and x in (2, 4)),
    "task.max_pitch_angle": ("cube", "qlearn", "task", real(lambda x: x > 0)),
    "task.init_roll_vel": ("cube", "qlearn", "task", real(lambda x: abs(x) <= 100)),
    "task.angular_speed": ("turtlebot", "qlearn", "task", real(lambda x: 0 < x <= 3.14159265)),
    "task.linear_forward_speed": ("turtlebot", "qlearn", "task", real(lambda x: 0 < x <= 0.7)),
    "learner.alpha": ("cartpole", "qlearn", "learner", real(lambda x: 0 < x <= 1)),
    "learner.gamma": ("cartpole", "qlearn", "learner", real(lambda x: 0 <= x <= 1)),
    "learner.epsilon": ("cartpole", "qlearn", "learner", real(lambda x: 0 <= x <= 1)),
    "learner.epsilon_discount": ("cartpole", "qlearn", "learner", real(lambda x: 0 < x <= 1)),
    "max_episodes": ("cartpole", "qlearn", "none", integer_in(0, 10**9)),  # 0: its tuned file's env steps budget it
    "learner.lr": ("cartpole", "dqn", "learner", real(lambda x: x > 0)),
    "learner.lr_decay": ("cartpole", "dqn", "learner", real(lambda x: x >= 0)),
    "learner.updates": ("cartpole", "dqn", "learner", real(lambda x: x > 0)),
    "learner.epsilon.epsilon": ("cartpole", "dqn", "learner", real(lambda x: 0.02 <= x <= 1)),
    "learner.epsilon.decay": ("cartpole", "mbalunovic", "learner", real(lambda x: 0 < x <= 1)),
}

VALUES = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-3.0, 3.0),
    st.integers(-5, 10),
    st.integers(-(2**70), 2**70),
    st.sampled_from([0, 0.0, 1, 1.0, -0.0, 2, 4, 1e-9, 0.7, 1.57, 2 * math.pi, "abc", True, None]),
)


@pytest.mark.parametrize("key", sorted(RANGES))
@settings(max_examples=12, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(value=VALUES)
def test_values_over_a_keys_range(key, value):
    robot, learner, parts, valid = RANGES[key]
    cfg = compose_cfg(f"robot={robot}", f"learner={learner}")
    OmegaConf.update(cfg, key, value, merge=False)
    if valid(value):
        if parts == "none":
            check_run_config(cfg)
        else:
            build(cfg, parts)
        return
    message = one_line_error(cfg, "learner" if parts == "none" else parts)
    assert key in message and "got" in message, message
    assert repr(value) in message, message


# -- end to end: the command line prints one line and exits 2 -------------------------------
def _train(tmp_path: Path, *overrides: str) -> subprocess.CompletedProcess:
    return run_train(f"hydra.run.dir={tmp_path}", "quiet=true", *overrides)




@pytest.mark.parametrize("overrides, line", [
    (["task.pos_step=-1"], "error: task.pos_step must be a finite number > 0; got -1"),
    (["robot=cube", "task=stay_up"], "error: task=stay_up needs robot=cartpole; got robot=cube"),
    (["robot=cartpole", "task=wall"], "error: task=wall needs robot=turtlebot; got robot=cartpole"),
    (["num_envs=-3"], "error: num_envs must be an integer in [1, 4096]; got -3"),
])
def test_command_line_prints_one_error_line_and_exits_2(tmp_path, overrides, line):
    proc = _train(tmp_path, *overrides)
    assert proc.stderr.strip().splitlines() == [line], proc.stderr[-1500:]
    assert proc.returncode == 2
