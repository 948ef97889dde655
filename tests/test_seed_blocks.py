"""Seed blocks: one env of S x n copies, seeded ``[s1, ..., sS]``, is S envs of n copies
seeded s1 ... sS, copy for copy, episode starts and restarts included (tasks/env.py)."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from tensordict import TensorDict

from tasks.catalog import compose, robot_names
from tasks.factory import build_env

SEEDS = (3, 7, 11)


@pytest.mark.parametrize("robot", robot_names())
def test_each_block_steps_exactly_as_its_seed_alone(robot):
    n, steps, limit = 2, 60, 25  # a 25-step time limit: every robot's episodes restart
    cfg = compose(robot, overrides=[f"task.max_episode_steps={limit}"])
    batch = build_env(cfg, n * len(SEEDS), list(SEEDS))
    alone = [build_env(cfg, n, s) for s in SEEDS]
    actions = np.random.default_rng(0).integers(batch.task.n_actions, size=(steps, n * len(SEEDS)))
    td_b = batch.reset()
    tds = [env.reset() for env in alone]
    restarts = 0
    try:
        for t in range(steps):
            td_b.set("action", torch.as_tensor(actions[t]))
            td_b, next_b = batch.step_and_maybe_reset(td_b)
            for b, env in enumerate(alone):
                tds[b].set("action", torch.as_tensor(actions[t, batch.block(b)]))
                td, tds[b] = env.step_and_maybe_reset(tds[b])
                for key in ("observation", "reward", "done", "terminated"):
                    assert torch.equal(td_b["next", key][batch.block(b)], td["next", key]), (t, b, key)
                assert torch.equal(next_b["observation"][batch.block(b)], tds[b]["observation"]), (t, b)
            restarts += int(td_b["next", "done"].sum())
            td_b = next_b
    finally:
        batch.close()
        for env in alone:
            env.close()
    assert restarts > 0, "no episode ended: the restarts were not compared"


@pytest.mark.parametrize("robot", robot_names())
def test_a_renewed_block_steps_exactly_as_its_new_seed_alone(robot):
    """Block 1 held (its run done), then renewed as seed 5: from there it steps as a new env
    of seed 5; blocks 0 and 2 as their seeds alone throughout."""
    n, limit, renewed = 2, 25, 5
    before, held, after = 30, 7, 60
    cfg = compose(robot, overrides=[f"task.max_episode_steps={limit}"])
    batch = build_env(cfg, n * len(SEEDS), list(SEEDS))
    alone = {0: build_env(cfg, n, SEEDS[0]), 2: build_env(cfg, n, SEEDS[2])}
    rng = np.random.default_rng(0)
    td_b, tds = batch.reset(), {b: env.reset() for b, env in alone.items()}
    restarts = 0
    try:
        for t in range(before + held + after):
            if t == before:
                batch.physics.hold(batch.block_mask(1))
            if t == before + held:
                first = batch.renew_block(1, renewed)
                alone[1] = build_env(cfg, n, renewed)
                tds[1] = alone[1].reset()
                assert torch.equal(first, tds[1]["observation"])
                assert batch.seed_block(1).divergences == 0
                td_b.get("observation")[batch.block(1)] = first
            actions = rng.integers(batch.task.n_actions, size=n * len(SEEDS))
            td_b.set("action", torch.as_tensor(actions))
            td_b, next_b = batch.step_and_maybe_reset(td_b)
            for b, env in alone.items():
                tds[b].set("action", torch.as_tensor(actions[batch.block(b)]))
                td, tds[b] = env.step_and_maybe_reset(tds[b])
                for key in ("observation", "reward", "done", "terminated"):
                    assert torch.equal(td_b["next", key][batch.block(b)], td["next", key]), (t, b, key)
                assert torch.equal(next_b["observation"][batch.block(b)], tds[b]["observation"]), (t, b)
            if t >= before + held:
                restarts += int(td_b["next", "done"][batch.block(1)].sum())
            td_b = next_b
    finally:
        batch.close()
        for env in alone.values():
            env.close()
    assert restarts > 0, "the renewed block's episodes never ended: their restarts were not compared"


def test_seed_blocks_must_divide_the_copies():
    with pytest.raises(ValueError, match="multiple of the number of seed blocks"):
        build_env(compose("cartpole"), 5, [0, 1])


def test_held_copies_stay_and_the_others_step_as_before():
    """``BatchedPhysics.hold``: a finished seed's copies keep their state; the rest step as
    they would with every copy stepping."""
    cfg = compose("cube")
    held, free = build_env(cfg, 4, [1, 2]), build_env(cfg, 4, [1, 2])
    try:
        for env in (held, free):
            env.reset()
        held.physics.hold(np.array([True, True, False, False]))
        frozen = held.physics.state[:2].copy()
        action = torch.full((4,), 0)  # the wheel to full speed: everything moves
        for _ in range(5):
            for env in (held, free):
                env.step(TensorDict(action=action, batch_size=[4]))
        assert np.array_equal(held.physics.state[:2], frozen)
        assert np.array_equal(held.physics.state[2:], free.physics.state[2:])
        assert not np.array_equal(free.physics.state[:2], frozen)
    finally:
        held.close()
        free.close()


def test_greedy_evaluation_steps_only_the_copies_still_running(monkeypatch):
    """runs.evaluate.evaluate holds a copy once its episode ends: later physics steps take
    fewer copies, and the result is the one stepping every copy to the end gives."""
    from runs.evaluate import evaluate
    from robots.physics import BatchedPhysics

    def policy(td):  # drives most copies off the rail early, some late
        action = (torch.arange(td.batch_size[0]) % 3 == 0).long()
        return td.set("action", action)

    cfg = compose("cartpole")
    env = build_env(cfg, 12, 5)
    stepped = []
    real_rollout = type(env.physics._pool).rollout
    monkeypatch.setattr(type(env.physics._pool), "rollout",
                        lambda pool, models, datas, start, *a, **k: stepped.append(len(start))
                        or real_rollout(pool, models, datas, start, *a, **k))
    try:
        env.set_seed(5)
        held = evaluate(env, policy)
        monkeypatch.setattr(BatchedPhysics, "hold", lambda self, mask: None)
        env.set_seed(5)
        everyone = evaluate(env, policy)
    finally:
        env.close()
    assert held == everyone
    assert stepped[0] == 12 and min(stepped[: len(stepped) // 2]) < 12, stepped
