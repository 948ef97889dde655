"""Every learner on cartpole/stay_up over 3 seeds, side by side (run by hand).

    python bench/learners.py [--seeds 0 1 2] [--learners qlearn n1try ...] [extra overrides]

Runs one Hydra multirun of train.py and prints, per learner and seed, episodes,
env steps and wall-clock seconds to the win criterion and the final greedy
score, then the median per learner. Results stay in the printed sweep folder.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from learners.summary import summarize_run  # noqa: E402

LEARNERS = ["qlearn", "n1try", "mbalunovic", "ruippeixotog", "dqn"]


def fmt(value, spec=".0f") -> str:
    return "-" if value is None else format(value, spec)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--learners", nargs="+", default=LEARNERS)
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides for every run")
    args = parser.parse_args()
    sweep_dir = ROOT / "multirun" / f"bench_learners_{time.strftime('%Y%m%d-%H%M%S')}"
    cmd = [sys.executable, "train.py", "-m", f"learner={','.join(args.learners)}",
           f"seed={','.join(map(str, args.seeds))}", "quiet=true", "robot=cartpole",
           f"hydra.sweep.dir={sweep_dir}", *args.overrides]
    print("running:", " ".join(cmd), flush=True)
    subprocess.run(cmd, cwd=ROOT, check=False)
    runs = [summarize_run(d) for d in sorted(p for p in sweep_dir.iterdir() if p.is_dir())]
    header = f"{'learner':14s} {'seed':>4s} {'solved':>6s} {'episodes':>8s} {'env_steps':>9s} " \
             f"{'wall_s':>7s} {'greedy_len':>10s}"
    print("\n" + header)
    for r in runs:
        print(f"{r.get('learner', '?'):14s} {r.get('seed', -1):4d} {str(r.get('solved', 'fail')):>6s} "
              f"{fmt(r.get('episodes_to_solve')):>8s} {fmt(r.get('steps_to_solve')):>9s} "
              f"{fmt(r.get('wall_to_solve'), '.1f'):>7s} {fmt(r.get('greedy_mean_length'), '.1f'):>10s}")
    print(f"\nsweep folder: {sweep_dir}")


if __name__ == "__main__":
    main()
