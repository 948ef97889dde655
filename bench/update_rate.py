"""The learners' hot paths, timed side by side in one process (run by hand).

    python bench/update_rate.py [--seconds 0.5] [--rounds 5]

qlearn: transitions per second of our batched epsilon-greedy choice and table update
(``QLearn.act`` + ``QLearn.observe``, one member, observations discretised on the way) at batch 64
and 4096, on cart-pole's 4 entries x 10 bins (a 10,000 x 2 table), beside a plain dict
Q-learner as the original openai_ros ``qlearn.py`` (a dict keyed by (state, action);
choose: a random action with probability epsilon, else the max over actions; learn:
Q += alpha * (r + gamma * max - Q)), given the states already discretised, one
transition at a time. The two alternate in chunks of ``--seconds``; medians over
``--rounds``.

dqn: one update of ``learners.dqn`` (one member) on a cart-pole network of 4x64x64x2, batch
128 (:data:`PINNED`; the tuned file's other settings) and its parts, each timed in chunks
of 100 calls alternating with the others.

``--switches``: instead, one update of the plain dqn against the dqn with each of Rainbow's
parts on (``learner.n_step=3``, ``prioritized``, ``dueling``, ``noisy``, ``distributional``
on 51 atoms) and with all of them (``learner=rainbow``), in alternating chunks of 100.

``--denormals``: instead, one Adam step of the cart-pole rainbow's network whose first moment
holds denormal numbers (as a dead unit's weights leave it), with the runs' flushing of them to
0 (``runs.lifecycle.denormals_flushed``) and without, alternating.

The last lines are machine-readable::

    DQN_UPDATE batch=128 us=<median per update>
    DQN_SWITCH name=<plain|n_step|...|rainbow> us=<median per update> ratio=<to plain>   (--switches)
    ADAM_DENORMALS us=<median, denormals kept> flushed_us=<median, flushed> ratio=<x>   (--denormals)
    QLEARN_RATE batch=64 ours=<t/s> dict=<t/s> ratio=<x>
    QLEARN_RATE batch=4096 ours=<t/s> dict=<t/s> ratio=<x>
"""

from __future__ import annotations

import argparse
import contextlib
import random
import statistics
import sys
import time
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import torch  # noqa: E402
from hydra.utils import instantiate  # noqa: E402
from tensordict import TensorDict  # noqa: E402

from learners.qlearn import QLearn  # noqa: E402
from robots.cartpole import CartPole  # noqa: E402
from tasks.catalog import compose  # noqa: E402
from tasks.stay_up import StayUp  # noqa: E402

BATCHES = (64, 4096)


class DictQLearner:
    """Tabular Q-learning on a dict keyed by (state, action), one transition at a time."""

    def __init__(self, n_actions: int, alpha: float, gamma: float, epsilon: float,
                 seed: int = 0) -> None:
        self.q: dict[tuple[int, int], float] = {}
        self.actions = list(range(n_actions))
        self.alpha, self.gamma, self.epsilon = alpha, gamma, epsilon
        self.rng = random.Random(seed)

    def choose(self, state: int) -> int:
        if self.rng.random() < self.epsilon:
            return self.rng.choice(self.actions)
        q = [self.q.get((state, a), 0.0) for a in self.actions]
        return self.actions[q.index(max(q))]

    def learn(self, state: int, action: int, reward: float, next_state: int) -> None:
        best = max(self.q.get((next_state, a), 0.0) for a in self.actions)
        old = self.q.get((state, action), 0.0)
        self.q[(state, action)] = old + self.alpha * (reward + self.gamma * best - old)


def interleaved(runs: dict[str, Callable[[], float]], rounds: int) -> dict[str, float]:
    """Calls each of ``runs`` (returning a rate) once per round, alternating; the medians."""
    rates: dict[str, list[float]] = {name: [] for name in runs}
    for run in runs.values():
        run()  # warm-up
    for _ in range(rounds):
        for name, run in runs.items():
            rates[name].append(run())
    return {name: statistics.median(values) for name, values in rates.items()}


# -- qlearn -------------------------------------------------------------------
def transitions(task, batch: int, n: int, gen: torch.Generator) -> list[TensorDict]:
    """``n`` batches of random transitions within the task's tabular bounds."""
    bounds = task.tabular_bounds
    low, high = torch.as_tensor(bounds.low), torch.as_tensor(bounds.high)
    n_obs = len(task.observation_names)

    def observations() -> torch.Tensor:
        obs = torch.zeros(batch, n_obs)
        unit = torch.rand(batch, len(bounds.indices), generator=gen, dtype=torch.float64)
        obs[:, list(bounds.indices)] = (low + unit * (high - low)).float()
        return obs

    return [TensorDict({"observation": observations(), ("next", "observation"): observations(),
                        ("next", "reward"): torch.rand(batch, 1, generator=gen),
                        ("next", "terminated"): torch.rand(batch, 1, generator=gen) < 0.05},
                       batch_size=[batch]) for _ in range(n)]


def ours_rate(learner: QLearn, data: list[TensorDict], seconds: float) -> float:
    """Transitions per second of choice + update, cycling through ``data``."""
    done, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for td in data:
            learner.observe(learner.act(td))
        done += sum(td.numel() for td in data)
    return done / (time.perf_counter() - start)


def dict_rate(learner: DictQLearner, data: list[tuple[list, list, list]], seconds: float) -> float:
    """Transitions per second of choose + learn, one transition at a time."""
    done, start = 0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for states, rewards, next_states in data:
            for s, r, s2 in zip(states, rewards, next_states):
                learner.learn(s, learner.choose(s), r, s2)
            done += len(states)
    return done / (time.perf_counter() - start)


def qlearn_rates(batch: int, seconds: float, rounds: int) -> dict[str, float]:
    """Our rate and the dict learner's on the same transitions, alternating."""
    task = StayUp(CartPole())
    ours = QLearn(alpha=0.1, gamma=0.9, epsilon=0.1, number_splits=10)
    ours.build(task, torch.Generator().manual_seed(0))
    data = transitions(task, batch, max(1, 16384 // batch), torch.Generator().manual_seed(1))
    index = ours.discretizer
    plain = [(index(td["observation"]).tolist(), td["next", "reward"].reshape(-1).tolist(),
              index(td["next", "observation"]).tolist()) for td in data]
    theirs = DictQLearner(task.n_actions, alpha=0.1, gamma=0.9, epsilon=0.1)
    return interleaved({"ours": lambda: ours_rate(ours, data, seconds),
                        "dict": lambda: dict_rate(theirs, plain, seconds)}, rounds)


# -- dqn ----------------------------------------------------------------------
# The network and minibatch every timed update uses, whatever the tuned files hold (the
# cart-pole's studies pick other sizes per learner, which would time sizes, not switches).
PINNED = ("learner.hidden=[64,64]", "learner.batch_size=128")


def dqn_learner(stored: int = 20_000, learner: str = "dqn", overrides: tuple[str, ...] = ()):
    """The cart-pole DQN with its tuned file but :data:`PINNED` sizes (one member;
    ``learner`` and ``overrides``: another of the family), its buffer holding ``stored``
    random transitions."""
    cfg = compose(robot="cartpole", learner=learner, overrides=[*PINNED, *overrides])
    learner = instantiate(cfg.learner, _convert_="all")
    learner.build(StayUp(CartPole()), torch.Generator().manual_seed(0))
    gen = torch.Generator().manual_seed(0)
    buffer = learner.buffers[0]
    rows = torch.randn(stored, buffer.rows.shape[1], generator=gen)
    n = learner.n_obs
    rows[:, 2 * n] = torch.randint(0, learner.n_actions, (stored,), generator=gen)
    rows[:, 2 * n + 2] = (torch.rand(stored, generator=gen) < 0.05).float()
    if rows.shape[1] > 2 * n + 3:  # n-step rows: the rewards each sums
        rows[:, 2 * n + 3] = torch.randint(1, learner.n_step + 1, (stored,), generator=gen).float()
    for chunk in rows.split(16):
        buffer.put(chunk)  # as a run stores them (prioritized replay gives each its priority)
    buffer.book()
    return learner


SWITCHES = {"plain": ("dqn", ()), "n_step": ("dqn", ("learner.n_step=3",)),
            "prioritized": ("dqn", ("learner.prioritized=true",)), "dueling": ("dqn", ("learner.dueling=true",)),
            "noisy": ("dqn", ("learner.noisy=true",)),
            "distributional": ("dqn", ("learner.distributional=true", "learner.v_min=0", "learner.v_max=100")),
            "rainbow": ("rainbow", ())}


def switch_times(rounds: int) -> dict[str, float]:
    """Median microseconds per update of the dqn with each of :data:`SWITCHES`, interleaved."""
    def timer(learner) -> Callable[[], float]:
        def run() -> float:
            start = time.perf_counter()
            learner.optimize(100)
            return (time.perf_counter() - start) / 100 * 1e6
        return run

    return interleaved({name: timer(dqn_learner(learner=base, overrides=extra))
                        for name, (base, extra) in SWITCHES.items()}, rounds)


def dqn_parts(learner) -> dict[str, Callable[[], object]]:
    """The update and its parts as calls on one sampled minibatch."""
    from learners.dqn import _DISTANCES, td_terms
    from learners.member import adam_step
    from learners.transitions import unpack

    buffer, stored = learner.buffers[0], len(learner.buffers[0])
    batch = unpack(buffer.sample_rows(stored).unsqueeze(0))
    distance = _DISTANCES[learner.loss_function]

    def q_of(params):
        return lambda x: learner.net.q(params, x)

    def backward() -> None:
        leaf = learner.params.detach().requires_grad_(True)
        q, target = td_terms(q_of(leaf), q_of(learner.target), batch, learner.gamma, learner.double_dqn)
        distance(q, target, reduction="none").mean((1, 2)).sum().backward()

    grads = torch.zeros_like(learner.params)
    moments = torch.zeros_like(learner.params), torch.zeros_like(learner.params)
    params = learner.params.clone()
    return {
        "update (whole)": lambda: learner.optimize(1),
        "replay sample": lambda: buffer.sample_rows(stored),
        "forward (q, targets)": lambda: td_terms(q_of(learner.params), q_of(learner.target), batch,
                                                 learner.gamma, learner.double_dqn),
        "q forward + loss + backward": backward,
        "adam (member axis)": lambda: adam_step(params, grads, *moments, [1], [1e-3]),
        "target update": lambda: learner.target.lerp_(learner.params, learner.tau),
    }


def dqn_times(rounds: int) -> dict[str, float]:
    """Median microseconds per call of each part, in alternating chunks of 100 calls."""
    def timer(call: Callable[[], object]) -> Callable[[], float]:
        def run() -> float:
            start = time.perf_counter()
            for _ in range(100):
                call()
            return (time.perf_counter() - start) / 100 * 1e6
        return run

    parts = dqn_parts(dqn_learner())
    return interleaved({name: timer(call) for name, call in parts.items()}, rounds)


def denormal_times(rounds: int) -> dict[str, float]:
    """Median microseconds of one Adam step of the cart-pole rainbow's network (its tuned
    file's sizes, one member) whose first moment holds denormal numbers where the gradient
    is 0 (a dead unit's weights: 68% of them, the share a trained run's large layers held),
    inside :func:`runs.lifecycle.denormals_flushed` and outside, alternating chunks of 100."""
    from learners.member import adam_step
    from runs.lifecycle import denormals_flushed

    learner = instantiate(compose(robot="cartpole", learner="rainbow").learner, _convert_="all")
    learner.build(StayUp(CartPole()), torch.Generator().manual_seed(0))
    gen = torch.Generator().manual_seed(0)
    dead = torch.rand(learner.params.shape, generator=gen) < 0.68
    grads = torch.randn(learner.params.shape, generator=gen).mul_(1e-3).masked_fill_(dead, 0.0)

    def timer(flush: bool) -> Callable[[], float]:
        params, exp_avg_sq = learner.params.clone(), grads.square().masked_fill_(dead, 1e-10)  # decaying
        exp_avg = grads.clone().masked_fill_(dead, torch.finfo(torch.float32).smallest_normal / 2 ** 23)

        def run() -> float:
            with denormals_flushed() if flush else contextlib.nullcontext():
                start = time.perf_counter()
                for _ in range(100):
                    adam_step(params, grads, exp_avg, exp_avg_sq, [1000], [1e-3])
                return (time.perf_counter() - start) / 100 * 1e6
        return run

    print(f"adam step of {learner.params.shape[1]:,} parameters, {int(dead.sum()):,} of them holding denormals:")
    return interleaved({"denormals": timer(False), "flushed": timer(True)}, rounds)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=0.5, help="length of one timed chunk")
    parser.add_argument("--rounds", type=int, default=5, help="chunks per contestant")
    parser.add_argument("--switches", action="store_true", help="the dqn's update with each of Rainbow's parts")
    parser.add_argument("--denormals", action="store_true",
                        help="an Adam step on moments holding denormals, flushed to 0 or not")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.denormals:
        times = denormal_times(max(args.rounds, 5) * 3)
        for name, us in times.items():
            print(f"  {name:10s} {us:8.1f}")
        print(f"ADAM_DENORMALS us={times['denormals']:.1f} flushed_us={times['flushed']:.1f} "
              f"ratio={times['denormals'] / times['flushed']:.2f}")
        return
    if args.switches:
        times = switch_times(max(args.rounds, 5) * 3)
        print("dqn, cart-pole network 4x64x64x2, batch 128: one update (median us), each part on alone:")
        for name, us in times.items():
            print(f"  {name:16s} {us:8.1f}  {us / times['plain']:.2f}x")
        for name, us in times.items():
            print(f"DQN_SWITCH name={name} us={us:.1f} ratio={us / times['plain']:.2f}")
        return
    times = dqn_times(max(args.rounds, 5) * 3)
    print("dqn, cart-pole network 4x64x64x2, batch 128 (median us per call):")
    for name, us in times.items():
        print(f"  {name:28s} {us:8.1f}")
    rates = {batch: qlearn_rates(batch, args.seconds, args.rounds) for batch in BATCHES}
    print("qlearn, 10,000 x 2 table (transitions/s, median):")
    for batch, r in rates.items():
        print(f"  batch {batch:5d}: ours {r['ours']:12,.0f}  dict {r['dict']:10,.0f}  "
              f"ratio {r['ours'] / r['dict']:.1f}x")
    print(f"DQN_UPDATE batch=128 us={times['update (whole)']:.1f}")
    for batch, r in rates.items():
        print(f"QLEARN_RATE batch={batch} ours={r['ours']:.0f} dict={r['dict']:.0f} "
              f"ratio={r['ours'] / r['dict']:.2f}")


if __name__ == "__main__":
    main()
