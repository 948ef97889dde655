"""Wall-clock and env steps for dqn and qlearn to reach the win criterion on
cartpole/stay_up, over 3 seeds, and what a whole process costs around it (run by hand).

    python bench/time_to_solve.py [--seeds 0 1 2] [--num-envs-dqn 16] [--num-envs-qlearn 1]
    python bench/time_to_solve.py --against rainbow --seeds 1000 1001 1002 1003
    python bench/time_to_solve.py --seeds 0 --overrides max_env_steps=400   # the wiring only

Per learner, a Hydra sweep over the seeds; ``wall_s`` is the run's own clock to the
solving episode (training, from the run's start). Then one plain process,
``python train.py robot=cartpole learner=dqn seed=<first seed> eval_episodes=0
quiet=true``, timed from outside from its start to its exit, beside the part of it
before the first env step (imports, config, building; ``first_step_s`` of its
summary.json, by the kernel's process clock) and its run's own time to solve.

Last lines: ``START dqn cartpole/stay_up process_s=<start to exit> first_step_s=<start
to the first env step> wall_to_solve_s=<in the run> rest_s=<the remainder: after the
verdict is known, writing and plotting, and exiting>`` and ``SOLVE <learner>
cartpole/stay_up median_wall_s=<v> solved=<k>/3`` (the median over the seeds that
solved; ``nan`` if none did).

``--against rainbow`` instead: ``python train.py robot=cartpole learner=<dqn|rainbow>
seed=<s> quiet=true`` (each with its tuned file), one process at a time, the two
alternating which goes first from seed to seed; per seed each one's time to solve (the
run's own clock) and the ratio, then ``AGAINST rainbow/dqn cartpole/stay_up
median_ratio=<v> medians=<rainbow>/<dqn> both_solved=<k>/<n>`` (the issue's target: within 2x).
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import subprocess
import sys
import time
from pathlib import Path

from sweep import ROOT, fmt, run_sweep
from runs.summary import summarize_run  # noqa: E402  (sweep puts the root on the path)


#: ``--overrides``: set on every train.py run (a budget for a quick check of the script).
EXTRA: list[str] = []


def plain_run(overrides: list[str]) -> tuple[float, Path]:
    """One plain ``train.py robot=cartpole <overrides> quiet=true``, timed from outside:
    (seconds from start to exit, its run folder)."""
    cmd = [sys.executable, "train.py", "robot=cartpole", *overrides, *EXTRA, "quiet=true"]
    print("running:", " ".join(cmd), flush=True)
    start = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    process_s = time.perf_counter() - start
    found = re.search(r"^VERDICT .* run_dir=(.+)$", proc.stdout, re.MULTILINE)
    if proc.returncode != 0 or found is None:
        sys.exit(f"error: train.py exit code {proc.returncode}\n{proc.stdout}{proc.stderr}")
    return process_s, ROOT / found.group(1)


def whole_process(seed: int, num_envs: int) -> str:
    """One plain ``train.py`` dqn run, timed from outside; its START line."""
    overrides = ["learner=dqn", f"seed={seed}", "eval_episodes=0"]
    if num_envs != 16:  # the tuned file's
        overrides.append(f"num_envs={num_envs}")
    process_s, run_dir = plain_run(overrides)
    first = json.loads((run_dir / "summary.json").read_text()).get("first_step_s")
    solve = summarize_run(run_dir).get("wall_to_solve")
    rest = None if first is None or solve is None else process_s - first - solve
    return (f"START dqn cartpole/stay_up process_s={process_s:.1f} first_step_s={fmt(first, '.1f')} "
            f"wall_to_solve_s={fmt(solve, '.1f')} rest_s={fmt(rest, '.1f')}")


def against(other: str, base: str, seeds: list[int]) -> None:
    """``other`` and ``base`` seed by seed, one process at a time, alternating which goes first."""
    won: dict[str, list[float]] = {other: [], base: []}
    ratios = []
    for i, seed in enumerate(seeds):
        order = (base, other) if i % 2 == 0 else (other, base)
        walls = {}
        for learner in order:
            _, run_dir = plain_run([f"learner={learner}", f"seed={seed}"])
            walls[learner] = summarize_run(run_dir).get("wall_to_solve")
        for learner, wall in walls.items():
            if wall is not None:
                won[learner].append(wall)
        both = None not in walls.values()
        if both:
            ratios.append(walls[other] / walls[base])
        print(f"seed={seed} {base}_s={fmt(walls[base], '.1f')} {other}_s={fmt(walls[other], '.1f')} "
              f"ratio={fmt(ratios[-1] if both else None, '.2f')}", flush=True)
    median = statistics.median(ratios) if ratios else float("nan")
    medians = "/".join(f"{statistics.median(won[k]):.1f}" if won[k] else "nan" for k in (other, base))
    print(f"AGAINST {other}/{base} cartpole/stay_up median_ratio={median:.2f} medians={medians} "
          f"both_solved={len(ratios)}/{len(seeds)}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--num-envs-dqn", type=int, default=16)
    parser.add_argument("--num-envs-qlearn", type=int, default=1)
    parser.add_argument("--learners", nargs="+", default=["dqn", "qlearn"], choices=["dqn", "qlearn"])
    parser.add_argument("--against", choices=["rainbow"],
                        help="instead: this learner against dqn, one plain run at a time per seed")
    parser.add_argument("--overrides", nargs="+", default=[], metavar="KEY=VALUE",
                        help="set on every train.py run, e.g. max_env_steps=400 (a quick check)")
    args = parser.parse_args()
    EXTRA[:] = args.overrides
    if args.against:
        return against(args.against, "dqn", args.seeds)
    seeds = ",".join(map(str, args.seeds))
    results = {}
    for learner, n in (("dqn", args.num_envs_dqn), ("qlearn", args.num_envs_qlearn)):
        if learner not in args.learners:
            continue
        _, runs = run_sweep(f"time_to_solve_{learner}", [
            "robot=cartpole", f"learner={learner}", f"seed={seeds}", f"num_envs={n}",
            "eval_episodes=0", *EXTRA])
        results[learner] = runs
        for r in runs:
            print(f"{learner:7s} seed={r.get('seed')} num_envs={n} solved={r.get('solved')} "
                  f"episodes={fmt(r.get('episodes_to_solve'))} env_steps={fmt(r.get('steps_to_solve'))} "
                  f"wall_s={fmt(r.get('wall_to_solve'), '.1f')}")
    start_line = whole_process(args.seeds[0], args.num_envs_dqn)
    print()
    print(start_line)
    for learner, runs in results.items():
        won = [r["wall_to_solve"] for r in runs if r.get("solved")]
        median = statistics.median(won) if won else float("nan")
        print(f"SOLVE {learner} cartpole/stay_up median_wall_s={median:.1f} solved={len(won)}/{len(runs)}")


if __name__ == "__main__":
    main()
