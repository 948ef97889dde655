"""What an asynchronous actor could save here (run by hand): a batch's env steps and its dqn
updates one after the other, then on two threads at once.

    python bench/async_bound.py [--robot cartpole] [--seeds 10] [--steps 3000] [--rounds 3]

A batch of dqn seeds steps its copies, then updates every member, one after the other (the
update needs the step's transition; the next action needs the update). An actor that acted
with the parameters from before the latest update could step while the update runs on the
second core, at the price of every fixed-seed number. Its best case on this machine:
``--steps`` env steps of the robot's default task at one copy a seed (the product's
``step_and_maybe_reset``, uniformly random actions) and the tuned file's updates a step of
``--seeds`` members (the update floor's plain stacked dqn update,
:func:`bench.seed_batch.plain_update`, at the tuned file's network and minibatch), timed
one after the other and then with the updates on a second thread. Acting, storing, booking
and the learner's sampling are not in it: they hold Python's lock, so a real actor hides less.

Last lines, a round each: ``ROUND <r> env_s=<v> updates_s=<v> serial_s=<v> threads_s=<v>
saved=<share of serial> hidden=<share of the update time hidden>``; then ``BOUND
saved=<median> hidden=<median>``. Its reading is on the docs' performance page
(docs/performance.md, "What an asynchronous actor could save").
"""

from __future__ import annotations

import argparse
import statistics
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    from tasks import catalog

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="cartpole", choices=catalog.robot_names(),
                        help="its default task, with its tuned dqn file")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--steps", type=int, default=3000, help="env steps a round")
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    if min(args.seeds, args.steps, args.rounds) < 1:
        sys.exit("error: --seeds, --steps and --rounds must be >= 1")

    import torch

    from bench.seed_batch import plain_update

    torch.set_num_threads(1)  # as a run's updates (torch_threads)
    cfg = catalog.compose(robot=args.robot, learner="dqn")
    env = catalog.make_env(args.robot, num_envs=args.seeds)
    n_obs = env.observation_spec["observation"].shape[-1]
    sizes = [n_obs, *cfg.learner.hidden, env.task.n_actions]
    activation = torch.relu if cfg.learner.activation == "relu" else torch.tanh
    update = plain_update("dqn", args.seeds, list(zip(sizes[1:], sizes[:-1])), int(cfg.learner.batch_size), activation)
    rounds = round(args.steps * float(cfg.learner.updates))
    td = env.reset()

    def steps(n: int) -> None:
        nonlocal td
        for _ in range(n):
            td["action"] = env.action_spec.rand()
            _, td = env.step_and_maybe_reset(td)

    def updates(n: int) -> None:
        for _ in range(n):
            update()

    steps(200)  # warm
    updates(100)
    saved, hidden = [], []
    print(f"{args.robot}: {args.seeds} copies, {args.steps} env steps and {rounds} updates of {args.seeds} members "
          f"(layers {sizes}, minibatch {cfg.learner.batch_size}) a round", flush=True)
    for r in range(args.rounds):
        start = time.perf_counter()
        steps(args.steps)
        env_s = time.perf_counter() - start
        start = time.perf_counter()
        updates(rounds)
        updates_s = time.perf_counter() - start
        start = time.perf_counter()
        learner = threading.Thread(target=updates, args=(rounds,))
        learner.start()
        steps(args.steps)
        learner.join()
        threads_s = time.perf_counter() - start
        serial = env_s + updates_s
        saved.append((serial - threads_s) / serial)
        hidden.append((serial - threads_s) / updates_s)
        print(f"ROUND {r} env_s={env_s:.3f} updates_s={updates_s:.3f} serial_s={serial:.3f} threads_s={threads_s:.3f} "
              f"saved={saved[-1]:.2f} hidden={hidden[-1]:.2f}", flush=True)
    env.close()
    print(f"BOUND saved={statistics.median(saved):.2f} hidden={statistics.median(hidden):.2f}")


if __name__ == "__main__":
    main()
