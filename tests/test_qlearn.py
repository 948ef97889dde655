"""Tabular Q-learning: the state mapping, the update rule and its options, learning."""

import csv

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from runs.checkpoint import CheckpointError, load_model, save_model
from runs.evaluate import evaluate
from learners.discretizer import Discretizer
from learners.qlearn import QLearn
from tests.inprocess import run_train
from runs.run import Run
from runs.training_state import seed_everything
from robots.cartpole import CartPole
from tasks.base import Bounds
from tasks import factory
from tasks.env import RobotTaskEnv
from tasks.stay_up import StayUp

NAMES = ("a", "b", "c")


def test_discretizer_is_mixed_radix_over_bins_first_entry_fastest():
    d = Discretizer(Bounds.from_config({"a": [0, 1], "c": [-2, 2]}, NAMES), [4, 2])
    obs = torch.tensor([
        [0.10, 99.0, -1.0],   # a bin 0, c bin 0 -> 0
        [0.30, 99.0, -1.0],   # a bin 1 -> 1
        [0.99, 99.0, 1.5],    # a bin 3, c bin 1 -> 3 + 4*1 = 7
        [-5.0, 0.0, 9.0],     # clipped: a bin 0, c bin 1 -> 4
    ])
    assert d(obs).tolist() == [0, 1, 7, 4]
    assert d.n_states == 8
    by_name = Discretizer(Bounds.from_config({"a": [0, 1], "c": [-2, 2]}, NAMES), {"c": 2, "a": 4})
    assert by_name(obs).tolist() == [0, 1, 7, 4]
    ignored = Discretizer(Bounds.from_config({"a": [0, 1], "c": [-2, 2]}, NAMES), {"c": 2})
    assert ignored(obs).tolist() == [0, 0, 1, 1] and ignored.n_states == 2


class FakeTask:
    n_actions = 2

    def __init__(self):
        self.tabular_bounds = Bounds.from_config({"a": [0, 4]}, NAMES)


def transition(state_obs, action, reward, next_obs, terminated):
    n = len(action)
    return TensorDict({
        "observation": torch.tensor(state_obs, dtype=torch.float32).reshape(n, 3),
        "action": torch.tensor(action),
        ("next", "observation"): torch.tensor(next_obs, dtype=torch.float32).reshape(n, 3),
        ("next", "reward"): torch.tensor(reward, dtype=torch.float32).reshape(n, 1),
        ("next", "terminated"): torch.tensor(terminated).reshape(n, 1),
    }, batch_size=[n])


def learner(**kw):
    q = QLearn(alpha=0.5, gamma=0.9, epsilon=0.0, number_splits=4, **kw)
    q.build(FakeTask())
    return q


def apply(q, *args):
    td = transition(*args)
    td["state_index"] = q.discretizer(td["observation"])
    q.observe(td)


def test_update_bootstraps_from_the_best_next_action():
    q = learner()
    q.table[0][2] = torch.tensor([3.0, 5.0])
    apply(q, [[0.5, 0, 0]], [1], [1.0], [[2.5, 0, 0]], [False])
    assert q.table[0][0, 1].item() == pytest.approx(0.5 * (1.0 + 0.9 * 5.0))
    assert q.table[0][0, 0].item() == 0.0


def test_no_bootstrap_through_terminal_unless_asked():
    for flag, expected in ((False, 0.5 * 1.0), (True, 0.5 * (1.0 + 0.9 * 5.0))):
        q = learner(bootstrap_terminal=flag)
        q.table[0][2] = torch.tensor([3.0, 5.0])
        apply(q, [[0.5, 0, 0]], [1], [1.0], [[2.5, 0, 0]], [True])
        assert q.table[0][0, 1].item() == pytest.approx(expected)


def test_first_visit_sets_q_to_reward_when_asked():
    q = learner(first_visit_reward=True)
    q.table[0][2] = torch.tensor([3.0, 5.0])
    apply(q, [[0.5, 0, 0]], [1], [7.0], [[2.5, 0, 0]], [False])
    assert q.table[0][0, 1].item() == 7.0
    apply(q, [[0.5, 0, 0]], [1], [7.0], [[2.5, 0, 0]], [False])
    assert q.table[0][0, 1].item() == pytest.approx(7.0 + 0.5 * (7.0 + 4.5 - 7.0))


def test_duplicate_pairs_in_a_batch_average_their_increments():
    q = learner()
    apply(q, [[0.5, 0, 0], [0.6, 0, 0]], [1, 1], [2.0, 4.0], [[3.5, 0, 0], [3.5, 0, 0]], [True, True])
    assert q.table[0][0, 1].item() == pytest.approx(0.5 * 3.0)


def test_greedy_action_and_epsilon_decay_with_floor():
    q = learner(epsilon_discount=0.5, epsilon_min=0.2)
    q.table[0][1] = torch.tensor([0.0, 1.0])
    td = TensorDict({"observation": torch.tensor([[1.5, 0, 0]] * 50)}, batch_size=[50])
    assert (q.member(0).policy(td)["action"] == 1).all()
    q.schedules[0].value = 0.9
    for expected in (0.45, 0.225, 0.1125, 0.1125):
        q.end_episodes({0: 1})
        assert q.schedules[0].value == pytest.approx(expected)


def test_epsilon_one_explores_uniformly_and_noise_option_too():
    for noise in (False, True):
        q = learner(noise_exploration=noise)
        q.table[0][1] = torch.tensor([0.0, 1.0])
        q.schedules[0].value = 1.0
        td = TensorDict({"observation": torch.tensor([[1.5, 0, 0]] * 2000)}, batch_size=[2000])
        share = q.member(0).policy(td)["action"].float().mean().item()
        # Plain epsilon: uniform (0.5). Noise of the Q magnitude: still favours the best action.
        assert (0.45 < share < 0.55) if not noise else (0.6 < share < 0.9), share


def test_checkpoint_roundtrip_and_clear_errors(tmp_path):
    q = learner()
    q.table[0].uniform_()
    save_model(tmp_path / "model.pt", q.member(0), meta={})
    q2 = learner()
    load_model(tmp_path / "model.pt", q2.member(0))
    assert torch.equal(q2.table[0], q.table[0])
    with pytest.raises(CheckpointError, match="does not exist"):
        load_model(tmp_path / "missing.pt", q2.member(0))
    (tmp_path / "bad.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(CheckpointError, match="cannot be read"):
        load_model(tmp_path / "bad.pt", q2.member(0))
    other = QLearn(number_splits=3)
    other.build(FakeTask())
    with pytest.raises(CheckpointError, match="does not fit"):
        load_model(tmp_path / "model.pt", other.member(0))


def random_policy(n_actions, seed):
    gen = torch.Generator().manual_seed(seed)

    def act(td):
        td["action"] = torch.randint(0, n_actions, td.batch_size, generator=gen)
        return td
    return act


# qlearn's learning check in CI (10 s); the default run solving the cart-pole: -m slow (tests/test_success.py)
def test_tuned_qlearn_beats_random_three_times_on_a_fixed_seed(tmp_path):
    seed = 0
    done = run_train("max_episodes=200", f"seed={seed}", "quiet=true", f"hydra.run.dir={tmp_path}")
    assert done.returncode == 0, done.stderr[-2000:]
    with open(tmp_path / "metrics.csv", newline="") as f:
        trained = np.mean([float(row["length"]) for row in list(csv.DictReader(f))[-50:]])
    random_env = RobotTaskEnv(StayUp(CartPole()), num_envs=50, seed=seed)
    random = evaluate(random_env, random_policy(2, seed))["mean_length"]
    assert trained >= 3 * random, (trained, random)


def full_table_update(q, td):
    """The update as it was first written, with work in the table's size: the reference."""
    table, n = q.table[0], q.n_actions
    state, action = td["state_index"].reshape(-1), td["action"].reshape(-1)
    reward = td["next", "reward"].reshape(-1).to(torch.float64)
    bootstrap = table[q.discretizer(td["next", "observation"]).reshape(-1)].amax(-1)
    target = reward + q.gamma * torch.where(td["next", "terminated"].reshape(-1), 0.0, bootstrap)
    old = table[state, action]
    new = old + q.alpha * (target - old)
    flat = state * n + action
    delta = torch.zeros(table.numel(), dtype=torch.float64).index_add_(0, flat, new - old)
    count = torch.zeros(table.numel(), dtype=torch.float64).index_add_(0, flat, torch.ones_like(old))
    hit = count > 0
    expected = table.clone()
    expected.view(-1)[hit] += delta[hit] / count[hit]
    return expected


@pytest.mark.parametrize("batch", [1, 300])
def test_batched_update_matches_the_full_table_arithmetic_bit_for_bit(batch):
    q = learner()
    gen = torch.Generator().manual_seed(batch)
    q.table[0].uniform_(-1, 1, generator=gen)
    obs, next_obs = (torch.rand(batch, 3, generator=gen) * 4 for _ in range(2))
    td = transition(obs.tolist(), torch.randint(0, 2, (batch,), generator=gen).tolist(),
                    torch.randn(batch, generator=gen).tolist(), next_obs.tolist(),
                    (torch.rand(batch, generator=gen) < 0.2).tolist())
    td["state_index"] = q.discretizer(td["observation"])
    expected = full_table_update(q, td)
    q.observe(td)
    assert torch.equal(q.table[0], expected)
