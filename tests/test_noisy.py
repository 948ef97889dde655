"""Noisy nets (learner.noisy): the stacked members' noisy forward against TorchRL's
``NoisyLinear`` given the same noise, its initialisation, the factorised noise's statistics,
acting by the noise (no epsilon) and greedy actions from the mean weights."""

from __future__ import annotations

import math

import torch
from hydra.utils import instantiate
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import NoisyLinear

from runs.training_state import seed_everything
from tasks.catalog import compose
from tasks.factory import build_env


def built(*overrides: str, seeds=(1, 2)):
    cfg = compose("cartpole", learner="dqn", overrides=["learner.noisy=true", "learner.hidden=[16,16]", *overrides])
    env = build_env(cfg, 1, 0)
    learner = instantiate(cfg.learner, _convert_="all")
    learner.build(env.task, [seed_everything(s) for s in seeds])
    env.close()
    return learner


def test_the_noisy_forward_is_torchrls_noisy_linear_given_the_same_noise():
    """Each member's stacked forward, with its noise, equals its template network of TorchRL
    NoisyLinear layers holding that noise in weight_epsilon and bias_epsilon."""
    learner = built("learner.dueling=true")
    noise = learner.net.noise([torch.Generator().manual_seed(5), torch.Generator().manual_seed(6)], "cpu")
    x = torch.randn(2, 7, 4)
    stacked, mean = learner.net.q(learner.params, x, noise), learner.net.q(learner.params, x)
    for b in range(2):
        net = learner.net.load(learner.params[b])
        layers = [m for m in net if isinstance(m, NoisyLinear)]
        assert len(layers) == 3
        for layer, (e_in, e_out) in zip(layers, noise):
            layer.weight_epsilon.copy_(torch.outer(e_out[b], e_in[b]))
            layer.bias_epsilon.copy_(e_out[b])
        with set_exploration_type(ExplorationType.RANDOM):
            assert torch.allclose(stacked[b], net(x[b]), atol=1e-5)
        assert torch.allclose(mean[b], net(x[b]), atol=1e-5)  # outside RANDOM: TorchRL's mean weights


def test_noisy_layers_start_as_torchrls_do():
    learner = built("learner.noisy_sigma=0.3")
    first = learner.net.load(learner.params[0])[0]
    assert torch.allclose(first.weight_sigma, torch.full((16, 4), 0.3 / math.sqrt(4)))
    assert first.weight_mu.abs().max() <= 1 / math.sqrt(4)
    assert not torch.equal(learner.params[0], learner.params[1])  # each member its own stream


def test_the_factorised_noise_has_the_papers_statistics():
    """f(x) = sign(x) sqrt|x| of standard normals: mean 0, E f^2 = E|x| = sqrt(2/pi); zero
    noise for a member without a stream."""
    learner = built()
    generator = torch.Generator().manual_seed(0)
    draws = torch.cat([
        torch.cat([torch.cat(pair, dim=1) for pair in learner.net.noise([generator], "cpu")], dim=1)
        for _ in range(2000)])
    assert abs(draws.mean()) < 0.01 and abs((draws ** 2).mean() - math.sqrt(2 / math.pi)) < 0.01
    assert all(not e.any() for pair in learner.net.noise([None], "cpu") for e in pair)


def test_it_acts_by_its_noise_not_epsilon_and_evaluates_with_the_mean_weights():
    learner = built("learner.epsilon.epsilon=1.0", "learner.epsilon.epsilon_min=1.0", "learner.noisy_sigma=1e-6")
    from tensordict import TensorDict
    td = TensorDict({"observation": torch.randn(2 * 64, 4)}, batch_size=[2 * 64])
    greedy = learner.act_members(td, None, True, [None, None]).get("action")
    # epsilon 1 would make about half of them random: with almost no noise, none differ
    assert torch.equal(learner.act(td).get("action"), greedy)
    assert learner.stats(0)["epsilon"] == 0.0
    assert "epsilon" not in learner.train_stats(0)  # the progress line and train/* show no unused epsilon
    noisy = built("learner.noisy_sigma=5.0")
    greedy = noisy.act_members(td, None, True, [None, None]).get("action")
    assert torch.equal(noisy.act_members(td, None, True, [None, None]).get("action"), greedy)  # the mean: fixed
    assert not torch.equal(noisy.act(td).get("action"), greedy)  # large noise moves some argmaxes
