"""n-step returns (learner.n_step, learners/nstep.py): the rows a queue emits against the
sums written out by hand (a full queue, an episode's end by termination and by the time
limit), the TD target's gamma^k, and a dqn run with n_step=3 that learns, resumes exactly
after a kill and refuses n_step=0 in one line."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from inprocess import run_train
import torch

from learners.dqn import td_terms
from learners.transitions import Transitions, pack, unpack
from learners.nstep import NStep

ROOT = Path(__file__).resolve().parents[1]


def step(obs: float, action: int, reward: float, next_obs: float, terminated: bool) -> Transitions:
    """One copy's transition (observations of one number)."""
    return Transitions(torch.tensor([[float(obs)]]), torch.tensor([[action]]), torch.tensor([[float(reward)]]),
                       torch.tensor([[float(next_obs)]]), torch.tensor([[terminated]]))


def test_a_full_queue_emits_its_oldest_with_n_discounted_rewards():
    q = NStep(3, copies=1, n_obs=1, gamma=0.5)
    assert q.push(step(0, 0, 1.0, 1, False), torch.tensor([False])) is None
    assert q.push(step(1, 1, 2.0, 2, False), torch.tensor([False])) is None
    out = q.push(step(2, 2, 4.0, 3, False), torch.tensor([False]))
    # s0, a0: 1 + 0.5 * 2 + 0.25 * 4 = 3, bootstrapping from s3 with gamma^3
    assert out.observation.tolist() == [[0.0]] and out.action.tolist() == [[0]]
    assert out.reward.tolist() == [[3.0]] and out.next_observation.tolist() == [[3.0]]
    assert out.terminated.tolist() == [[False]] and out.steps.tolist() == [[3.0]]
    out = q.push(step(3, 0, 8.0, 4, False), torch.tensor([False]))
    assert out.observation.tolist() == [[1.0]] and out.reward.tolist() == [[2 + 0.5 * 4 + 0.25 * 8]]


@pytest.mark.parametrize("terminated", [True, False])
def test_an_episodes_end_empties_the_queue_each_with_what_follows_it(terminated):
    """At a termination nothing bootstraps; at the time limit (truncated) each row bootstraps
    from the last next observation with gamma^k, k the rewards it sums."""
    q = NStep(3, copies=1, n_obs=1, gamma=0.5)
    q.push(step(0, 0, 1.0, 1, False), torch.tensor([False]))
    out = q.push(step(1, 1, 2.0, 9, terminated), torch.tensor([True]))
    assert out.observation.tolist() == [[0.0], [1.0]]
    assert out.reward.tolist() == [[1 + 0.5 * 2], [2.0]] and out.steps.tolist() == [[2.0], [1.0]]
    assert out.next_observation.tolist() == [[9.0], [9.0]]
    assert out.terminated.tolist() == [[terminated], [terminated]]
    assert q.count.tolist() == [0]  # the next episode starts an empty queue
    assert q.push(step(5, 0, 1.0, 6, False), torch.tensor([False])) is None


def test_copies_queue_apart_and_emit_copy_by_copy():
    q = NStep(2, copies=2, n_obs=1, gamma=1.0)
    batch = Transitions(torch.tensor([[0.0], [10.0]]), torch.tensor([[0], [1]]), torch.tensor([[1.0], [5.0]]),
                        torch.tensor([[1.0], [11.0]]), torch.tensor([[False], [True]]))
    out = q.push(batch, torch.tensor([False, True]))  # copy 1 ends at once, copy 0 waits
    assert out.observation.tolist() == [[10.0]] and out.reward.tolist() == [[5.0]]
    assert q.count.tolist() == [1, 0]


def test_the_td_target_of_an_n_step_row_discounts_by_gamma_to_the_k():
    rows = pack(Transitions(torch.zeros(2, 1), torch.zeros(2, 1, dtype=torch.int64), torch.tensor([[1.0], [1.0]]),
                            torch.zeros(2, 1), torch.tensor([[False], [True]]), torch.tensor([[3.0], [2.0]])))
    batch = unpack(rows)
    assert batch.steps.tolist() == [[3.0], [2.0]]
    q, target = td_terms(lambda x: torch.full((len(x), 2), 10.0), lambda x: torch.full((len(x), 2), 10.0),
                         batch, 0.5, double_dqn=False)
    assert target.tolist() == [[1 + 0.5 ** 3 * 10], [1.0]]


def train(*args: str, kill: str | None = None) -> subprocess.CompletedProcess:
    if not kill:  # in this process (tests/inprocess.py); a kill needs a process of its own
        return run_train(*args)
    script = ["tests/kill_at.py", kill] if kill else ["train.py"]
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    return subprocess.run([sys.executable, *script, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=600, env=env)


RUN = ("robot=cartpole", "learner=dqn", "learner.n_step=3", "learner.prioritized=true", "learner.noisy=true",
       "learner.distributional=true", "learner.v_max=100", "max_env_steps=3000", "max_episodes=0",
       "eval_episodes=2", "checkpoint_every=20", "quiet=true", "seed=5",
       "~tuned", "num_envs=16", "learner.train_every=episode", "learner.updates=8", "learner.batch_size=128",
       "learner.tau=0.01")  # terms of its own (the cart-pole's former hand pick), whatever the tuned file


def test_an_n_step_run_killed_resumes_to_its_uninterrupted_end(tmp_path):
    """The queues (and, with prioritized replay, the priorities; noisy layers draw from the
    member's saved stream) are part of the training state: killed after its fourth
    checkpoint and resumed, a run with every switch on ends with the metrics and network
    of one never stopped."""
    whole = train(*RUN, f"hydra.run.dir={tmp_path / 'whole'}")
    assert whole.returncode == 0, whole.stderr[-2000:]
    killed = train(*RUN, f"hydra.run.dir={tmp_path / 'run'}", kill="checkpoint:4")
    assert killed.returncode == -9
    state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)
    assert state["learner"]["optimizer_steps"] > 0
    assert state["learner"]["n_step_queues"]["count"].shape == (16,)  # the queues of the 16 copies, saved
    priorities = state["learner"]["priorities"]["values"]
    assert priorities.dtype == torch.float64 and len(set(priorities[priorities > 0].tolist())) > 1  # TD errors'
    done = train(f"resume={tmp_path / 'run'}")
    assert done.returncode == 0, done.stderr[-2000:]
    assert (tmp_path / "run" / "metrics.csv").read_bytes() == (tmp_path / "whole" / "metrics.csv").read_bytes()
    a, b = (torch.load(d / "model.pt", weights_only=True)["actor"] for d in (tmp_path / "run", tmp_path / "whole"))
    assert all(torch.equal(a[k], b[k]) for k in a)


def test_n_step_below_one_is_one_line(tmp_path):
    proc = train("robot=cartpole", "learner=dqn", "learner.n_step=0", f"hydra.run.dir={tmp_path / 'r'}")
    err = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 2 and len(err) == 1 and "learner.n_step" in err[0], proc.stderr
