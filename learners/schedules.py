"""Exploration schedules TorchRL does not ship: each gives epsilon per step or per episode.

A schedule has ``value`` (the current epsilon), ``step(n)`` (``n`` env
transitions happened) and ``episode_end()`` (an episode finished). The learner reads
``value`` each time it acts, in its own epsilon-greedy draw over its members (the draw TorchRL's
``EGreedyModule`` makes: a uniform per copy, then a random action where it falls below epsilon).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from params import require
from params.declare import check_fields, param

PREFIX = "learner.epsilon"


def _start(default: float) -> Any:
    return param(default, "epsilon at the start", ge=0, le=1)


def _floor(default: float) -> Any:
    return param(default, "epsilon never goes below it (at most the start)", ge=0, le=1)


def _checked(schedule: Any) -> None:
    check_fields(schedule, PREFIX)
    require(schedule.epsilon_min <= schedule.epsilon,
            f"{PREFIX}.epsilon_min must be in [0, epsilon] = [0, {schedule.epsilon}]",
            schedule.epsilon_min)


@dataclass(eq=False)
class LogEpisodeEpsilon:
    """n1try: per episode e, max(min, min(cap, 1 - log10((e + 1) * decay))); the cap
    itself shrinks by ``epsilon_decay`` after each episode while above ``epsilon_min``."""

    epsilon: float = _start(1.0)
    epsilon_min: float = _floor(0.01)
    epsilon_decay: float = param(0.995, "the cap's factor per episode; also scales the log", gt=0,
                                 le=1)

    def __post_init__(self) -> None:
        _checked(self)
        self.cap, self.decay = self.epsilon, self.epsilon_decay
        self.episode = 0

    @property
    def value(self) -> float:
        logged = 1.0 - math.log10((self.episode + 1) * self.decay)
        return max(self.epsilon_min, min(self.cap, logged))

    def step(self, n: int = 1) -> None:
        pass

    def episode_end(self) -> None:
        self.episode += 1
        if self.cap > self.epsilon_min:
            self.cap *= self.decay

    def state_dict(self) -> dict:
        return {"cap": self.cap, "episode": self.episode}

    def load_state_dict(self, state: dict) -> None:
        self.cap, self.episode = state["cap"], state["episode"]


@dataclass(eq=False)
class MultiplicativeEpsilon:
    """epsilon <- max(epsilon_min, epsilon * decay) after every step (mbalunovic)
    or every episode (ruippeixotog), as ``per`` says."""

    epsilon: float = _start(1.0)
    epsilon_min: float = _floor(0.1)
    decay: float = param(0.99, "epsilon's factor per step or episode", gt=0, le=1)
    per: str = param("episode", "when it decays", choices=("step", "episode"))

    def __post_init__(self) -> None:
        _checked(self)
        self.value = self.epsilon

    def _decay(self, times: int) -> None:
        self.value = max(self.epsilon_min, self.value * self.decay**times)

    def step(self, n: int = 1) -> None:
        if self.per == "step":
            self._decay(n)

    def episode_end(self) -> None:
        if self.per == "episode":
            self._decay(1)

    def state_dict(self) -> dict:
        return {"value": self.value}

    def load_state_dict(self, state: dict) -> None:
        self.value = state["value"]


@dataclass(eq=False)
class LinearEpsilon:
    """From ``epsilon`` to ``epsilon_min`` linearly over ``steps`` env transitions."""

    epsilon: float = _start(1.0)
    epsilon_min: float = _floor(0.02)
    steps: int = param(3000, "env transitions from the start to the floor", ge=1)

    def __post_init__(self) -> None:
        _checked(self)
        self.start = self.epsilon
        self.done_steps = 0

    @property
    def value(self) -> float:
        frac = min(1.0, self.done_steps / self.steps)
        return self.start + frac * (self.epsilon_min - self.start)

    def step(self, n: int = 1) -> None:
        self.done_steps += n

    def episode_end(self) -> None:
        pass

    def state_dict(self) -> dict:
        return {"done_steps": self.done_steps}

    def load_state_dict(self, state: dict) -> None:
        self.done_steps = state["done_steps"]


class EpisodeDecayEpsilon:
    """The original Q-learner's: after each episode, epsilon *= ``discount`` while it is above
    ``epsilon_min`` (so it may end just below it); a member's own, made from its settings."""

    def __init__(self, epsilon: float, epsilon_min: float, discount: float) -> None:
        self.value, self.epsilon_min, self.discount = float(epsilon), float(epsilon_min), float(discount)

    def step(self, n: int = 1) -> None:
        pass

    def episode_end(self) -> None:
        if self.value > self.epsilon_min:
            self.value *= self.discount

    def state_dict(self) -> dict:
        return {"value": self.value}

    def load_state_dict(self, state: dict) -> None:
        self.value = float(state["value"])
