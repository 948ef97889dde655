"""Distributional values (learner.distributional, learners/distributional.py): the
projection onto the support against a case worked by hand, the update's loss against
TorchRL's ``DistributionalDQNLoss`` on the same batch and networks, the saved model as
TorchRL's ``DistributionalQValueActor`` acting as the learner does, and actions from the
distributions' means."""

from __future__ import annotations

import pytest
import torch
from hydra.utils import instantiate
from tensordict import TensorDict
from torchrl.objectives import DistributionalDQNLoss

from learners.distributional import c51_terms, expected, project, support
from learners.transitions import Transitions
from runs.training_state import seed_everything
from tasks.catalog import compose
from tasks.factory import build_env


def test_the_projection_splits_each_shifted_atom_between_its_neighbours():
    """Support (-1, 0, 1), p = (0.2, 0.5, 0.3), r = 0.5, discount 0.5: the atoms move to 0,
    0.5 and 1; 0.5 is split half and half, 0 and 1 land on atoms whole."""
    z = support(3, -1.0, 1.0)
    p = torch.tensor([[0.2, 0.5, 0.3]])
    m = project(p, torch.tensor([[0.5]]), 0.5, torch.tensor([[False]]), z)
    assert torch.allclose(m, torch.tensor([[0.0, 0.45, 0.55]]))
    assert torch.allclose((m * z).sum(), 0.5 + 0.5 * (p * z).sum())  # the mean moves as the values do
    ended = project(p, torch.tensor([[0.5]]), 0.5, torch.tensor([[True]]), z)  # all mass at r
    assert torch.allclose(ended, torch.tensor([[0.0, 0.5, 0.5]]))
    clipped = project(p, torch.tensor([[5.0]]), 0.5, torch.tensor([[False]]), z)  # beyond v_max: the last atom
    assert torch.allclose(clipped, torch.tensor([[0.0, 0.0, 1.0]]))


def built(*overrides: str, seeds=(4,)):
    cfg = compose("cartpole", learner="dqn", overrides=["learner.distributional=true", "learner.hidden=[16]",
                                                         "learner.atoms=11", "learner.v_min=-5", "learner.v_max=20",
                                                         *overrides])
    env = build_env(cfg, 1, 0)
    learner = instantiate(cfg.learner, _convert_="all")
    learner.build(env.task, [seed_everything(s) for s in seeds])
    env.close()
    return learner


@pytest.mark.parametrize("dueling", [False, True])
def test_the_loss_is_torchrls_distributional_dqn_loss(dueling):
    learner = built(f"learner.dueling={str(dueling).lower()}")
    learner.target[0].normal_(0.0, 0.3, generator=torch.Generator().manual_seed(9))  # a target unlike the online
    n = 32
    g = torch.Generator().manual_seed(3)
    batch = Transitions(torch.randn(n, 4, generator=g), torch.randint(0, 2, (n, 1), generator=g),
                        torch.rand(n, 1, generator=g) * 3 - 1, torch.randn(n, 4, generator=g),
                        torch.rand(n, 1, generator=g) < 0.2)
    mine, q, target, m = c51_terms(lambda x: learner.net.q(learner.params[:1], x),
                                   lambda x: learner.net.q(learner.target[:1], x),
                                   Transitions(*(t.unsqueeze(0) for t in batch[:5])), 0.9, True, learner.z)
    actor = learner.actor
    learner.net.load(learner.target[0])
    loss_module = DistributionalDQNLoss(actor, gamma=0.9)  # its target: a copy of the actor now
    learner.net.load(learner.params[0])
    loss_module.value_network_params.update_(TensorDict.from_module(actor))  # its online: the learner's
    td = TensorDict({"observation": batch.observation, "action": batch.action.squeeze(-1),
                     "next": {"observation": batch.next_observation, "reward": batch.reward,
                              "done": batch.terminated, "terminated": batch.terminated}}, batch_size=[n])
    theirs = loss_module(td)["loss"]
    assert torch.allclose(mine.mean(), theirs, atol=1e-5)
    assert torch.allclose(mine.squeeze(-1).squeeze(0), td.get("td_error").squeeze(-1), atol=1e-5)
    assert torch.allclose(m.sum(-1), torch.ones(1, n), atol=1e-5)  # the target a distribution
    assert torch.allclose(target, (m * learner.z).sum(-1, keepdim=True))


def test_actions_are_the_argmax_of_the_means_and_the_saved_actor_agrees():
    learner = built("learner.dueling=true", seeds=(1, 2))
    obs = torch.randn(2 * 16, 4)
    td = TensorDict({"observation": obs}, batch_size=[32])
    action = learner.act_members(td, None, True, [None, None]).get("action")
    means = expected(learner.net.q(learner.params, obs.view(2, 16, 4)), learner.z)
    assert torch.equal(action.view(2, 16), means.argmax(-1))
    for b in range(2):
        saved = built("learner.dueling=true", seeds=(7,))
        saved.load_model_state(0, learner.model_state(b), "model.pt")
        acted = saved.actor(TensorDict({"observation": obs[16 * b:16 * (b + 1)]}, batch_size=[16]))
        assert torch.equal(acted.get("action"), action[16 * b:16 * (b + 1)])
        assert acted.get("action_value").shape == (16, 11, 2)  # TorchRL's [atoms, actions]


@pytest.mark.parametrize("v_max, warned", [(20.0, True), (150.0, False)])
def test_a_value_range_the_returns_lie_beyond_is_said_once(v_max, warned):
    """Issue 67: rainbow's [-10, 10] against cart-pole's returns of up to 100 gave no word. A
    C51 learner whose stored rewards, earned every step, make a discounted return beyond
    [v_min, v_max] says so (the run prints each subject once); one whose range holds them
    does not. The targets' mass on the end atoms is a train/* number (support_edge)."""
    learner = built(f"learner.v_max={v_max}", "learner.gamma=0.99", "learner.reward_scale=1.0")
    rows = Transitions(observation=torch.zeros(1200, 4), action=torch.zeros(1200, 1, dtype=torch.int64),
                       reward=torch.ones(1200, 1), next_observation=torch.zeros(1200, 4),
                       terminated=torch.zeros(1200, 1, dtype=torch.bool), steps=None)
    from learners.transitions import pack

    learner.buffers[0].put(pack(rows))
    advice = learner.advice(0)
    assert bool(advice) == warned
    if warned:
        assert advice["value_range"].startswith(f"learner.v_min/v_max [-5, {v_max:g}] may not hold this task's "
                                                "returns: its mean reward 1 a step")
        assert "discounted return of 100 at gamma 0.99" in advice["value_range"]
    learner.optimize(3)
    assert 0.0 <= learner.train_stats(0)["support_edge"] <= 1.0
