"""A DQN's replay rows: transitions as plain tensors, and one float row per transition.

A row is the observation, the next observation, the action, the reward and ``terminated``
(and, for an n-step row, the rewards it sums: :mod:`learners.nstep`); :func:`pack` makes
rows and :func:`unpack` reads them back as views.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from tensordict import TensorDictBase


class Transitions(NamedTuple):
    """Transitions as plain tensors: ``observation`` and ``next_observation`` ``[..., n_obs]``,
    ``action`` ``[..., 1]`` (int64; a continuous action: float ``[..., dims]``), ``reward`` ``[..., 1]``, ``terminated`` ``[..., 1]`` (bool);
    ``steps`` ``[..., 1]``: the rewards an n-step row sums (:mod:`learners.nstep`; None: one)."""

    observation: torch.Tensor
    action: torch.Tensor
    reward: torch.Tensor
    next_observation: torch.Tensor
    terminated: torch.Tensor
    steps: torch.Tensor | None = None

    @classmethod
    def of(cls, td: TensorDictBase) -> Transitions:
        """The transitions of a TorchRL tensordict (``observation``, ``action``, ``next``)."""
        n, nxt = td.numel(), td.get("next")
        return cls(td.get("observation").reshape(n, -1), td.get("action").reshape(n, -1),
                   nxt.get("reward").reshape(n, 1), nxt.get("observation").reshape(n, -1),
                   nxt.get("terminated").reshape(n, 1))


def pack(batch: Transitions) -> torch.Tensor:
    """One float row per transition: observation, next observation, action, reward, terminated
    (and steps, for n-step rows)."""
    dtype = batch.observation.dtype
    steps = () if batch.steps is None else (batch.steps.to(dtype),)
    return torch.cat((batch.observation, batch.next_observation, batch.action.to(dtype),
                      batch.reward.to(dtype), batch.terminated.to(dtype), *steps), dim=-1)


def unpack(rows: torch.Tensor, continuous: int = 0) -> Transitions:
    """The :class:`Transitions` of rows made by :func:`pack` (``[..., width]``; views, but
    action and terminated); an odd width carries ``steps``. ``continuous``: the rows hold
    that many float action numbers (a continuous action; views too), not one action index."""
    if continuous:
        n, d = (rows.shape[-1] - 2 - continuous) // 2, continuous
        return Transitions(rows[..., :n], rows[..., 2 * n:2 * n + d], rows[..., 2 * n + d:2 * n + d + 1],
                           rows[..., n:2 * n], rows[..., 2 * n + d + 1:2 * n + d + 2] != 0)
    n = (rows.shape[-1] - 3) // 2
    steps = rows[..., 2 * n + 3:] if rows.shape[-1] == 2 * n + 4 else None
    return Transitions(rows[..., :n], rows[..., 2 * n:2 * n + 1].long(), rows[..., 2 * n + 1:2 * n + 2],
                       rows[..., n:2 * n], rows[..., 2 * n + 2:2 * n + 3] != 0, steps)
