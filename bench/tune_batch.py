"""One tuning study with its trials asked and trained together against the same study asked
one trial at a time (run by hand).

    python bench/tune_batch.py [--robot cartpole] [--learner dqn] [--trials 12] [--seeds 0 1]
                               [--budget 5000] [--per-batch N ...] [--repeats R] [--space <file>]
                               [-- extra overrides]

Runs ``train.py -m hydra/sweeper=optuna`` twice on the same pair, side by side in this run:
``trials_per_batch=1`` (each trial's seeds one batch, as a study ran before trials batched)
and ``trials_per_batch=<per-batch>`` (default: all trials; the sampler's random startup trials
go first as a batch of their own, :func:`sweeps.tuning.batch_size`), each with
its own new study (a journal file under the bench's folder, as the grid's studies;
``--storage sqlite``: an SQLite database), the same sampler seed, no pruner, every
trial sampled (not the current configuration first) and the same env-step budget per
trial and seed. The default space holds member-wise settings
only (a space with a shape setting splits the batch: ``--space`` to try one). Prints
each study's wall seconds (start to exit), best value, and the batched study's physics
floor (its copy-steps priced at this machine's rollout cost at its widths, as
``bench/seed_batch.py`` prices a seed batch).

One study's best value is one draw of the sampler's luck: ``--repeats R`` runs every
variant with the sampler seeds 0 .. R-1 (the same seeds for each; ``--sampler-seeds 2 3``
names them instead, to add repeats to an earlier run's) and ``--per-batch``
takes several sizes (``--per-batch 12 4``: 12 a batch, and 4); the last
line then gives each variant's mean best and wall over the repeats.

``--ref <commit>``: instead, the batched study in an earlier commit (a git worktree) and
in this checkout, alternating, each ``--repeats`` times: ``TUNE_REF ... before_s after_s
ratio`` and each one's floor ratio.

``--pruners null median successive_halving hyperband``: instead, the batched study with
each pruner (rungs as the grid's studies: from a ninth of the budget), over the repeats:
each one's mean best value and the env steps its jobs took (a pruner's saving).

Last lines: ``TUNE <robot> <learner> trials=<n> per_batch=<k> seeds=<s> budget=<steps> sequential_s=<v>
batched_s=<v> ratio=<batched/sequential> physics_floor_s=<v> floor_ratio=<batched/floor>
sequential_best=<v> batched_best=<v>``.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "bench"))

from seed_batch import floor_of, load, timed  # noqa: E402

SPACES = {  # member-wise settings (the learners' MEMBER_WISE)
    "qlearn": {"learner.alpha": "tag(log, interval(0.02, 1.0))", "learner.gamma": "interval(0.6, 0.999)",
               "learner.epsilon_discount": "tag(log, interval(0.98, 0.9999))"},
    "dqn": {"learner.lr": "tag(log, interval(0.0001, 0.01))", "learner.gamma": "interval(0.9, 0.999)",
            "learner.tau": "interval(0.001, 0.05)"},
}


def study(args, tag: str, per_batch: int, space: Path, out: Path, sampler_seed: int = 0,
          pruner: str = "null", tree: Path = ROOT) -> tuple[float, float, int]:
    """One study (run by ``tree``'s train.py: this checkout or another commit's): (wall
    seconds, best value, env steps its jobs took)."""
    import json

    import optuna

    from tune_grid import pruning  # the grid's studies' rungs

    from sweeps.tuning import open_storage

    url = f"sqlite:///{out / 'studies.db'}" if args.storage == "sqlite" else f"journal://{out / 'studies.log'}"
    cmd = [sys.executable, "train.py", "-m", "hydra/sweeper=optuna", f"robot={args.robot}", f"learner={args.learner}",
           f"hydra.sweeper.study={tag}", f"hydra.sweeper.storage={url}", f"hydra.sweeper.search={space}",
           f"hydra.sweeper.n_trials={args.trials}", f"hydra.sweeper.trials_per_batch={per_batch}",
           f"hydra.sweeper.seeds=[{','.join(map(str, args.seeds))}]", f"hydra.sweeper.budget_steps={args.budget}",
           *pruning(pruner, args.budget), f"hydra.sweeper.sampler_seed={sampler_seed}", "hydra.sweeper.start_from_current=false",
           f"hydra.sweep.dir={out / tag}", *args.extra]
    seconds, _, _ = timed(cmd, cwd=tree)
    best = optuna.load_study(study_name=tag, storage=open_storage(url)).best_value
    steps = sum(json.loads(f.read_text()).get("env_steps", 0) for f in (out / tag).glob("*/summary.json"))
    return seconds, best, steps


def copies_of(args) -> int:
    """The copies each job of the studies runs (its config's ``num_envs``)."""
    from tasks import catalog

    return int(catalog.compose(args.robot, learner=args.learner, overrides=list(args.extra)).num_envs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="cartpole")
    parser.add_argument("--learner", default="dqn", choices=sorted(SPACES))
    parser.add_argument("--trials", type=int, default=12)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1])
    parser.add_argument("--budget", type=int, default=5000)
    parser.add_argument("--per-batch", type=int, nargs="+",
                        help="trials asked together by the batched study, one or more sizes (default: all)")
    parser.add_argument("--repeats", type=int, default=1, help="sampler seeds 0 .. R-1, every variant each")
    parser.add_argument("--sampler-seeds", type=int, nargs="+",
                        help="instead of --repeats: these sampler seeds (to add one to earlier repeats)")
    parser.add_argument("--pruners", nargs="+", help="instead: the batched study with each pruner (null, median, "
                        "successive_halving, hyperband): best value and env steps spent")
    parser.add_argument("--space", type=Path)
    parser.add_argument("--storage", choices=("journal", "sqlite"), default="journal",
                        help="the studies' storage: a journal file (as the grid's studies) or SQLite")
    parser.add_argument("--ref", help="instead: the batched study in this checkout against the same study in this "
                        "earlier commit (a git worktree under /tmp), alternating which goes first each repeat")
    parser.add_argument("extra", nargs="*", help="overrides for every job (after --)")
    args = parser.parse_args()
    if args.trials < 1 or args.budget < 1:
        sys.exit("error: --trials and --budget must be >= 1")
    args.sampler_seeds = args.sampler_seeds or list(range(args.repeats))
    args.repeats = len(args.sampler_seeds)
    out = ROOT / "multirun" / f"bench_tune_batch_{time.strftime('%Y%m%d-%H%M%S')}"
    out.mkdir(parents=True)
    space = args.space or out / "space.yaml"
    if not args.space:
        space.write_text("".join(f"{k}: {v}\n" for k, v in SPACES[args.learner].items()))
    print(f"load average (1/5/15 min) at the start: {load()} on {os.cpu_count()} cores", flush=True)
    if args.pruners:
        return compare_pruners(args, space, out)
    if args.ref:
        return against_ref(args, space, out)
    sizes = args.per_batch or [args.trials]
    found: dict[int, list[tuple[float, float]]] = {1: [], **{k: [] for k in sizes}}
    for r in args.sampler_seeds:
        for k in found:  # interleaved: each repeat runs every variant
            found[k].append(study(args, f"batch{k}_seed{r}", k, space, out, sampler_seed=r)[:2])
            print(f"repeat {r}: per_batch={k} wall_s={found[k][-1][0]:.1f} best={found[k][-1][1]:.4g}", flush=True)
    copies = copies_of(args)
    print(f"load average (1/5/15 min) at the end: {load()}")
    sequential_s, sequential_best = (statistics.fmean(v[i] for v in found[1]) for i in (0, 1))
    for k in sizes:
        batched_s, batched_best = (statistics.fmean(v[i] for v in found[k]) for i in (0, 1))
        floor_s = floor_of(args.robot, out / f"batch{k}_seed{args.sampler_seeds[0]}", k * len(args.seeds) * copies)
        print(f"TUNE {args.robot} {args.learner} trials={args.trials} per_batch={k} seeds={len(args.seeds)} "
              f"budget={args.budget} repeats={args.repeats} "
              f"sequential_s={sequential_s:.1f} batched_s={batched_s:.1f} ratio={batched_s / sequential_s:.2f} "
              f"physics_floor_s={floor_s:.1f} floor_ratio={batched_s / floor_s:.2f} "
              f"sequential_best={sequential_best:.4g} batched_best={batched_best:.4g} "
              f"(bests {', '.join(f'{v[1]:.3g}' for v in found[k])} against {', '.join(f'{v[1]:.3g}' for v in found[1])})")


def against_ref(args, space: Path, out: Path) -> None:
    """The batched study (all trials at once, or the first ``--per-batch``) in ``--ref``'s
    tree and in this checkout, alternating which goes first each repeat: each one's wall
    seconds, the ratio, and each one's distance from the physics floor of its own jobs."""
    from before_after import worktree

    trees = {"before": worktree(args.ref), "after": ROOT}
    k = (args.per_batch or [args.trials])[0]
    found: dict[str, list[float]] = {name: [] for name in trees}
    for i, r in enumerate(args.sampler_seeds):
        for name in (list(trees) if i % 2 == 0 else list(trees)[::-1]):
            found[name].append(study(args, f"{name}{r}", k, space, out, sampler_seed=r, tree=trees[name])[0])
            print(f"repeat {r}: {name} wall_s={found[name][-1]:.1f}", flush=True)
    copies = copies_of(args)
    floors = {name: floor_of(args.robot, out / f"{name}{args.sampler_seeds[0]}", k * len(args.seeds) * copies) for name in trees}
    print(f"load average (1/5/15 min) at the end: {load()}")
    before, after = (statistics.fmean(found[name]) for name in trees)
    print(f"TUNE_REF {args.robot} {args.learner} trials={args.trials} per_batch={k} seeds={len(args.seeds)} "
          f"budget={args.budget} repeats={args.repeats} ref={args.ref} before_s={before:.1f} after_s={after:.1f} "
          f"ratio={after / before:.2f} floor_ratio_before={before / floors['before']:.2f} "
          f"floor_ratio_after={after / floors['after']:.2f}")


def compare_pruners(args, space: Path, out: Path) -> None:
    """Each pruner's batched study over the repeats: mean best value, env steps, wall."""
    found: dict[str, list[tuple[float, float, int]]] = {k: [] for k in args.pruners}
    for r in args.sampler_seeds:
        for pruner in args.pruners:
            found[pruner].append(study(args, f"{pruner}_seed{r}", args.trials, space, out, r, pruner))
            s, best, steps = found[pruner][-1]
            print(f"repeat {r}: pruner={pruner} wall_s={s:.1f} best={best:.4g} env_steps={steps}", flush=True)
    print(f"load average (1/5/15 min) at the end: {load()}")
    for pruner, rows in found.items():
        wall, best, steps = (statistics.fmean(v[i] for v in rows) for i in range(3))
        print(f"PRUNE {args.robot} {args.learner} pruner={pruner} trials={args.trials} seeds={len(args.seeds)} "
              f"budget={args.budget} repeats={args.repeats} best={best:.4g} env_steps={steps:.0f} wall_s={wall:.1f} "
              f"(bests {', '.join(f'{v[1]:.3g}' for v in rows)})")


if __name__ == "__main__":
    main()
