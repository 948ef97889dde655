"""Proportional prioritized replay of one replay buffer (Schaul et al. 2016; Rainbow's).

A row ``i`` is drawn with probability ``P(i) = p_i^alpha / sum_k p_k^alpha``, where
``p_i = |TD error| + eps`` from the last minibatch that held it; a row not yet in a
minibatch has the largest ``p`` seen so far (1 at first), so every new transition is likely
drawn soon. A minibatch is stratified: the total mass cut into ``batch`` equal segments, one
uniform draw in each. Each drawn row's importance weight corrects the update's bias::

    w_i = (N P(i))^-beta / max_k (N P(k))^-beta = (p_i^alpha / min_k p_k^alpha)^-beta

(TorchRL's ``PrioritizedSampler`` weight; its compiled sum tree does not load in torchrl
0.14.1 here). The draw is a cumulative sum and a binary search over the stored rows: one
vectorised pass per minibatch instead of a sum tree walked in Python
(``bench/update_rate.py`` prices it against a uniform draw).
"""

from __future__ import annotations

import torch


def annealed_beta(beta: float, updates: int, over: int) -> float:
    """``beta`` raised linearly to 1 over the first ``over`` updates."""
    return beta + (1.0 - beta) * min(1.0, updates / over)


class Priorities:
    """The priorities ``p^alpha`` of a buffer's ``capacity`` rows (float64; 0: never written)."""

    def __init__(self, capacity: int, alpha: float, eps: float, device: torch.device | str = "cpu") -> None:
        self.alpha, self.eps = float(alpha), float(eps)
        self.values = torch.zeros(capacity, dtype=torch.float64, device=device)
        # the largest p = |TD error| + eps so far, before alpha (a tensor: no host sync per update)
        self.max_priority = torch.ones((), dtype=torch.float64, device=device)

    def added(self, index: torch.Tensor) -> None:
        """Rows ``index`` were (over)written: each gets the largest priority so far."""
        self.values[index.to(self.values.device)] = self.max_priority ** self.alpha

    def sample(self, stored: int, batch: int, beta: float,
               generator: torch.Generator | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """``(index, weight)``: ``batch`` rows of the first ``stored`` drawn in proportion to
        their priorities (one per stratum), and their importance weights (float32)."""
        values = self.values[:stored]
        cumulative = values.cumsum(0)
        strata = torch.rand(batch, dtype=torch.float64, generator=generator).to(values.device)
        mass = (torch.arange(batch, dtype=torch.float64, device=values.device) + strata) * (cumulative[-1] / batch)
        index = torch.searchsorted(cumulative, mass, right=True).clamp_(max=stored - 1)
        weight = (values[index] / values.min()).pow_(-beta)
        return index, weight.float()

    def update(self, index: torch.Tensor, td_error: torch.Tensor) -> None:
        """The rows ``index`` of a minibatch take their new ``|td_error|`` (a row drawn twice:
        its later one)."""
        raw = td_error.detach().abs().reshape(-1).double() + self.eps
        self.values[index] = raw.pow(self.alpha)
        self.max_priority = torch.maximum(self.max_priority, raw.max())

    def state_dict(self) -> dict:
        return {"values": self.values.cpu().clone(), "max_priority": float(self.max_priority)}

    def load_state_dict(self, state: dict) -> None:
        self.values.copy_(state["values"])
        self.max_priority.fill_(float(state["max_priority"]))


__all__ = ["Priorities", "annealed_beta"]
