"""``python -m bench.benchmark --tune``: every pair of the benchmark's plan tuned by one study
each, on the same terms, resuming where it stopped.

Per task x learner of ``bench/benchmark.yaml`` (its ``tuning`` block: trials, seeds,
pruner; the env-step budget a trial's seed gets is the task's ``budget_steps``, the
benchmark's own), one Optuna study, ``bench-<task>-<learner>``, kept in a journal file
in the repository (``bench/studies/<task>_<learner>.log``: how each tuned file was found
can be read there later). Each pair runs ``train.py -m hydra/sweeper=optuna`` with every
trial x seed trained side by side (``trials_per_batch``: all of them; the plan's
``startup_trials`` random trials go first, together, then the rest, guided by them:
:func:`sweeps.tuning.batch_size`), asking only the
trials its study still lacks: run the same command again after a stop and each study
takes over the trials the stop left running and goes on to its count. A study that
finishes writes the pair's ``conf/tuned/`` file (``write_tuned``; its header: the study,
budget, trials, seeds and best value). Its first trial is the current configuration
(the hand-picked tuned file where the space holds its values; where it does not, the
study values it on the same seeds and budget), so a hand pick is kept wherever no
sampled trial beats it on the tuning seeds. With the plan's ``value_defaults`` each study
also values the learner's own values of what it searches (its published ones), and the
file holds them where they beat every trial; a finished study that has not valued them
gets a sweep of no trials that does (the maze's first five, of greedy laps, are not
asked). Tasks the plan runs with extra overrides (``cube_minus_y``) are variants of
another task's config and are not tuned, nor are the plan's learner ``variants`` of another
learner (the dqn with one switch on: the dqn's tuned file and the switch); a variant entry
that names its own learner (ppo's, which only sets how often it is evaluated) is tuned.

``--studies <folder>`` replays the grid with its journals there and no tuned file written
(to time it from empty journals); each sweep's wall minutes go to the folder's ``runs.csv``
as it ends, each run of the command's wall minutes to its ``grid_runs.csv`` (the machine's
time, where studies ran side by side), and ``--minutes`` adds them up (:func:`run_minutes`,
:func:`grid_run_minutes`, :func:`grid_minutes`).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path
from typing import Sequence

from sweeps import child

ROOT = Path(__file__).resolve().parents[1]
STUDIES = Path("bench") / "studies"  # from ROOT (the URL in each tuned file's header names no machine)
SWEEPS = Path("tuning") / "bench"  # from ROOT: each pair's sweep folders (and consoles, several at once)


def journal_study(name: str, path: Path):
    """Study ``name`` in the journal file ``path`` (from the project's root), or None where
    there is no such file or study."""
    import optuna

    if not (ROOT / path).is_file():
        return None
    from sweeps.tuning import open_storage

    try:
        return optuna.load_study(study_name=name, storage=open_storage(f"journal://{ROOT / path}"))
    except KeyError:
        return None


def study_counts(study) -> tuple[int, int]:
    """(trials ``study`` holds that count: finished, pruned, failed but not asked again;
    trials running); (0, 0) for no study."""
    import optuna

    if study is None:
        return 0, 0
    state = optuna.trial.TrialState
    retried = {t.user_attrs.get("retry_of") for t in study.trials}
    counted = [t for t in study.trials if t.state in (state.COMPLETE, state.PRUNED)
               or (t.state == state.FAIL and t.number not in retried)]
    return len(counted), sum(t.state == state.RUNNING for t in study.trials)


def defaults_valued(study) -> bool:
    """Whether ``study`` has valued the learner's own values of the searched settings
    (``value_defaults``; or found it had begun with them), or cannot: a study of an earlier
    objective (the maze's first five: greedy laps), which the sweeper does not continue on
    other terms. False for no study."""
    from runs.summary import SUCCESS_AND_SPEED

    if study is None:
        return False
    return "defaults_value" in study.user_attrs or study.metric_names not in (None, [SUCCESS_AND_SPEED])


def written(spec: dict, learner: str, task: str) -> bool:
    """Whether the pair's tuned file is its study's (its header names the study): a study
    that finished without writing it (write_tuned off) gets a sweep of no new trials that
    writes it."""
    from sweeps.tuning import names_study
    from tasks.catalog import default_task, tuned_file

    per_task = spec["task"] != default_task(spec["robot"])
    path = tuned_file(spec["robot"], learner, spec["task"] if per_task else None)
    return path.is_file() and names_study(path.read_text(), f"bench-{task}-{learner}")


def pruning(pruner: str, budget: int, first_rung: int = 9) -> list[str]:
    """The sweeper's pruning overrides for trials of ``budget`` env steps: ``pruner``, its
    first rung at ``budget / first_rung`` (successive halving and Hyperband), and reports
    three times a rung."""
    rung = max(budget // first_rung, 1)
    return [f"hydra.sweeper.report_every={max(rung // 3, 1)}", f"hydra.sweeper.pruner={pruner}",
            *([f"hydra.sweeper.pruners.{pruner}.min_resource={rung}"]
              if pruner in ("successive_halving", "hyperband") else [])]


def command(task: str, spec: dict, learner: str, tuning: dict, missing: int, sweep_dir: Path,
            studies: Path = STUDIES, write: bool = True, extra: Sequence[str] = ()) -> list[str]:
    """The tuning sweep of one pair: ``missing`` more trials of its study (its journal in
    ``studies``), its folders in ``sweep_dir``; ``write``: its tuned file written when it ends;
    ``extra``: overrides every trial runs with (the plan's entry of the learner itself, e.g.
    ppo's evaluations once a rollout on the cube), as the pair's benchmark row does."""
    budget = int(spec["budget_steps"])
    name = f"{task}_{learner}"
    write = write and tuning.get("write_tuned", True)
    return [sys.executable, "train.py", "-m", "hydra/sweeper=optuna", f"robot={spec['robot']}", f"task={spec['task']}",
            f"learner={learner}", f"hydra.sweeper.study=bench-{task}-{learner}",
            f"hydra.sweeper.storage=journal://{studies / f'{name}.log'}",
            f"hydra.sweeper.n_trials={missing}", f"hydra.sweeper.trials_per_batch={int(tuning['trials'])}",
            f"hydra.sweeper.seeds=[{','.join(str(s) for s in tuning['seeds'])}]",
            f"hydra.sweeper.budget_steps={budget}",
            *pruning(tuning["pruner"], budget, int(tuning.get("first_rung", 9))),
            # the plan's random trials (the sweeper's own default where it names none)
            *([f"hydra.sweeper.startup_trials={int(tuning['startup_trials'])}"] if "startup_trials" in tuning else []),
            # the learner's own values of the searched settings valued too (the published ones)
            *(["hydra.sweeper.value_defaults=true"] if tuning.get("value_defaults") else []),
            "hydra.sweeper.sampler_seed=0", f"hydra.sweeper.write_tuned={str(write).lower()}",
            f"hydra.sweep.dir={sweep_dir}", *extra]


def entry_overrides(plan: dict, learner: str, task: str) -> list[str]:
    """The overrides of the plan's entry ``learner`` under ``variants`` on ``task`` (its own and
    the task's), none where it has no entry."""
    variant = plan.get("variants", {}).get(learner, {})
    return [*variant.get("overrides", []), *variant.get("task_overrides", {}).get(task, [])]


def learners_of(plan: dict, task: str, asked: list[str] | None = None) -> list[str]:
    """The learners of ``task``: those ``asked``, else the task's own list where the plan
    gives it one (the continuous-control tasks), else the plan's."""
    return list(asked or plan["tasks"][task].get("learners", plan["learners"]))


def tune(plan: dict, tasks: list[str] | None, learners: list[str] | None, dry_run: bool = False,
         jobs: int | None = None, studies: Path = STUDIES) -> int:
    """Tunes every pair asked for (the plan's by default), ``jobs`` studies at once (each a
    process of one thread; default: one per core; several at once start longest first,
    :func:`longest_first`); the number of pairs left unfinished.
    With more than one at once, each sweep's console goes to ``tuning/bench/<pair>/<time>.log``.
    ``studies``: the journals' folder (from the project's root); any other than
    ``bench/studies`` is a replay, e.g. to time the grid: its studies write no tuned file."""
    tuning = plan["tuning"]
    write = Path(studies) == STUDIES and bool(tuning.get("write_tuned", True))
    (ROOT / studies).mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    pending: list[tuple[str, list[str], int]] = []  # (pair, its sweep's command, its trials left)
    for task in tasks or list(plan["tasks"]):
        spec = plan["tasks"][task]
        if spec.get("overrides"):
            print(f"{task}: a variant of {spec['robot']}/{spec['task']} (overrides {spec['overrides']}): not tuned")
            continue
        for learner in learners_of(plan, task, learners):
            name = f"{task}_{learner}"
            variant = plan.get("variants", {}).get(learner, {})
            if variant.get("learner", learner) != learner:  # ppo's entry only sets its evaluations: tuned
                print(f"{name}: a variant of {variant['learner']} (overrides {variant.get('overrides', [])}): "
                      f"runs {variant['learner']}'s tuned file with them, not tuned")
                continue
            study = journal_study(f"bench-{task}-{learner}", studies / f"{name}.log")
            counted, running = study_counts(study)
            missing = int(tuning["trials"]) - counted - running
            valued = not tuning.get("value_defaults") or defaults_valued(study)
            if missing <= 0 and not running and (not write or written(spec, learner, task)) and valued:
                print(f"{name}: study complete ({counted} trials)")
                continue
            cmd = command(task, spec, learner, tuning, max(missing, 0), SWEEPS / name / stamp, studies, write,
                          entry_overrides(plan, learner, task))
            print(f"{name}: {counted} trials done, {running} left running, {max(missing, 0)} to ask\n  "
                  + " ".join(cmd[1:]), flush=True)
            pending.append((name, cmd, max(missing, 0) + running))
    if dry_run or not pending:
        return len(pending)
    jobs = min(jobs or child.cores(), len(pending))
    if jobs > 1:
        pending = longest_first(pending, int(tuning["trials"]))
        print("longest first (the grid's records of each study's minutes): "
              + ", ".join(name for name, _, _ in pending), flush=True)
    logs = [ROOT / SWEEPS / name / f"{stamp}.log" for name, _, _ in pending] if jobs > 1 else [None] * len(pending)
    clock: dict[int, float] = {}

    def started(i: int) -> None:
        clock[i] = time.monotonic()
        if logs[i] is not None:
            print(f"{pending[i][0]}: started, its console in {logs[i].relative_to(ROOT)}", flush=True)

    def ended(i: int, code: int) -> None:
        minutes = (time.monotonic() - clock[i]) / 60
        record_run(studies, pending[i][0], minutes, code, jobs)
        print(f"{pending[i][0]}: " + (f"done in {minutes:.1f} min" if code == 0 else
                                      f"the sweep exited {code} after {minutes:.1f} min; run the same "
                                      "command again to go on"), flush=True)

    print(f"{len(pending)} studies to run, {jobs} at once", flush=True)
    speed = physics_speed()  # before any study starts: the machine as quiet as this command leaves it
    begun = time.monotonic()
    try:
        codes = child.call_all([cmd for _, cmd, _ in pending], ROOT, jobs, logs, started=started, ended=ended)
    finally:  # a piece stopped by Ctrl-C is machine time of the grid too; the pairs it started
        if clock:
            record_grid(studies, [pending[i][0] for i in sorted(clock)], (time.monotonic() - begun) / 60, jobs,
                        speed)
    return sum(code != 0 for code in codes)


def longest_first(pending: list[tuple[str, list[str], int]], trials: int) -> list[tuple[str, list[str], int]]:
    """``pending`` (pair, command, trials left) in the order that ends soonest when several
    run at once: the longest first, each priced at its study's minutes in the grid's own
    records (``bench/studies``, :func:`grid_minutes`) times the share of its trials left; a
    pair without a record goes first. In the plan's order the last study can run alone on
    one core while the others stand idle."""
    known = {name: minutes for name, _, minutes in grid_minutes(STUDIES)}

    def expected(item: tuple[str, list[str], int]) -> float:
        name, _, left = item
        return known[name] * left / max(trials, 1) if name in known else float("inf")

    return sorted(pending, key=expected, reverse=True)


RUNS = "runs.csv"  # in a studies folder: one row per sweep the grid command ran, as it ends
GRID_RUNS = "grid_runs.csv"  # in a studies folder: one row per run of the grid command, as it ends


def _append(path: Path, header: list[str], row: list) -> None:
    import csv

    new = not path.is_file()
    with open(path, "a", newline="") as f:
        out = csv.writer(f)
        if new:
            out.writerow(header)
        out.writerow(row)


def record_run(studies: Path, pair: str, minutes: float, code: int, jobs: int) -> None:
    """Appends one sweep's wall minutes to ``studies``' :data:`RUNS` (kept with the journals:
    a grid tuned over several sessions adds up its pieces there)."""
    _append(ROOT / studies / RUNS, ["pair", "ended", "minutes", "exit_code", "studies_at_once", "cpu"],
            [pair, time.strftime("%Y-%m-%dT%H:%M:%S"), f"{minutes:.2f}", code, jobs, cpu()])


def record_grid(studies: Path, pairs: list[str], minutes: float, jobs: int, speed: float | None = None) -> None:
    """Appends one run of the grid command to ``studies``' :data:`GRID_RUNS`: the ``pairs`` it
    started, its wall minutes from its first sweep's start to its last's end (or to its
    stop, a Ctrl-C included), the machine's time (with several studies
    at once the sweeps' minutes overlap; their sum over-counts it), and ``speed``, the
    machine's :func:`physics_speed` when it started (machines of one kind differ: pieces run
    on different days compare through it)."""
    _append(ROOT / studies / GRID_RUNS,
            ["ended", "minutes", "studies", "studies_at_once", "pairs", "cpu", "cartpole_us_per_copy_step"],
            [time.strftime("%Y-%m-%dT%H:%M:%S"), f"{minutes:.2f}", len(pairs), jobs, " ".join(pairs), cpu(),
             "" if speed is None else f"{speed:.3f}"])


def physics_speed(copies: int = 64, seconds: float = 1.0) -> float:
    """Microseconds a copy-step of the cart-pole's physics takes here (``copies`` side by side,
    at rest, :func:`bench.seed_batch.per_copy_step`): a yardstick of the machine, read as
    in its earlier rows."""
    from bench.seed_batch import per_copy_step

    return per_copy_step("cartpole", copies, seconds, at_rest=True) * 1e6


def grid_run_minutes(studies: Path = STUDIES) -> list[float]:
    """The wall minutes of each run of the grid command :func:`record_grid` recorded in ``studies``."""
    import csv

    path = ROOT / studies / GRID_RUNS
    if not path.is_file():
        return []
    with open(path, newline="") as f:
        return [float(row["minutes"]) for row in csv.DictReader(f)]


def cpu() -> str:
    """This machine's processor and the cores this process may use (machines of one kind
    differ: a record says which)."""
    try:
        with open("/proc/cpuinfo") as f:
            model = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), "")
    except OSError:
        model = ""
    return f"{model or 'unknown'} x {child.cores()}"


def run_minutes(studies: Path = STUDIES) -> dict[str, float]:
    """Per pair, the wall minutes of the sweeps :func:`record_run` recorded in ``studies``."""
    import csv

    path = ROOT / studies / RUNS
    minutes: dict[str, float] = {}
    if path.is_file():
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                minutes[row["pair"]] = minutes.get(row["pair"], 0.0) + float(row["minutes"])
    return minutes


def machine_minutes(trials) -> float:
    """The minutes a study's trials were running: the union of their start-to-end spans
    (trials side by side count once, the time between two batches not at all; a trial
    taken over after a stop spans the stop)."""
    spans = sorted((t.datetime_start, t.datetime_complete) for t in trials
                   if t.datetime_start is not None and t.datetime_complete is not None)
    total, end = 0.0, None
    for start, stop in spans:
        if end is None or start > end:
            total += (stop - start).total_seconds()
            end = stop
        elif stop > end:
            total += (stop - end).total_seconds()
            end = stop
    return total / 60


def grid_minutes(studies: Path = STUDIES) -> list[tuple[str, int, float]]:
    """Per journal of ``studies`` (from the project's root): (pair, trials finished, the
    minutes its trials ran, :func:`machine_minutes`); the grid's machine time is their sum
    where its studies ran one at a time."""
    import optuna

    from sweeps.tuning import open_storage

    rows = []
    for path in sorted((ROOT / studies).glob("*.log")):
        name = path.stem
        storage = open_storage(f"journal://{path}")
        for summary in optuna.get_all_study_summaries(storage):
            trials = optuna.load_study(study_name=summary.study_name, storage=storage).trials
            rows.append((name, sum(t.state.is_finished() for t in trials), machine_minutes(trials)))
    return rows
