"""Small pieces every task uses: argument checks, substeps, tabular state bounds.

A task is a plain class that *has* a robot and provides:

``n_actions``, ``observation_names``, ``n_substeps``, ``max_episode_steps``,
``tabular_state`` (:class:`Bounds`), ``build_arena()``, ``bind(physics)``,
``initialize_episode(physics, mask, rng)``, ``apply_action(physics, action)``,
``observation(physics)``, ``terminated(physics, obs)`` and
``reward(physics, obs, terminated)``, all over the whole batch of copies.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np


class ConfigError(ValueError):
    """A parameter value the task, robot or learner cannot honour."""


def require(condition: bool, what: str, got: Any) -> None:
    """Raises :class:`ConfigError` ``"<what>; got <got>"`` unless ``condition``."""
    if not condition:
        raise ConfigError(f"{what}; got {got!r}")


def substeps_for(running_step: float, timestep: float) -> int:
    """How many physics steps of ``timestep`` make one control step."""
    require(running_step > 0, "task.running_step must be > 0", running_step)
    require(timestep > 0, "task.physics_timestep must be > 0", timestep)
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
        names, indices, low, high = [], [], [], []
        for name, (lo, hi) in spec.items():
            require(name in observation_names,
                    f"tabular_state entries must be among {list(observation_names)}", name)
            require(lo < hi, f"tabular_state.{name} must be [low, high] with low < high", [lo, hi])
            names.append(name)
            indices.append(list(observation_names).index(name))
            low.append(float(lo))
            high.append(float(hi))
        require(len(names) > 0, "tabular_state must name at least one observation", dict(spec))
        return cls(tuple(names), tuple(indices), np.asarray(low), np.asarray(high))
