"""What the learners on continuous actions share (:mod:`learners.sac`, :mod:`learners.td3`,
:mod:`learners.ppo`): their networks (TorchRL's ``MLP``), the tanh-squashed Gaussian of SAC's
and PPO's policies (TorchRL's ``NormalParamExtractor`` and ``TanhNormal``, its draws and
log-probabilities computed member-exact by :func:`~learners.member.lanes`), and the settings
of an off-policy actor-critic's replay (SAC's and TD3's)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from tensordict.nn import NormalParamExtractor
from torch import nn
from torchrl.modules import MLP
from torchrl.modules.distributions import TanhNormal
from torchrl.modules.distributions.utils import safetanh_noeps

from learners.device import DEVICE_NOTE, check_device
from learners.member import lanes, obs_scale_param
from params.declare import param

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU}
DISTANCES = {"l2": nn.functional.mse_loss, "smooth_l1": nn.functional.smooth_l1_loss}

LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))


class GaussianHead(NormalParamExtractor):
    """TorchRL's ``NormalParamExtractor`` (the last layer's outputs as ``loc`` and a biased
    softplus ``scale``), its softplus computed by :func:`~learners.member.lanes`."""

    def forward(self, tensor: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc, scale = tensor.chunk(2, -1)
        return loc, lanes(self.scale_mapping, scale).clamp_min(self.scale_lb)


def tanh_normal_actor(template: nn.Sequential) -> nn.Module:
    """A network ending in :class:`GaussianHead` as TorchRL's ``ProbabilisticActor`` of a
    ``TanhNormal`` (what ``model.pt`` holds of SAC's and PPO's policies)."""
    from tensordict.nn import TensorDictModule
    from torchrl.modules import ProbabilisticActor

    module = TensorDictModule(template, in_keys=["observation"], out_keys=["loc", "scale"])
    return ProbabilisticActor(module, in_keys=["loc", "scale"], distribution_class=TanhNormal)


def squash(preimage: torch.Tensor) -> torch.Tensor:
    """The action of a pre-tanh value: TorchRL's safe tanh, by :func:`~learners.member.lanes`."""
    return lanes(safetanh_noeps, preimage)


def squashed(loc: torch.Tensor, scale: torch.Tensor, noise: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """``(action, log_prob)`` of TorchRL's ``TanhNormal(loc, scale)`` at the pre-tanh value
    ``loc + noise * scale``: its ``rsample_and_log_prob`` with the noise given rather than
    drawn, step by step (the Gaussian's log density less the tanh's log Jacobian, TorchRL's
    safe tanh), its transcendental functions by :func:`~learners.member.lanes`."""
    preimage = loc + noise * scale
    return squash(preimage), log_prob_of(loc, scale, preimage)


def mlp(inputs: int, outputs: int, hidden: list[int], activation: str) -> nn.Sequential:
    """TorchRL's ``MLP`` of ``hidden`` widths with ``activation`` (a key of :data:`ACTIVATIONS`)."""
    return MLP(in_features=inputs, out_features=outputs, num_cells=hidden, activation_class=ACTIVATIONS[activation])


def log_prob_of(loc: torch.Tensor, scale: torch.Tensor, preimage: torch.Tensor) -> torch.Tensor:
    """The tanh-squashed Gaussian's log-probability of the action ``tanh(preimage)``."""
    density = -((preimage - loc) ** 2) / (2 * scale**2) - lanes(torch.log, scale) - LOG_SQRT_2PI
    jacobian = 2.0 * (math.log(2.0) - preimage - lanes(nn.functional.softplus, -2.0 * preimage))
    return density.sum(-1) - jacobian.sum(-1)


@dataclass(eq=False)
class ReplaySettings:
    """The settings an off-policy actor-critic's replay and updates take (SAC's and TD3's)."""

    hidden: list[int] = param([256, 256], "widths of the actor's and each critic's hidden layers")
    activation: str = param("relu", "hidden layers' activation", choices=tuple(ACTIVATIONS))
    obs_scale: dict[str, float] | None = obs_scale_param()
    lr: float = param(3e-4, "Adam's learning rate of the actor and the critics", gt=0)
    gamma: float = param(0.99, "discount of the next state's value", ge=0, le=1)
    loss: str = param("l2", "critics' TD error loss", choices=tuple(DISTANCES))
    buffer_size: int = param(100_000, "replay buffer capacity, transitions", ge=1, le=10**7)
    batch_size: int = param(256, "transitions per minibatch", ge=1, le=65_536)
    updates: float = param(1.0, "minibatches per collected transition", gt=0)
    learning_starts: int = param(1000, "transitions in the buffer before the first update; until then "
                                       "the member acts uniformly at random", ge=1)
    grad_clip: float = param(0.0, "gradient norm clip of each network", ge=0, note="0 = no clipping")
    reward_scale: float = param(1.0, "factor on every reward the learner stores", gt=0)
    device: str = param("cpu", "where the networks, updates and replay buffer live",
                        note=DEVICE_NOTE, check=check_device)


__all__ = ["ACTIVATIONS", "DISTANCES", "GaussianHead", "ReplaySettings", "log_prob_of", "mlp", "squash", "squashed",
           "tanh_normal_actor"]
