"""Wall-clock and env steps for dqn and qlearn to reach the win criterion on
cartpole/stay_up, over 3 seeds (run by hand).

    python bench/time_to_solve.py [--seeds 0 1 2] [--num-envs-dqn 16] [--num-envs-qlearn 1]

Last lines: ``SOLVE <learner> cartpole/stay_up median_wall_s=<v> solved=<k>/3``
(the median over the seeds that solved; ``nan`` if none did).
"""

from __future__ import annotations

import argparse
import statistics

from sweep import fmt, run_sweep


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--num-envs-dqn", type=int, default=16)
    parser.add_argument("--num-envs-qlearn", type=int, default=1)
    args = parser.parse_args()
    seeds = ",".join(map(str, args.seeds))
    results = {}
    for learner, n in (("dqn", args.num_envs_dqn), ("qlearn", args.num_envs_qlearn)):
        _, runs = run_sweep(f"time_to_solve_{learner}", [
            "robot=cartpole", f"learner={learner}", f"seed={seeds}", f"num_envs={n}",
            "eval_episodes=0"])
        results[learner] = runs
        for r in runs:
            print(f"{learner:7s} seed={r.get('seed')} num_envs={n} solved={r.get('solved')} "
                  f"episodes={fmt(r.get('episodes_to_solve'))} env_steps={fmt(r.get('steps_to_solve'))} "
                  f"wall_s={fmt(r.get('wall_to_solve'), '.1f')}")
    print()
    for learner, runs in results.items():
        won = [r["wall_to_solve"] for r in runs if r.get("solved")]
        median = statistics.median(won) if won else float("nan")
        print(f"SOLVE {learner} cartpole/stay_up median_wall_s={median:.1f} solved={len(won)}/{len(runs)}")


if __name__ == "__main__":
    main()
