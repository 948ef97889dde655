"""A declared task's start state per joint (tasks/start.py): its own ranges, a pair of slides
over a disc, the joint's limits, the shared noise on the others, and one line for a mistake."""

from __future__ import annotations

import numpy as np
import pytest

from params import ConfigError
from tasks import catalog, factory

N = 4000  # copies: their starts are the distribution's samples


def started(robot: str, *reset: str) -> np.ndarray:
    """The ``qpos`` and ``qvel`` of N copies just started with ``task.reset`` replaced by ``reset``."""
    cfg = catalog.compose(robot, overrides=["~task.reset", *(f"+task.reset.{r}" for r in reset)])
    env = factory.build_env(cfg, N, 0)
    env.reset()
    state = np.concatenate([env.physics.qpos.copy(), env.physics.qvel.copy()], axis=1)
    env.close()
    return state


def test_a_joint_takes_its_own_ranges_and_the_others_the_shared_noise():
    s = started("acrobot", "joints={shoulder: 3.0, elbow: {position: [-0.5, 0.5], velocity: [-1, 1]}}",
                "position_noise=0.1", "velocity_noise=0.2")
    shoulder, elbow, shoulder_vel, elbow_vel = s.T
    assert 2.9 <= shoulder.min() < 2.91 and 3.09 < shoulder.max() <= 3.1  # 3 +- the shared 0.1
    assert -0.5 <= elbow.min() < -0.49 and 0.49 < elbow.max() <= 0.5  # its own range, no noise added
    assert np.abs(shoulder_vel).max() <= 0.2 and 0.19 < np.abs(shoulder_vel).max()
    assert -1 <= elbow_vel.min() < -0.99 and 0.99 < elbow_vel.max() <= 1


def test_a_pair_of_slides_is_uniform_over_a_disc_at_rest():
    s = started("point_mass", "disc={joints: [root_x, root_y], radius: 0.2, center: [0.05, 0.0]}")
    x, y = s[:, 0] - 0.05, s[:, 1]
    r = np.hypot(x, y)
    assert r.max() <= 0.2 and r.max() > 0.199
    assert abs((r ** 2).mean() / 0.04 - 0.5) < 0.02  # uniform over the area: E[r^2] = R^2 / 2
    assert abs(np.mean(x > 0) - 0.5) < 0.03 and abs(np.mean(y > 0) - 0.5) < 0.03
    assert not s[:, 2:].any()  # at rest


def test_positions_stay_within_a_limited_joints_range_unless_asked():
    clipped = started("double_pendulum", "joints={slider: {position: [-2, 2]}}")
    assert clipped[:, 0].min() == -1.0 and clipped[:, 0].max() == 1.0  # the slide's range
    free = started("double_pendulum", "joints={slider: {position: [-2, 2], within_limits: false}}")
    assert free[:, 0].min() < -1.5 and free[:, 0].max() > 1.5


@pytest.mark.parametrize("reset, says", [
    ("joints={elbow: {position: [1, 0]}}", r"task.reset.joints.elbow.position must be a number or \[low, high\]"),
    ("joints={elbow: {speed: 1}}", "task.reset.joints.elbow takes position, velocity, within_limits"),
    ("joints={elbo: 1.0}", "the model has no joint 'elbo'; close matches: elbow"),
    ("disc={joints: [shoulder], radius: 0.1}", "task.reset.disc.joints must name two joints"),
    ("disc={joints: [shoulder, elbow], radius: -1}", "task.reset.disc.radius must be a number > 0"),
    ("spread=1", "task.reset takes joints, disc, position_noise, velocity_noise"),
])
def test_a_mistake_in_the_start_state_is_one_line(reset, says):
    with pytest.raises(ConfigError, match=says) as err:
        started("acrobot", reset)
    assert "\n" not in str(err.value)
