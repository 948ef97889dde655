"""Moving-cube physics, the one_disk_walk task's episode rules, and a short Q-learning run."""

import dataclasses
import math
from pathlib import Path

import mujoco
import numpy as np
import pytest
import torch
from dm_control import mjcf
from torchrl.envs.utils import check_env_specs

from runs.evaluate import evaluate
from learners.qlearn import QLearn
from tests.inprocess import train_in_process
from runs.run import Run
from runs.training_state import seed_everything
from robots.cartpole import CartPole
from robots.cube import Cube
from robots.physics import BatchedPhysics
from params import ConfigError
from tasks import factory
from tasks.env import RobotTaskEnv, compile_model
from tasks.one_disk_walk import WHEEL_STOP, OneDiskWalk
from tasks.stay_up import StayUp

ALL = np.array([True])
CONF = Path(__file__).resolve().parent.parent / "conf"


@pytest.fixture
def make_cube_env():
    envs = []

    def make(num_envs: int = 1, seed: int = 0, robot: dict | None = None, **task_kwargs):
        task_kwargs.setdefault("reset_noise", 0.0)
        task_kwargs.setdefault("wheel_speed_noise", 0.0)
        env = RobotTaskEnv(OneDiskWalk(Cube(**(robot or {})), **task_kwargs),
                           num_envs=num_envs, seed=seed)
        envs.append(env)
        return env

    yield make
    for env in envs:
        env.close(raise_if_closed=False)


def hold(env, seconds, speed=None):
    """Steps copy 0 substep by substep with the wheel command held.

    Returns the cube's y per substep and the lowest any corner went.
    """
    robot = env.task.robot
    if speed is not None:
        robot.command_wheel_speed(env.physics, speed)
    ys, lowest = [], np.inf
    for _ in range(int(round(seconds / env.physics.timestep))):
        env.physics.step(1)
        ys.append(robot.odometry(env.physics).position[0, 1])
        lowest = min(lowest, robot.lowest_corner_z(env.physics)[0])
    return np.array(ys), lowest


def step(env, td, action):
    td["action"] = torch.full((env.num_envs,), action, dtype=torch.int64)
    return env.step(td)["next"]


# -- the robot ------------------------------------------------------------------

def test_model_has_the_original_masses_and_wheel_axis(make_cube_env):
    env = make_cube_env(robot=dict(torque_limit=50.0, speed_limit=300.0, velocity_gain=2.0))
    model = env.model
    body = lambda name: mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
    assert model.body_mass[body("cube/cube")] == pytest.approx(0.5)
    np.testing.assert_allclose(model.body_inertia[body("cube/cube")], [0.003333] * 3)
    wheel = body("cube/wheel")
    assert model.body_mass[wheel] == pytest.approx(0.5)
    # Cylinder r = 0.08: axial inertia m r^2 / 2 about the cube's x axis.
    assert model.body_inertia[wheel].max() == pytest.approx(0.5 * 0.5 * 0.08**2)
    joint = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, "cube/wheel")
    np.testing.assert_allclose(model.jnt_axis[joint], [1, 0, 0])
    assert env.task.robot.half_edge == pytest.approx(0.1)
    # Robot config reaches the servo.
    assert model.actuator_forcerange[0].tolist() == [-50.0, 50.0]
    assert model.actuator_ctrlrange[0].tolist() == [-300.0, 300.0]
    assert model.actuator_gainprm[0, 0] == pytest.approx(2.0)


@pytest.mark.parametrize("speed, direction", [(100.0, 1), (-100.0, -1)])
def test_spinning_the_wheel_up_tips_the_cube_over_one_edge(make_cube_env, speed, direction):
    env = make_cube_env()
    env.reset()
    ys, lowest = hold(env, 1.5, speed)
    # Spinning the wheel about +x throws the cube about -x: it rolls towards +y.
    assert 0.15 <= direction * ys[-1] <= 0.25, ys[-1]
    odom = env.task.robot.odometry(env.physics)
    roll, pitch, yaw = odom.rpy[0]
    assert roll == pytest.approx(-direction * np.pi / 2, abs=0.02)  # one quarter turn
    assert abs(pitch) < 0.02 and abs(yaw) < 0.02
    assert abs(odom.position[0, 0]) < 0.01  # no sideways slide
    assert np.abs(odom.linear_velocity[0]).max() < 1e-3  # and it came to rest
    assert lowest > -0.005


def test_braking_a_spinning_wheel_tips_the_cube_back(make_cube_env):
    env = make_cube_env(init_roll_vel=100.0)
    env.reset()
    assert env.task.robot.wheel_speed(env.physics)[0] == pytest.approx(100.0)
    ys, lowest = hold(env, 0.5)
    assert abs(ys[-1]) < 1e-3  # a steadily spinning wheel does nothing
    ys, lowest = hold(env, 1.5, 0.0)
    assert -0.25 <= ys[-1] <= -0.15, ys[-1]
    assert lowest > -0.005


def test_idle_cube_stays_put(make_cube_env):
    env = make_cube_env()
    env.reset()
    ys, lowest = hold(env, 2.0, 0.0)
    speeds = np.abs(np.diff(ys)) / env.physics.timestep
    assert speeds.max() < 1e-3
    assert abs(ys[-1]) < 1e-3
    assert lowest > -0.005


def test_slow_ramp_then_burst_walks_further(make_cube_env):
    """The course's gait: ramp the wheel down in small steps (the cube only
    rocks), then jump it to full speed (the cube tips forward again)."""
    env = make_cube_env()
    env.reset()
    ys, lowest = hold(env, 0.6, 100.0)
    first = ys[-1]
    for speed in np.arange(90.0, -101.0, -10.0):
        ys, low = hold(env, 0.06, speed)
        lowest = min(lowest, low)
        assert abs(ys[-1] - first) < 0.02, speed
    ys, low = hold(env, 1.5, 100.0)
    assert ys[-1] - first > 0.15
    assert min(lowest, low) > -0.005


def test_cube_needs_a_free_joint():
    cube = Cube()
    arena = mjcf.RootElement()
    arena.attach(cube.mjcf_model)
    with pytest.raises(ValueError, match="freejoint"):
        cube.bind(BatchedPhysics(compile_model(arena), 1))


# -- the task -------------------------------------------------------------------

def test_actions_set_the_wheel_speed_command(make_cube_env):
    env = make_cube_env()
    td = env.reset()
    for action, expected in ((0, 100), (3, 100), (4, 90), (4, 80), (2, 0), (4, -10),
                             (1, -100), (4, -100), (3, -90), (0, 100)):
        td = step(env, td, action)
        # The servo reaches the command within a step; the observation rounds it.
        assert td["observation"][0, 0].item() == expected, action


def test_custom_speed_values(make_cube_env):
    env = make_cube_env(roll_speed_fixed_value=60.0, roll_speed_increment_value=25.0)
    td = env.reset()
    for action, expected in ((3, 25), (3, 50), (3, 60), (1, -60), (3, -35)):
        td = step(env, td, action)
        assert td["observation"][0, 0].item() == expected, action


def test_observation_is_rounded_pose_and_speed(make_cube_env):
    env = make_cube_env(4, seed=1)
    td = env.reset()
    gen = torch.Generator().manual_seed(0)
    robot = env.task.robot
    for _ in range(25):
        td["action"] = torch.randint(0, 5, (4,), generator=gen)
        td = env.step(td)["next"]
        obs = td["observation"].numpy().astype(float)
        odom = robot.odometry(env.physics)
        exact = np.column_stack([robot.wheel_speed(env.physics), odom.position[:, 1],
                                 odom.rpy, odom.linear_velocity[:, 1]])[:, [0, 1, 2, 3, 5, 4]]
        assert np.all(obs[:, 0] == np.round(obs[:, 0]))
        np.testing.assert_allclose(obs[:, 1:] * 10, np.round(obs[:, 1:] * 10), atol=1e-4)
        assert np.all(np.abs(obs[:, 0] - exact[:, 0]) <= 0.5 + 1e-6)
        assert np.all(np.abs(obs[:, 1:] - exact[:, 1:]) <= 0.05 + 1e-6)


def place(env, rpy, z=None):
    """Puts copy 0 at rest on the floor (on an edge if tilted) with orientation ``rpy``."""
    roll, pitch, _ = rpy
    h = env.task.robot.half_edge
    if z is None:
        z = h * max(abs(np.cos(pitch)) + abs(np.sin(pitch)), abs(np.cos(roll)) + abs(np.sin(roll)))
    env.task.robot.set_state(env.physics, ALL, [0.0, 0.0, z], np.array([rpy]))


@pytest.mark.parametrize("rpy", [(0.0, 0.3, 0.0), (0.0, -0.3, 0.0), (0.0, 0.0, 0.15),
                                 (0.0, 0.0, -0.15), (0.0, 0.3, 0.05)])
def test_pitch_or_yaw_beyond_limit_terminates_with_penalty(make_cube_env, rpy):
    env = make_cube_env(end_episode_points=700)
    td = env.reset()
    place(env, rpy)
    out = step(env, td, 2)
    assert out["terminated"].item() and out["done"].item() and not out["truncated"].item()
    assert out["reward"].item() == -700.0


def test_within_limits_runs_on_and_yaw_costs_its_sine(make_cube_env):
    env = make_cube_env()
    td = env.reset()
    place(env, (0.0, 0.0, 0.08))
    for _ in range(5):
        td = step(env, td, 2)
        assert not td["done"].item()
        assert td["reward"].item() == round(-np.sin(0.08) * 1000)  # -80: still, but yawed


def test_reward_is_the_sum_of_rounded_terms(make_cube_env):
    env = make_cube_env(move_distance_reward_weight=700.0, y_linear_speed_reward_weight=300.0,
                        y_axis_angle_reward_weight=2000.0)
    td = env.reset()
    place(env, (0.0, 0.0, 0.03))
    robot = env.task.robot
    for action in (0, 2, 2, 2, 2, 2, 2):
        before = robot.odometry(env.physics).position[0, 1]
        td = step(env, td, action)
        odom = robot.odometry(env.physics)
        expected = (round((odom.position[0, 1] - before) * 700.0)
                    + round(odom.linear_velocity[0, 1] * 300.0)
                    + round(-abs(np.sin(odom.rpy[0, 2])) * 2000.0))
        assert td["reward"].item() == expected


@pytest.mark.parametrize("weight, sign", [(1000.0, 1), (-1000.0, -1)])
def test_walking_plus_y_pays_unless_the_speed_weight_is_negative(make_cube_env, weight, sign):
    env = make_cube_env(y_linear_speed_reward_weight=weight)
    for action, moves in ((0, 1), (1, -1)):  # wheel to +fixed tips +y, to -fixed tips -y
        td = env.reset()
        rewards = []
        for k in range(12):  # one tip, then hold the command
            td = step(env, td, action if k == 0 else (3 if action == 0 else 4))
            rewards.append(td["reward"].item())
        y = env.task.episode_info(env.physics)["y_displacement"][0]
        assert moves * y > 0.15
        # First step of the tip and the whole tip: the sign follows the motion
        # times the speed weight (the distance term is 1000 per metre only).
        assert np.sign(rewards[0]) == moves * sign
        assert np.sign(sum(rewards)) == moves * sign
        assert not td["done"].item()


def test_episode_info_is_y_distance_from_start(make_cube_env):
    env = make_cube_env(2, init_cube_pose=[0.5, -1.0, 0.0])
    td = env.reset()
    np.testing.assert_allclose(env.task.robot.odometry(env.physics).position[:, :2],
                               [[0.5, -1.0], [0.5, -1.0]])
    td["action"] = torch.tensor([0, 1])
    td = env.step(td)["next"]
    for _ in range(15):
        td["action"] = torch.tensor([3, 4])
        td = env.step(td)["next"]
    info = env.task.episode_info(env.physics)["y_displacement"]
    assert 0.15 < info[0] < 0.25 and -0.25 < info[1] < -0.15
    np.testing.assert_allclose(td["observation"][:, 1].numpy(), np.round(info, 1), atol=1e-6)


def test_time_limit_is_truncation_not_termination(make_cube_env):
    env = make_cube_env(max_episode_steps=30)
    td = env.reset()
    for k in range(30):
        td = step(env, td, 2)
        assert td["done"].item() == (k == 29)
    assert td["truncated"].item() and not td["terminated"].item()


def test_reset_is_at_rest_with_small_seeded_yaw(make_cube_env):
    env = make_cube_env(64, seed=3, reset_noise=0.005, init_roll_vel=30.0)
    env.reset()
    odom = env.task.robot.odometry(env.physics)
    yaw = odom.rpy[:, 2]
    assert np.all(np.abs(yaw) <= 0.005) and yaw.std() > 0.001
    np.testing.assert_allclose(odom.rpy[:, :2], 0.0, atol=1e-12)
    np.testing.assert_allclose(odom.position[:, 2], 0.1)
    np.testing.assert_allclose(env.task.robot.wheel_speed(env.physics), 30.0)
    env.set_seed(3)
    env.reset()
    np.testing.assert_array_equal(env.task.robot.odometry(env.physics).rpy[:, 2], yaw)


def test_the_default_starts_differ_in_yaw_and_wheel_speed_and_never_tip_the_cube(make_cube_env):
    """Issue 65: twenty greedy episodes are twenty trajectories. The default start noise
    (+-0.05 rad of yaw, +-5 rad/s of wheel speed) gives every copy its own start, and a cube
    left idle from any of them stays on its face."""
    env = make_cube_env(20, seed=10_000, reset_noise=0.05, wheel_speed_noise=5.0)
    env.reset()
    odom = env.task.robot.odometry(env.physics)
    yaw, wheel = odom.rpy[:, 2], env.task.robot.wheel_speed(env.physics)
    assert len(np.unique(yaw)) == 20 and np.all(np.abs(yaw) <= 0.05) and yaw.std() > 0.02
    assert len(np.unique(wheel)) == 20 and np.all(np.abs(wheel) <= 5.0) and wheel.std() > 2.0
    start = odom.position.copy()
    td = env.reset()
    for _ in range(100):
        td = env.step(td.set("action", torch.full((20,), WHEEL_STOP))).get("next")
    odom = env.task.robot.odometry(env.physics)
    assert np.abs(odom.position[:, :2] - start[:, :2]).max() < 0.005  # rocked at most: no tip (0.2 m)
    assert np.abs(odom.rpy[:, :2]).max() < 0.05


@pytest.mark.parametrize("num_envs", [1, 4])
def test_check_env_specs(make_cube_env, num_envs):
    env = make_cube_env(num_envs, reset_noise=0.005)
    check_env_specs(env)
    assert env.observation_spec["observation"].shape == (num_envs, 6)
    assert env.action_spec.space.n == 5


def rollout_states(env, seed, steps=60):
    env.set_seed(seed)
    gen = torch.Generator().manual_seed(0)
    td = env.reset()
    states = []
    for _ in range(steps):
        td["action"] = torch.randint(0, 5, (env.num_envs,), generator=gen)
        _, td = env.step_and_maybe_reset(td)
        states.append(env.physics.state.copy())
    return np.stack(states)


def test_same_seed_identical_rollouts(make_cube_env):
    a = rollout_states(make_cube_env(4, reset_noise=0.005), seed=7)
    b = rollout_states(make_cube_env(4, reset_noise=0.005), seed=7)
    c = rollout_states(make_cube_env(4, reset_noise=0.005), seed=8)
    np.testing.assert_array_equal(a, b)
    assert not np.allclose(a, c)


def test_task_and_robot_must_match():
    with pytest.raises(ConfigError, match="one_disk_walk needs robot=cube"):
        OneDiskWalk(CartPole())
    with pytest.raises(ConfigError, match="stay_up needs robot=cartpole"):
        StayUp(Cube())


@pytest.mark.parametrize("bad", [dict(n_actions=3), dict(end_episode_points=-1000),
                                 dict(running_step=0.0605), dict(roll_speed_fixed_value=2000.0),
                                 dict(init_cube_pose=[0.0, 0.0]), dict(max_yaw_angle=0.0)])
def test_bad_task_parameters_name_the_key(bad):
    with pytest.raises(ConfigError) as err:
        OneDiskWalk(Cube(), **bad)
    assert next(iter(bad)) in str(err.value)
    assert len(str(err.value).splitlines()) == 1


def test_hydra_composes_cube_with_its_task_and_tuned_learner():
    from hydra import compose, initialize_config_dir
    from hydra.utils import instantiate

    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", overrides=["robot=cube", "learner=qlearn"])
        course = compose(config_name="config", overrides=["robot=cube", "learner=qlearn", "~tuned"])
        bad = compose(config_name="config", overrides=["robot=cartpole", "task=one_disk_walk"])
    assert cfg.task._target_ == "tasks.one_disk_walk.OneDiskWalk"
    assert cfg.task.running_step == 0.06 and cfg.task.end_episode_points == 1000
    assert (cfg.learner.alpha, cfg.learner.gamma, cfg.learner.epsilon) == (0.2193, 0.9611, 0.9)  # its study's
    # Without the tuned file: the course unit's parameters, the baseline.
    assert (course.learner.alpha, course.learner.gamma, course.learner.epsilon_discount) == (0.1, 0.7, 0.999)
    assert dict(cfg.learner.number_splits) == {"wheel_speed": 24, "y_speed": 5, "yaw": 5}
    task = factory.build_task(cfg)
    assert task.tabular_bounds.names == ("wheel_speed", "y_speed", "yaw")
    learner = instantiate(cfg.learner, _convert_="all")
    learner.build(task)
    assert learner.discretizer.n_states == 24 * 5 * 5
    with pytest.raises(Exception, match="one_disk_walk needs robot=cube"):
        factory.build_task(bad)


# -- learning -------------------------------------------------------------------

def mean_y(env, policy) -> float:
    return evaluate(env, policy)["info_mean"]["y_displacement"]


def train_and_evaluate(tmp_path, weight: float) -> float:
    """300 episodes of q-learning on 4 copies, rewarded by ``weight`` per m/s along +y, through
    ``train.py``; the greedy policy's mean walk along y on 8 fresh starts."""
    member = train_in_process(
        tmp_path / f"w{weight}", "robot=cube", "learner=qlearn", "~tuned", "seed=0", "num_envs=4",
        "max_episodes=300", "eval_episodes=0", "stop_when_solved=false", "quiet=true", "learner.alpha=0.1",
        "learner.gamma=0.7", "learner.epsilon=0.9", "learner.epsilon_discount=0.999",
        "learner.number_splits=[21,5,3]", f"task.y_linear_speed_reward_weight={weight}", "task.max_episode_steps=200")
    eval_env = RobotTaskEnv(OneDiskWalk(Cube(), max_episode_steps=200), num_envs=8, seed=10_000)
    with member.greedy():
        y = mean_y(eval_env, member.policy)
    eval_env.close()
    return y


@pytest.fixture(scope="module")
def random_policy_y():
    env = RobotTaskEnv(OneDiskWalk(Cube(), max_episode_steps=200), num_envs=64, seed=10_000)
    gen = torch.Generator().manual_seed(0)
    y = mean_y(env, lambda td: td.set("action", torch.randint(0, 5, (64,), generator=gen)))
    env.close()
    return y


@pytest.mark.parametrize("weight, sign", [(1000.0, 1), (-1000.0, -1)])
def test_qlearning_walks_the_rewarded_way(tmp_path, random_policy_y, weight, sign):
    y = train_and_evaluate(tmp_path, weight)
    assert abs(random_policy_y) < 0.08  # a random policy goes nowhere on average
    assert sign * y > 0.15  # at least one edge in the rewarded direction
    assert sign * (y - random_policy_y) > 0.1
