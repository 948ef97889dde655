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
train_return_mean=<v> greedy_return=<v> greedy_rate=<v> rate=<v> wall_s=<v> process_s=<v> run_dir=<path>``
(``greedy_rate``: the share of the final greedy evaluation's episodes that passed, ``rate``: the
share the rule asks; ``wall_s``: the run's own clock; ``process_s``: the process's, imports
and building included).
"""

from __future__ import annotations

import os
import signal
import sys
import traceback
from functools import partial
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

# Only what checks a command is imported here (Hydra, the configs, their declared
# parameters): torch, TorchRL and MuJoCo come in when a job has passed every check, so a
# refused value or --help answers in well under a second (bench/answers.py measures it).
import robots  # noqa: F401  (sets a headless GL backend before dm_control loads)
from params import ConfigError
from params.private_api import configs_parsed_once, mode_of_the_flag
from runs.command import config_dir_args, end_promptly, flags_first, hydra_error, one_line, physical
from runs.folder import MadeFolders, WRITE_FAILED, cannot_write, check_output_folder, with_run_choices, write_hydra_record
from runs.job import compose_job, keep_failure, refusals
from runs.layout import compare_command, is_run_folder, is_sweep_folder, train_command
from runs.settings import check_hydra_key, moved, moved_to
from runs.signals import hold_early
from tasks.catalog import GROUPS, config_dirs, names, use_config_dirs, with_tuned_layers


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
# --help names the command the user ran (python train.py, or the installed mujoco-rl-train).
OmegaConf.register_new_resolver("train_command", train_command, replace=True)
OmegaConf.register_new_resolver("compare_command", compare_command, replace=True)
# A mode=eval folder says so in its name (``..._qlearn_eval_<pid>``): it is not a training run.
OmegaConf.register_new_resolver("eval_mark", lambda mode: "_eval" if mode == "eval" else "", replace=True)

_IN_JOB = False  # from main on, an unexpected exception is a bug: its trace is shown
_LAUNCHER_PID = None  # the process that runs Hydra's launcher (jobs in a joblib worker differ)
_MADE: MadeFolders | None = None  # the folders there were before Hydra made the run's
REFUSALS = refusals()  # one line, exit 2


def _fail(message: str, run_dir: Path, in_sweep: bool, status: int = 2) -> None:
    """Prints ``message``; a sweep job keeps it in ``error.txt`` and lets the sweep go on (the
    sweep's end says on stderr how many jobs failed, so the job's own line goes to stdout)."""
    if not in_sweep:
        if _MADE is not None:  # a refused command leaves no folder it made
            _MADE.remove(run_dir)
        print(message, file=sys.stderr)
        sys.exit(status)
    keep_failure(run_dir, message)


def _job(cfg: DictConfig, run_dir: Path, overrides: list[str], in_sweep: bool) -> dict:
    """Makes one job (:func:`runs.job.compose_job` checks it before anything is written): its
    summary. A single run calls nothing of ``sweeps/``: only a tuning trial reports to its
    study, only ``resume=<sweep folder>`` resumes a sweep. (The seeds launcher composes the
    jobs it trains together itself.)"""
    hydra_cfg = HydraConfig.get()
    record = partial(write_hydra_record, run_dir, ".hydra-resume" if is_run_folder(cfg.get("resume")) else ".hydra",
                     cfg, hydra_cfg, hydra_cfg.overrides.task)  # Hydra's record of the command (hydra.output_subdir: null)
    if in_sweep:  # a sweep keeps each job's record, a refused job's too (its error.txt beside it)
        record()
    if isinstance(cfg.get("resume"), str) and is_sweep_folder(cfg.resume):  # every unfinished job, seeds together
        from sweeps.resume import resume_sweep

        summaries = resume_sweep(cfg, overrides)
        record()  # once it resumed something: a refused resume writes nothing there
        return next((s for s in summaries if s.get("interrupted")), {})
    job = compose_job(cfg, run_dir, overrides, hydra_cfg)
    job.run_dir.mkdir(parents=True, exist_ok=True)

    def progress():
        if job.resume or job.cfg.get("trial") is None:  # a resumed trial job reports to no study
            return None
        from sweeps.tuning import trial_link  # only a tuning trial reports to a study

        return trial_link(job.cfg, job.run_dir, hydra_cfg.sweeper)

    from runs.lifecycle import train_alone  # torch, TorchRL, MuJoCo: every check passed

    return train_alone(job, None if in_sweep else record, REFUSALS, progress)


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> None:
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
        if summary.get("failed") and not in_sweep:  # its line or trace is printed, and in error.txt
            sys.exit(int(summary.get("status", 1)))
    except REFUSALS as err:
        return _fail(f"error: {one_line(err)}", run_dir, in_sweep)
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
        sys.argv[1:] = [physical(arg) for arg in sys.argv[1:]]
        use_config_dirs(config_dir_args(sys.argv[1:]))
        args = with_run_choices(sys.argv[1:])  # mode=eval of a run: its choices (and its --config-dir)
        use_config_dirs(config_dir_args(args))
        # '~tuned': both layers; '--config-dir d' anywhere (Hydra's parser is not so lenient)
        sys.argv[1:] = flags_first(with_tuned_layers(args))
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
    own_configs_only = len(config_dirs()) == 1 and not any(  # conf/ alone: no --config-dir (use_config_dirs above)
        a in ("-cp", "--config-path") or a.startswith("--config-path=") for a in sys.argv[1:])
    try:
        # a sweep composes each job: its YAML files parsed once; the mode is -m's, not composed for
        with configs_parsed_once(), mode_of_the_flag(own_configs_only):
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
        print(f"error: {hydra_error(err)}", file=sys.stderr)
        sys.exit(1 if sweep and state.end_failed_sweep() else 2)
    if sweep:
        status = state.end_stopped_sweep()
        sys.exit(state.end_sweep() if status is None else status)


def run() -> None:
    """The program (``python train.py``, the installed ``mujoco-rl-train``): :func:`cli`, the
    process ended as soon as its exit handlers have run (:func:`runs.command.end_promptly`)."""
    end_promptly(cli)


if __name__ == "__main__":
    run()
