"""Every learner on every robot's task over 3 seeds, judged by each task's own measure (run by hand).

    python bench/learners.py [--robots <names in conf/robot/>] [--learners qlearn dqn ...]
                             [--seeds 0 1 2] [-- extra overrides]
    python bench/learners.py --read multirun/bench_learners_*     # tabulate finished sweeps

e.g. ``-- hydra/launcher=joblib hydra.launcher.n_jobs=2`` runs two jobs at a time, and
``-- num_envs=8 max_episodes=200`` caps a long sweep (say so with the table).

Runs one Hydra multirun of train.py per robot (its tuned files apply as in a
plain run) and prints one table: robot/task x learner -> seeds solved (and by
which judge), the greedy policy's measure per seed, median episodes and wall
seconds to solve, and a uniformly random policy's measure on the same greedy
evaluation episodes for scale. Results stay in the printed sweep folders.
"""

from __future__ import annotations

import argparse
import statistics

import torch

from pathlib import Path

from sweep import fmt, job_summaries, run_sweep

from runs.evaluate import evaluate, measure_of
from tasks import catalog
from tasks.catalog import make_env

ROBOTS = catalog.robot_names()  # every robot in conf/robot/
LEARNERS = ["qlearn", "n1try", "mbalunovic", "ruippeixotog", "dqn"]


def random_policy_measure(robot: str, episodes: int = 20, seed: int = 10_000) -> tuple[float, object]:
    """The task's measure for uniformly random actions, one episode in each of ``episodes`` copies."""
    env = make_env(robot, num_envs=episodes, seed=seed)
    task = env.task
    gen = torch.Generator().manual_seed(seed)

    def act(td):
        return td.set("action", torch.randint(0, task.n_actions, (episodes,), generator=gen))

    value = measure_of(evaluate(env, act), task.success.measure)
    env.close()
    return value, task.success


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robots", nargs="+", default=ROBOTS)
    parser.add_argument("--learners", nargs="+", default=LEARNERS)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--read", nargs="+", type=Path, default=[],
                        help="finished sweep folders to tabulate instead of running new ones")
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides for every run")
    args = parser.parse_args()
    runs, folders = [], []
    if args.read:
        for folder in args.read:
            folders.append(folder)
            runs += job_summaries(folder)
    else:
        for robot in args.robots:
            sweep_dir, found = run_sweep(f"bench_learners_{robot}", [
                f"robot={robot}", f"learner={','.join(args.learners)}",
                f"seed={','.join(map(str, args.seeds))}", *args.overrides])
            folders.append(sweep_dir)
            runs += found
    rows = []
    for robot in dict.fromkeys(r.get("robot") for r in runs if r.get("robot")):
        random_value, success = random_policy_measure(robot)
        for learner in dict.fromkeys(r.get("learner") for r in runs if r.get("robot") == robot):
            mine = sorted((r for r in runs if r.get("robot") == robot and r.get("learner") == learner),
                          key=lambda r: r.get("seed", -1))
            won = [r for r in mine if r.get("solved")]
            med = lambda key: statistics.median(r[key] for r in won) if won else None  # noqa: E731
            judges = sorted({r["decided_by"] for r in won})
            rows.append({
                "task": f"{robot}/{mine[0].get('task')}",
                "learner": learner,
                "rule": f"{success.measure} {success.judge} >= {success.threshold:g} {success.unit}",
                "solved": f"{len(won)}/{len(mine)}" + (f" ({','.join(judges)})" if judges else ""),
                "greedy": " ".join(fmt(r.get("greedy"), ".2f") if r.get("status") == "ok"
                                   else r.get("status", "?") for r in mine),
                "episodes": fmt(med("episodes_to_solve")),
                "wall_s": fmt(med("wall_to_solve"), ".1f"),
                "random": f"{random_value:.2f}",
            })
    columns = ("task", "learner", "rule", "solved", "greedy", "episodes", "wall_s", "random")
    widths = {c: max(len(c), *(len(r[c]) for r in rows)) for c in columns}
    print("\nper robot/task and learner: solved k/n seeds (judge), the greedy "
          "policy's measure per seed, median episodes and wall seconds to solve (solved seeds), "
          "a random policy's measure")
    print("| " + " | ".join(c.ljust(widths[c]) for c in columns) + " |")
    print("|" + "|".join("-" * (widths[c] + 2) for c in columns) + "|")
    for r in rows:
        print("| " + " | ".join(r[c].ljust(widths[c]) for c in columns) + " |")
    for folder in folders:
        print(f"sweep folder: {folder}")


if __name__ == "__main__":
    main()
