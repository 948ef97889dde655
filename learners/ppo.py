"""Proximal policy optimisation with the clipped objective (Schulman et al. 2017), written for one member.

One member's algorithm (CleanRL's ``ppo_continuous_action.py`` reads alike): a tanh-squashed
Gaussian policy (the same head as :mod:`learners.sac`; a ``ProbabilisticActor`` in
``model.pt``) and a value network, learning from rollouts of ``rollout_steps`` env steps:
advantages by GAE (TorchRL's ``generalized_advantage_estimate``), then ``epochs`` passes
of ``minibatches`` minibatches, each the losses of TorchRL's ``ClipPPOLoss``: the clipped
surrogate ``-min(r A, clip(r, 1 - eps, 1 + eps) A)`` (advantages normalised within the
minibatch), ``critic_coef`` times the value's squared error to its GAE target, less
``entropy_coef`` times the Gaussian's entropy; one Adam step of both networks, their
gradients clipped together.

The seeds and trials of a batch are one layer beneath (:class:`learners.member.RolloutLearner`:
networks, Adam, rollouts, streams); :func:`ppo_losses` computes the losses of every member
in one call, with ClipPPOLoss's numbers (``tests/test_ppo.py``). Old log-probabilities are
those of the pre-tanh values the policy drew (kept in the rollout), so a saturated action's
ratio is exact rather than recovered through ``atanh``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import torch
from torch import nn

from learners.device import DEVICE_NOTE, check_device, resolve_device
from learners.member import GroupStep, Losses, RolloutLearner, lanes, obs_scale_param
from learners.continuous import (ACTIVATIONS, LOG_SQRT_2PI, GaussianHead, log_prob_of, mlp, squash, squashed,
                                 tanh_normal_actor)
from params import require
from params.declare import check_fields, param


def ppo_losses(actor: Callable, critic: Callable, minibatch: Mapping[str, torch.Tensor], clip_epsilon: float,
               critic_coef: float, entropy_coef: float, normalize_advantage: bool = True) -> dict[str, torch.Tensor]:
    """ClipPPOLoss's terms on a minibatch (``[k, S, ...]``, a member's rows each): per member
    ``loss_objective``, ``loss_critic`` and ``loss_entropy`` ``[k]``, with the critic's
    ``value`` and its ``target`` ``[k, S, 1]``, the ``entropy`` and ``clip_fraction``."""
    loc, scale = actor(minibatch["observation"])
    log_prob = log_prob_of(loc, scale, minibatch["preimage"])
    ratio = lanes(torch.exp, log_prob - minibatch["log_prob"])
    advantage = minibatch["advantage"]
    if normalize_advantage and advantage.shape[1] > 1:
        advantage = (advantage - advantage.mean(1, keepdim=True)) / advantage.std(1, keepdim=True).clamp_min(1e-6)
    surrogate = torch.minimum(ratio * advantage, ratio.clamp(1.0 - clip_epsilon, 1.0 + clip_epsilon) * advantage)
    value = critic(minibatch["observation"])
    target = minibatch["returns"].unsqueeze(-1)
    entropy = (0.5 + LOG_SQRT_2PI + lanes(torch.log, scale)).sum(-1)  # the Gaussian's, before tanh
    clipped = ((ratio - 1.0).abs() > clip_epsilon).float()
    return {"loss_objective": -surrogate.mean(1), "loss_critic": critic_coef * ((value - target) ** 2).mean((1, 2)),
            "loss_entropy": -entropy_coef * entropy.mean(1), "value": value, "target": target,
            "entropy": entropy.detach(), "clip_fraction": clipped}


@dataclass(eq=False)
class PPO(RolloutLearner):
    """PPO (see the module docstring), over :class:`RolloutLearner`."""

    hidden: list[int] = param([64, 64], "widths of the actor's and the critic's hidden layers")
    activation: str = param("tanh", "hidden layers' activation", choices=tuple(ACTIVATIONS))
    obs_scale: dict[str, float] | None = obs_scale_param()
    lr: float = param(3e-4, "Adam's learning rate of the actor and the critic", gt=0)
    gamma: float = param(0.99, "discount of the next state's value", ge=0, le=1)
    gae_lambda: float = param(0.95, "GAE's lambda (0: one-step TD advantages, 1: Monte Carlo)", ge=0, le=1)
    rollout_steps: int = param(2048, "env steps of each copy per rollout (the rollout holds that many x "
                                     "num_envs transitions)", ge=1, le=10**6)
    epochs: int = param(10, "passes over each rollout", ge=1, le=1000)
    minibatches: int = param(32, "minibatches per pass over the rollout's rollout_steps x num_envs "
                                 "transitions (a remainder sits each pass out)", ge=1, le=65_536)
    clip_epsilon: float = param(0.2, "the probability ratio's clip, 1 +- this", gt=0, lt=1)
    critic_coef: float = param(0.5, "weight of the value loss", ge=0)
    entropy_coef: float = param(0.0, "weight of the entropy bonus", ge=0)
    normalize_advantage: bool = param(True, "advantages normalised within each minibatch")
    grad_clip: float = param(0.5, "norm clip of the actor's and the critic's gradients together", ge=0,
                             note="0 = no clipping")
    reward_scale: float = param(1.0, "factor on every reward the learner stores", gt=0)
    device: str = param("cpu", "where the networks, updates and rollouts live", note=DEVICE_NOTE,
                        check=check_device)

    kind = "ppo"
    MEMBER_WISE = ("lr", "gamma", "gae_lambda", "grad_clip", "reward_scale")
    SIZING = ()

    def __post_init__(self) -> None:
        check_fields(self, "learner")
        require(1 <= len(self.hidden) <= 16 and all(1 <= h <= 65_536 for h in self.hidden),
                "learner.hidden must list 1 to 16 layer widths in [1, 65536]", self.hidden)
        require(self.minibatches <= self.rollout_steps, "learner.minibatches must be at most "
                f"learner.rollout_steps ({self.rollout_steps})", self.minibatches)
        self.hidden = [int(h) for h in self.hidden]
        self.device = str(resolve_device(self.device))

    def networks(self, task) -> dict[str, tuple[nn.Sequential, bool]]:
        """The actor (observation -> loc, scale of each action's Gaussian before tanh) and the
        critic (observation -> V)."""
        actor = nn.Sequential(*mlp(self.n_obs, 2 * self.n_actions, self.hidden, self.activation), GaussianHead())
        return {"actor": (actor, False), "critic": (mlp(self.n_obs, 1, self.hidden, self.activation), False)}

    def policy(self, template: nn.Sequential) -> nn.Module:
        """The actor as ``model.pt`` holds it (:func:`learners.sac.tanh_normal_actor`)."""
        return tanh_normal_actor(template)

    def draw_act(self, generator: torch.Generator, n: int) -> torch.Tensor:
        """One step's standard normal noise for ``n`` copies."""
        return torch.empty(n, self.n_actions).normal_(generator=generator)

    def act_with(self, actor: Callable, observation: torch.Tensor, noise: torch.Tensor | None) -> dict:
        """The squashed Gaussian's draw at ``noise`` (or, None, its deterministic action
        ``tanh(loc)``), with its pre-tanh value and log-probability, which the rollout keeps."""
        loc, scale = actor(observation)
        if noise is None:
            return {"action": squash(loc), "action_preimage": loc,
                    "action_log_prob": log_prob_of(loc, scale, loc)}
        action, log_prob = squashed(loc, scale, noise)
        return {"action": action, "action_preimage": loc + noise * scale, "action_log_prob": log_prob}

    def losses(self, actor: GroupStep, critic: GroupStep, minibatch: Mapping[str, torch.Tensor],
               own: Sequence[PPO]) -> Losses:
        """Each member's summed PPO losses; both networks step."""
        terms = ppo_losses(actor, critic, minibatch, self.clip_epsilon, self.critic_coef, self.entropy_coef,
                           self.normalize_advantage)
        loss = terms["loss_objective"] + terms["loss_critic"] + terms["loss_entropy"]
        extras = {"loss_objective": terms["loss_objective"].detach().unsqueeze(-1).expand_as(terms["entropy"]),
                  "entropy": terms["entropy"], "clip_fraction": terms["clip_fraction"]}
        return Losses(loss, ("actor", "critic"), (), terms["loss_critic"].detach(), terms["value"],
                      terms["target"], extras)


__all__ = ["PPO", "ppo_losses"]
