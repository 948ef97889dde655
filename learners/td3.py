"""Twin delayed DDPG (Fujimoto et al. 2018), written for one member.

One member's algorithm (CleanRL's ``td3_continuous_action.py`` reads alike): a deterministic
policy ``tanh(MLP(s))`` (TorchRL's ``MLP``; an ``Actor`` in ``model.pt``) exploring with
Gaussian noise, twin Q-networks, and target copies of all three. Per minibatch, the losses
of TorchRL's ``TD3Loss``: the critics' TD error to ``r + gamma * min_i Q'_i(s', a')`` where
``a'`` is the target policy's action plus clipped noise (target policy smoothing), and, every
``policy_delay`` updates, the actor's ``-Q_1(s, pi(s))``, after which the targets follow by
Polyak averaging.

The seeds and trials of a batch are one layer beneath (:class:`learners.member.ActorCriticLearner`);
:func:`td3_losses` computes the losses of every member in one call, with TD3Loss's numbers
(``tests/test_td3.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Hashable, Mapping, Sequence

import torch
from torch import nn

from learners.continuous import DISTANCES, ReplaySettings, mlp
from learners.device import resolve_device
from learners.member import ActorCriticLearner, GroupStep, Losses, check_replay_settings
from learners.transitions import Transitions
from params.declare import check_fields, param


def td3_losses(actor: GroupStep, q1: GroupStep, q2: GroupStep, batch: Transitions, noise: torch.Tensor,
               gamma: float | torch.Tensor, policy_noise: float, noise_clip: float, with_actor: bool,
               distance: str = "l2") -> dict[str, torch.Tensor]:
    """TD3's losses on ``batch`` (``[k, B, ...]``): ``loss_qvalue`` per transition (the two
    critics' summed), ``loss_actor`` where ``with_actor``, ``q`` (the first critic's values)
    and ``target``. ``noise`` ``[k, B, dims]``: each member's standard normal draws for the
    target policy's smoothing. Terminated transitions do not bootstrap; truncated ones do."""
    found = {}
    if with_actor:
        chosen = torch.cat((batch.observation, actor(batch.observation)), -1)
        found["loss_actor"] = -q1.frozen(chosen)
    with torch.no_grad():
        smoothing = (noise * policy_noise).clamp(-noise_clip, noise_clip)
        next_action = (actor.target(batch.next_observation) + smoothing).clamp(-1.0, 1.0)
        after = torch.cat((batch.next_observation, next_action), -1)
        target = batch.reward + gamma * torch.minimum(q1.target(after), q2.target(after)) * ~batch.terminated
    taken = torch.cat((batch.observation, batch.action), -1)
    q = q1(taken)
    distance = DISTANCES[distance]
    found["loss_qvalue"] = distance(q, target, reduction="none") + distance(q2(taken), target, reduction="none")
    return found | {"q": q, "target": target}


@dataclass(eq=False)
class TD3(ReplaySettings, ActorCriticLearner):
    """Twin delayed DDPG (see the module docstring), over :class:`ActorCriticLearner`."""

    tau: float = param(0.005, "Polyak averaging rate of the target actor and critics", gt=0, le=1)
    exploration_noise: float = param(0.1, "standard deviation of the Gaussian noise on each exploring action "
                                          "(actions in [-1, 1])", ge=0)
    policy_noise: float = param(0.2, "standard deviation of the target policy's smoothing noise", ge=0)
    noise_clip: float = param(0.5, "the smoothing noise clipped to +-this", ge=0)
    policy_delay: int = param(2, "critic updates per actor update (and per target update)", ge=1)

    kind = "td3"
    out_keys = ("action",)
    critic = "q1"
    MEMBER_WISE = ("lr", "gamma", "tau", "learning_starts", "grad_clip", "reward_scale", "buffer_size",
                   "batch_size", "updates")
    SIZING = ("buffer_size",)

    def __post_init__(self) -> None:
        check_fields(self, "learner")
        check_replay_settings(self)
        self.device = str(resolve_device(self.device))

    # -- one member's networks -----------------------------------------------

    def networks(self, task) -> dict[str, tuple[nn.Sequential, bool]]:
        """The actor (observation -> tanh of its outputs, one per action) and two critics
        ((observation, action) -> Q), each with a target copy."""
        actor = nn.Sequential(*mlp(self.n_obs, self.n_actions, self.hidden, self.activation), nn.Tanh())
        critic = self.n_obs + self.n_actions
        return {"actor": (actor, True), "q1": (mlp(critic, 1, self.hidden, self.activation), True),
                "q2": (mlp(critic, 1, self.hidden, self.activation), True)}

    def policy(self, template: nn.Sequential) -> nn.Module:
        """The actor as ``model.pt`` holds it: TorchRL's deterministic ``Actor``."""
        from torchrl.modules import Actor

        return Actor(template, in_keys=["observation"])

    # -- one member's acting and losses ----------------------------------------
    def draw_act(self, generator: torch.Generator, n: int) -> torch.Tensor:
        """One step's standard normal exploration noise for ``n`` copies."""
        return torch.empty(n, self.n_actions).normal_(generator=generator)

    def act_with(self, actor: Callable, observation: torch.Tensor, noise: torch.Tensor | None) -> dict:
        """The policy's action, plus ``exploration_noise`` times ``noise`` (clipped to [-1, 1])."""
        action = actor(observation)
        return {"action": action if noise is None else (action + self.exploration_noise * noise).clamp(-1.0, 1.0)}

    def draw_update(self, generator: torch.Generator, batch_size: int) -> torch.Tensor:
        """One update's draws: standard normal noise for the target policy's smoothing."""
        return torch.empty(batch_size, self.n_actions).normal_(generator=generator)

    def update_kind(self, b: int) -> Hashable:
        """``actor`` on every ``policy_delay``-th update of member ``b``, else the critics'."""
        return "actor" if (self.steps[b] + 1) % self.policy_delay == 0 else "critics"

    def losses(self, nets: Mapping[str, GroupStep], batch: Transitions, noise: torch.Tensor,
               gamma: float | torch.Tensor, own: Sequence[TD3], kind: Hashable = "critics") -> Losses:
        """The critics' loss, and on an actor update the actor's too, after which every target follows."""
        with_actor = kind == "actor"
        terms = td3_losses(nets["actor"], nets["q1"], nets["q2"], batch, noise, gamma, self.policy_noise,
                           self.noise_clip, with_actor, self.loss)
        critic_loss = terms["loss_qvalue"].mean((1, 2))
        if not with_actor:
            return Losses(critic_loss, ("q1", "q2"), (), critic_loss.detach(), terms["q"], terms["target"], {})
        loss = critic_loss + terms["loss_actor"].mean((1, 2))
        every = ("q1", "q2", "actor")
        return Losses(loss, every, every, critic_loss.detach(), terms["q"], terms["target"],
                      {"loss_actor": terms["loss_actor"].detach()})


__all__ = ["TD3", "td3_losses"]
