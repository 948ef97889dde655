"""How fast a user gets an answer, in CPU seconds of a fresh process (run by hand).

    python bench/answers.py [--rounds 3]

Each command runs ``--rounds`` times as its own process (the rounds interleaved); the CPU
time is the child's user + system time (``resource.getrusage``), which a busy machine
stretches less than the wall time:

- ``error``: ``train.py learner.gama=0.9`` (a misspelt setting) to its one ``error:`` line;
- ``value``: ``train.py learner=dqn learner.lr=-1`` (a value out of range) to its line;
- ``help``: ``train.py --help``;
- ``compare``: ``compare.py`` on a finished two-job sweep (made first, not timed), its
  table and files written;
- ``first_step``: ``train.py max_episodes=1 eval_episodes=0`` to its first env step
  (``summary.json``'s ``first_step_s``, wall time from process start) and to its exit.

The issue's goal: under 1 s to an error line and to the comparison's table, under 2 s to
the first env step, on an idle 2-core machine. Last lines: ``ANSWER <name> cpu_s=<median>
wall_s=<median>`` (``first_step`` also ``first_step_s=<median>``).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def timed(args: list[str]) -> tuple[float, float]:
    """(CPU seconds, wall seconds) of one child process."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    start = time.perf_counter()
    subprocess.run([sys.executable, *args], cwd=ROOT, capture_output=True, text=True,
                   env={**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")})
    wall = time.perf_counter() - start
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), wall


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rounds", type=int, default=3)
    args = parser.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="answers_"))
    sweep = tmp / "sweep"
    subprocess.run([sys.executable, "train.py", "-m", "seed=0,1", "max_episodes=3", "eval_episodes=0",
                    "quiet=true", f"hydra.sweep.dir={sweep}"], cwd=ROOT, capture_output=True, check=True)
    commands = {
        "error": ["train.py", "learner.gama=0.9"],
        "value": ["train.py", "learner=dqn", "learner.lr=-1"],
        "help": ["train.py", "--help"],
        "compare": ["compare.py", str(sweep)],
    }
    found: dict[str, list[tuple[float, ...]]] = {name: [] for name in [*commands, "first_step"]}
    for r in range(args.rounds):
        for name, command in commands.items():
            found[name].append(timed(command))
        run = tmp / f"run{r}"
        cpu, wall = timed(["train.py", "max_episodes=1", "eval_episodes=0", "quiet=true", f"hydra.run.dir={run}"])
        first = json.loads((run / "summary.json").read_text())["first_step_s"]
        found["first_step"].append((cpu, wall, first))
    for name, rows in found.items():
        cpu, wall = statistics.median(r[0] for r in rows), statistics.median(r[1] for r in rows)
        extra = f" first_step_s={statistics.median(r[2] for r in rows):.2f}" if name == "first_step" else ""
        print(f"ANSWER {name} cpu_s={cpu:.2f} wall_s={wall:.2f}{extra}")


if __name__ == "__main__":
    main()
