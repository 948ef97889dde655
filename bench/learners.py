"""Every learner on cartpole/stay_up over 3 seeds, side by side (run by hand).

    python bench/learners.py [--seeds 0 1 2] [--learners qlearn n1try ...] [-- extra overrides]

e.g. ``-- hydra/launcher=joblib hydra.launcher.n_jobs=2`` runs two jobs at a time.

Runs one Hydra multirun of train.py and prints, per learner and seed, episodes,
env steps and wall-clock seconds to the win criterion and the final greedy
score, then the median per learner. Results stay in the printed sweep folder.
"""

from __future__ import annotations

import argparse
import statistics

from sweep import fmt, run_sweep

LEARNERS = ["qlearn", "n1try", "mbalunovic", "ruippeixotog", "dqn"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--learners", nargs="+", default=LEARNERS)
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides for every run")
    args = parser.parse_args()
    sweep_dir, runs = run_sweep("bench_learners", [
        "robot=cartpole", f"learner={','.join(args.learners)}",
        f"seed={','.join(map(str, args.seeds))}", *args.overrides])
    print(f"\n{'learner':13s} {'seed':>4s} {'solved':>6s} {'episodes':>8s} {'env_steps':>9s} "
          f"{'wall_s':>7s} {'greedy_len':>10s}")
    for r in runs:
        print(f"{str(r.get('learner')):13s} {r.get('seed', -1):4d} {str(r.get('solved', 'failed')):>6s} "
              f"{fmt(r.get('episodes_to_solve')):>8s} {fmt(r.get('steps_to_solve')):>9s} "
              f"{fmt(r.get('wall_to_solve'), '.1f'):>7s} {fmt(r.get('greedy_mean_length'), '.1f'):>10s}")
    print("\nper learner: solved seeds, median episodes / env steps / wall_s to solve, median greedy length")
    for learner in args.learners:
        mine = [r for r in runs if r.get("learner") == learner]
        won = [r for r in mine if r.get("solved")]
        med = lambda key, rs: statistics.median(r[key] for r in rs) if rs else None  # noqa: E731
        print(f"{learner:13s} solved={len(won)}/{len(mine)} episodes={fmt(med('episodes_to_solve', won))} "
              f"env_steps={fmt(med('steps_to_solve', won))} wall_s={fmt(med('wall_to_solve', won), '.1f')} "
              f"greedy={fmt(med('greedy_mean_length', [r for r in mine if 'greedy_mean_length' in r]), '.1f')}")
    print(f"\nsweep folder: {sweep_dir}")


if __name__ == "__main__":
    main()
