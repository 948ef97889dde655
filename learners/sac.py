"""Soft actor-critic (Haarnoja et al. 2018, with the learned temperature), written for one member.

One member's algorithm (CleanRL's ``sac_continuous_action.py`` reads alike): a tanh-squashed
Gaussian policy (TorchRL's ``MLP``, ``NormalParamExtractor`` and ``TanhNormal``; a
``ProbabilisticActor`` in ``model.pt``), twin Q-networks with Polyak-averaged targets, and
a temperature ``alpha`` tuned towards a target entropy. Per minibatch, the three losses of
TorchRL's ``SACLoss`` (its version 2, no value network): the critics' TD error to
``r + gamma * (min_i Q'_i(s', a') - alpha log pi(a'|s'))``, the actor's
``alpha log pi(a|s) - min_i Q_i(s, a)`` and the temperature's
``-log alpha * (log pi(a|s) + target entropy)``; then one Adam step of each.

The seeds and trials of a batch are one layer beneath (:class:`learners.member.ActorCriticLearner`:
their networks, optimizers, replay buffers and streams). :func:`sac_losses` computes the
losses for every member in one call rather than through ``SACLoss``: the same numbers
(``tests/test_sac.py``), with each member's sampling noise drawn from its own stream.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, Mapping, Sequence

import torch
from torch import nn

from learners.continuous import DISTANCES, GaussianHead, ReplaySettings, mlp, squash, squashed, tanh_normal_actor
from learners.device import resolve_device
from learners.member import ActorCriticLearner, GroupStep, Losses, check_replay_settings, lanes
from learners.transitions import Transitions
from params import require
from params.declare import check_fields, param

def sac_losses(actor: Callable, q1: GroupStep, q2: GroupStep, log_alpha: torch.Tensor, batch: Transitions,
               noise: torch.Tensor, gamma: float | torch.Tensor, target_entropy: float | torch.Tensor,
               distance: str = "l2") -> dict[str, torch.Tensor]:
    """SAC's losses on ``batch`` (``[k, B, ...]``, a member's rows each): ``loss_qvalue``,
    ``loss_actor`` and ``loss_alpha`` per transition ``[k, B, 1]``, with ``q`` (the first
    critic's values), ``target``, ``log_prob`` and ``alpha``. ``noise`` ``[k, 2, B, dims]``:
    each member's standard normal draws for the next actions, then the current ones.
    Terminated transitions do not bootstrap; truncated ones do."""
    alpha = lanes(torch.exp, log_alpha.detach()).unsqueeze(-1)  # [k, 1, 1]
    with torch.no_grad():
        next_action, next_log_prob = squashed(*actor(batch.next_observation), noise[:, 0])
        after = torch.cat((batch.next_observation, next_action), -1)
        soft = torch.minimum(q1.target(after), q2.target(after)) - alpha * next_log_prob.unsqueeze(-1)
        target = batch.reward + gamma * soft * ~batch.terminated
    taken = torch.cat((batch.observation, batch.action), -1)
    q = q1(taken)
    distance = DISTANCES[distance]
    loss_qvalue = distance(q, target, reduction="none") + distance(q2(taken), target, reduction="none")
    action, log_prob = squashed(*actor(batch.observation), noise[:, 1])
    chosen = torch.cat((batch.observation, action), -1)
    log_prob = log_prob.unsqueeze(-1)
    loss_actor = alpha * log_prob - torch.minimum(q1.frozen(chosen), q2.frozen(chosen))
    loss_alpha = -log_alpha.unsqueeze(-1) * (log_prob.detach() + target_entropy)
    return {"loss_qvalue": loss_qvalue, "loss_actor": loss_actor, "loss_alpha": loss_alpha, "q": q,
            "target": target, "log_prob": log_prob.detach(), "alpha": alpha.expand_as(q)}


@dataclass(eq=False)
class SAC(ReplaySettings, ActorCriticLearner):
    """Soft actor-critic (see the module docstring), over :class:`ActorCriticLearner`."""

    alpha_lr: float = param(3e-4, "Adam's learning rate of the temperature (log alpha)", gt=0)
    alpha_init: float = param(1.0, "the temperature alpha at the start (the entropy's weight)", gt=0)
    fixed_alpha: bool = param(False, "keep alpha at alpha_init (no tuning towards target_entropy)")
    target_entropy: float | None = param(None, "entropy the temperature is tuned towards, nats",
                                         note="null = minus the number of actions")
    tau: float = param(0.005, "Polyak averaging rate of the target critics", gt=0, le=1)

    kind = "sac"
    out_keys = ("action",)
    critic = "q1"
    MEMBER_WISE = ("lr", "alpha_lr", "alpha_init", "target_entropy", "gamma", "tau", "learning_starts",
                   "grad_clip", "reward_scale", "buffer_size", "batch_size", "updates")
    SIZING = ("buffer_size",)

    def __post_init__(self) -> None:
        check_fields(self, "learner")
        check_replay_settings(self)
        require(self.target_entropy is None or math.isfinite(self.target_entropy),
                "learner.target_entropy must be a finite number or null", self.target_entropy)
        self.device = str(resolve_device(self.device))

    # -- one member's networks -----------------------------------------------

    def networks(self, task) -> dict[str, tuple[nn.Sequential | None, bool]]:
        """The actor (observation -> loc, scale of each action's Gaussian before tanh), two
        critics ((observation, action) -> Q) with target copies, and log alpha."""
        actor = nn.Sequential(*mlp(self.n_obs, 2 * self.n_actions, self.hidden, self.activation), GaussianHead())
        critic = self.n_obs + self.n_actions
        return {"actor": (actor, False), "q1": (mlp(critic, 1, self.hidden, self.activation), True),
                "q2": (mlp(critic, 1, self.hidden, self.activation), True), "alpha": (None, False)}

    def initial(self, name: str, own: SAC) -> torch.Tensor:
        """log alpha at the start (``alpha``, the one plain group)."""
        return torch.tensor([math.log(own.alpha_init)])

    def policy(self, template: nn.Sequential) -> nn.Module:
        """The actor as ``model.pt`` holds it (:func:`tanh_normal_actor`)."""
        return tanh_normal_actor(template)

    # -- one member's acting and losses ----------------------------------------
    def draw_act(self, generator: torch.Generator, n: int) -> torch.Tensor:
        """One step's standard normal noise for ``n`` copies."""
        return torch.empty(n, self.n_actions).normal_(generator=generator)

    def act_with(self, actor: Callable, observation: torch.Tensor, noise: torch.Tensor | None) -> dict:
        """The squashed Gaussian's draw at ``noise``, or its deterministic action ``tanh(loc)``."""
        loc, scale = actor(observation)  # the draw's action as :func:`squashed` makes it, its log-prob not needed
        return {"action": squash(loc if noise is None else loc + noise * scale)}

    def draw_update(self, generator: torch.Generator, batch_size: int) -> torch.Tensor:
        """One update's draws: standard normal noise for the next actions, then the current ones."""
        return torch.empty(2, batch_size, self.n_actions).normal_(generator=generator)

    def losses(self, nets: Mapping[str, GroupStep], batch: Transitions, noise: torch.Tensor,
               gamma: float | torch.Tensor, own: Sequence[SAC], kind: None = None) -> Losses:
        """Each member's summed SAC losses: every update steps all its networks (the
        temperature unless ``fixed_alpha``), the target critics follow."""
        entropy = [-float(self.n_actions) if v.target_entropy is None else float(v.target_entropy) for v in own]
        target_entropy = entropy[0] if len(set(entropy)) == 1 else torch.tensor(entropy).view(-1, 1, 1)
        terms = sac_losses(nets["actor"], nets["q1"], nets["q2"], nets["alpha"].value, batch, noise, gamma,
                           target_entropy, self.loss)
        loss = (terms["loss_qvalue"] + terms["loss_actor"]).mean((1, 2))
        stepped = ("actor", "q1", "q2")
        if not self.fixed_alpha:
            loss = loss + terms["loss_alpha"].mean((1, 2))
            stepped += ("alpha",)
        extras = {"loss_actor": terms["loss_actor"].detach(), "entropy": -terms["log_prob"], "alpha": terms["alpha"]}
        return Losses(loss, stepped, ("q1", "q2"), terms["loss_qvalue"].detach().mean((1, 2)), terms["q"],
                      terms["target"], extras)


__all__ = ["SAC", "sac_losses"]
