"""Seeds stacked (learners/stack.py): every seed of a stack acts and learns bit for bit as
its learner alone, step by step (actions, networks or table, optimizer state, replay
buffer, schedule, counters, statistics, random streams), for qlearn and every DQN
variant, per-step and per-episode updates, one copy a seed or several; seeds not due
for an update are left as they are; a stacked seed's saved state is its own."""

from __future__ import annotations

import pytest
import torch
from hydra.utils import instantiate

from learners.stack import DQNStack, QLearnStack, stack
from runs.catalog import compose
from runs.seeding import seed_everything
from tasks.factory import build_env

SEEDS = (3, 8, 5)
LIMIT = 25  # steps per episode: episodes end often, so per-episode updates come at many steps


def tensors_equal(a, b) -> bool:
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and a.dtype == b.dtype and torch.equal(a, b)
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(tensors_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(tensors_equal(x, y) for x, y in zip(a, b))
    return a == b


def config(learner: str, overrides=()):
    return compose("cartpole", learner=learner, overrides=list(overrides))


def made(cfg, seed: int):
    """A learner as a run of ``seed`` makes it: the globals seeded, then built."""
    generator = seed_everything(seed)
    learner = instantiate(cfg.learner, _convert_="all")
    learner.build(build_env(cfg, 1, seed).task, generator)
    return learner


def alone(cfg, seed: int, n: int, steps: int):
    """A learner trained alone on ``n`` copies (the loop of learners.base.train without a run):
    the learner, its actions per step and torch's global generator state at the end."""
    learner = made(cfg, seed)
    env = build_env(cfg, n, seed, LIMIT)
    learner.begin()
    td, actions = env.reset(), []
    for _ in range(steps):
        td = learner.act(td)
        actions.append(td.get("action").clone())
        td, nxt = env.step_and_maybe_reset(td)
        learner.observe(td)
        for _ in range(int(td.get(("next", "done")).sum())):
            learner.end_episode()
        td = nxt
    env.close()
    return learner, actions, torch.get_rng_state()


def together(cfg, n: int, steps: int):
    """The seeds' learners as one stack on one env of seed blocks; per seed the learner, its
    actions per step and its torch stream's state at the end."""
    learners, streams = [], []
    for seed in SEEDS:
        learners.append(made(cfg, seed))
        streams.append(torch.Generator())
        streams[-1].set_state(torch.get_rng_state())
    stacked = stack(learners, streams)
    assert isinstance(stacked, QLearnStack if cfg.learner._target_.endswith("QLearn") else DQNStack)
    env = build_env(cfg, n * len(SEEDS), list(SEEDS), LIMIT)
    live = list(range(len(SEEDS)))
    for learner in learners:
        learner.begin()
    td, actions = env.reset(), []
    for _ in range(steps):
        td = stacked.act(td, live)
        actions.append(td.get("action").clone())
        td, nxt = env.step_and_maybe_reset(td)
        stacked.observe(td, live)
        done = td.get(("next", "done")).reshape(len(SEEDS), n)
        for b, learner in enumerate(learners):
            for _ in range(int(done[b].sum())):
                learner.end_episode()
        stacked.settle(live)
        td = nxt
    env.close()
    return [(learner, [a[env.block(b)] for a in actions], streams[b].get_state())
            for b, learner in enumerate(learners)]


def same_as_alone(cfg, n: int, steps: int) -> None:
    for b, (learner, actions, stream) in enumerate(together(cfg, n, steps)):
        single, single_actions, single_stream = alone(cfg, SEEDS[b], n, steps)
        for t, (a, s) in enumerate(zip(actions, single_actions)):
            assert torch.equal(a, s), (SEEDS[b], "action", t)
        assert tensors_equal(learner.training_state(), single.training_state()), SEEDS[b]
        assert tensors_equal(learner.model_state(), single.model_state()), SEEDS[b]
        stats = [{k: v for k, v in x.train_stats(reset=False).items() if k != "updates_per_s"}
                 for x in (learner, single)]
        assert stats[0] == stats[1], SEEDS[b]
        if learner.kind == "dqn":  # its stream is torch's global one alone
            assert torch.equal(stream, single_stream), SEEDS[b]
            assert learner.optimizer_steps > 0


DQN_CASES = {
    # the tuned cart-pole DQN: per-episode updates, 16 copies (here 4), Huber, Polyak target, clip
    "dqn per episode": ("dqn", 4, ["learner.batch_size=32", "learner.updates=3", "learner.learning_starts=100"]),
    # the default's per-transition updates, one copy a seed (acting products below BLAS size)
    "dqn per step, 1 copy": ("dqn", 1, ["~tuned", "learner.learning_starts=40", "learner.batch_size=16"]),
    # tanh, l2, Keras lr decay, no target network, one update per episode
    "n1try": ("n1try", 2, ["learner.batch_size=32"]),
    # l2, hard target copy every 100 updates (here 20), -200 at a termination, minibatch
    # products below BLAS size (a batch of 8)
    "mbalunovic": ("mbalunovic", 2, ["learner.target_update=20", "learner.batch_size=8"]),
    # l2, no target network, per episode, replay of 2000
    "ruippeixotog": ("ruippeixotog", 3, []),
    # a fixed input factor before the first layer (conf/tuned/cube_dqn.yaml's kind)
    "dqn with obs_scale": ("dqn", 2, ["learner.batch_size=32", "learner.updates=3", "learner.learning_starts=100",
                                      "+learner.obs_scale={cart_pos: 0.5, pole_vel: 3.0}"]),
}


@pytest.mark.parametrize("case", DQN_CASES)
def test_a_dqn_seed_in_a_stack_learns_bit_for_bit_as_alone(case):
    name, n, overrides = DQN_CASES[case]
    same_as_alone(config(name, overrides), n, steps=120)


@pytest.mark.parametrize("n, overrides", [
    (8, []),  # the tuned file: 8 copies (their pairs collide: averaged increments)
    (1, []),
    (3, ["learner.noise_exploration=true", "learner.first_visit_reward=true", "learner.bootstrap_terminal=true"]),
])
def test_a_qlearn_seed_in_a_stack_learns_bit_for_bit_as_alone(n, overrides):
    same_as_alone(config("qlearn", overrides), n, steps=150)


def snapshot(learner) -> dict:
    state = learner.training_state()
    return {k: v for k, v in state.items() if k != "buffer"} | {"updates": learner.tracker.count}


def test_seeds_not_due_keep_their_parameters_and_optimizer_state():
    """Per-episode updates: a round takes the seeds that owe one; the others' networks,
    target networks, Adam moments and steps, counters and streams do not change."""
    cfg = config("dqn", ["learner.batch_size=32", "learner.learning_starts=0"])
    learners, streams = [made(cfg, seed) for seed in SEEDS], [torch.Generator().manual_seed(s) for s in SEEDS]
    stacked = stack(learners, streams)
    env = build_env(cfg, 2 * len(SEEDS), list(SEEDS), LIMIT)
    live = list(range(len(SEEDS)))
    td = stacked.act(env.reset(), live)
    for _ in range(20):
        td, nxt = env.step_and_maybe_reset(td)
        stacked.observe(td, live)
        td = stacked.act(nxt, live)
    stacked._owe(0, 3)
    stacked._owe(2, 1)
    stacked.settle(live)  # every seed's first updates: its optimizer state starts
    before = [snapshot(learner) for learner in learners]
    stream = streams[1].get_state()
    stacked._owe(0, 2)
    stacked.settle(live)
    assert tensors_equal(snapshot(learners[1]), before[1]) and tensors_equal(snapshot(learners[2]), before[2])
    assert torch.equal(streams[1].get_state(), stream)
    assert learners[0].optimizer_steps == 5 and learners[2].optimizer_steps == 1
    assert learners[1].optimizer_steps == 0 and learners[1].training_state()["optimizer"]["state"] == {}
    assert not tensors_equal(snapshot(learners[0])["net"], before[0]["net"])
    env.close()


def test_a_stacked_seeds_saved_state_is_its_own():
    """Views of the stacked tensors would save every seed's: a seed's states hold copies."""
    for name in ("dqn", "qlearn"):
        cfg = config(name)
        learners = [made(cfg, seed) for seed in SEEDS]
        stacked = stack(learners, [torch.Generator() for _ in SEEDS])
        if name == "dqn":
            stacked._start(1)
        for state in (learners[1].model_state(), learners[1].training_state()):
            tensors = [v for v in _leaves(state) if isinstance(v, torch.Tensor)]
            assert tensors and all(t.untyped_storage().nbytes() == t.nbytes for t in tensors), name


def _leaves(state):
    if isinstance(state, dict):
        for value in state.values():
            yield from _leaves(value)
    elif isinstance(state, (list, tuple)):
        for value in state:
            yield from _leaves(value)
    else:
        yield state


def test_only_one_learner_kind_of_two_or_more_seeds_stacks():
    learners = [made(config("qlearn"), seed) for seed in SEEDS[:2]]
    assert stack(learners[:1], [torch.Generator()]) is None
    assert stack([learners[0], made(config("dqn"), 1)], [torch.Generator()] * 2) is None
