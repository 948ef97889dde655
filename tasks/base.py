"""Small pieces every task uses: argument checks, substeps, tabular state bounds.

A task is a plain class that *has* a robot and provides:

``n_actions``, ``observation_names``, ``n_substeps``, ``max_episode_steps``,
``tabular_state`` (:class:`Bounds`), ``build_arena()``, ``bind(physics)``,
``initialize_episode(physics, mask, rng)``, ``apply_action(physics, action)``,
``observation(physics)``, ``terminated(physics, obs)`` and
``reward(physics, obs, terminated)``, all over the whole batch of copies;
``success`` (:class:`Success`, what "solved" means for it) and, unless its
measure is the episode length, ``episode_info(physics)`` holding that measure.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from params import finite, require, whole


def substeps_for(running_step: float, timestep: float) -> int:
    """How many physics steps of ``timestep`` make one control step."""
    require(finite(running_step) and running_step > 0,
            "task.running_step must be a finite number > 0", running_step)
    require(finite(timestep) and timestep > 0,
            "task.physics_timestep must be a finite number > 0", timestep)
    n = round(running_step / timestep)
    require(
        n >= 1 and abs(n * timestep - running_step) < 1e-9,
        f"task.running_step must be a whole multiple of task.physics_timestep ({timestep})",
        running_step,
    )
    return int(n)


@dataclass(frozen=True)
class Bounds:
    """Which observation entries form a tabular state, and the range of each."""

    names: tuple[str, ...]
    indices: tuple[int, ...]
    low: np.ndarray
    high: np.ndarray

    @classmethod
    def from_config(cls, spec: Mapping[str, Sequence[float]], observation_names: Sequence[str]):
        require(isinstance(spec, Mapping),
                "task.tabular_state must map observation names to [low, high]", spec)
        names, indices, low, high = [], [], [], []
        for name, pair in spec.items():
            require(name in observation_names,
                    f"task.tabular_state entries must be among {list(observation_names)}", name)
            require(isinstance(pair, (Sequence, np.ndarray)) and not isinstance(pair, str)
                    and len(pair) == 2 and all(finite(v) for v in pair),
                    f"task.tabular_state.{name} must be [low, high], two finite numbers", pair)
            lo, hi = pair
            require(lo < hi, f"task.tabular_state.{name} must be [low, high] with low < high",
                    [lo, hi])
            names.append(name)
            indices.append(list(observation_names).index(name))
            low.append(float(lo))
            high.append(float(hi))
        require(len(names) > 0, "task.tabular_state must name at least one observation", dict(spec))
        return cls(tuple(names), tuple(indices), np.asarray(low), np.asarray(high))


JUDGES = ("training", "greedy")


@dataclass(frozen=True)
class Success:
    """What "solved" means for a task: a per-episode measure and a threshold on it.

    ``measure`` names the value an episode is scored by: ``"length"`` (its
    number of steps) or a key of the task's ``episode_info``. ``judge`` says
    which episodes decide: ``"training"``, the mean over the last ``window``
    training (exploring) episodes, or ``"greedy"``, the mean over one greedy
    evaluation's episodes. Either way the verdict is ``>= threshold`` after at
    least ``min_episodes`` training episodes; an infinite threshold never
    solves (the whole episode budget runs).
    """

    measure: str
    unit: str
    description: str
    threshold: float
    judge: str = "training"
    window: int = 100
    min_episodes: int = 100

    KEYS = ("measure", "threshold", "judge", "window", "min_episodes")

    @classmethod
    def from_config(cls, win: Mapping[str, Any] | None, default: "Success",
                    measures: Mapping[str, tuple[str, str]]) -> "Success":
        """``default`` with the entries of ``task.win`` applied; ``measures`` maps each
        measure the task offers to its (unit, description)."""
        win = dict(win or {})
        require(isinstance(win, dict), f"task.win must map {', '.join(cls.KEYS)} to values", win)
        unknown = sorted(set(win) - set(cls.KEYS))
        require(not unknown, f"task.win entries must be among {', '.join(cls.KEYS)}",
                ", ".join(map(str, unknown)))
        measure = win.get("measure", default.measure)
        require(measure in measures, f"task.win.measure must be one of {', '.join(measures)}", measure)
        threshold = win.get("threshold", default.threshold)
        require(isinstance(threshold, numbers.Real) and not isinstance(threshold, bool)
                and not math.isnan(threshold),
                "task.win.threshold must be a number (inf: never solved, the whole budget runs)",
                threshold)
        judge = win.get("judge", default.judge)
        require(judge in JUDGES, f"task.win.judge must be one of {', '.join(JUDGES)}", judge)
        window = win.get("window", default.window)
        require(whole(window) and 1 <= window <= 1_000_000,
                "task.win.window must be an integer in [1, 1000000]", window)
        min_episodes = win.get("min_episodes", default.min_episodes)
        require(whole(min_episodes) and min_episodes >= 0,
                "task.win.min_episodes must be an integer >= 0", min_episodes)
        unit, description = measures[measure]
        return cls(measure, unit, description, float(threshold), judge, int(window), int(min_episodes))

    def met(self, value: float, episodes: int) -> bool:
        """Whether a mean ``value`` of the measure, after ``episodes`` training episodes, solves."""
        return episodes >= max(self.min_episodes, 1) and value >= self.threshold

    def describe(self) -> str:
        """``"distance walked towards +y >= 1 m"``: the rule in words."""
        return f"{self.description} >= {self.threshold:g} {self.unit}".rstrip()
