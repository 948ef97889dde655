"""One learner over a member axis (learners/): every member of a learner of several acts and
learns bit for bit as the same seed in a learner of one (actions, networks or table,
optimizer state, replay buffer, schedule, counters, statistics, random streams), for
qlearn and every DQN variant, per-step and per-episode updates, one copy a member or
several; members not due for an update are left as they are; a member's saved state is
its own."""

from __future__ import annotations

import pytest
import torch
from hydra.utils import instantiate

from params import ConfigError
from tasks.catalog import compose
from runs.training_state import seed_everything
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
    return compose("cartpole", learner=learner, overrides=[f"task.max_episode_steps={LIMIT}", *overrides])


def made(cfg, seeds, cfgs=None):
    """A learner of one member per seed, each stream seeded as a run of that seed seeds it;
    ``cfgs``: each member's own config (its member-wise learner settings)."""
    generators = [seed_everything(seed) for seed in seeds]
    learner = instantiate(cfg.learner, _convert_="all")
    variants = None if cfgs is None else [instantiate(c.learner, _convert_="all") for c in cfgs]
    learner.build(build_env(cfg, 1, seeds[0]).task, generators, variants)
    return learner


def trained(cfg, seeds, n: int, steps: int, cfgs=None):
    """A learner of ``seeds`` trained on ``n`` copies a member (the loop of runs.loop.train
    without runs): the learner and each member's actions per step."""
    learner = made(cfg, seeds, cfgs)
    env = build_env(cfg, n * len(seeds), list(seeds) if len(seeds) > 1 else seeds[0])
    learner.begin()
    td, actions = env.reset(), []
    for _ in range(steps):
        td = learner.act(td)
        actions.append(td.get("action").clone().view(len(seeds), n))
        td, nxt = env.step_and_maybe_reset(td)
        learner.observe(td)
        done = td.get(("next", "done")).reshape(len(seeds), n).sum(1)
        learner.end_episodes({b: int(count) for b, count in enumerate(done) if count})
        td = nxt
    env.close()
    return learner, actions


def same_as_alone(cfg, n: int, steps: int, cfgs=None) -> None:
    """Each member of a learner of :data:`SEEDS` (``cfgs``: each with its own config) as its
    seed alone with its config."""
    together, actions = trained(cfg, SEEDS, n, steps, cfgs)
    for b, seed in enumerate(SEEDS):
        single, single_actions = trained(cfg if cfgs is None else cfgs[b], (seed,), n, steps)
        for t, (a, s) in enumerate(zip(actions, single_actions)):
            assert torch.equal(a[b], s[0]), (seed, "action", t)
        assert tensors_equal(together.training_state(b), single.training_state(0)), seed
        assert tensors_equal(together.model_state(b), single.model_state(0)), seed
        # its greedy policy seen alone (a run's evaluations in a batch) acts as the single's
        observation = build_env(cfg, 16, 7).reset()
        mine, alone = together.member(b), single.member(0)
        with mine.greedy(), alone.greedy():
            assert torch.equal(mine.policy(observation.clone()).get("action"),
                               alone.policy(observation.clone()).get("action")), (seed, "greedy")
        stats = [{k: v for k, v in x.train_stats(i, reset=False).items() if k != "updates_per_s"}
                 for x, i in ((together, b), (single, 0))]
        assert stats[0] == stats[1], seed
        if together.kind in ("dqn", "sac", "td3", "ppo"):
            assert together.steps[b] > 0


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
    # n-step returns (3): each member's queues, rows with their steps, gamma^k targets
    "dqn n-step": ("dqn", 2, ["learner.batch_size=32", "learner.updates=3", "learner.learning_starts=100",
                              "learner.n_step=3"]),
    # dueling heads beside n-step returns
    "dqn dueling": ("dqn", 2, ["learner.batch_size=32", "learner.updates=3", "learner.learning_starts=100",
                               "learner.dueling=true", "learner.n_step=2"]),
    # prioritized replay beside n-step returns: each member's priorities, draws and weights
    "dqn prioritized": ("dqn", 2, ["learner.batch_size=32", "learner.updates=3", "learner.learning_starts=100",
                                   "learner.prioritized=true", "learner.n_step=2",
                                   "learner.priority_beta_updates=50"]),
    # every switch of Rainbow's parts at once: noisy dueling C51 layers, n-step rows, prioritized draws
    "dqn every switch": ("dqn", 2, ["learner.batch_size=32", "learner.updates=3", "learner.learning_starts=100",
                                    "learner.noisy=true", "learner.dueling=true", "learner.n_step=3",
                                    "learner.prioritized=true", "learner.distributional=true",
                                    "learner.atoms=21", "learner.v_max=50"]),
    # a fixed input factor before the first layer (conf/tuned/cube_dqn.yaml's kind)
    "dqn with obs_scale": ("dqn", 2, ["learner.batch_size=32", "learner.updates=3", "learner.learning_starts=100",
                                      "+learner.obs_scale={cart_pos: 0.5, pole_vel: 3.0}"]),
    # SAC on the cart-pole's continuous form: actor, twin critics and their targets, the
    # temperature, each with its own Adam; random actions until learning_starts
    "sac, 1 copy": ("sac", 1, ["learner.hidden=[16,16]", "learner.batch_size=16", "learner.learning_starts=40"]),
    "sac, 2 copies, fixed alpha, clip": ("sac", 2, ["learner.hidden=[8]", "learner.batch_size=8",
                                                    "learner.learning_starts=30", "learner.updates=2",
                                                    "learner.fixed_alpha=true", "learner.grad_clip=1.0",
                                                    "learner.loss=smooth_l1"]),
    # a fixed input factor before every network (the critics' action inputs by 1)
    "sac with obs_scale": ("sac", 2, ["learner.hidden=[8]", "learner.batch_size=8", "learner.learning_starts=30",
                                      "+learner.obs_scale={cart_pos: 0.5, pole_vel: 3.0}"]),
    # TD3: a delayed actor (members whose updates step it, and those whose do not, apart),
    # target actor and critics, smoothing noise from each member's stream
    "td3, 2 copies": ("td3", 2, ["learner.hidden=[16]", "learner.batch_size=8", "learner.learning_starts=30",
                                 "learner.policy_delay=3", "learner.activation=tanh"]),
    # PPO: rollouts of 16 steps (several a run), GAE, 3 epochs of 4 minibatches from each
    # member's permutations, the actor's and critic's gradients clipped together
    "ppo, 2 copies": ("ppo", 2, ["learner.hidden=[16]", "learner.rollout_steps=16", "learner.epochs=3",
                                 "learner.minibatches=4"]),
}


# One Rainbow switch at a time: -m slow (17 s); "dqn every switch" holds them all in CI.
ONE_SWITCH = ("dqn n-step", "dqn dueling", "dqn prioritized")


@pytest.mark.parametrize("case", [pytest.param(c, marks=pytest.mark.slow) if c in ONE_SWITCH else c for c in DQN_CASES])
def test_a_dqn_member_learns_bit_for_bit_as_alone(case):
    name, n, overrides = DQN_CASES[case]
    same_as_alone(config(name, overrides), n, steps=120)


@pytest.mark.parametrize("n, overrides", [
    (8, []),  # the tuned file: 8 copies (their pairs collide: averaged increments)
    (1, []),
    (3, ["learner.noise_exploration=true", "learner.first_visit_reward=true", "learner.bootstrap_terminal=true"]),
])
def test_a_qlearn_member_learns_bit_for_bit_as_alone(n, overrides):
    same_as_alone(config("qlearn", overrides), n, steps=150)


# Trials side by side: members that differ in their member-wise settings (MEMBER_WISE).
TRIAL_CASES = {
    "qlearn": ("qlearn", 3, [], [[], ["learner.alpha=0.3", "learner.gamma=0.9"],
                                 ["learner.epsilon=0.5", "learner.epsilon_discount=0.99", "learner.epsilon_min=0.2",
                                  "learner.initial_q=5"]]),
    # each member's own bins (the cart-pole's tuned mapping, fewer, another with an entry
    # ignored): its table its own block of rows
    "qlearn bins": ("qlearn", 3, [], [
        [], ["learner.number_splits={cart_pos: 3, cart_vel: 3, pole_angle: 3, pole_vel: 3}", "learner.alpha=0.3"],
        ["learner.number_splits={cart_pos: 2, cart_vel: 7, pole_angle: 5, pole_vel: 1}", "learner.initial_q=1"]]),
    "dqn": ("dqn", 2, ["learner.batch_size=32", "learner.learning_starts=100", "learner.updates=3"],
            [[], ["learner.lr=0.003", "learner.gamma=0.95", "learner.tau=0.05", "learner.lr_decay=0.001"],
             ["learner.updates=1.5", "learner.learning_starts=60", "learner.grad_clip=0", "learner.reward_scale=0.1",
              "learner.epsilon.steps=500", "learner.done_episode_reward=-5"]]),
    # prioritized replay with each member's exponents and offsets
    "dqn prioritized": ("dqn", 2, ["learner.batch_size=32", "learner.learning_starts=100", "learner.updates=3",
                                   "learner.prioritized=true"],
                        [[], ["learner.priority_alpha=0.3", "learner.priority_beta=1.0"],
                         ["learner.priority_eps=0.01", "learner.priority_beta_updates=20"]]),
    # each member's replay buffer and minibatch size (ruippeixotog's and mbalunovic's spaces):
    # a round updates the members of each minibatch size together
    "dqn buffer and batch sizes": ("dqn", 2, ["learner.learning_starts=40", "learner.updates=3"],
                                   [["learner.batch_size=32", "learner.buffer_size=500"],
                                    ["learner.batch_size=16", "learner.buffer_size=150"],
                                    ["learner.batch_size=32", "learner.buffer_size=2000", "learner.lr=0.003"]]),
    "dqn prioritized, own sizes": ("dqn", 2, ["learner.learning_starts=40", "learner.updates=3",
                                              "learner.prioritized=true", "learner.n_step=2"],
                                   [["learner.batch_size=8", "learner.buffer_size=100"],
                                    ["learner.batch_size=24", "learner.buffer_size=300"],
                                    ["learner.batch_size=8", "learner.buffer_size=300"]]),
    "sac": ("sac", 2, ["learner.hidden=[16]", "learner.learning_starts=30"],
            [["learner.batch_size=16"], ["learner.lr=0.001", "learner.gamma=0.9", "learner.tau=0.05",
                                         "learner.alpha_init=0.2", "learner.batch_size=8"],
             ["learner.updates=0.5", "learner.target_entropy=-0.5", "learner.reward_scale=0.1",
              "learner.alpha_lr=0.01", "learner.buffer_size=300", "learner.batch_size=16"]]),
    # hard target copies every 20, 7 and 13 updates beside Polyak: all have a target network
    "mbalunovic": ("mbalunovic", 2, ["learner.batch_size=8"],
                   [["learner.target_update=20"], ["learner.target_update=7", "learner.gamma=0.9"],
                    ["learner.target_update=0", "learner.tau=0.02"]]),
}


@pytest.mark.parametrize("case", TRIAL_CASES)
def test_members_with_their_own_settings_learn_each_as_alone(case):
    name, n, shared, own = TRIAL_CASES[case]
    cfgs = [config(name, [*shared, *extra]) for extra in own]
    same_as_alone(cfgs[0], n, steps=120, cfgs=cfgs)


@pytest.mark.parametrize("name, a, b, says", [
    ("dqn", [], ["learner.hidden=[32]"], "learner.hidden differs between members"),
    ("dqn", [], ["learner.tau=0", "learner.double_dqn=false"], "learner.double_dqn differs"),
    ("mbalunovic", ["learner.target_update=20"], ["learner.target_update=0"], "a target network or none"),
    ("qlearn", [], ["learner.noise_exploration=true"], "learner.noise_exploration differs"),
])
def test_members_that_differ_in_a_shape_are_refused_in_one_line(name, a, b, says):
    cfgs = [config(name, a), config(name, b)]
    with pytest.raises(ConfigError, match=says) as err:
        made(cfgs[0], SEEDS[:2], cfgs)
    assert "\n" not in str(err.value)


# A batch's freed member given another trial x seed (Learner.renew): member 1 of SEEDS made anew
# as seed RENEWED, with the case's new settings (None: the learner's), halfway through.
RENEWED = 11
RENEW_CASES = {
    "qlearn": ("qlearn", 3, [], None, None),
    # other bins than the member it replaces: the table laid out again, the others' rows kept
    "qlearn, other bins": ("qlearn", 3, [], TRIAL_CASES["qlearn bins"][3],
                           ["learner.number_splits={cart_pos: 4, cart_vel: 2, pole_angle: 6, pole_vel: 3}",
                            "learner.alpha=0.2", "learner.initial_q=2"]),
    "dqn per step, 1 copy": (*DQN_CASES["dqn per step, 1 copy"], None, None),
    "dqn every switch": (*DQN_CASES["dqn every switch"], None, None),
    # a minibatch size no member had: a round of its own
    "dqn, own sizes": (*TRIAL_CASES["dqn prioritized, own sizes"][:4],
                       ["learner.batch_size=16", "learner.buffer_size=200", "learner.lr=0.002"]),
    "mbalunovic": (*TRIAL_CASES["mbalunovic"][:4], ["learner.target_update=5", "learner.gamma=0.8"]),
    "sac": (*TRIAL_CASES["sac"][:4], ["learner.batch_size=4", "learner.alpha_init=3.0"]),
    "ppo": ("ppo", 1, ["learner.hidden=[8]", "learner.rollout_steps=12", "learner.minibatches=3"], None, None),
    # a renewed member's delayed actor starts its count afresh: a round of its own kind
    "td3": ("td3", 1, ["learner.hidden=[8]", "learner.batch_size=8", "learner.learning_starts=20",
                       "learner.policy_delay=2"], None, None),
}


@pytest.mark.parametrize("case", RENEW_CASES)
def test_a_renewed_member_learns_bit_for_bit_as_a_fresh_one(case):
    """Member 1, renewed after 60 steps, acts and learns for 80 more as a learner of its new
    seed and settings alone on the same rows; members 0 and 2 as their seeds alone, untouched."""
    name, n, shared, own, new = RENEW_CASES[case]
    cfgs = None if own is None else [config(name, [*shared, *extra]) for extra in own]
    cfg = config(name, shared) if cfgs is None else cfgs[0]
    renewed_cfg = cfg if new is None else config(name, [*shared, *new])
    before, after, k = 60, 80, len(SEEDS)
    together = made(cfg, SEEDS, cfgs)
    env = build_env(cfg, n * k, list(SEEDS))
    together.begin()
    td, alone, rows = env.reset(), None, slice(n, 2 * n)
    for t in range(before + after):
        if t == before:
            variant = None if new is None else instantiate(renewed_cfg.learner, _convert_="all")
            together.renew(1, seed_everything(RENEWED), variant)
            alone = made(renewed_cfg, (RENEWED,))
            alone.begin()
        observed = td
        td = together.act(td)
        if alone is not None:
            assert torch.equal(alone.act(observed[rows].clone()).get("action"), td.get("action")[rows]), t
        td, nxt = env.step_and_maybe_reset(td)
        together.observe(td)
        done = td.get(("next", "done")).reshape(k, n).sum(1)
        together.end_episodes({b: int(count) for b, count in enumerate(done) if count})
        if alone is not None:
            alone.observe(td[rows].clone())
            if done[1]:
                alone.end_episodes({0: int(done[1])})
        td = nxt
    env.close()
    assert tensors_equal(together.training_state(1), alone.training_state(0))
    assert tensors_equal(together.model_state(1), alone.model_state(0))
    stats = [{k: v for k, v in x.train_stats(i, reset=False).items() if k != "updates_per_s"}
             for x, i in ((together, 1), (alone, 0))]
    assert stats[0] == stats[1]
    if together.kind in ("dqn", "sac", "td3", "ppo"):
        assert together.steps[1] > 0  # it learned after its renewal
    for b in (0, 2):
        single, _ = trained(cfg if cfgs is None else cfgs[b], (SEEDS[b],), n, before + after)
        assert tensors_equal(together.training_state(b), single.training_state(0)), SEEDS[b]


def snapshot(learner, b: int) -> dict:
    state = learner.training_state(b)
    return {k: v for k, v in state.items() if k != "buffer"} | {"updates": learner.trackers[b].count}


def test_members_not_due_keep_their_parameters_and_optimizer_state():
    """Per-episode updates: a round takes the members that owe one; the others' networks,
    target networks, Adam moments and steps, counters and streams do not change."""
    cfg = config("dqn", ["learner.batch_size=32", "learner.learning_starts=0", "learner.train_every=episode",
                         "learner.updates=1"])
    learner = made(cfg, SEEDS)
    env = build_env(cfg, 2 * len(SEEDS), list(SEEDS))
    td = learner.act(env.reset())
    for _ in range(20):
        td, nxt = env.step_and_maybe_reset(td)
        learner.observe(td)
        td = learner.act(nxt)
    learner.end_episodes({0: 3, 2: 1})  # every member's first updates: its optimizer state starts
    before = [snapshot(learner, b) for b in range(len(SEEDS))]
    stream = learner.generators[1].get_state()
    learner.end_episodes({0: 2})
    assert tensors_equal(snapshot(learner, 1), before[1]) and tensors_equal(snapshot(learner, 2), before[2])
    assert torch.equal(learner.generators[1].get_state(), stream)
    assert learner.steps == [5, 0, 1]
    assert learner.training_state(1)["optimizer"]["state"] == {}
    assert not tensors_equal(snapshot(learner, 0)["net"], before[0]["net"])
    env.close()


def test_a_members_saved_state_is_its_own():
    """Views of the members' tensors would save every member's: a member's states hold copies."""
    for name in ("dqn", "qlearn"):
        learner = made(config(name), SEEDS)
        for state in (learner.model_state(1), learner.training_state(1)):
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


def test_a_member_loads_another_members_state_and_acts_as_it():
    """A state saved from member 2 of a learner of three, loaded into a learner of one, gives
    the same greedy actions (the state is the member's, the layout the same)."""
    for name in ("dqn", "qlearn"):
        cfg = config(name)
        together, _ = trained(cfg, SEEDS, 2, 60)
        single = made(cfg, (0,))
        single.load_training_state(0, together.training_state(2))
        env = build_env(cfg, 4, 11)
        td = env.reset()
        mine, theirs = single.member(0), together.member(2)
        with mine.greedy(), theirs.greedy():
            assert torch.equal(mine.policy(td)["action"], theirs.policy(td)["action"]), name
        env.close()


def squares(out) -> torch.Tensor:
    """The sum of squares of a network's output (or outputs: an actor's location and scale)."""
    return sum(o.square().sum() for o in (out if isinstance(out, tuple) else (out,)))


@pytest.mark.parametrize("robot, name", [("cartpole", "dqn"), ("pendulum", "sac")])
def test_every_weight_and_bias_takes_its_gradient_after_adam_moved_them(robot, name):
    """A learner makes its members' layer views once: after Adam changed the parameters in
    place, a backward through them still gives each member the gradients its network alone
    (the template holding its parameters) gets, every weight's and bias's (an unsqueezed view
    of a bias leaf loses its way back to it and reads 0)."""
    learner = made(compose(robot, learner=name), SEEDS)
    groups = list(learner.groups.values()) if hasattr(learner, "groups") else [learner.group]
    for group in [g for g in groups if getattr(g, "net", None) is not None]:
        inputs = next(m for m in group.net.template if isinstance(m, torch.nn.Linear)).in_features
        x = torch.randn(len(SEEDS), 64, inputs, generator=torch.Generator().manual_seed(0))
        for _ in range(2):  # two Adam steps on gradients that moved every parameter
            group.grads.fill_(0.1)
            group.adam.step(None, group.params, group.grads, range(len(SEEDS)), [1e-2] * len(SEEDS))
        group.grads.zero_()
        squares(group.net.q(group.leaves, x)).backward()
        for b in range(len(SEEDS)):
            alone = group.net.load(group.params[b])
            alone.zero_grad()
            squares(alone(x[b])).backward()
            expected = torch.cat([p.grad.reshape(-1) for p in alone.parameters()])
            slots = [slot for layer in group.net.plan if not callable(layer) for slot in layer]
            assert all(expected[start:end].ne(0).any() for start, end, _ in slots)  # every weight and bias moves
            torch.testing.assert_close(group.grads[b], expected, rtol=1e-4, atol=1e-6)
