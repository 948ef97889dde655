"""Cart-pole physics and the stay_up task's episode rules."""

import numpy as np
import pytest
import torch

from robots.cartpole import CartPole
from params import ConfigError
from tasks.stay_up import StayUp
from tasks.env import RobotTaskEnv

ALL = np.array([True])


def hold(env, seconds, command=None):
    """Steps the physics with the cart command held; returns (times, joint states)."""
    robot = env.task.robot
    if command is not None:
        robot.command(env.physics, np.array([command]))
    states = []
    for _ in range(int(round(seconds / env.task.running_step))):
        env.physics.step(env.task.n_substeps)
        states.append(robot.joint_states(env.physics))
    return states


def test_pole_falls_within_two_seconds_without_control(make_cartpole_env):
    env = make_cartpole_env(1, reset_noise=0.0)
    env.reset()
    env.task.robot.set_joint_states(env.physics, ALL, 0.0, 0.0, 0.05, 0.0)
    states = hold(env, 2.0, command=0.0)
    angles = np.array([s.pole_angle[0] for s in states])
    assert angles.max() > 0.7, angles[-5:]
    # It fell the way it leaned, and kept falling (no spring back to upright).
    assert np.all(np.diff(angles[: np.argmax(angles > 0.7)]) > 0)


def test_upright_pole_with_hinge_friction_stays(make_cartpole_env):
    """Below friction torque (0.1 N m > m g l sin 0.02) a nearly upright pole does not move."""
    env = make_cartpole_env(1, reset_noise=0.0)
    env.reset()
    env.task.robot.set_joint_states(env.physics, ALL, 0.0, 0.0, 0.02, 0.0)
    states = hold(env, 1.0, command=0.0)
    assert abs(states[-1].pole_angle[0] - 0.02) < 1e-3


def test_cart_velocity_follows_command(make_cartpole_env):
    env = make_cartpole_env(1, reset_noise=0.0)
    env.reset()
    for command in (0.5, -1.5, 3.0):
        states = hold(env, 0.2, command=command)
        assert states[-1].cart_vel[0] == pytest.approx(command, abs=0.02)
        # Within one control step the servo has it nearly there.
        assert abs(states[0].cart_vel[0] - command) < 0.1 * abs(command) + 0.05


def test_position_control_reaches_commanded_position(make_cartpole_env):
    env = make_cartpole_env(1, reset_noise=0.0, control_type="position")
    env.reset()
    states = hold(env, 2.0, command=0.5)
    assert states[-1].cart_pos[0] == pytest.approx(0.5, abs=0.02)


def test_effort_control_accelerates_by_force(make_cartpole_env):
    env = make_cartpole_env(1, reset_noise=0.0, control_type="effort")
    env.reset()
    env.task.robot.set_joint_states(env.physics, ALL, 0.0, 0.0, 0.0, 0.0)
    states = hold(env, 0.08, command=35.0)
    # A free-hinged rod adds a quarter of its mass at first: a = F / (2.5 + 1.0 / 4).
    assert states[-1].cart_vel[0] == pytest.approx(35.0 / 2.75 * 0.08, rel=0.03)
    assert states[-1].pole_angle[0] < -0.05  # the pole swings back as the cart pulls away


def test_actions_accumulate_the_velocity_command(make_cartpole_env):
    env = make_cartpole_env(1, reset_noise=0.0)
    td = env.reset()
    for action, expected in ((1, 1.0), (1, 2.0), (0, 1.0), (0, 0.0), (0, -1.0)):
        td["action"] = torch.tensor([action])
        td = env.step(td)["next"]
        assert env.physics.ctrl[0, 0] == expected
        assert td["observation"][0, 1].item() == pytest.approx(expected, abs=0.05)


def test_four_actions_take_ten_times_the_step(make_cartpole_env):
    env = make_cartpole_env(1, reset_noise=0.0, n_actions=4)
    td = env.reset()
    td["action"] = torch.tensor([3])
    env.step(td)
    assert env.physics.ctrl[0, 0] == pytest.approx(10.0)
    td["action"] = torch.tensor([2])
    env.step(td)
    assert env.physics.ctrl[0, 0] == pytest.approx(0.0)


def test_cart_beyond_rail_limit_terminates(make_cartpole_env):
    env = make_cartpole_env(1, reset_noise=0.0)
    td = env.reset()
    # Keep the pole up artificially so only the cart position can end the episode.
    for step in range(200):
        td["action"] = torch.tensor([1 if step == 0 else 1 - (step % 2)])
        env.task.robot.set_joint_states(env.physics, ALL, env.physics.qpos[0, 0],
                                        env.physics.qvel[0, 0], 0.0, 0.0)
        out = env.step(td)["next"]
        x = out["observation"][0, 0].item()
        if out["done"].item():
            assert out["terminated"].item() and not out["truncated"].item()
            assert x >= 1.0
            break
        assert x < 1.0
        td = out
    else:
        pytest.fail("cart never reached the rail limit")


def test_time_limit_is_truncation_not_termination(make_cartpole_env):
    env = make_cartpole_env(1, reset_noise=0.0, max_episode_steps=1000)
    td = env.reset()
    for step in range(1000):
        # Freeze the robot upright: the only way to end is the time limit.
        env.task.robot.set_joint_states(env.physics, ALL, 0.0, 0.0, 0.0, 0.0)
        td["action"] = torch.tensor([step % 2])
        out = env.step(td)["next"]
        if step < 999:
            assert not out["done"].item()
        td = out
    assert out["truncated"].item() and out["done"].item() and not out["terminated"].item()


def test_pole_angle_limit_terminates(make_cartpole_env):
    env = make_cartpole_env(1, reset_noise=0.0)
    td = env.reset()
    env.task.robot.set_joint_states(env.physics, ALL, 0.0, 0.0, 0.3, 0.0)
    for _ in range(100):
        td["action"] = torch.tensor([0])  # pushes the cart away from under the pole
        out = env.step(td)["next"]
        if out["done"].item():
            break
        td = out
    assert out["terminated"].item()
    assert abs(out["observation"][0, 2].item()) >= 0.7


def test_reset_perturbation_is_small_and_seeded(make_cartpole_env):
    env = make_cartpole_env(64, seed=3)
    obs = env.reset()["observation"].numpy()
    assert np.all(np.abs(obs) <= 0.05 + 1e-9)
    assert obs.std(0).min() > 0.01
    env.set_seed(3)
    np.testing.assert_array_equal(env.reset()["observation"].numpy(), obs)


@pytest.mark.parametrize("bad", [dict(n_actions=3), dict(control_type="torque"),
                                 dict(running_step=0.041), dict(pos_step=-1.0),
                                 dict(min_pole_angle=0.7, max_pole_angle=-0.7)])
def test_bad_task_parameters_name_the_key(bad):
    with pytest.raises((ConfigError, ValueError)) as err:
        StayUp(CartPole(), **bad)
    assert any(key in str(err.value) for key in bad) or "control_type" in str(err.value)
