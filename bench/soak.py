"""Memory over a long run (run by hand): a DQN run of many short episodes, its resident
memory printed every 500 episodes (about 4 minutes on a busy 2-core machine).

    python bench/soak.py [--episodes 8000] [--every 500] [--trace] [--trim] [overrides ...]

The run is ``train.py``'s (``runs.lifecycle.execute``: the CSV logger, metrics files,
checkpoints and greedy evaluations every 1,000 episodes) on cartpole with
``task.max_episode_steps=10`` (many episodes per second), a 5,000-transition replay
buffer (full within the first samples: the warm-up) and ``stop_when_solved=false``, in a
temporary folder. Extra arguments are Hydra overrides on top. ``--trace`` adds
tracemalloc's five allocation sites that grew most between the sample at a third of the
run (after warm-up) and the last one (slow: Python allocations are traced). ``--trim``
returns the C heap's free memory to the system (glibc's ``malloc_trim``) before each
sample: growth that remains is memory in use, not the allocator holding on to freed pages.

Goal: flat after warm-up, under 10 MB per 100,000 episodes; the measurements are on the docs'
performance page (docs/performance.md). The last line is machine-readable::

    SOAK episodes=<n> rss_mb_start=<MB at the first sample> rss_mb_end=<MB> kb_per_1000=<growth
    per 1,000 episodes after warm-up (least squares over the samples past the first third)>
"""

from __future__ import annotations

import argparse
import ctypes
import os
import sys
import tempfile
import tracemalloc
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runs import run as run_module  # noqa: E402
from tasks.catalog import compose  # noqa: E402
from runs.lifecycle import execute  # noqa: E402

BASE = ["learner=dqn", "task.max_episode_steps=10", "learner.buffer_size=5000", "stop_when_solved=false",
        "quiet=true", "checkpoint_every=1000", "eval_every=1000", "eval_episodes=4"]


def rss_mb() -> float:
    """This process's resident memory in MB (Linux ``/proc``)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def sample_every(every: int, samples: list[tuple[int, float]], trace: list, trim: bool) -> None:
    """Wraps ``Run._finish`` to note the memory every ``every`` booked episodes."""
    finish = run_module.Run._finish
    libc = ctypes.CDLL("libc.so.6") if trim else None

    def noted(self, *args, **kwargs):
        episode = finish(self, *args, **kwargs)
        if self.n_episodes % every == 0:
            if libc is not None:
                libc.malloc_trim(0)
            samples.append((self.n_episodes, rss_mb()))
            print(f"episode {self.n_episodes:>7}: rss {samples[-1][1]:8.1f} MB", flush=True)
            if tracemalloc.is_tracing():
                trace.append(tracemalloc.take_snapshot())
        return episode

    run_module.Run._finish = noted


def slope_kb_per_1000(samples: list[tuple[int, float]]) -> float:
    """Least-squares growth in KB per 1,000 episodes over the samples past the first third."""
    tail = samples[len(samples) // 3:]
    if len(tail) < 2:
        return float("nan")
    xs, ys = [e for e, _ in tail], [m for _, m in tail]
    mx, my = sum(xs) / len(xs), sum(ys) / len(ys)
    var = sum((x - mx) ** 2 for x in xs)
    return sum((x - mx) * (y - my) for x, y in zip(xs, ys)) / var * 1000 * 1024 if var else float("nan")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=8000)
    parser.add_argument("--every", type=int, default=500)
    parser.add_argument("--trace", action="store_true")
    parser.add_argument("--trim", action="store_true")
    args, overrides = parser.parse_known_args()
    if args.trace:
        tracemalloc.start(5)
    samples: list[tuple[int, float]] = []
    trace: list = []
    sample_every(args.every, samples, trace, args.trim)
    cfg = compose(overrides=[*BASE, f"max_episodes={args.episodes}", *overrides])
    with tempfile.TemporaryDirectory() as folder:
        execute(cfg, Path(folder), choices={"robot": "cartpole", "task": "stay_up", "learner": "dqn"})
    if len(trace) >= 2:
        for stat in trace[-1].compare_to(trace[len(trace) // 3], "traceback")[:5]:
            print(f"grew {stat.size_diff / 1024:9.1f} KB in {stat.count_diff:+d} blocks at "
                  + " <- ".join(f"{Path(f.filename).name}:{f.lineno}" for f in stat.traceback))
    print(f"SOAK episodes={samples[-1][0] if samples else 0} rss_mb_start={samples[0][1]:.1f} "
          f"rss_mb_end={samples[-1][1]:.1f} kb_per_1000={slope_kb_per_1000(samples):.1f}")


if __name__ == "__main__":
    main()
