"""Dueling heads (learner.dueling): the head's Q = V + A - mean A on a hand-made row, the
stacked members' forward equal to the saved model's (the TorchRL actor of model.pt), and
a dueling run that learns the cart-pole."""

from __future__ import annotations

import torch
from hydra.utils import instantiate

from learners.dqn import DuelingHead, dueling
from runs.training_state import seed_everything
from tasks.catalog import compose
from tasks.factory import build_env


def test_the_head_is_value_plus_advantage_less_its_mean():
    x = torch.tensor([[2.0, 1.0, 3.0, 5.0]])  # V = 2, A = (1, 3, 5), mean 3
    assert torch.allclose(dueling(x), torch.tensor([[0.0, 2.0, 4.0]]), atol=1e-6)  # one product: rounding
    assert torch.equal(DuelingHead()(x), dueling(x))
    per_atom = torch.tensor([[2.0, 1.0, 3.0, 5.0, -1.0, 0.0, 0.0, 3.0]])  # two atoms, each its own V and A
    assert torch.allclose(dueling(per_atom, atoms=2), torch.tensor([[0.0, 2.0, 4.0, -2.0, -2.0, 1.0]]), atol=1e-6)
    assert dueling(x).argmax(-1).item() == 2  # the advantage's argmax, whatever V


def test_the_stacked_dueling_networks_are_the_saved_models():
    """Two members' Q-values from the stacked parameters equal each member's template
    network (what model.pt's actor computes), which ends in the dueling head."""
    cfg = compose("cartpole", learner="dqn", overrides=["learner.dueling=true", "learner.hidden=[16,16]"])
    env = build_env(cfg, 1, 0)
    learner = instantiate(cfg.learner, _convert_="all")
    learner.build(env.task, [seed_everything(1), seed_everything(2)])
    assert isinstance(learner.net.template[-1], DuelingHead) and learner.net.size == (4 * 16 + 16) + (
        16 * 16 + 16) + (16 * 3 + 3)  # the last layer: V and two advantages
    x = torch.randn(2, 5, 4)
    stacked = learner.net.q(learner.params, x)
    for b in range(2):
        net = learner.net.load(learner.params[b])
        assert torch.allclose(stacked[b], net(x[b]), atol=1e-6)
    saved = learner.model_state(1)
    assert learner.member(1).model_state()["arch"]["dueling"] is True and "actor" in saved
    env.close()
