"""One DQN update of several seeds at once, four ways, side by side (run by hand).

    python bench/stack_update.py [--seeds 1 2 5 10] [--rounds 7]

On the tuned cart-pole DQN (4x64x64x2 ReLU, batch 128, Huber, double DQN, gradient clip),
each of S seeds with its own networks and its own minibatch:

- gradients (forward, loss, backward) of every seed's minibatch:
  ``loop``: each seed's own ``td_terms`` + loss + ``backward`` in turn (a run alone);
  ``stack``: :class:`learners.stack.DQNStack`'s stacked forward and hand-written backward;
  ``func``: ``torch.func.vmap(grad(loss))`` over ``functional_call`` on
  ``stack_module_state``'s parameters;
  ``tensordict``: ``TensorDict.from_modules`` parameters, the loss under ``to_module``,
  ``torch.vmap(grad(...))`` over them;
  each with the largest difference of its gradients from ``loop``'s;
- the whole update (gradients, clip, Adam, target network, statistics): ``loop`` (each
  seed's ``DQN._update``) against ``stack`` (``DQNStack._round`` of all seeds).

Timed in chunks of 20 calls alternating between the contestants; medians of ``--rounds``.

Measured 2026-11-26 (2 cores shared with other jobs, load average 3.4-3.7; torch 2.13 CPU,
one thread), microseconds for all S seeds, gradients differing from the loop's by 0 for
every way:

    S   gradients: loop  stack  func  tensordict    whole update: loop  stack  ratio
    1              407    324   1813   2434                       672    660   0.98
    2              771    430   2011   2619                      1431    832   0.58
    3             1176    526   2263   2767                      2046    926   0.45
    10            4334   1368   3843   4163                      7497   2675   0.36

``torch.func`` and tensordict pay their transforms' overhead on every call (about 1.5 ms
here), more than the whole stacked gradient of three seeds; the stack is used.
Last lines: ``STACK_GRAD seeds=<S> loop_us=.. stack_us=.. func_us=.. tensordict_us=..
stack_diff=.. func_diff=.. tensordict_diff=..`` and ``STACK_UPDATE seeds=<S> loop_us=..
stack_us=.. ratio=..``.
"""

from __future__ import annotations

import argparse
import copy
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
from torch.func import functional_call, grad, stack_module_state, vmap  # noqa: E402

from learners.dqn import _DISTANCES, Transitions, td_terms  # noqa: E402
from learners.stack import DQNStack  # noqa: E402
from robots.cartpole import CartPole  # noqa: E402
from runs.catalog import compose  # noqa: E402
from tasks.stay_up import StayUp  # noqa: E402


def learners(seeds: int, stored: int = 5_000) -> list:
    """``seeds`` tuned cart-pole DQNs, each its own initial network and ``stored`` random
    transitions in its buffer."""
    cfg = compose(robot="cartpole", learner="dqn")
    found = []
    for seed in range(seeds):
        torch.manual_seed(seed)
        learner = instantiate(cfg.learner, _convert_="all")
        learner.build(StayUp(CartPole()))
        gen = torch.Generator().manual_seed(100 + seed)
        rows = torch.randn(stored, learner.buffer.rows.shape[1], generator=gen)
        n = learner.n_obs
        rows[:, 2 * n] = torch.randint(0, learner.n_actions, (stored,), generator=gen)
        rows[:, 2 * n + 2] = (torch.rand(stored, generator=gen) < 0.05).float()
        learner.buffer.extend(rows)
        found.append(learner)
    return found


def timed(call: Callable[[], object], calls: int = 20) -> Callable[[], float]:
    def run() -> float:
        start = time.perf_counter()
        for _ in range(calls):
            call()
        return (time.perf_counter() - start) / calls * 1e6
    return run


def interleaved(runs: dict[str, Callable[[], float]], rounds: int) -> dict[str, float]:
    times: dict[str, list[float]] = {name: [] for name in runs}
    for run in runs.values():
        run()
    for _ in range(rounds):
        for name, run in runs.items():
            times[name].append(run())
    return {name: statistics.median(values) for name, values in times.items()}


def gradient_contestants(group: list) -> tuple[dict[str, Callable[[], list[torch.Tensor]]], list]:
    """Each way's call giving every seed's gradients, stacked ``[S, ...]`` per parameter."""
    first = group[0]
    distance = _DISTANCES[first.loss_function]
    batches = [g.buffer.sample_transitions(len(g.buffer)) for g in group]
    stacked = Transitions(*(torch.stack(parts) for parts in zip(*batches)))

    def loop() -> list[torch.Tensor]:
        for learner, batch in zip(group, batches):
            q, target = td_terms(learner._q, learner._target_q, batch, learner.gamma, learner.double_dqn)
            for p in learner._params:
                p.grad = None
            distance(q, target).backward()
        return [torch.stack([learner._params[k].grad for learner in group]) for k in range(len(first._params))]

    nets = [copy.deepcopy(g.net) for g in group]
    targets = [copy.deepcopy(g.target_net) for g in group]
    params, _ = stack_module_state(nets)
    target_params, _ = stack_module_state(targets)
    base = copy.deepcopy(first.net).to("meta")

    def seed_loss(p, tp, obs, action, reward, next_obs, terminated):
        q = functional_call(base, p, (obs,)).gather(-1, action)
        next_q = functional_call(base, tp, (next_obs,))
        best = functional_call(base, p, (next_obs,)).argmax(-1, keepdim=True)
        target = (reward + first.gamma * next_q.gather(-1, best) * ~terminated).detach()
        return distance(q, target)

    func_grad = vmap(grad(seed_loss))

    def func() -> list[torch.Tensor]:
        grads = func_grad(params, target_params, *stacked)
        return list(grads.values())

    td_params = TensorDict.from_modules(*nets, as_module=True)
    td_targets = TensorDict.from_modules(*targets, as_module=True)
    module = copy.deepcopy(first.net)

    def td_loss(p, tp, obs, action, reward, next_obs, terminated):
        with p.to_module(module):
            q = module(obs).gather(-1, action)
            best = module(next_obs).argmax(-1, keepdim=True)
        with tp.to_module(module):
            next_q = module(next_obs)
        target = (reward + first.gamma * next_q.gather(-1, best) * ~terminated).detach()
        return distance(q, target)

    td_grad = vmap(grad(td_loss))

    def tensordict() -> list[torch.Tensor]:
        grads = td_grad(td_params.data, td_targets.data, *stacked)
        return [grads[key] for key in td_params.keys(include_nested=True, leaves_only=True)]

    stack = DQNStack(group, [torch.Generator() for _ in group])

    def ours() -> list[torch.Tensor]:
        with torch.no_grad():
            return stack._loss(stack.weights, stack.weights if stack.shared_target else stack.targets, stacked)[3]

    return {"loop": loop, "stack": ours, "func": func, "tensordict": tensordict}, group


def max_diff(a: list[torch.Tensor], b: list[torch.Tensor]) -> float:
    return max(float((x - y).abs().max()) for x, y in zip(a, b))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 5, 10])
    parser.add_argument("--rounds", type=int, default=7)
    args = parser.parse_args()
    torch.set_num_threads(1)
    lines = []
    for seeds in args.seeds:
        if seeds < 1:
            sys.exit("error: --seeds must be >= 1")
        contestants, group = gradient_contestants(learners(seeds))
        reference = contestants["loop"]()
        diffs = {name: max_diff(call(), reference) for name, call in contestants.items() if name != "loop"}
        times = interleaved({name: timed(call) for name, call in contestants.items()}, args.rounds)
        lines.append(f"STACK_GRAD seeds={seeds} " + " ".join(f"{k}_us={v:.0f}" for k, v in times.items())
                     + " " + " ".join(f"{k}_diff={v:.2g}" for k, v in diffs.items()))
        loop_group, stack_group = learners(seeds), learners(seeds)
        stack = DQNStack(stack_group, [torch.Generator() for _ in stack_group])
        stored = {b: len(learner.buffer) for b, learner in enumerate(stack_group)}
        everyone = list(range(seeds))

        def loop_update() -> None:
            for learner in loop_group:
                learner._update(learner.buffer.sample_transitions(len(learner.buffer)))

        def stack_update() -> None:
            stack._round(everyone, stored, lambda b, work: work() or True)

        times = interleaved({"loop": timed(loop_update), "stack": timed(stack_update)}, args.rounds)
        lines.append(f"STACK_UPDATE seeds={seeds} loop_us={times['loop']:.0f} stack_us={times['stack']:.0f} "
                     f"ratio={times['stack'] / times['loop']:.2f}")
        print(lines[-2], lines[-1], sep="\n", flush=True)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
