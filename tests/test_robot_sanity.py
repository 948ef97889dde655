"""Physics sanity of every robot in conf/robot/, on its default task: the template
a new robot gets for free (docs/own-robot.md).

A robot's own physical facts (a pole falls without control, a spun-up wheel tips
the cube, a base stops at a wall) go in its own test file, as in
tests/test_cartpole.py; these checks hold for any robot:

- random actions for a few hundred steps never make the physics diverge;
- the actuators move the robot: the same start under two different action
  sequences ends in different states;
- copies of one batch are independent and the same seed repeats itself:
  copies started alike and driven alike stay bit-identical;
- left alone (the first action repeated), nothing flies off: speeds stay bounded.
"""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tasks import factory
from tasks import catalog

ROBOTS = catalog.robot_names()
STEPS = 200


def env_for(robot: str, num_envs: int, seed: int = 0):
    return factory.build_env(catalog.compose(robot), num_envs, seed)


def drive(env, actions: torch.Tensor) -> np.ndarray:
    """Steps ``env`` through ``actions`` (steps x copies) without resets; the final physics state."""
    td = env.reset()
    for a in actions:
        td = env.step(td.set("action", a))["next"]
    return env.physics.state.copy()


@pytest.mark.parametrize("robot", ROBOTS)
def test_random_actions_never_diverge(robot):
    env = env_for(robot, 8, seed=1)
    gen = torch.Generator().manual_seed(1)
    td = env.reset()
    for _ in range(STEPS):
        td.set("action", torch.randint(0, env.task.n_actions, (8,), generator=gen))
        _, td = env.step_and_maybe_reset(td)
        assert np.isfinite(env.physics.state).all()
    assert env.divergences == 0
    env.close()


@pytest.mark.parametrize("robot", ROBOTS)
def test_actions_move_the_robot(robot):
    env = env_for(robot, 2)
    n = env.task.n_actions
    # Copy 0 repeats action 0, copy 1 cycles through the others: both from one start.
    actions = torch.stack([torch.tensor([0, 1 + (t % (n - 1))]) for t in range(20)])
    td = env.reset()
    env.physics.state[1] = env.physics.state[0]
    for a in actions:
        td = env.step(td.set("action", a))["next"]
    qpos = env.physics.qpos
    assert np.abs(qpos[0] - qpos[1]).max() > 1e-3, "different actions left the robot where it was"
    env.close()


@pytest.mark.parametrize("robot", ROBOTS)
def test_copies_are_independent_and_repeatable(robot):
    gen = torch.Generator().manual_seed(2)
    env = env_for(robot, 4, seed=2)
    actions = torch.randint(0, env.task.n_actions, (50, 1), generator=gen).expand(50, 4)
    td = env.reset()
    env.physics.state[:] = env.physics.state[0]  # four copies, one start
    for a in actions:
        td = env.step(td.set("action", a))["next"]
    assert (env.physics.state == env.physics.state[0]).all(), "alike copies drifted apart"
    env.close()
    a, b = env_for(robot, 4, seed=3), env_for(robot, 4, seed=3)
    assert np.array_equal(drive(a, actions), drive(b, actions)), "the same seed did not repeat"
    a.close()
    b.close()


@pytest.mark.parametrize("robot", ROBOTS)
def test_left_alone_nothing_flies_off(robot):
    env = env_for(robot, 2)
    drive(env, torch.zeros((STEPS, 2), dtype=torch.int64))
    speed = np.abs(env.physics.qvel).max()
    assert np.isfinite(speed) and speed < 1e3, f"a joint moves at {speed:g} after {STEPS} steps"
    env.close()
