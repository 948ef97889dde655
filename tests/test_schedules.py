"""The epsilon schedules of the DQN variants follow their formulas."""

import math

import pytest

from learners.schedules import LinearEpsilon, LogEpisodeEpsilon, MultiplicativeEpsilon
from params import ConfigError


def test_n1try_log_schedule_per_episode():
    s = LogEpisodeEpsilon(epsilon=1.0, epsilon_min=0.01, epsilon_decay=0.995)
    seen = []
    for e in range(12):
        expected = max(0.01, min(s.cap, 1.0 - math.log10((e + 1) * 0.995)))
        assert s.value == pytest.approx(expected)
        seen.append(s.value)
        s.step(100)  # steps do not move it
        s.episode_end()
    assert seen[0] == pytest.approx(1.0) and seen[1] == pytest.approx(1 - math.log10(1.99))
    assert seen[-1] == 0.01  # by episode 10 the log term is below the floor


def test_multiplicative_per_step_and_per_episode_with_floor():
    per_step = MultiplicativeEpsilon(epsilon=1.0, epsilon_min=0.1, decay=0.99, per="step")
    per_step.step(10)
    per_step.episode_end()
    assert per_step.value == pytest.approx(0.99**10)
    per_step.step(1000)
    assert per_step.value == 0.1
    per_episode = MultiplicativeEpsilon(epsilon=1.0, epsilon_min=0.1, decay=0.995, per="episode")
    per_episode.step(50)
    assert per_episode.value == 1.0
    per_episode.episode_end()
    assert per_episode.value == pytest.approx(0.995)


def test_linear_schedule():
    s = LinearEpsilon(epsilon=1.0, epsilon_min=0.1, steps=100)
    s.step(50)
    assert s.value == pytest.approx(0.55)
    s.step(500)
    assert s.value == pytest.approx(0.1)


@pytest.mark.parametrize("make", [
    lambda: LogEpisodeEpsilon(epsilon=1.5),
    lambda: MultiplicativeEpsilon(epsilon=0.5, epsilon_min=0.6),
    lambda: MultiplicativeEpsilon(per="week"),
    lambda: LinearEpsilon(steps=0),
])
def test_bad_schedule_values_are_config_errors(make):
    with pytest.raises(ConfigError, match="got"):
        make()
