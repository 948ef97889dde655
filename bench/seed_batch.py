"""Seeds in one process against one seed alone: wall time and peak memory (run by hand).

    python bench/seed_batch.py [--seeds 10] [--learners qlearn dqn] [--qlearn-steps 150000]
                               [--dqn-steps 30000]

Per learner, side by side in this run: one plain process ``train.py seed=0`` and one
``train.py -m seed='range(N)'`` (the ``seeds`` launcher: one batch of N seeds), each
with the same per-seed budget of env steps (``max_env_steps``; an episode budget
would let the batch wait for its slowest seed), training past "solved" so every seed spends the whole budget. Timed from
outside, start to exit; the peak memory is the largest resident set of the process.

Measured 2026-11-26 (2 cores, one busy with another job; seeds 10, the defaults):
``BATCH qlearn seeds=10 one_s=38.9 batch_s=378.4 ratio=9.72 per_seed_ratio=0.972 peak_rss_mb=601``,
``BATCH dqn seeds=10 one_s=10.4 batch_s=72.8 ratio=6.99 per_seed_ratio=0.699 peak_rss_mb=622``.

Last lines, per learner: ``BATCH <learner> seeds=<N> one_s=<v> batch_s=<v>
ratio=<batch/one> per_seed_ratio=<batch/(N*one)> peak_rss_mb=<batch>``.
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


# Runs the command it is given and prints its peak RSS (kB): a fresh parent per measurement.
WRAP = ("import resource, subprocess, sys; code = subprocess.call(sys.argv[1:], stdout=subprocess.DEVNULL); "
        "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, file=sys.stderr); sys.exit(code)")


def timed(cmd: list[str]) -> tuple[float, float]:
    """Runs ``cmd`` in the project folder; (seconds start to exit, its peak RSS in MB)."""
    print("running:", " ".join(cmd), flush=True)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", WRAP, *cmd], cwd=ROOT, stderr=subprocess.PIPE, text=True)
    seconds = time.perf_counter() - t0
    if proc.returncode:
        sys.exit(f"error: {' '.join(cmd)} exited {proc.returncode}: {proc.stderr[-500:]}")
    return seconds, int(proc.stderr.split()[-1]) / 1024


def budget(learner: str, args) -> list[str]:
    """The same env-step budget for every seed (so no seed waits for a slower one)."""
    steps = args.qlearn_steps if learner == "qlearn" else args.dqn_steps
    return [f"max_env_steps={steps}", "learner.nepisodes=100000000", "stop_when_solved=false"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--learners", nargs="+", default=["qlearn", "dqn"])
    parser.add_argument("--qlearn-steps", type=int, default=150000)
    parser.add_argument("--dqn-steps", type=int, default=30000)
    args = parser.parse_args()
    if args.seeds < 1:
        sys.exit("error: --seeds must be >= 1")
    out = ROOT / "multirun" / f"bench_seed_batch_{time.strftime('%Y%m%d-%H%M%S')}"
    rows = []
    for learner in args.learners:
        common = [f"learner={learner}", "quiet=true", *budget(learner, args)]
        one_s, one_mb = timed([sys.executable, "train.py", *common, "seed=0",
                               f"hydra.run.dir={out / learner / 'one'}"])
        batch_s, batch_mb = timed([sys.executable, "train.py", "-m", *common, f"seed=range({args.seeds})",
                                   f"hydra.sweep.dir={out / learner / 'batch'}"])
        rows.append((learner, one_s, batch_s, one_mb, batch_mb))
    for learner, one_s, batch_s, one_mb, batch_mb in rows:
        print(f"BATCH {learner} seeds={args.seeds} one_s={one_s:.1f} batch_s={batch_s:.1f} "
              f"ratio={batch_s / one_s:.2f} per_seed_ratio={batch_s / (args.seeds * one_s):.3f} "
              f"peak_rss_mb={batch_mb:.0f} (one seed: {one_mb:.0f})")


if __name__ == "__main__":
    main()
