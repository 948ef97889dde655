"""No setting fakes a verdict: a policy that acts at random never meets any task's success
threshold (its own measure, as a greedy evaluation reads it), over valid robot and task
settings drawn by hypothesis; settings that would blind a task's measure are refused.

The maze and the wall judge a collision by the laser (a reading below ``min_range``), so
a fan that cannot see the sides (``robot.laser_rays=1`` drove 3.6 "laps" a centimetre from
the outer wall) is refused by ``tasks.maze.MazeTask``.
"""

from __future__ import annotations

import math

import pytest
import torch
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from params import ConfigError
from runs.evaluate import evaluate, measure_of
from tasks.catalog import compose, default_task, robot_names
from tasks.factory import build_env
from tasks.maze import MAX_RAY_GAP

COPIES = 8


def random_verdict(cfg, seed: int) -> tuple[float, float]:
    """(the task's measure over ``COPIES`` episodes of uniformly random actions, its threshold)."""
    env = build_env(cfg, COPIES, seed)
    generator = torch.Generator().manual_seed(seed)
    n = env.task.n_actions

    def act(td):
        td["action"] = torch.randint(0, n, (td.batch_size[0],), generator=generator)
        return td

    try:
        result = evaluate(env, act)
    finally:
        env.close()
    success = env.task.success
    return measure_of(result, success.measure), success.threshold


@pytest.mark.parametrize("robot", robot_names())
def test_a_random_policy_fails_every_robots_default_task(robot):
    value, threshold = random_verdict(compose(robot, default_task(robot)), seed=7)
    assert value < threshold, (robot, value, threshold)


@settings(max_examples=8, deadline=None, database=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(task=st.sampled_from(["maze", "wall"]), fov=st.floats(math.pi, 2 * math.pi), data=st.data(),
       min_range=st.floats(0.2, 1.5), seed=st.integers(0, 10_000))
def test_no_valid_laser_setting_lets_a_random_policy_pass_the_maze(task, fov, data, min_range, seed):
    fewest = math.ceil(fov / MAX_RAY_GAP - 1e-6) + (0 if fov >= 2 * math.pi - 1e-6 else 1)
    rays = data.draw(st.integers(fewest, 4 * fewest))
    overrides = [f"robot.laser_rays={rays}", f"robot.laser_fov={fov}", f"task.min_range={min_range}"]
    value, threshold = random_verdict(compose("turtlebot", task, overrides=overrides), seed)
    assert value < threshold, (overrides, value, threshold)


@pytest.mark.parametrize("setting", ["robot.laser_rays=1", "robot.laser_fov=2.0", "robot.laser_rays=18",
                                     "robot.laser_fov=6.2831853"])
def test_a_fan_that_cannot_see_the_sides_is_refused(setting):
    with pytest.raises(ConfigError, match="judges a collision by the laser"):
        build_env(compose("turtlebot", "maze", overrides=[setting]), 1, 0)
