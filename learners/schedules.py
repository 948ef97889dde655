"""Exploration schedules TorchRL does not ship: each gives epsilon per step or per episode.

A schedule has ``value`` (the current epsilon), ``step(n)`` (``n`` env
transitions happened) and ``episode_end()`` (an episode finished). The learner
copies ``value`` into TorchRL's ``EGreedyModule`` before acting.
"""

from __future__ import annotations

import math

from params import finite, require, whole


def _check(epsilon: float, epsilon_min: float) -> None:
    require(finite(epsilon) and 0 <= epsilon <= 1, "learner.epsilon.epsilon must be in [0, 1]",
            epsilon)
    require(finite(epsilon_min) and 0 <= epsilon_min <= epsilon,
            f"learner.epsilon.epsilon_min must be in [0, epsilon] = [0, {epsilon}]", epsilon_min)


class LogEpisodeEpsilon:
    """n1try: per episode e, max(min, min(cap, 1 - log10((e + 1) * decay))); the cap
    itself shrinks by ``epsilon_decay`` after each episode while above ``epsilon_min``."""

    def __init__(self, epsilon: float = 1.0, epsilon_min: float = 0.01,
                 epsilon_decay: float = 0.995) -> None:
        _check(epsilon, epsilon_min)
        require(finite(epsilon_decay) and 0 < epsilon_decay <= 1,
                "learner.epsilon.epsilon_decay must be in (0, 1]", epsilon_decay)
        self.cap, self.epsilon_min, self.decay = float(epsilon), float(epsilon_min), float(epsilon_decay)
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


class MultiplicativeEpsilon:
    """epsilon <- max(epsilon_min, epsilon * decay) after every step (mbalunovic)
    or every episode (ruippeixotog), as ``per`` says."""

    def __init__(self, epsilon: float = 1.0, epsilon_min: float = 0.1, decay: float = 0.99,
                 per: str = "episode") -> None:
        _check(epsilon, epsilon_min)
        require(finite(decay) and 0 < decay <= 1, "learner.epsilon.decay must be in (0, 1]", decay)
        require(per in ("step", "episode"), "learner.epsilon.per must be step or episode", per)
        self.value, self.epsilon_min, self.decay, self.per = (
            float(epsilon), float(epsilon_min), float(decay), per)

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


class LinearEpsilon:
    """From ``epsilon`` to ``epsilon_min`` linearly over ``steps`` env transitions."""

    def __init__(self, epsilon: float = 1.0, epsilon_min: float = 0.05, steps: int = 10_000) -> None:
        _check(epsilon, epsilon_min)
        require(whole(steps) and steps >= 1, "learner.epsilon.steps must be an integer >= 1", steps)
        self.start, self.epsilon_min, self.steps = float(epsilon), float(epsilon_min), int(steps)
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
