"""This checkout against an earlier commit, side by side in one run (run by hand).

    python bench/before_after.py --ref <commit> [--after <commit>] [--dqn-seeds 0 1 2] [--seeds 10]
                                 [--qlearn-steps 60000] [--dqn-steps 15000] [--rounds 1]

The earlier commit (and ``--after``'s, else this checkout) is checked out as a git worktree
under ``/tmp`` and run with this interpreter (each tree imports its own packages: its
folder comes first on the path).
Per measure, the two trees run one after the other, alternating which goes first each
round, so the machine's load falls on both alike:

- ``DEFAULT``: ``python train.py`` (the quick start's run), seconds start to exit;
- ``DQN``: ``python train.py learner=dqn seed=<s>`` (cart-pole's tuned dqn) per seed: seconds
  start to exit, the run's own clock to solving (``wall_to_solve``), the episode it solved
  at and the milliseconds per 1,000 env steps of the whole run (the two trees' learners
  draw the same streams but round differently, so their seeds may solve at other episodes:
  the cost per env step compares the code, the time to solve what a user waits);
- ``BATCH``: per learner, one seed against a batch of ``--seeds`` seeds in one process
  (the ``seeds`` launcher), each seed the same env-step budget and training past solved,
  and the batch's physics floor (``bench/seed_batch.py``'s: below it no batch can go).

Last lines: ``DEFAULT before_s=.. after_s=.. ratio=..``, ``DQN seed=<s> before_s=.. after_s=..
before_solve_s=.. after_solve_s=.. before_episode=.. after_episode=.. before_ms_per_1k=..
after_ms_per_1k=.. ratio_per_step=..`` and ``BATCH <learner> tree=<before|after> one_s=..
batch_s=.. ratio=.. physics_floor_s=.. floor_distance=<batch_s / physics_floor_s>``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))

from seed_batch import physics_floor  # noqa: E402


def worktree(ref: str) -> Path:
    """``ref`` checked out under /tmp (made once, reused)."""
    sha = subprocess.run(["git", "rev-parse", "--short", ref], cwd=ROOT, capture_output=True, text=True,
                         check=True).stdout.strip()
    where = Path("/tmp") / f"tree-{sha}"
    if not (where / "train.py").is_file():
        subprocess.run(["git", "worktree", "add", "-f", str(where), sha], cwd=ROOT, check=True,
                       capture_output=True)
    return where


def timed(tree: Path, args: list[str]) -> tuple[float, str]:
    """``train.py <args>`` in ``tree``: (seconds start to exit, its standard output)."""
    cmd = [sys.executable, "train.py", *args]
    print(f"running in {tree}:", " ".join(args), flush=True)
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, cwd=tree, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if proc.returncode:
        sys.exit(f"error: {' '.join(cmd)} in {tree} exited {proc.returncode}: {proc.stderr[-800:]}")
    return seconds, proc.stdout


def summary_of(tree: Path, stdout: str) -> dict:
    """The run's summary.json, with ``wall_to_solve`` read from its files."""
    sys.path.insert(0, str(ROOT))
    from runs.summary import summarize_run

    found = re.search(r"^VERDICT .* run_dir=(.+)$", stdout, re.MULTILINE)
    run_dir = tree / found.group(1)
    return {**json.loads((run_dir / "summary.json").read_text()), **summarize_run(run_dir)}


def pair(trees: dict[str, Path], round_: int, work) -> dict[str, object]:
    """``work(tree)`` in both trees, the first alternating with the round."""
    order = list(trees) if round_ % 2 == 0 else list(trees)[::-1]
    return {name: work(trees[name]) for name in order}


def default(trees: dict[str, Path], rounds: int) -> None:
    times = {name: [] for name in trees}
    for r in range(rounds):
        for name, (seconds, _) in pair(trees, r, lambda t: timed(t, ["quiet=true"])).items():
            times[name].append(seconds)
    before, after = (min(times[k]) for k in ("before", "after"))
    print(f"DEFAULT before_s={before:.1f} after_s={after:.1f} ratio={after / before:.3f}", flush=True)


def dqn(trees: dict[str, Path], seeds: list[int]) -> None:
    for r, seed in enumerate(seeds):
        found = {}
        for name, (seconds, out) in pair(trees, r, lambda t: timed(
                t, ["learner=dqn", f"seed={seed}", "quiet=true"])).items():
            summary = summary_of(trees[name], out)
            found[name] = (seconds, summary)
        line = [f"DQN seed={seed}"]
        for name in ("before", "after"):
            seconds, s = found[name]
            line += [f"{name}_s={seconds:.1f}", f"{name}_solve_s={s['wall_to_solve'] if s['wall_to_solve'] is not None else float('nan'):.1f}",
                     f"{name}_episode={s.get('solved_at')}",
                     f"{name}_ms_per_1k={1e6 * s['wall_s'] / max(s['env_steps'], 1):.1f}"]
        per_step = [1e6 * found[k][1]["wall_s"] / max(found[k][1]["env_steps"], 1) for k in ("before", "after")]
        print(" ".join(line), f"ratio_per_step={per_step[1] / per_step[0]:.3f}", flush=True)


def no_episode_cap(tree: Path) -> str:
    """The override that lifts the episode budget in ``tree``: the run's ``max_episodes`` (0 =
    none), or, in a tree from before the budget moved to the run, the learner's ``nepisodes``."""
    moved = "max_episodes:" in (tree / "conf" / "config.yaml").read_text()
    return "max_episodes=0" if moved else "learner.nepisodes=100000000"


def batch(trees: dict[str, Path], learners: list[str], seeds: int, steps: dict[str, int]) -> None:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    for r, learner in enumerate(learners):
        common = [f"learner={learner}", "quiet=true", f"max_env_steps={steps[learner]}", "stop_when_solved=false"]

        def both(tree: Path) -> tuple[float, float, Path]:
            where = Path("/tmp") / f"bench_before_after_{stamp}" / tree.name / learner
            args = [*common, no_episode_cap(tree)]
            one, _ = timed(tree, [*args, "seed=0", f"hydra.run.dir={where / 'one'}"])
            many, _ = timed(tree, ["-m", *args, f"seed=range({seeds})", f"hydra.sweep.dir={where / 'batch'}"])
            return one, many, where / "batch"

        for name, (one, many, folder) in pair(trees, r, both).items():
            floor = physics_floor(learner, "tuned", seeds, folder)
            print(f"BATCH {learner} tree={name} one_s={one:.1f} batch_s={many:.1f} ratio={many / one:.2f} "
                  f"physics_floor_s={floor:.1f} floor_distance={many / floor:.2f}", flush=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ref", required=True, help="the earlier commit")
    parser.add_argument("--after", default=None, help="a later commit to compare (default: this checkout)")
    parser.add_argument("--dqn-seeds", nargs="*", type=int, default=[0, 1, 2])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--learners", nargs="*", default=["qlearn", "dqn"])
    parser.add_argument("--qlearn-steps", type=int, default=60000)
    parser.add_argument("--dqn-steps", type=int, default=15000)
    parser.add_argument("--rounds", type=int, default=1, help="runs of the default each tree (the fastest counts)")
    args = parser.parse_args()
    trees = {"before": worktree(args.ref), "after": worktree(args.after) if args.after else ROOT}
    print(f"before: {trees['before']} ({args.ref}); after: {trees['after']}; load average "
          f"{os.getloadavg()[0]:.2f}", flush=True)
    default(trees, args.rounds)
    dqn(trees, args.dqn_seeds)
    batch(trees, args.learners, args.seeds, {"qlearn": args.qlearn_steps, "dqn": args.dqn_steps})
    print(f"load average at the end {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
