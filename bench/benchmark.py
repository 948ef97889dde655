"""Every learner on every task, on fresh seeds under one env-step budget: docs/benchmark.md's table.

    python -m bench.benchmark                      # the plan in bench/benchmark.yaml; rewrites docs/benchmark.md
    python -m bench.benchmark --quick              # cart-pole x qlearn, dqn; 3 seeds; minutes
    python -m bench.benchmark --tasks cube --learners dqn --seeds 5 [-- extra overrides]
    python -m bench.benchmark --read benchmark/<folder>   # tabulate a finished (or partial) run again
    python -m bench.benchmark --out bench/results/<name> --jobs 2  # two pairs at once, records in git
    python -m bench.benchmark --tune [--tasks ...] [--learners ...] [--jobs N]   # one study per pair (bench/tune_grid.py)
    python -m bench.benchmark --tune --studies bench/timing/<name>   # a replay in another folder (no tuned file)
    python -m bench.benchmark --tune --minutes [--studies ...]       # each study's minutes from its journal

Each task x learner x setting (``published``: the learner's defaults, ``'~tuned'``;
``tuned``: its ``conf/tuned/`` files, the robot's ``<robot>_<learner>`` and the task's
``<robot>_<task>_<learner>`` on top, each where it exists) is one Hydra multirun of ``train.py`` over the seeds,
trained together in one process (the ``seeds`` launcher), each seed with the same budget
of env steps and stopped when its verdict says solved. A seed *succeeds* when its
finished policy does: at least the task's rate (90%) of the final greedy evaluation's
episodes pass its threshold (a record from before rates: that evaluation's mean meets
it; the training verdict alone can be met by a policy that no longer is). Results go to a
folder (``benchmark/<time>/`` unless ``--out``): ``seeds.csv`` (one row per seed),
``benchmark.csv`` and ``benchmark.md`` (one row per pair), the sweeps' job folders, and per
pair a record (``<task>/<learner>_<setting>.json``: its command, exit code, wall seconds and
seeds' rows) from which the tables are made again when the job folders are gone. A folder
under ``bench/results/`` is kept in the repository without its job folders and consoles
(``.gitignore``): a benchmark run over several sessions commits its records as pairs end.
``--jobs N`` trains N pairs at once (each one process of one thread); ``--threads T`` gives
each pair's process T torch threads instead (a pair alone on a machine of T cores ends sooner;
a pair may go on with another number than it began with).
Without ``--quick`` docs/benchmark.md (between its markers) is rewritten from the table
(``--readme`` names another file, ``--no-readme`` leaves it alone).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import platform
import statistics
import subprocess
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

from omegaconf import OmegaConf
from tqdm import tqdm

from bench.tune_grid import entry_overrides, learners_of
from sweeps import child
from runs.layout import is_sweep_folder

ROOT = Path(__file__).resolve().parents[1]
PLAN = Path(__file__).with_name("benchmark.yaml")
BEGIN, END = "<!-- benchmark:begin -->", "<!-- benchmark:end -->"
SETTINGS = ("published", "tuned")
SEED_COLUMNS = ("task", "robot/task", "learner", "setting", "seed", "status", "success", "verdict",
                "measure", "threshold", "greedy", "greedy_rate", "env_steps", "wall_s", "steps_to_solve",
                "wall_to_solve", "stuck", "stuck_steps", "error", "run_dir")
PAIR_COLUMNS = ("task", "learner", "setting", "seeds", "success", "verdict_solved", "failed",
                "measure", "greedy_iqm", "ci_low", "ci_high", "steps_to_success", "wall_to_success",
                "batch_wall_s", "budget_steps", "stuck", "tuned_file", "note")


class BadInput(Exception):
    """A benchmark request that cannot run; the message says what is allowed."""


@dataclass(frozen=True)
class Job:
    """One task x learner x setting: one multirun over the seeds."""

    task: str
    robot: str
    task_name: str
    learner: str
    setting: str
    budget: int
    seeds: tuple[int, ...]
    overrides: tuple[str, ...] = ()  # the plan's (published settings, a variant's) and the command line's
    base: str | None = None  # a plan variant's learner config (``learner`` then names the variant)

    @property
    def folder(self) -> str:
        return f"{self.task}/{self.learner}_{self.setting}"


def load_plan(quick: bool) -> dict:
    """bench/benchmark.yaml as a dict, with its ``quick`` preset applied when asked."""
    plan = OmegaConf.to_container(OmegaConf.load(PLAN))
    preset = plan.pop("quick")
    if quick:
        plan["tasks"] = {name: dict(plan["tasks"][name], budget_steps=preset["budget_steps"])
                         for name in preset["tasks"]}
        plan.update(learners=preset["learners"], settings=preset["settings"], seeds=preset["seeds"])
    return plan


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="python -m bench.benchmark", description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the small preset of bench/benchmark.yaml")
    parser.add_argument("--tasks", nargs="+", help="task names of bench/benchmark.yaml (default: all)")
    parser.add_argument("--learners", nargs="+", help="learners (default: the plan's)")
    parser.add_argument("--settings", nargs="+", help="published and/or tuned (default: the plan's)")
    parser.add_argument("--seeds", type=int, help="seeds per pair (default: the plan's)")
    parser.add_argument("--first-seed", type=int, help="the first seed (default: the plan's)")
    parser.add_argument("--budget", type=int, help="env steps per seed, every task (default: each task's)")
    parser.add_argument("--out", type=Path, help="the results folder (default: benchmark/<time>)")
    parser.add_argument("--readme", type=Path, help="the page whose benchmark block to rewrite (default: docs/benchmark.md)")
    parser.add_argument("--block", help="write the page's <!-- benchmark:BLOCK:begin --> block instead of its main "
                                        "table (a part of the plan run on its own, e.g. rainbow)")
    parser.add_argument("--no-readme", action="store_true", help="leave docs/benchmark.md alone")
    parser.add_argument("--solo", action="store_true",
                        help="also time each pair's first seed alone (what one process saved)")
    parser.add_argument("--read", type=Path, help="tabulate this results folder again; run nothing")
    parser.add_argument("--tune", action="store_true",
                        help="tune every pair by one study each (the plan's tuning block), resuming; run nothing else")
    parser.add_argument("--dry-run", action="store_true", help="with --tune: print each pair's command only")
    parser.add_argument("--jobs", type=int, help="pairs trained at once, a process of one thread each (default: 1); "
                                                 "with --tune: studies at once (default: one per core)")
    parser.add_argument("--threads", type=int, help="torch threads of each pair's process (default: the runs' "
                        "torch_threads, 1); a seed's numbers may then differ from one thread's in their last bits")
    parser.add_argument("--studies", type=Path, help="with --tune: the studies' journal folder, from the project's "
                        "root (default: bench/studies); another folder is a replay: no conf/tuned/ file is written")
    parser.add_argument("--minutes", action="store_true", help="with --tune: each study's minutes, its sweeps' (the "
                        "folder's runs.csv) and its trials' (their spans in its journal), and their sums; run nothing")
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides for every run (after --)")
    return parser.parse_args(argv)


def plan_jobs(args: argparse.Namespace, plan: dict) -> list[Job]:
    """The jobs asked for; :class:`BadInput` for anything that cannot run."""
    from tasks import catalog

    tasks = args.tasks or list(plan["tasks"])
    unknown = [t for t in tasks if t not in plan["tasks"]]
    if unknown:
        raise BadInput(f"unknown task {unknown[0]!r}; the benchmark's tasks: {', '.join(plan['tasks'])}")
    learners = args.learners or sorted({name for task in tasks for name in learners_of(plan, task)})
    variants = plan.get("variants", {})
    known = [*catalog.names("learner"), *variants]
    bad = [name for name in learners if name not in known]
    if bad:
        raise BadInput(f"unknown learner {bad[0]!r}; learners: {', '.join(known)}")
    settings = args.settings or plan["settings"]
    bad = [s for s in settings if s not in SETTINGS]
    if bad:
        raise BadInput(f"unknown setting {bad[0]!r}; settings: {', '.join(SETTINGS)}")
    n = plan["seeds"] if args.seeds is None else args.seeds
    if n < 1:
        raise BadInput(f"--seeds must be at least 1, got {n}")
    first = plan["first_seed"] if args.first_seed is None else args.first_seed
    if first < 0:
        raise BadInput(f"--first-seed must be >= 0, got {first}")
    if args.budget is not None and args.budget < 1:
        raise BadInput(f"--budget must be a positive number of env steps, got {args.budget}")
    jobs = []
    for task in tasks:
        spec = plan["tasks"][task]
        for learner in learners_of(plan, task, args.learners):
            variant = variants.get(learner, {})
            for setting in settings:
                extra = [*spec.get("overrides", []), *entry_overrides(plan, learner, task),
                         *(plan.get("published_overrides", []) if setting == "published" else []),
                         *args.overrides]
                jobs.append(Job(task, spec["robot"], spec["task"], learner, setting,
                                args.budget or int(spec["budget_steps"]), tuple(range(first, first + n)),
                                tuple(extra), variant.get("learner")))
    return jobs


def overrides(job: Job) -> list[str]:
    """The Hydra overrides of one job (its seeds aside)."""
    picks = [f"robot={job.robot}", f"task={job.task_name}", f"learner={job.base or job.learner}",
             f"max_env_steps={job.budget}", "max_episodes=0"]
    return [*picks, *(["~tuned"] if job.setting == "published" else []), *job.overrides]


def tuned_files(job: Job) -> list[str]:
    """The tuned files ``job``'s runs apply, by name: the robot's, then the task's (either
    may be missing)."""
    from tasks import catalog

    return catalog.tuned_layers(job.robot, job.task_name, job.base or job.learner)


def has_tuned_file(job: Job) -> bool:
    """Whether ``job`` has a tuned file to run with (the robot's or the task's)."""
    return bool(tuned_files(job))


def applied_tuned(job: Job, rows: list[dict]) -> str:
    """The tuned files ``job``'s runs applied, ``a + b``: as its first run folder's run.json
    recorded them (``tuned``, ``tuned_task``), else as conf/tuned/ has them now; ``""`` for a
    published job or one that never ran."""
    if job.setting != "tuned" or not rows:
        return ""
    for row in rows:
        try:
            saved = json.loads((Path(row["run_dir"]) / "run.json").read_text())
        except (OSError, ValueError, TypeError, KeyError):
            continue
        if isinstance(saved, dict) and "tuned" in saved:
            return " + ".join(str(saved[k]) for k in ("tuned", "tuned_task") if saved.get(k))
    return " + ".join(tuned_files(job))


def _headers(tuned: str) -> dict[str, list[str]]:
    """The header (leading comment lines) of each file of a tuned label (``a + b``)."""
    from tasks.catalog import config_file

    heads = {}
    for name in filter(None, tuned.split(" + ")):
        path = config_file("tuned", name)
        try:
            lines = path.read_text(errors="replace").splitlines() if path else []
        except OSError:
            lines = []
        heads[name] = lines[:next((i for i, line in enumerate(lines) if not line.startswith("#")), len(lines))]
    return heads


def kept_hand_picks(tuned: str) -> list[str]:
    """The files of a tuned label (``a + b``) that their study kept: a hand pick that valued
    at least as well as the study's best trial on the tuning seeds (its header says so)."""
    from sweeps.tuning import KEPT

    return [name for name, head in _headers(tuned).items() if any(line.startswith(f"# {KEPT}") for line in head[:2])]


def own_values_kept(tuned: str) -> list[str]:
    """The files of a tuned label whose study wrote the learner's own values of the searched
    settings (valued above every trial on the tuning seeds; its header says so)."""
    from sweeps.tuning import OWN_VALUES

    return [name for name, head in _headers(tuned).items()
            if any(line.startswith(f"# written instead: {OWN_VALUES}") for line in head)]


def check_budget(job: Job) -> None:
    """:class:`BadInput` when the budget cannot let every copy finish one full-length episode."""
    from params import ConfigError
    from tasks import catalog

    try:
        cfg = catalog.compose(overrides=overrides(job))
    except ConfigError as err:
        raise BadInput(f"{job.task} x {job.learner} ({job.setting}): {err}") from None
    except Exception as err:  # Hydra's own errors: an override that names nothing
        raise BadInput(f"{job.task} x {job.learner} ({job.setting}): "
                       f"{str(err).splitlines()[0]}") from None
    need = int(cfg.num_envs) * int(cfg.task.max_episode_steps)
    if job.budget < need:
        raise BadInput(f"a budget of {job.budget} env steps cannot finish an episode of {job.task} x "
                       f"{job.learner} ({job.setting}): {cfg.num_envs} copies x up to "
                       f"{cfg.task.max_episode_steps} steps need {need}; give --budget {need} or more")


def check_tuned_budget(job: Job) -> None:
    """:class:`BadInput` when ``job``'s tuned files judge it with another budget than the
    plan's: a user's run with them (``train.py robot=.. task=.. learner=..``) and the pair's
    row must be the same run, ``max_env_steps`` the plan's ``budget_steps`` and no episode
    budget (``max_episodes: 0``)."""
    if job.setting != "tuned" or not has_tuned_file(job):
        return
    from tasks import catalog

    cfg = catalog.compose(overrides=[f"robot={job.robot}", f"task={job.task_name}",
                                     f"learner={job.base or job.learner}", *job.overrides])
    steps, episodes = int(cfg.get("max_env_steps") or 0), int(cfg.get("max_episodes") or 0)
    if (steps, episodes) != (job.budget, 0):
        files = " + ".join(f"conf/tuned/{name}.yaml" for name in tuned_files(job))
        raise BadInput(f"{files} judges {job.task} x {job.learner} with max_env_steps={steps} "
                       f"max_episodes={episodes}, the plan with {job.budget} env steps: a user's run and "
                       f"the benchmark's row would differ; set max_env_steps: {job.budget} and max_episodes: 0 "
                       f"there (or give --budget to run another budget on purpose)")


def pair_command(job: Job, out: Path, threads: int | None = None) -> tuple[list[str], bool]:
    """The command that trains ``job``'s seeds as one multirun into ``out/<task>/<learner>_<setting>/``,
    and whether it resumes: a pair stopped part way (its sweep folder there, no record)
    continues its seeds from their checkpoints (``train.py resume=<sweep>``). ``threads``: its
    process's torch threads (None: the runs' ``torch_threads``)."""
    sweep = out / job.folder
    resumed = is_sweep_folder(sweep)
    more = [] if threads is None else [f"torch_threads={threads}"]
    if resumed:
        return [sys.executable, "train.py", f"resume={sweep}", *more], True
    return [sys.executable, "train.py", "-m", "quiet=true", f"hydra.sweep.dir={sweep}",
            f"seed={','.join(map(str, job.seeds))}", *overrides(job), *more], False


def run_pairs(todo: list[Job], out: Path, bar: tqdm, jobs: int = 1, solo: bool = False,
              threads: int | None = None) -> None:
    """Trains the pairs of ``todo``, ``jobs`` at once (each a process of one thread, the seeds
    launcher's, or of ``threads``), each pair's seeds as one multirun (:func:`pair_command`). As a pair ends,
    its command, exit code, start (local time) and wall seconds (from its start; ``resumed``:
    from where it went on) go to ``<learner>_<setting>.json`` beside its sweep, with its seeds' rows
    (:func:`pair_seeds`); its console is ``<learner>_<setting>.log``. The bar moves as each
    seed writes its verdict; a pair that Ctrl-C or SIGTERM stopped gets no record (the same command goes
    on with it), nor a pair refused because another benchmark on ``out`` took it after this
    one planned (that one writes its record). ``solo`` (one pair at a time): also times the pair's first
    seed trained alone (``solo_wall_s``), to say what training the seeds in one process saved."""
    commands = [pair_command(job, out, threads) for job in todo]
    logs = [(out / job.folder).with_suffix(".log") for job in todo]
    for log, (_, resumed) in zip(logs, commands):
        if not resumed:  # a fresh pair's console starts empty (a resumed one's goes on)
            log.unlink(missing_ok=True)
    begun: dict[int, float] = {}
    started_at: dict[int, str] = {}
    done = [0] * len(todo)

    def started(i: int) -> None:
        begun[i], started_at[i] = time.perf_counter(), time.strftime("%Y-%m-%dT%H:%M:%S")

    def count(i: int) -> None:
        finished = seeds_ended(out / todo[i].folder)
        bar.update(max(0, finished - done[i]))
        done[i] = max(done[i], finished)

    def ended(i: int, returncode: int) -> None:
        if returncode in child.STOPPED:  # Ctrl-C or SIGTERM: no record, so the same command goes on with it
            return
        job, (cmd, resumed) = todo[i], commands[i]
        if returncode not in (0, 1) and trained_elsewhere(job, out):  # another process took it since the plan
            return
        wall = time.perf_counter() - begun[i]
        bar.update(len(job.seeds) - done[i])
        done[i] = len(job.seeds)
        lines = logs[i].read_text(errors="replace").strip().splitlines()
        record = {"command": cmd, "returncode": returncode, "wall_s": wall, "started": started_at[i],
                  "last_line": lines[-1] if lines else "", **({"resumed": True} if resumed else {}),
                  **({} if threads is None else {"torch_threads": threads})}
        if solo:
            t0 = time.perf_counter()
            alone = subprocess.run([sys.executable, "train.py", "quiet=true", f"hydra.run.dir={out / job.folder}_solo",
                                    f"seed={job.seeds[0]}", *overrides(job)], cwd=ROOT, capture_output=True)
            if alone.returncode == 0:
                record["solo_wall_s"] = time.perf_counter() - t0
        write_record(job, out, record)
        pair_seeds(job, out)
        if returncode not in (0, 1):  # 1: some seed failed (its row says why)
            tqdm.write(f"warning: {job.folder} exited {returncode}: {record['last_line']}")

    def poll() -> None:
        for i in begun:
            if done[i] < len(todo[i].seeds):
                count(i)

    child.call_all([cmd for cmd, _ in commands], ROOT, jobs, logs,
                   started=started, ended=ended, poll=poll)


def seeds_ended(sweep: Path) -> int:
    """How many of the sweep's seeds ended: finished (a summary.json that does not say
    interrupted) or failed (error.txt); a seed Ctrl-C stopped is still to run."""
    from runs.folder import is_finished
    return sum(1 for d in sweep.glob("*/") if is_finished(d) or (d / "error.txt").exists()) if sweep.is_dir() else 0


def job_record(job: Job, out: Path) -> dict:
    """What :func:`run_pairs` wrote about ``job`` (empty if it never ran)."""
    path = (out / job.folder).with_suffix(".json")
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def write_record(job: Job, out: Path, record: dict) -> None:
    """``job``'s record as JSON, a line per key and per seed's row (a kept record's diffs stay short)."""
    lines = [f" {json.dumps(key)}: {json.dumps(value)}" for key, value in record.items() if key != "seeds"]
    if "seeds" in record:
        lines.append(' "seeds": [\n' + ",\n".join(f"  {json.dumps(row)}" for row in record["seeds"]) + "\n ]")
    (out / job.folder).with_suffix(".json").write_text("{\n" + ",\n".join(lines) + "\n}\n")


def seed_rows(job: Job, sweep: Path) -> list[dict]:
    """One row per job folder of the sweep: its verdict, greedy measure and costs, and its
    greedy evaluations (``evaluations``: ``[env steps, measure]`` pairs, the figures' curves)."""
    from bench.sweep import job_summaries
    from runs.summary import succeeded
    from sweeps.comparison_plot import run_evaluations

    rows = []
    for s in job_summaries(sweep) if sweep.is_dir() else []:
        greedy, threshold = s.get("greedy"), s.get("threshold")
        ok = s["status"] == "ok"
        rows.append({
            "task": job.task, "robot/task": f"{job.robot}/{job.task_name}", "learner": job.learner,
            "setting": job.setting, "seed": s.get("seed"), "status": s["status"],
            "success": succeeded(s),
            "verdict": bool(ok and s.get("solved")), "measure": s.get("measure"),
            "threshold": threshold, "greedy": greedy, "greedy_rate": s.get("greedy_rate"), "rate": s.get("rate"),
            **_start_watch(s, job.budget),
            "env_steps": s.get("env_steps"),
            "wall_s": s.get("wall_s"), "steps_to_solve": s.get("steps_to_solve"),
            "wall_to_solve": s.get("wall_to_solve"), "error": s.get("error", ""), "run_dir": s["run_dir"],
            "evaluations": [list(point) for point in run_evaluations(s, "env_steps")] if ok else [],
        })
    return rows


def _start_watch(summary: dict, budget: int) -> dict:
    """``stuck`` and ``stuck_steps`` of a finished seed, replayed from its folder's files
    (:meth:`runs.run.StartWatch.of_folder`: the same for a run made before the watch read
    greedy evaluations); its summary's where the files cannot be read."""
    from runs.run import StartWatch

    try:
        watch = StartWatch.of_folder(Path(summary["run_dir"]), summary["measure"], summary["threshold"])
    except (OSError, KeyError, TypeError, ValueError):
        return {"stuck": summary.get("stuck"), "stuck_steps": summary.get("stuck_steps")}
    steps = int(summary.get("env_steps") or 0)
    return {"stuck": watch.stuck(steps, budget), "stuck_steps": watch.stuck_steps(steps)}


def pair_seeds(job: Job, out: Path) -> tuple[list[dict], str]:
    """``job``'s seed rows and the tuned files its runs applied (:func:`applied_tuned`): read
    from its job folders where they are, and kept in its record (``seeds``, ``tuned_file``)
    for when they are not: a results folder in the repository keeps its records (a few kB a
    pair) and leaves its job folders out, and is read back from those alone."""
    rows = seed_rows(job, out / job.folder)
    record = job_record(job, out)
    if not rows:
        return record.get("seeds", []), record.get("tuned_file", "")
    tuned = applied_tuned(job, rows)
    if record and (record.get("seeds") != rows or record.get("tuned_file") != tuned):
        write_record(job, out, {**record, "tuned_file": tuned, "seeds": rows})
    return rows, tuned


def _median(values: list) -> float | None:
    values = [v for v in values if v is not None]
    return statistics.median(values) if values else None


def pair_row(job: Job, rows: list[dict], wall: float | None, note: str = "", tuned: str | None = None) -> dict:
    """The table's row of one pair: success over seeds, the greedy measure's IQM and CI, costs;
    ``tuned``: the tuned files its runs applied (default: :func:`applied_tuned`)."""
    from sweeps.stats import iqm_ci

    won = [r for r in rows if r["success"]]
    centre, low, high = iqm_ci([r["greedy"] for r in rows if r["status"] == "ok"])
    measure = next((r["measure"] for r in rows if r["measure"]), "")
    errors = [r["error"] for r in rows if r["status"] != "ok" and r["error"]]
    notes = [note] if note else []
    if errors:
        notes.append(f"{len(errors)} seed(s) did not finish; the first: {errors[0]}")
    unjudged = sum(r["steps_to_solve"] is None for r in won)
    if unjudged:  # a success whose run's verdict never said solved has no time to success
        notes.append(f"{unjudged} of {len(won)} successes (the final greedy evaluation) were never judged solved by "
                     "the task's rule during training, so have no time to success" + (
                         "; the medians are of the others" if unjudged < len(won) else ""))
    stuck = sum(bool(r.get("stuck")) for r in rows)
    if stuck:  # issue 65: a run at its untrained level for a quarter of its budget or more
        notes.append(f"{stuck} of {len(rows)} seeds had a stuck start (a quarter of the budget or more at the "
                     "untrained level)")
    note = "; ".join(notes)
    return {
        "task": job.task, "learner": job.learner, "setting": job.setting, "seeds": len(rows), "stuck": stuck,
        "success": len(won), "verdict_solved": sum(r["verdict"] for r in rows),
        "failed": sum(r["status"] != "ok" for r in rows), "measure": measure,
        "greedy_iqm": centre, "ci_low": low, "ci_high": high,
        "steps_to_success": _median([r["steps_to_solve"] for r in won]),
        "wall_to_success": _median([r["wall_to_solve"] for r in won]),
        "batch_wall_s": wall, "budget_steps": job.budget, "note": note,
        "tuned_file": applied_tuned(job, rows) if tuned is None else tuned,
    }


def write_csv(path: Path, columns: tuple[str, ...], rows: list[dict]) -> None:
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        writer.writeheader()
        writer.writerows(rows)


def _g(value, spec: str = ".4g") -> str:
    return "-" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, spec)


def _iqm_text(row: dict) -> str:
    if row["seeds"] == 0 or _g(row["greedy_iqm"]) == "-":
        return "-"
    if _g(row["ci_low"]) == "-":
        return f"{_g(row['greedy_iqm'])} [no CI]"
    return f"{_g(row['greedy_iqm'])} [{_g(row['ci_low'])}, {_g(row['ci_high'])}]"


COLUMNS = ("*success*: seeds whose final greedy evaluation met the task's rule (its pass rate; records from "
           "before rates: its mean); *IQM [95% CI]*: the "
           "interquartile mean over the seeds of that evaluation's measure, with a 95% bootstrap interval; "
           "*steps to success* and *s to success*: medians over the successful seeds of the env steps and "
           "seconds (the batch's clock) when the run's verdict said solved; *s, all seeds*: the pair's wall "
           "time, its seeds trained together in one process.")


def markdown(pairs: list[dict], plan_text: str, specs: dict[str, str], figures: dict[str, str] | None = None) -> str:
    """The Benchmark section's body: how it was made, the columns' meaning, then one table per
    task (each at most ~120 characters wide; its notes below it; every number in the CSVs)."""
    lines = [plan_text, "", COLUMNS, ""]
    for task in dict.fromkeys(p["task"] for p in pairs):
        mine = [p for p in pairs if p["task"] == task]
        measure = next((p["measure"] for p in mine if p["measure"]), "measure")  # a pair not run yet has none
        lines += [f"**{task}** ({specs[task]}; budget {mine[0]['budget_steps']:,} env steps per seed)", "",
                  f"| learner | setting | success | greedy_{measure}"
                  + " IQM [95% CI] | steps to success | s to success | s, all seeds |",
                  "|---|---|---|---|---|---|---|"]
        if figures and task in figures:  # before the table: the figure, then its numbers
            lines[-2:-2] = [f"[![{task}: each learner's greedy measure against env steps, and at the end]"
                            f"({figures[task]})]({figures[task]})", ""]  # a click opens it at full size
        notes = []
        for p in mine:
            success = f"{p['success']}/{p['seeds']}" if p["seeds"] else "-"
            if p["seeds"] and p["failed"]:  # a pair still running (or stopped) is not a 0/10
                success += f" ({p['failed']} not finished)"
            setting = f"tuned ({p['tuned_file']})" if p["tuned_file"] else p["setting"]
            lines.append(f"| {p['learner']} | {setting} | {success} | {_iqm_text(p)} | "
                         f"{_g(p['steps_to_success'], ',.0f')} | {_g(p['wall_to_success'], '.1f')} | "
                         f"{_g(p['batch_wall_s'], '.0f')} |")
            if p["note"]:
                notes.append(f"- {p['learner']} ({p['setting']}): {p['note']}")
        lines += ["", *notes, *([""] if notes else [])]
    return "\n".join(lines).rstrip() + "\n"


def markers(block: str | None) -> tuple[str, str]:
    """The page's markers of the main table, or of a named ``block`` (``--block``)."""
    return (BEGIN, END) if not block else (f"<!-- benchmark:{block}:begin -->", f"<!-- benchmark:{block}:end -->")


def page_text(readme: Path, block: str | None = None) -> str:
    """The text of the page ``readme``, checked to hold the markers of ``block``'s table
    (:class:`BadInput` if it is missing, unreadable or without them)."""
    try:
        text = readme.read_text()
    except (OSError, UnicodeDecodeError) as err:
        why = getattr(err, "strerror", None) or err  # a decoding error has no strerror
        raise BadInput(f"--readme {readme}: cannot read it ({why}); give a markdown page that holds the benchmark "
                       "markers, or --no-readme") from None
    begin, end = markers(block)
    if begin not in text or end not in text:
        raise BadInput(f"{readme} has no {begin} ... {end} markers to put the table between")
    return text


def rewrite_readme(readme: Path, body: str, block: str | None = None) -> None:
    """Replaces what lies between the benchmark markers of ``readme`` with ``body``."""
    text = page_text(readme, block)
    begin, end = markers(block)
    head, rest = text.split(begin, 1)
    _, tail = rest.split(end, 1)
    readme.write_text(f"{head}{begin}\n{body}{end}{tail}")


def describe(jobs: list[Job], commands: list[str]) -> str:
    """How the table was made: the commands, the seeds, what success and the numbers mean."""
    cores = child.cores()
    seeds = sorted({s for job in jobs for s in job.seeds})
    mine = [set(job.overrides) for job in jobs if job.setting == "published"]
    published = sorted(set.intersection(*mine)) if mine else []  # a variant's or a task's own: in its row
    return (f"Generated by {', '.join(f'`{c}`' for c in commands)} ({cores} cores, "
            f"{platform.processor() or platform.machine()}) on seeds {seeds[0]}-{seeds[-1]}, which no "
            "tuning used. `published`: the learner's defaults"
            + (f" ({', '.join(published)})" if published else "")
            + "; `tuned`: its conf/tuned files (the robot's, and the task's on top where there is one).")


def read_plan(out: Path) -> tuple[list[Job], list[str]]:
    """The jobs and command lines of the results folder ``out`` (its ``plan.json``)."""
    try:
        plan = json.loads((out / "plan.json").read_text())
        jobs = [Job(**{**job, "seeds": tuple(job["seeds"]), "overrides": tuple(job["overrides"])})
                for job in plan["jobs"]]
        return jobs, [str(c) for c in plan["commands"]]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise BadInput(f"{out}: no readable plan.json ({type(err).__name__}); "
                       "a folder written by python -m bench.benchmark has one") from None


def finished(job: Job, out: Path) -> bool:
    """Whether ``job`` ran to its end in ``out`` (a failed seed counts: its row says why)."""
    return job_record(job, out).get("returncode") in (0, 1)


def trained_elsewhere(job: Job, out: Path) -> bool:
    """Whether another process trains ``job`` in ``out`` now (one of its seeds' folders is
    locked by a live run): said in one line, and the pair left to that process, which
    writes its record when it ends."""
    from runs.folder import sweep_holders

    sweep = out / job.folder
    if not sweep.is_dir():
        return False
    holders = sorted(set(sweep_holders(sweep).values()))
    if holders:
        print(f"{job.folder}: trained now by another process (pid {', '.join(holders)}); left to it")
    return bool(holders)


def merge(old: list[Job], new: list[Job], out: Path) -> list[Job]:
    """The plan of a results folder given more jobs: the old ones in order, a new job in
    place of an old one of the same task, learner and setting unless that one finished."""
    keyed = {(j.task, j.learner, j.setting): j for j in old}
    for job in new:
        key = (job.task, job.learner, job.setting)
        if key not in keyed or not (keyed[key] == job or finished(keyed[key], out)):
            keyed[key] = job
        elif keyed[key] != job:
            raise BadInput(f"{out} already holds {job.folder} run with other seeds, budget or "
                           "overrides; use another --out folder")
    return list(keyed.values())


def run(args: argparse.Namespace) -> Path:
    """Runs (or reads back) the benchmark and writes its tables; returns the results folder.
    Given an ``--out`` folder of an earlier benchmark, it adds the jobs asked for and runs
    those that have not finished (a stopped benchmark continues where it was)."""
    command = "python -m bench.benchmark" + (" " + " ".join(sys.argv[1:]) if sys.argv[1:] else "")
    if args.read:
        out = args.read
        if not out.is_dir():
            raise BadInput(f"--read {out}: no such results folder")
        jobs, commands = read_plan(out)
    else:
        jobs = plan_jobs(args, load_plan(args.quick))
        out = args.out = args.out or ROOT / "benchmark" / time.strftime("%Y%m%d-%H%M%S")
        commands = []
        if (out / "plan.json").exists():
            old, commands = read_plan(out)
            jobs = merge(old, jobs, out)
    runnable = [job for job in jobs if job.setting == "published" or has_tuned_file(job)]
    listed = commands if args.read else [*commands, command]
    page = None if args.no_readme else args.readme or (None if quick_run(listed) else ROOT / "docs" / "benchmark.md")
    if page is not None:  # before any pair runs: a page that cannot take the table is told now
        page_text(page, args.block)
    if not args.read:
        todo = [job for job in runnable if not finished(job, out) and not trained_elsewhere(job, out)]
        for job in todo:
            check_budget(job)
            if args.budget is None:  # the plan's budget: the tuned files must carry it
                check_tuned_budget(job)
        out.mkdir(parents=True, exist_ok=True)
        commands = [c for c in commands if c != command] + [command]  # run again to go on: listed once
        (out / "plan.json").write_text(json.dumps(
            {"commands": commands, "jobs": [asdict(job) for job in jobs]}, indent=1))
        with tqdm(total=sum(len(job.seeds) for job in todo), unit="seed", desc="benchmark") as bar:
            run_pairs(todo, out, bar, args.jobs or 1, args.solo, args.threads)
    pairs, all_seeds = tabulate(jobs, runnable, out)
    figures = {}
    if page is not None:  # the page's figures, beside it
        from bench.benchmark_figures import draw

        for task in dict.fromkeys(p["task"] for p in pairs):
            name = f"{args.block or 'benchmark'}-{task}.png"
            if draw(task, pairs, all_seeds, page.parent / "assets" / "benchmark" / name):
                figures[task] = f"assets/benchmark/{name}"
    body = markdown(pairs, describe(jobs, commands), specs_of(jobs, all_seeds), figures)
    (out / "benchmark.md").write_text(body)
    if page is not None:
        rewrite_readme(page, body, args.block)
    print(body)
    print(f"results in {out}")
    return out


def quick_run(commands: list[str]) -> bool:
    """Whether the results came from ``--quick`` (they leave the page alone)."""
    return any("--quick" in c.split() for c in commands)


def tabulate(jobs: list[Job], runnable: list[Job], out: Path) -> tuple[list[dict], list[dict]]:
    """Every pair's row and every seed's, also written to benchmark.csv and seeds.csv."""
    all_seeds, pairs = [], []
    for job in jobs:
        if job not in runnable:
            pairs.append(pair_row(job, [], None, "no tuned file"))
            continue
        rows, tuned = pair_seeds(job, out)
        record = job_record(job, out)
        all_seeds += rows
        notes = []
        if not record:
            notes.append("unfinished: its multirun did not end (stopped, or still running)" if rows else "not run")
        elif not rows:
            notes.append(f"exit {record.get('returncode')}: {record.get('last_line', '')}")
        solo = record.get("solo_wall_s")
        if solo and rows and not notes:
            notes.append(f"{len(rows)} seeds in one process: {record['wall_s']:.0f} s; one seed alone "
                         f"{solo:.0f} s ({record['wall_s'] / (len(rows) * solo):.2f} of {len(rows)} runs alone)")
        if record.get("resumed") and rows:  # the seeds' clocks span every piece; the record's only the last
            notes.append("resumed after a stop: its s, all seeds is the last piece's only")
        kept = kept_hand_picks(tuned) if rows else []
        if kept:
            notes.append("a hand pick its study kept (valued at least as well as the study's best trial on the "
                         f"tuning seeds): {', '.join(kept)}")
        own = own_values_kept(tuned) if rows else []
        if own:
            notes.append("the learner's own values of the searched settings, which its study valued above every "
                         f"trial on the tuning seeds: {', '.join(own)}")
        pairs.append(pair_row(job, rows, record.get("wall_s"), "; ".join(notes), tuned))
    write_csv(out / "seeds.csv", SEED_COLUMNS, all_seeds)
    write_csv(out / "benchmark.csv", PAIR_COLUMNS, pairs)
    return pairs, all_seeds


def specs_of(jobs: list[Job], all_seeds: list[dict]) -> dict[str, str]:
    """Per task: robot/task and the success rule its runs were judged by."""
    specs = {}
    for job in jobs:
        rule = next((r for r in all_seeds if r["task"] == job.task and r["threshold"] is not None), None)
        specs[job.task] = f"{job.robot}/{job.task_name}" + (
            f", success: greedy {rule['measure']} >= {rule['threshold']:g}" if rule else "")
    return specs


def check_studies(folder: Path | None) -> Path:
    """``--studies``: a folder inside the project, as a path from its root (the default:
    ``bench/studies``); :class:`BadInput` otherwise."""
    from bench.tune_grid import STUDIES

    if folder is None:
        return STUDIES
    full = (ROOT / folder).resolve()
    if not full.is_relative_to(ROOT.resolve()) or (full.exists() and not full.is_dir()):
        raise BadInput(f"--studies must be a folder inside the project (its journals are kept with it), got {folder}")
    return full.relative_to(ROOT.resolve())


def print_grid_minutes(studies: Path) -> None:
    """``--tune --minutes``: per study, its sweeps' wall minutes (as the grid command recorded
    them in the folder's runs.csv) and its trials' (from its journal), and their sums."""
    from bench.tune_grid import GRID_RUNS, RUNS, grid_minutes, grid_run_minutes, run_minutes

    rows, swept, grid = grid_minutes(studies), run_minutes(studies), grid_run_minutes(studies)
    if not rows:
        raise BadInput(f"no study journal (<task>_<learner>.log) in {studies}")
    print(f"{'pair':<24} trials  sweeps' min  trials' min")
    for name, trials, minutes in rows:
        recorded = f"{swept[name]:12.1f}" if name in swept else f"{'-':>12}"
        print(f"{name:<24} {trials:>6} {recorded} {minutes:12.1f}")
    print(f"{len(rows)} stud{'y' if len(rows) == 1 else 'ies'}: {sum(swept.values()) / 60:.2f} hours of sweeps ({len(swept)} recorded in "
          f"{studies / RUNS}), {sum(m for _, _, m in rows) / 60:.2f} hours of trials (their start-to-end spans, "
          "a trial taken over after a stop spanning the stop)")
    if grid:
        print(f"the grid command's wall time: {sum(grid) / 60:.2f} hours over {len(grid)} run{'s' * (len(grid) != 1)} "
              f"({studies / GRID_RUNS}; the machine's time where studies ran side by side)")


def main(argv: list[str] | None = None) -> None:
    args = parse_args(argv)
    try:
        if args.jobs is not None and args.jobs < 1:
            what = "studies" if args.tune else "pairs"
            raise BadInput(f"--jobs must be at least 1 ({what} at once), got {args.jobs}")
        if args.threads is not None and args.threads < 1:
            raise BadInput(f"--threads must be at least 1 (torch threads a pair's process), got {args.threads}")
        if args.threads is not None and args.tune:
            raise BadInput("--threads is for training pairs; a study (--tune) is one process of one thread")
        if args.solo and (args.jobs or 1) > 1:
            raise BadInput("--solo times a seed alone beside nothing else: give it --jobs 1")
        if args.tune:
            from bench.tune_grid import tune

            studies = check_studies(args.studies)
            if args.minutes:
                return print_grid_minutes(studies)
            left = tune(load_plan(False), args.tasks, args.learners, args.dry_run, args.jobs, studies)
            sys.exit(1 if left and not args.dry_run else 0)  # a dry run lists the pairs left: not a failure
        run(args)
    except BadInput as err:
        sys.exit(f"error: {err}")
    except KeyboardInterrupt:
        if args.tune:
            sys.exit("stopped; run the same command again: each study takes over the trials it left running")
        sys.exit(f"stopped; run the same command with --out {args.out} to go on (finished pairs are kept, a "
                 "stopped one continues from its checkpoints)")


if __name__ == "__main__":
    main()
