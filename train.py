"""Train (or evaluate) a learner on a robot's task, all chosen by Hydra config.

    python train.py                                  # cartpole / stay_up / qlearn
    python train.py robot=cube learner=qlearn        # the robot's default task follows
    python train.py -m learner=qlearn seed=0,1,2     # a sweep
    python train.py mode=eval checkpoint=outputs/.../model.pt
    python train.py resume=outputs/...               # continue a stopped or killed run
    python train.py resume=multirun/...              # ... every unfinished job of a sweep, seeds together

The run folder (printed at the end) holds config.yaml (resolved), metrics.csv,
timing.csv, reward_curve.png, model.pt, checkpoint.pt (the whole training
state, every ``checkpoint_every`` episodes and at the end) and, with
``video=true``, policy.mp4. Ctrl-C (or SIGTERM) stops at the next step, saves
checkpoint.pt and prints the resume command. The last line printed is
machine-readable, its numbers named as in summary.json (:mod:`runs.summary`; ``<m>`` the
task's measure, ``<w>`` its window):
``VERDICT solved=<true|false> episodes=<n> solved_at=<n|-> measure=<m> judge=<training|greedy>
judged_<m>=<v> threshold=<v> train_<m>_best_rolling<w>=<v> train_<m>_last<w>=<v> greedy_<m>=<v>
train_return_mean=<v> greedy_return=<v> wall_s=<v> run_dir=<path>``.
"""

from __future__ import annotations

import os
import re
import signal
import sys
import traceback
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.errors import InstantiationException
from hydra.types import RunMode
from omegaconf import DictConfig, ListConfig, OmegaConf

# Only what checks a command is imported here (Hydra, the configs, their declared
# parameters): torch, TorchRL and MuJoCo come in when a job has passed every check, so a
# refused value or --help answers in well under a second (bench/answers.py measures it).
import robots  # noqa: F401  (sets a headless GL backend before dm_control loads)
from params import CheckpointError, ConfigError, did_you_mean
from runs.console import tee_console, tuned_changes
from tasks.catalog import (GROUPS, compose, locate_model, names, run_choices, unreadable_conf_file, use_config_dirs,
                          with_tuned_layers)
from runs.folder import (WRITE_FAILED, MadeFolders, cannot_write, check_new_run, check_output_folder, eval_config,
                         resumed_config, run_folder_of, taken, with_run_choices, write_hydra_record)
from runs.layout import BATCH_JOB, is_run_folder, is_sweep_folder
from runs.settings import check_hydra_key, check_no_empty_mappings, check_run_config, moved, moved_to
from runs.signals import hold_early

if TYPE_CHECKING:
    from runs.lifecycle import Job


# ``resume=<run folder>`` makes Hydra write into that folder (conf/config.yaml);
# a wrong path gets a fresh folder and the one-line error from ``resumed_config``.
OmegaConf.register_new_resolver("if_run_folder",
                                lambda path, yes, no: yes if path and (is_run_folder(path) or is_sweep_folder(path))
                                else no, replace=True)
# Default run and sweep folders end in the process id: two runs started in the same second
# get two folders. Cached, as Hydra's ${now:}: Hydra copies a resolver's cached values from the
# launching process into each job's config, so every job of a sweep, in any worker process
# (joblib, submitit), resolves hydra.sweep.dir to the launching process's folder.
OmegaConf.register_new_resolver("pid", lambda: str(os.getpid()), replace=True, use_cache=True)

_IN_JOB = False  # from main on, an unexpected exception is a bug: its trace is shown
_LAUNCHER_PID = None  # the process that runs Hydra's launcher (jobs in a joblib worker differ)
_MADE: MadeFolders | None = None  # the folders there were before Hydra made the run's
REFUSALS = (ConfigError, CheckpointError, InstantiationException)  # one line, exit 2


def _one_line(err: BaseException) -> str:
    """The innermost message of a config error, without Hydra's wrapping."""
    while isinstance(err, InstantiationException) and err.__cause__ is not None:
        err = err.__cause__
    return str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__


def _fail(message: str, run_dir: Path, in_sweep: bool, status: int = 2) -> None:
    """Prints ``message``; a sweep job keeps it in ``error.txt`` and lets the sweep go on (the
    sweep's end says on stderr how many jobs failed, so the job's own line goes to stdout)."""
    if not in_sweep:
        if _MADE is not None:  # a refused command leaves no folder it made
            _MADE.remove(run_dir)
        print(message, file=sys.stderr)
        sys.exit(status)
    print(message, flush=True)
    try:
        (run_dir / "error.txt").write_text(message + "\n")
    except OSError:
        pass


def _job(cfg: DictConfig, run_dir: Path, overrides: list[str], in_sweep: bool) -> dict | Job:
    """Dispatches one job: resume, evaluate or train (every key checked before anything
    is written); returns the run's summary, or, for a job of a seed batch
    (``hydra.job.env_set`` names it), its checked :class:`runs.lifecycle.Job`, which the seeds
    launcher trains with the others. A single run calls nothing of ``sweeps/``: only a
    tuning trial reports to its study, only ``resume=<sweep folder>`` resumes a sweep."""
    hydra_cfg = HydraConfig.get()
    record = partial(write_hydra_record, run_dir, ".hydra-resume" if is_run_folder(cfg.get("resume")) else ".hydra",
                     cfg, hydra_cfg, hydra_cfg.overrides.task)  # Hydra's record of the command (hydra.output_subdir: null)
    if in_sweep:  # a sweep keeps each job's record, a refused job's too (its error.txt beside it)
        record()
    choices = run_choices(hydra_cfg.runtime.choices)  # tuned: None where no file applies
    sources = hydra_cfg.runtime.config_sources  # conf/, then any --config-dir
    use_config_dirs([s.path for s in sources if s.schema == "file" and s.provider != "main"])
    cfg = locate_model(cfg, choices.get("robot"), sources)
    resume = bool(cfg.get("resume"))
    if resume:
        if not isinstance(cfg.resume, str):
            raise ConfigError(f"resume must be the path of a run folder; got {cfg.resume!r}")
        if is_sweep_folder(cfg.resume):  # every unfinished job of the sweep, seeds together
            from sweeps.resume import resume_sweep

            summaries = resume_sweep(cfg, overrides)
            record()  # once it resumed something: a refused resume writes nothing there
            return next((s for s in summaries if s.get("interrupted")), {})
        from runs.training_state import read_run_json

        cfg, run_dir = resumed_config(cfg, overrides)
        choices = read_run_json(run_dir)
    elif cfg.mode == "eval" and run_folder_of(cfg.get("checkpoint")) is not None:
        cfg = eval_config(cfg, overrides)
    check_run_config(cfg)
    check_no_empty_mappings(cfg, overrides)
    changes = None if resume or cfg.mode == "eval" else tuned_changes(cfg, choices, overrides)
    from runs.lifecycle import Job, batchable, execute  # torch, TorchRL, MuJoCo: every check passed

    run_dir.mkdir(parents=True, exist_ok=True)
    job = Job(cfg, run_dir, choices, overrides, changes)
    if in_sweep and not resume and batchable(cfg) and hydra_cfg.job.env_set.get(BATCH_JOB):
        if cfg.get("trial") is not None:  # a tuning trial's job reports to its study from the batch
            from sweeps.tuning import trial_link

            job.progress = trial_link(cfg, run_dir, hydra_cfg.sweeper)
        return job  # the seeds launcher trains it with the other jobs of its group
    if not resume:
        check_new_run(run_dir)  # before the lock too: a finished run's .lock is not touched
    with taken(run_dir, REFUSALS):  # one run's record per folder: nothing written before the lock
        if not resume:
            check_new_run(run_dir)
        if not in_sweep:
            record()
        with tee_console(run_dir / "train.log"):
            # A resumed trial job trains without reporting: its study has moved on.
            progress = None
            if not resume and cfg.get("trial") is not None:  # only a tuning sweep's job reports to a study
                from sweeps.tuning import trial_link

                progress = trial_link(cfg, run_dir, hydra_cfg.sweeper)
            return execute(cfg, run_dir, resume=resume, choices=choices, changes=changes,
                           overrides=overrides, progress=progress)


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> Job | None:
    global _IN_JOB
    _IN_JOB = True
    in_sweep = HydraConfig.get().mode == RunMode.MULTIRUN
    # Unresolved: an override such as seed=${oops} is the validator's to report, not a crash here.
    overrides = list(OmegaConf.to_container(HydraConfig.get().overrides.task, resolve=False))
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    if in_sweep and os.getpid() != _LAUNCHER_PID:
        hold_early()  # a worker's job: a signal before its training starts is kept for it
    if in_sweep:
        from sweeps.state import sweep_stopped  # a single run imports nothing of sweeps/

        if sweep_stopped():
            return  # the sweep was stopped before this job began: it never starts
    try:
        summary = _job(cfg, run_dir, overrides, in_sweep)
        if not isinstance(summary, dict):  # a runs.lifecycle.Job
            return summary  # Hydra's JobReturn carries it to the seeds launcher
    except REFUSALS as err:
        return _fail(f"error: {_one_line(err)}", run_dir, in_sweep)
    except OSError as err:  # the run folder: missing, read-only, full
        if (run_dir / "run.json").is_file():  # the run had started: its files could not be written
            return _fail(cannot_write(err, run_dir), run_dir, in_sweep, WRITE_FAILED)
        where = f"{err.filename}: " if err.filename else ""
        return _fail(f"error: cannot write the run: {where}{err.strerror or err}", run_dir, in_sweep)
    except Exception:
        if not in_sweep:
            raise
        # One broken job must not cost the sweep its other jobs: keep the trace, go on.
        trace = traceback.format_exc()
        print(trace, file=sys.stderr)
        (run_dir / "error.txt").write_text(trace)
        return
    if summary.get("interrupted") and in_sweep and os.getpid() != _LAUNCHER_PID and _sibling_should_exit():
        # A sibling of a worker that died: saved, it ends its worker (the launcher waits for it).
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(128 + int(summary.get("signal", signal.SIGTERM)))
    if summary.get("interrupted") and os.getpid() == _LAUNCHER_PID:
        # In a sweep too: Ctrl-C stops the sweep, not just this job (cli reports the jobs). A job
        # in a worker process (joblib) just returns: its launcher has the signal as well.
        sys.exit(128 + int(summary.get("signal", signal.SIGINT)))


def _sibling_should_exit() -> bool:
    from sweeps.state import sibling_should_exit

    return sibling_should_exit()


def cli() -> None:
    """``main`` with Hydra's own errors (an override it cannot parse or apply, an unknown
    config choice, a run folder it cannot create) as one ``error:`` line and exit 2; a
    sweep stopped by Ctrl-C or SIGTERM prints the comparison of the jobs that finished
    and lists how to resume each unfinished job; a sweep in which a job failed or never
    started exits 1 after its comparison."""
    global _LAUNCHER_PID, _MADE
    _LAUNCHER_PID = os.getpid()
    # Hydra raises instead of printing a page; set whatever the environment says (HYDRA_FULL_ERROR=0
    # would send a mistyped key to Hydra's own six lines and exit 1).
    os.environ["HYDRA_FULL_ERROR"] = "1"
    sweep = any(a in ("-m", "--multirun") for a in sys.argv[1:])
    try:
        sys.argv[1:] = [_physical(arg) for arg in sys.argv[1:]]
        use_config_dirs(_config_dir_args(sys.argv[1:]))
        # '~tuned': both layers; '--config-dir d' anywhere (Hydra's parser is not so lenient)
        sys.argv[1:] = _flags_first(with_tuned_layers(with_run_choices(sys.argv[1:])))
        for i, arg in enumerate(sys.argv[1:], 1):  # before Hydra writes its record (.hydra/, train.log) there
            key, _, value = arg.partition("=")
            if key in ("hydra.run.dir", "hydra.sweep.dir") and value:
                sys.argv[i] = arg = f"{key}={check_output_folder(key, value)}"
            if arg.startswith("~") and arg[1:] in GROUPS:
                raise ConfigError(f"{arg} would leave the run without a {arg[1:]}; allowed: "
                                  f"{arg[1:]}=<one of {', '.join(names(arg[1:]))}>")
            if key.startswith("+") and key.lstrip("+").startswith("hydra."):
                check_hydra_key(arg)
            if moved_to(key.lstrip("+~")):
                raise ConfigError(moved(key.lstrip("+~"), value))
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    run_dirs = [a.split("=", 1)[1] for a in sys.argv[1:] if a.startswith("hydra.run.dir=")]
    _MADE = MadeFolders(run_dirs[-1] if run_dirs else None, Path.cwd())
    if sweep:  # a single run imports nothing of sweeps/
        from sweeps import state

        state.SWEEP["signal"] = None  # a new sweep: an earlier one's stop in this process (a test's) is not its own
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, state.stop_sweep)
        state.let_siblings_save()
    try:
        main()
    except (state.SweepRefused if sweep else ()) as err:  # before any job started: nothing was written
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    except SystemExit as stop:  # a job in this process was stopped: the sweep stops too
        if sweep and stop.code in (128 + signal.SIGINT, 128 + signal.SIGTERM):
            state.SWEEP["signal"] = stop.code - 128
        else:
            raise
    except ConfigError as err:  # a launcher's or sweeper's own check, before any job starts
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    except Exception as err:  # noqa: BLE001 - before a job starts, any failure is the input's
        if _IN_JOB:
            raise
        print(f"error: {_hydra_error(err)}", file=sys.stderr)
        sys.exit(1 if sweep and state.end_failed_sweep() else 2)
    if sweep:
        status = state.end_stopped_sweep()
        sys.exit(state.end_sweep() if status is None else status)


_VALUED = ("--config-dir", "-cd", "--config-name", "-cn", "--config-path", "-cp", "--cfg", "-c", "--package",
           "-p", "--experimental-rerun")
_INFO = ("all", "config", "defaults", "defaults-tree", "plugins", "searchpath")


def _physical(arg: str) -> str:
    """``resume=`` or ``checkpoint=`` a path that exists, resolved through its symlinks before
    its ``..`` (as the file system does, where text would not: ``link/../K``)."""
    key, eq, value = arg.partition("=")
    if eq and key.lstrip("+") in ("resume", "checkpoint") and value and "${" not in value and "," not in value:
        path = Path(value)
        if path.exists():
            return f"{key}={path.resolve()}"
    return arg


def _flags_first(args: list[str]) -> list[str]:
    """Hydra's options (``--config-dir d``, ``-m``, ...) before the overrides, wherever they were
    typed: Hydra's parser takes the overrides as one run of words, so ``robot=x --config-dir d
    mode=eval`` would be "unrecognized arguments"."""
    flags, overrides, i = [], [], 0
    while i < len(args):
        arg = args[i]
        if not arg.startswith("-"):
            overrides.append(arg)
        elif arg in _VALUED and i + 1 < len(args):
            flags += [arg, args[i + 1]]
            i += 1
        elif arg in ("--info", "-i") and i + 1 < len(args) and args[i + 1] in _INFO:
            flags += [arg, args[i + 1]]
            i += 1
        else:
            flags.append(arg)
        i += 1
    return [*flags, *overrides]


def _config_dir_args(args: list[str]) -> list[str]:
    """The folders of Hydra's ``--config-dir`` / ``-cd`` options in ``args``."""
    found = []
    for i, arg in enumerate(args):
        if arg in ("--config-dir", "-cd") and i + 1 < len(args):
            found.append(args[i + 1])
        elif arg.startswith("--config-dir="):
            found.append(arg.split("=", 1)[1])
    return found


def _unknown_key(err: Exception) -> str | None:
    """Hydra's "Could not override 'learner.gama'" as our line: the key, the closest one
    there is and the keys of its node (composed with the command line's robot, task, learner)."""
    found = re.search(r"Could not override '([^']+)'", str(err))
    if found is None:
        return None
    key = found.group(1)
    picks = [a for a in sys.argv[1:] if a.split("=", 1)[0] in ("robot", "task", "learner")]
    try:
        cfg = compose(overrides=picks)
    except Exception:  # noqa: BLE001 - the suggestion is a courtesy
        return None
    parent = key.rpartition(".")[0]
    node = OmegaConf.select(cfg, parent) if parent else cfg
    if parent and node is not None and not isinstance(node, (DictConfig, ListConfig)):
        return f"{key} is not a setting: {parent} is a value here ({parent}={node!r}), not a group of settings"
    names = [k for k in node if not str(k).startswith("_")] if isinstance(node, DictConfig) else []
    if not names:
        return None
    where = f"{parent}." if parent else ""
    hint = did_you_mean(key.rpartition(".")[2], names, where)
    return f"{key} is not a setting; {hint}allowed{' in ' + parent if parent else ''}: {', '.join(map(str, names))}"


def _plugin_or_type_error(text: str) -> str | None:
    """Hydra's "Could not find 'hydra/launcher/ray'" (a launcher or sweeper not installed) and
    "Error merging override k=v (Value 'v' of type 'str' could not be converted to Integer ...)"
    (a launcher setting of the wrong type) as our line, or None."""
    found = re.search(r"Could not find 'hydra/(launcher|sweeper)/([^']+)' Available options in "
                      r"'hydra/\1': ([\w ]+?)(?: Config search path|$)", text)
    if found:
        group, name, options = found.groups()
        return (f"hydra/{group}={name} is not installed; installed: {', '.join(options.split())} "
                f"(a Hydra {group} plugin is a pip package, e.g. hydra-{'submitit-launcher' if group == 'launcher' else 'ax-sweeper'})")
    found = re.search(r"Error merging override (\S+) \(Value '(.*?)' of type '\w+' could not be "
                      r"converted to (\w+)", text)
    if found:
        override, value, kind = found.groups()
        return f"{override.split('=', 1)[0]} must be {'an' if kind[0] in 'AEIOU' else 'a'} {kind.lower()}; got {value!r}"
    found = re.search(r"Error merging override (\S+?)=(.*?) \(Cannot convert '(\w+)' to (\w+)", text)
    if found:
        key, value, got, kind = found.groups()
        return f"{key} must be a {kind}; got a {got}: {value}"
    return None


def _caused_by(err: BaseException, kind: type) -> bool:
    """Whether ``err`` or an exception in its chain (cause or context) is a ``kind``."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, kind):
            return True
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return False


def _hydra_error(err: Exception) -> str:
    """One line of what Hydra (or the OS, creating the run folder) refused."""
    unknown = _unknown_key(err)
    if unknown is not None:
        return unknown
    if _caused_by(err, UnicodeDecodeError):  # Hydra does not say which file
        searched = [Path(a.split("=", 1)[1].strip("[]").removeprefix("file://"))
                    for a in sys.argv[1:] if a.startswith("hydra.searchpath=")]
        bad = unreadable_conf_file([p for p in searched if p.is_dir()])
        if bad is not None:
            return f"{bad}; allowed: a YAML file in UTF-8"
    text = " ".join(line.strip() for line in str(err).splitlines() if line.strip())
    text = text.split(" Config search path:")[0]
    if isinstance(err, OSError) and err.filename:
        text = f"cannot create the run folder {err.filename}: {err.strerror}"
    cause = err.__cause__ or err.__context__
    if cause is not None and str(cause).strip() and str(cause).strip() not in text:
        text += f" ({' '.join(str(cause).split())})"
    return _plugin_or_type_error(text) or text or type(err).__name__


if __name__ == "__main__":
    cli()
