"""Prioritized replay (learner.prioritized, learners/priority.py): draws and importance
weights against Schaul et al.'s formulas, new rows at the largest priority, beta's
annealing, and the importance-weighted loss of a DQN update written out by hand. (Kill
and resume: tests/test_nstep.py; a member as alone: tests/test_members.py; bad settings:
tests/test_validation.py.)"""

from __future__ import annotations

import pytest
import torch

from learners.priority import Priorities, annealed_beta
from tests.test_members import build_env, config, made


def filled(td_errors: list[float], alpha: float, eps: float = 1e-6) -> Priorities:
    p = Priorities(8, alpha, eps)
    p.added(torch.arange(len(td_errors)))
    p.update(torch.arange(len(td_errors)), torch.tensor(td_errors))
    return p


def test_rows_are_drawn_in_proportion_to_their_priorities():
    td = [0.5, 2.0, 0.0, 1.0, 4.0]
    p = filled(td, alpha=0.6)
    generator = torch.Generator().manual_seed(0)
    counts = torch.zeros(len(td))
    for _ in range(400):
        index, _ = p.sample(len(td), 256, 0.0, generator)
        counts += torch.bincount(index, minlength=len(td))
    expected = (torch.tensor(td, dtype=torch.float64) + 1e-6) ** 0.6
    expected /= expected.sum()
    assert torch.allclose(counts / counts.sum(), expected.float(), atol=0.003)


def test_importance_weights_are_the_formula_normalised_by_the_largest():
    td = [0.5, 2.0, 0.0, 1.0, 4.0]
    p = filled(td, alpha=0.7)
    index, weight = p.sample(len(td), 64, 0.5, torch.Generator().manual_seed(1))
    probability = (torch.tensor(td, dtype=torch.float64) + 1e-6) ** 0.7
    probability /= probability.sum()
    w = (len(td) * probability) ** -0.5
    assert torch.allclose(weight.double(), (w / w.max())[index], rtol=1e-6)
    assert weight.dtype == torch.float32 and weight.max() <= 1.0


def test_a_minibatch_takes_one_row_per_stratum():
    """Equal priorities and a minibatch of the buffer's size: each row exactly once."""
    p = filled([1.0] * 8, alpha=0.6)
    index, weight = p.sample(8, 8, 0.4, torch.Generator().manual_seed(2))
    assert index.tolist() == list(range(8)) and weight.tolist() == [1.0] * 8


def test_new_rows_take_the_largest_priority_so_far():
    p = Priorities(4, alpha=0.5, eps=0.01)
    p.added(torch.tensor([0]))
    assert p.values[0] == 1.0  # before any update: 1
    p.update(torch.tensor([0]), torch.tensor([8.99]))
    p.added(torch.tensor([1, 2]))
    assert torch.allclose(p.values[:3], torch.tensor([3.0, 3.0, 3.0], dtype=torch.float64))
    p.update(torch.tensor([1]), torch.tensor([-0.0]))  # smaller errors do not lower the largest
    p.added(torch.tensor([3]))
    assert p.values[1] == pytest.approx(0.1) and p.values[3] == pytest.approx(3.0)


def test_beta_rises_linearly_to_one_and_stays():
    assert [annealed_beta(0.4, u, 100) for u in (0, 50, 100, 500)] == pytest.approx([0.4, 0.7, 1.0, 1.0])


def test_an_update_minimises_the_importance_weighted_loss_and_writes_back_the_errors():
    """One update of a built learner against the same minibatch drawn and weighted by hand:
    its gradient is that of mean(w * huber(Q(s, a), target)), and the drawn rows take
    (|target - Q| + eps)^alpha."""
    cfg = config("dqn", ["learner.batch_size=16", "learner.learning_starts=0", "learner.prioritized=true",
                         "learner.grad_clip=0", "learner.priority_beta=0.5", "learner.updates=1"])
    learner = made(cfg, (3,))
    env = build_env(cfg, 4, [3])
    td = learner.act(env.reset())
    for _ in range(10):
        td, nxt = env.step_and_maybe_reset(td)
        learner.store(td)
        td = learner.act(nxt)
    env.close()
    buffer = learner.buffers[0]
    buffer.priorities.update(torch.arange(40), torch.linspace(0.0, 3.0, 40))  # unequal, known
    stored, priorities = len(buffer), buffer.priorities.values.clone()
    generator = torch.Generator()
    generator.set_state(learner.generators[0].get_state())
    index, weight = buffer.priorities.sample(stored, 16, 0.5, generator)
    params = learner.params.clone().requires_grad_(True)
    from learners.dqn import td_terms
    from learners.transitions import unpack
    batch = unpack(buffer.rows[index].unsqueeze(0))
    layers = learner.net.layers(params)
    target_layers = learner.net.layers(learner.target)
    q, target = td_terms(lambda x: learner.net.q(layers, x), lambda x: learner.net.q(target_layers, x),
                         batch, cfg.learner.gamma, True)
    loss = (torch.nn.functional.smooth_l1_loss(q, target, reduction="none") * weight.view(1, -1, 1)).mean()
    loss.backward()
    learner.optimize(1)
    assert torch.allclose(learner.grads, params.grad, atol=1e-7)
    again = priorities.clone()
    again[index] = ((target - q).detach().abs().reshape(-1).double() + 1e-6) ** 0.6
    assert torch.allclose(buffer.priorities.values, again)
