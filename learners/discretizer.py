"""Observation to tabular state index: equal bins per entry of the task's tabular state.

The task names which observation entries may form the tabular state and the range
``[low, high]`` of each (``task.tabular_state``, read as ``task.tabular_bounds``); the
learner's ``number_splits`` says how many equal bins each gets: one int for all, or a
mapping from entry name to bins (entries it leaves out get 1 bin, i.e. are ignored), or a
list in ``tabular_state`` order. Values outside a range fall into the end bins, and the
bins combine mixed-radix, first entry fastest::

    bin_i  = clip(floor((x_i - low_i) / (high_i - low_i) * splits_i), 0, splits_i - 1)
    index  = bin_0 + splits_0 * (bin_1 + splits_1 * (bin_2 + ...))
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np
import torch

from params import require
from tasks.base import Bounds

MAX_SPLITS = 2**31 - 1  # bins of one entry (torch's int32 indices); the table's size limits them further


class Discretizer:
    """Maps observations to tabular state indices (see the module docstring)."""

    def __init__(self, bounds: Bounds, splits: int | Sequence[int] | Mapping[str, int]) -> None:
        n = len(bounds.names)
        if isinstance(splits, Mapping):
            unknown = sorted(set(splits) - set(bounds.names))
            require(not unknown, f"learner.number_splits names must be among {list(bounds.names)}",
                    unknown)
            splits = [splits.get(name, 1) for name in bounds.names]
        elif isinstance(splits, (int, np.integer)):
            splits = [splits] * n
        splits = [int(s) for s in splits]
        require(len(splits) == n,
                f"learner.number_splits must be one int or one per tabular_state entry {list(bounds.names)}",
                splits)
        for name, s in zip(bounds.names, splits):
            require(1 <= s <= MAX_SPLITS, f"learner.number_splits.{name} must be an integer in "
                    f"[1, {MAX_SPLITS}] (1 = ignored)", s)
        self.bounds = bounds
        self.splits = splits
        self.n_states = math.prod(splits)  # Python ints: no overflow before the size check
        self._index = torch.as_tensor(bounds.indices)
        self._prefix = tuple(bounds.indices) == tuple(range(len(bounds.indices)))
        self._low = torch.as_tensor(bounds.low)
        self._width = torch.as_tensor(bounds.high - bounds.low)
        self._splits = torch.as_tensor(splits)
        self._top = self._splits - 1
        self._radix = torch.as_tensor(np.concatenate([[1], np.cumprod(splits)[:-1]]).astype(np.int64))

    def __call__(self, observation: torch.Tensor, rows: tuple[torch.Tensor, ...] | None = None) -> torch.Tensor:
        """Each observation's state index; ``rows``: each row's own ``(splits, top, radix)``
        (``[rows, entries]``: members of other bins side by side, :meth:`rows_of`), each row's
        index the one its own discretizer gives."""
        if self._prefix:  # the observation's first entries, in order: a view, no gather
            x = observation[..., : len(self._index)].to(torch.float64, copy=True)
        else:
            x = observation.index_select(-1, self._index).to(torch.float64)
        splits, top, radix = (self._splits, self._top, self._radix) if rows is None else rows
        bins = torch.minimum(x.sub_(self._low).div_(self._width).mul_(splits).floor_().long().clamp_min_(0), top)
        return bins @ radix if rows is None else (bins * radix).sum(-1)

    @staticmethod
    def rows_of(discretizers: Sequence[Discretizer], owner: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """``(splits, top, radix)`` of each row, row ``i`` discretized by
        ``discretizers[owner[i]]`` (all over the same bounds)."""
        return tuple(torch.stack([getattr(d, key) for d in discretizers]).index_select(0, owner)
                     for key in ("_splits", "_top", "_radix"))

    def describe(self) -> dict:
        return {
            "names": list(self.bounds.names),
            "low": self.bounds.low.tolist(),
            "high": self.bounds.high.tolist(),
            "splits": self.splits,
        }


class MemberDiscretizers:
    """Each member's :class:`Discretizer` (members may have their own ``number_splits``),
    those of equal splits one object; :meth:`__call__` maps every member's rows at once."""

    def __init__(self, bounds: Bounds, splits: Sequence[int | Sequence[int] | Mapping[str, int]]) -> None:
        made: dict[str, Discretizer] = {}
        self.each = [made.setdefault(repr(s), Discretizer(bounds, s)) for s in splits]
        self.alike = len(made) == 1
        self._rows: tuple[torch.Tensor, ...] | None = None  # every member's rows' bins, kept between steps

    def __call__(self, observation: torch.Tensor, members: Sequence[int] | None, n: int) -> torch.Tensor:
        """The state index of each row of ``observation``, ``n`` rows a member of ``members``
        (None: all), each by its member's own discretizer."""
        first = self.each[0]
        if self.alike:
            return first(observation)
        if members is None:
            if self._rows is None or len(self._rows[0]) != len(self.each) * n:
                self._rows = Discretizer.rows_of(self.each, torch.arange(len(self.each)).repeat_interleave(n))
            return first(observation, self._rows)
        if len(members) == 1:  # a member's own policy (its greedy evaluations): its own bins
            return self.each[members[0]](observation)
        return first(observation, Discretizer.rows_of(self.each, torch.as_tensor(list(members)).repeat_interleave(n)))


__all__ = ["MAX_SPLITS", "Discretizer", "MemberDiscretizers"]
