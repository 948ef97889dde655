"""Distributional values, C51 (Bellemare et al. 2017; Rainbow's), for the DQN family.

The network gives, per action, logits over ``atoms`` fixed returns ``z`` evenly spaced on
``[v_min, v_max]`` (the support), laid out ``[atoms, actions]`` as TorchRL's
``DistributionalQValueActor`` reads them; an action's value is its distribution's mean.
The target of a transition is the next state's distribution, of the action the online
network's means pick (double DQN) or the target's, shifted by the reward and shrunk by the
discount (``gamma^k`` for an n-step row, nothing bootstrapped after a termination), clipped
to the support and projected back onto it; the loss is its cross-entropy with the predicted
distribution of the taken action, as TorchRL's ``DistributionalDQNLoss`` computes it
(``tests/test_distributional.py`` holds them equal).
"""

from __future__ import annotations

from typing import Callable

import torch

from learners.transitions import Transitions

Logits = Callable[[torch.Tensor], torch.Tensor]  # observations -> logits [..., atoms * actions]


def support(atoms: int, v_min: float, v_max: float) -> torch.Tensor:
    """The ``atoms`` returns the distributions are over."""
    return torch.linspace(v_min, v_max, atoms)


def log_probabilities(logits: torch.Tensor, atoms: int) -> torch.Tensor:
    """``[..., atoms, actions]`` log-probabilities of flat logits ``[..., atoms * actions]``
    (computed over a contiguous last axis: on the CPU about 3x faster than over the strided
    atoms axis, ``bench/update_rate.py --switches``)."""
    by_action = logits.unflatten(-1, (atoms, -1)).transpose(-1, -2).contiguous()
    return by_action.log_softmax(-1).transpose(-1, -2)


def expected(logits: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """Each action's mean return ``[..., actions]`` from flat logits."""
    return (log_probabilities(logits, len(z)).exp() * z.unsqueeze(-1)).sum(-2)


def project(next_probability: torch.Tensor, reward: torch.Tensor, discount: torch.Tensor | float,
            terminated: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
    """The distribution ``next_probability`` (``[..., atoms]``) moved to ``reward + discount z``
    (none of it after a termination), clipped to the support and split between the two
    atoms each return falls between, in proportion to its closeness (mass that falls on an
    atom exactly stays whole there, as TorchRL's fix of ``l == u`` keeps it: its share of
    the atom above is 0). One floor and two scatters: half the time of TorchRL's floor,
    ceil and two corrections."""
    atoms, v_min, v_max = len(z), float(z[0]), float(z[-1])
    delta = (v_max - v_min) / (atoms - 1)
    shifted = (reward + (1 - terminated.to(reward.dtype)) * discount * z).clamp(v_min, v_max)
    b = (shifted - v_min) / delta
    low = b.floor()
    above = b - low  # the share of the atom above
    low_index = low.long()
    up_index = (low_index + 1).clamp_(max=atoms - 1)  # at v_max its share is 0
    m = torch.zeros_like(next_probability)
    m.scatter_add_(-1, low_index, next_probability * (1 - above))
    m.scatter_add_(-1, up_index, next_probability * above)
    return m


def c51_terms(net: Logits, target_net: Logits, batch: Transitions, gamma: torch.Tensor | float, double_dqn: bool,
              z: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(loss, q, target)`` of ``batch`` (each ``[..., batch, 1]``), and the projected targets
    ``[..., batch, atoms]``: the cross-entropy per transition, the taken actions' mean values
    and their targets' means (no gradient)."""
    atoms = len(z)
    log_p = log_probabilities(net(batch.observation), atoms)
    taken = batch.action.unsqueeze(-2).expand(*batch.action.shape[:-1], atoms, 1)
    log_p_taken = log_p.gather(-1, taken).squeeze(-1)
    with torch.no_grad():
        next_p = log_probabilities(target_net(batch.next_observation), atoms).exp()
        means = expected(net(batch.next_observation), z) if double_dqn else (next_p * z.unsqueeze(-1)).sum(-2)
        best = means.argmax(-1, keepdim=True).unsqueeze(-2).expand(*means.shape[:-1], atoms, 1)
        next_probability = next_p.gather(-1, best).squeeze(-1)
        discount = gamma if batch.steps is None else gamma ** batch.steps
        m = project(next_probability, batch.reward, discount, batch.terminated, z)
        q = (log_p_taken.detach().exp() * z).sum(-1, keepdim=True)
        target = (m * z).sum(-1, keepdim=True)
    loss = -(m * log_p_taken).sum(-1, keepdim=True)
    return loss, q, target, m


__all__ = ["c51_terms", "expected", "log_probabilities", "project", "support"]
