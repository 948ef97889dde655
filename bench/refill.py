"""A grid pair's tuning study in rounds against the same study with freed members refilled
(run by hand).

    python -m bench.refill [--pairs wall_qlearn maze_dqn] [--repeats 1] [--per-batch N]
                           [--trials N] [--out bench/timing/refill]

Runs each pair's grid sweep (``bench/tune_grid.command``: the plan's trials, seeds, budget,
successive halving, ``startup_trials``, ``value_defaults``, sampler seed 0) from an empty
journal twice, one after the other, the order alternating over the repeats: as the grid
runs it (rounds: a round waits for its slowest trial) and with ``hydra.sweeper.refill=true``
(a trial's freed members take the study's next trial at once). ``--per-batch`` and
``--trials`` replace the plan's trials a batch and a study. Each study's journal goes under
``--out`` with a row of ``studies.csv``; its console and job folders under
``tuning/bench/refill/``. Prints a line per study and, per pair, ``REFILL
<pair> rounds_s=<v> refill_s=<v> ratio=<refill/rounds> rounds_best=<v> refill_best=<v>``
(wall seconds start to exit; best: the study's best trial's value on the tuning seeds).
"""

from __future__ import annotations

import argparse
import csv
import statistics
import sys
import time
from pathlib import Path

from bench import child
from bench.benchmark import load_plan
from bench.seed_batch import load
from bench.tune_grid import ROOT, SWEEPS, command, cpu, journal_study


def study(pair: str, plan: dict, refill: bool, out: Path, per_batch: int | None, trials: int | None
          ) -> tuple[float, float | None, str]:
    """One study of ``pair`` from an empty journal in ``out``: its wall seconds, its best
    value and its trials' states."""
    import optuna

    task, learner = pair.split("_", 1)
    tuning = dict(plan["tuning"], **({"trials": per_batch} if per_batch else {}))
    mode = "refill" if refill else "rounds"
    name = f"{pair}_{mode}_{time.strftime('%Y%m%d-%H%M%S')}"
    folder, sweep = out / name, ROOT / SWEEPS / "refill" / name / "sweep"  # the journal kept; the jobs' not
    folder.mkdir(parents=True)
    sweep.parent.mkdir(parents=True)
    cmd = command(task, plan["tasks"][task], learner, tuning, trials or int(plan["tuning"]["trials"]),
                  sweep, studies=folder, write=False)
    cmd += ["hydra.sweeper.refill=true"] if refill else []
    start = time.perf_counter()
    with open(sweep.parent / "console.log", "w") as console:
        code = child.call(cmd, ROOT, stdout=console)
    seconds = time.perf_counter() - start
    if code:
        raise SystemExit(f"{pair} ({mode}) exited {code}: see {sweep.parent / 'console.log'}")
    found = journal_study(f"bench-{task}-{learner}", folder / f"{pair}.log")
    states = [t.state for t in found.trials]
    counts = ", ".join(f"{sum(s == k for s in states)} {k.name.lower()}"
                       for k in (optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.PRUNED,
                                 optuna.trial.TrialState.FAIL))
    best = found.best_value if any(s == optuna.trial.TrialState.COMPLETE for s in states) else None
    return seconds, best, counts


def record(path: Path, row: list) -> None:
    """Appends ``row`` to the CSV file ``path`` (its header first where it is new)."""
    new = not path.is_file()
    with open(path, "a", newline="") as f:
        writer = csv.writer(f)
        if new:
            writer.writerow(["ended", "pair", "mode", "per_batch", "trials", "seconds", "best", "trials_states",
                             "cpu", "load"])
        writer.writerow(row)


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m bench.refill", description=__doc__.splitlines()[0])
    parser.add_argument("--pairs", nargs="+", default=["wall_qlearn", "maze_dqn"])
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--per-batch", type=int, help="trials a batch (default: the plan's trials)")
    parser.add_argument("--trials", type=int, help="trials a study (default: the plan's)")
    parser.add_argument("--out", type=Path, default=Path("bench/timing/refill"))
    args = parser.parse_args()
    plan = load_plan(quick=False)
    for pair in args.pairs:
        seconds: dict[bool, list[float]] = {False: [], True: []}
        bests: dict[bool, list[float | None]] = {False: [], True: []}
        for r in range(args.repeats):
            for refill in ((False, True) if r % 2 == 0 else (True, False)):
                s, best, counts = study(pair, plan, refill, ROOT / args.out, args.per_batch, args.trials)
                seconds[refill].append(s)
                bests[refill].append(best)
                mode = "refill" if refill else "rounds"
                print(f"{pair} {mode}: {s:.1f} s, best {best}, {counts} (load {load()})", flush=True)
                record(ROOT / args.out / "studies.csv", [time.strftime("%Y-%m-%dT%H:%M:%S"), pair, mode,
                                                         args.per_batch or "", args.trials or "", f"{s:.1f}",
                                                         best, counts, cpu(), load()])
        rounds, refilled = statistics.fmean(seconds[False]), statistics.fmean(seconds[True])
        print(f"REFILL {pair} rounds_s={rounds:.1f} refill_s={refilled:.1f} ratio={refilled / rounds:.2f} "
              f"rounds_best={bests[False]} refill_best={bests[True]}", flush=True)


if __name__ == "__main__":
    sys.exit(main())
