"""Small pieces every task uses: argument checks, substeps, tabular state bounds.

A task is a plain class that *has* a robot and provides:

``n_actions``, ``observation_names``, ``n_substeps``, ``max_episode_steps``,
``tabular_state`` (:class:`Bounds`), ``build_arena()``, ``bind(physics)``,
``initialize_episode(physics, mask, rng)``, ``apply_action(physics, action)``,
``observation(physics)``, ``terminated(physics, obs)`` and
``reward(physics, obs, terminated)``, all over the whole batch of copies.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np


class ConfigError(ValueError):
    """A parameter value the task, robot or learner cannot honour."""


def require(condition: bool, what: str, got: Any) -> None:
    """Raises :class:`ConfigError` ``"<what>; got <got>"`` unless ``condition``."""
    if not condition:
        raise ConfigError(f"{what}; got {got!r}")


def finite(value: Any) -> bool:
    """Whether ``value`` is a real number (not a bool), neither NaN nor infinite."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def whole(value: Any) -> bool:
    """Whether ``value`` is a finite number with an integer value (``3`` or ``3.0``)."""
    return finite(value) and float(value).is_integer()


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
