"""A grid pair's tuning study in rounds against the same study with freed members refilled,
or against the same study on an earlier commit (run by hand).

    python -m bench.refill [--pairs wall_qlearn maze_dqn] [--repeats 1] [--per-batch N]
                           [--trials N] [--ref COMMIT] [--out bench/timing/refill]

Runs each pair's grid sweep (``bench/tune_grid.command``: the plan's trials, seeds, budget,
successive halving, ``startup_trials``, ``value_defaults``, sampler seed 0) from an empty
journal twice, one after the other, the order alternating over the repeats: as the grid
runs it (rounds: a round waits for its slowest trial) and with ``hydra.sweeper.refill=true``
(a trial's freed members take the study's next trial at once). ``--per-batch`` and
``--trials`` replace the plan's trials a batch and a study. ``--ref``: the study in rounds on
``COMMIT``'s code (a git worktree under /tmp, run with this interpreter; mode ``ref``) against
this checkout's, in place of refill. Each study's journal goes under ``--out`` with a row of
``studies.csv``; its console and job folders under ``tuning/bench/refill/``. Prints a line
per study and, per pair, ``REFILL <pair> rounds_s=<v> <refill|ref>_s=<v> ratio=<other/rounds>
rounds_best=<v> <refill|ref>_best=<v>`` (wall seconds start to exit; best: the study's best
trial's value on the tuning seeds), and each study's physics floor
(``bench/seed_batch.floor_of``: its jobs' copy-steps, training priced at its widest batch)
and its distance from it.
"""

from __future__ import annotations

import argparse
import csv
import statistics
import subprocess
import sys
import time
from pathlib import Path

from omegaconf import OmegaConf

from sweeps import child
from bench.before_after import worktree
from bench.benchmark import load_plan
from bench.seed_batch import floor_of, load
from bench.tune_grid import ROOT, SWEEPS, command, cpu, journal_study


def study(pair: str, plan: dict, mode: str, out: Path, per_batch: int | None, trials: int | None,
          tree: Path = ROOT) -> tuple[float, float | None, str, float]:
    """One study of ``pair`` from an empty journal in ``out``, by the code in ``tree``
    (``mode``: rounds, refill or ref): its wall seconds, its best value, its trials' states
    and its physics floor."""
    import optuna

    task, learner = pair.split("_", 1)
    tuning = dict(plan["tuning"], **({"trials": per_batch} if per_batch else {}))
    refill = mode == "refill"
    name = f"{pair}_{mode}_{time.strftime('%Y%m%d-%H%M%S')}"
    folder, sweep = out / name, ROOT / SWEEPS / "refill" / name / "sweep"  # the journal kept; the jobs' not
    folder.mkdir(parents=True)
    sweep.parent.mkdir(parents=True)
    cmd = command(task, plan["tasks"][task], learner, tuning, trials or int(plan["tuning"]["trials"]),
                  sweep, studies=folder, write=False)
    cmd += ["hydra.sweeper.refill=true"] if refill else []
    start = time.perf_counter()
    with open(sweep.parent / "console.log", "w") as console:
        code = child.call(cmd, tree, stdout=console)
    seconds = time.perf_counter() - start
    if code:
        raise SystemExit(f"{pair} ({mode}) exited {code}: see {sweep.parent / 'console.log'}")
    found = journal_study(f"bench-{task}-{learner}", folder / f"{pair}.log")
    states = [t.state for t in found.trials]
    counts = ", ".join(f"{sum(s == k for s in states)} {k.name.lower()}"
                       for k in (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED,
                                 optuna.trial.TrialState.FAIL))
    best = found.best_value if any(s == optuna.trial.TrialState.COMPLETE for s in states) else None
    robot = plan["tasks"][task]["robot"]
    return seconds, best, counts, floor_of(robot, sweep, widest(sweep, int(tuning["trials"]), len(tuning["seeds"])))


def widest(sweep: Path, trials: int, seeds: int) -> int:
    """The copies of a study's widest batch: ``trials`` x ``seeds`` jobs of its jobs' copies."""
    config = next(sweep.rglob("config.yaml"))
    return trials * seeds * int(OmegaConf.load(config).num_envs)


def record(path: Path, row: list) -> None:
    """Appends ``row`` to the CSV file ``path`` (its header first where it is new)."""
    new = not path.is_file()
    with open(path, "a", newline="") as f:
        writer = csv.writer(f)
        if new:
            writer.writerow(["ended", "pair", "mode", "per_batch", "trials", "seconds", "best", "trials_states",
                             "cpu", "load", "floor_s", "commit"])
        writer.writerow(row)


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m bench.refill", description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", nargs="+", default=["wall_qlearn", "maze_dqn"])
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--per-batch", type=int, help="trials a batch (default: the plan's trials)")
    parser.add_argument("--trials", type=int, help="trials a study (default: the plan's)")
    parser.add_argument("--ref", help="an earlier commit: its study in rounds against this checkout's")
    parser.add_argument("--out", type=Path, default=Path("bench/timing/refill"))
    args = parser.parse_args()
    plan = load_plan(quick=False)
    other = "ref" if args.ref else "refill"
    trees = {"rounds": ROOT, "refill": ROOT, "ref": worktree(args.ref) if args.ref else ROOT}
    commits = {mode: commit_of(tree) for mode, tree in trees.items()}
    for pair in args.pairs:
        seconds: dict[str, list[float]] = {"rounds": [], other: []}
        bests: dict[str, list[float | None]] = {"rounds": [], other: []}
        for r in range(args.repeats):
            for mode in (("rounds", other) if r % 2 == 0 else (other, "rounds")):
                s, best, counts, floor = study(pair, plan, mode, ROOT / args.out, args.per_batch, args.trials,
                                               trees[mode])
                seconds[mode].append(s)
                bests[mode].append(best)
                print(f"{pair} {mode} ({commits[mode]}): {s:.1f} s, best {best}, {counts}, physics floor "
                      f"{floor:.1f} s ({s / floor:.2f}x) (load {load()})", flush=True)
                record(ROOT / args.out / "studies.csv", [time.strftime("%Y-%m-%dT%H:%M:%S"), pair, mode,
                                                         args.per_batch or "", args.trials or "", f"{s:.1f}",
                                                         best, counts, cpu(), load(), f"{floor:.1f}",
                                                         commits[mode]])
        rounds, others = statistics.fmean(seconds["rounds"]), statistics.fmean(seconds[other])
        print(f"REFILL {pair} rounds_s={rounds:.1f} {other}_s={others:.1f} ratio={others / rounds:.2f} "
              f"rounds_best={bests['rounds']} {other}_best={bests[other]}", flush=True)


def commit_of(tree: Path) -> str:
    """The short commit checked out in ``tree`` (``+`` when its files differ from it)."""
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=tree, capture_output=True, text=True).stdout.strip()

    changed = git("status", "--porcelain", "--untracked-files=no")
    return git("rev-parse", "--short", "HEAD") + ("+" if changed else "")


if __name__ == "__main__":
    sys.exit(main())
