"""A batched training step against its physics, by the batch's width (run by hand).

    python bench/width.py [--robot cartpole] [--task stay_up] [--learner qlearn]
                          [--copies 8] [--members 24] [--live 2] [--steps 400] [--repeats 3]

A tuning study's members finish at different times (solved, pruned, out of budget): its
batch starts wide and ends with a few members live, the others' copies held
(``BatchedPhysics.hold``). Three batches of ``copies`` a member, side by side in this run
(their loops alternating ``repeats`` times), each stepped as ``runs.loop.train`` steps one
(act, env step, observe, end of episodes; no runs, files or evaluations):

- ``wide``: ``members`` members, all live;
- ``held``: ``members`` members, all but ``live`` held (a round's tail as it runs now);
- ``narrow``: ``live`` members alone (the tail with the held members' rows dropped).

Per batch, its milliseconds a step and its physics' alone (``physics.step`` of the same
env, holds included), and their ratio; then ``held / narrow``: what dropping finished
members' rows from the step would save.

Last line: ``WIDTH wide_ratio=<v> held_ratio=<v> narrow_ratio=<v> held_over_narrow=<v>``.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hydra.utils import instantiate  # noqa: E402

from runs.training_state import seed_everything  # noqa: E402
from tasks.catalog import compose  # noqa: E402
from tasks.factory import build_env  # noqa: E402


class Batch:
    """``members`` members of ``copies`` copies each, all but the first ``live`` held."""

    def __init__(self, args: argparse.Namespace, members: int, live: int) -> None:
        cfg = compose(args.robot, task=args.task, learner=args.learner)
        self.learner = instantiate(cfg.learner, _convert_="all")
        self.env = build_env(cfg, args.copies * members, list(range(members)))
        self.learner.build(self.env.task, [seed_everything(seed) for seed in range(members)])
        self.members, self.copies = members, args.copies
        self.live = None if live == members else list(range(live))
        if self.live is not None:
            held = np.zeros(self.env.num_envs, dtype=bool)
            held[live * args.copies:] = True
            self.env.physics.hold(held)
        self.learner.begin()
        self.td = self.env.reset()

    def train(self, steps: int) -> float:
        """Seconds for ``steps`` training steps."""
        learner, env, td = self.learner, self.env, self.td
        start = time.perf_counter()
        for _ in range(steps):
            td = learner.act(td, self.live)
            td, nxt = env.step_and_maybe_reset(td)
            learner.observe(td, self.live)
            done = td.get(("next", "done")).reshape(self.members, self.copies).sum(1).tolist()
            ended = {b: count for b, count in enumerate(done) if count and (self.live is None or b in self.live)}
            if ended:
                learner.end_episodes(ended)
            td = nxt
        self.td = td
        return time.perf_counter() - start

    def physics(self, steps: int) -> float:
        """Seconds for the physics alone of ``steps`` steps (its held copies still held)."""
        physics, substeps = self.env.physics, self.env.task.n_substeps
        start = time.perf_counter()
        for _ in range(steps):
            physics.step(substeps)
        return time.perf_counter() - start


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="cartpole")
    parser.add_argument("--task", default="stay_up")
    parser.add_argument("--learner", default="qlearn")
    parser.add_argument("--copies", type=int, default=8, help="copies a member")
    parser.add_argument("--members", type=int, default=24, help="the wide batch's members (12 trials x 2 seeds)")
    parser.add_argument("--live", type=int, default=2, help="members still live in the tail")
    parser.add_argument("--steps", type=int, default=400)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if not 1 <= args.live < args.members or args.copies < 1 or args.steps < 1 or args.repeats < 1:
        parser.error("need 1 <= --live < --members, and --copies, --steps, --repeats at least 1")
    torch.set_num_threads(1)
    batches = {"wide": Batch(args, args.members, args.members), "held": Batch(args, args.members, args.live),
               "narrow": Batch(args, args.live, args.live)}
    train = dict.fromkeys(batches, 0.0)
    physics = dict.fromkeys(batches, 0.0)
    for batch in batches.values():  # warm-up: first calls, buffers
        batch.train(20)
    print(f"load average {os.getloadavg()[0]:.2f}; {args.robot}/{args.task} x {args.learner}, {args.copies} copies "
          f"a member, {args.steps} steps x {args.repeats}", flush=True)
    for _ in range(args.repeats):
        for name, batch in batches.items():
            train[name] += batch.train(args.steps)
            physics[name] += batch.physics(args.steps)
    steps = args.steps * args.repeats
    ratio = {}
    for name, batch in batches.items():
        ratio[name] = train[name] / physics[name]
        live = batch.members if batch.live is None else len(batch.live)
        print(f"{name:<7} {batch.members:>3} members, {live:>3} live: {train[name] / steps * 1e3:7.2f} ms a step, "
              f"physics alone {physics[name] / steps * 1e3:7.2f} ms: {ratio[name]:.2f}x")
    print(f"WIDTH wide_ratio={ratio['wide']:.2f} held_ratio={ratio['held']:.2f} narrow_ratio={ratio['narrow']:.2f} "
          f"held_over_narrow={train['held'] / train['narrow']:.2f}")
    for batch in batches.values():
        batch.env.close()


if __name__ == "__main__":
    main()
