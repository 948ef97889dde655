"""Train (or evaluate) a learner on a robot's task, all chosen by Hydra config.

    python train.py                                  # cartpole / stay_up / qlearn
    python train.py robot=cube learner=qlearn        # the robot's default task follows
    python train.py -m learner=qlearn seed=0,1,2     # a sweep
    python train.py mode=eval checkpoint=outputs/.../model.pt
    python train.py resume=outputs/...               # continue a stopped or killed run

The run folder (printed at the end) holds config.yaml (resolved), metrics.csv,
timing.csv, reward_curve.png, model.pt, checkpoint.pt (the whole training
state, every ``checkpoint_every`` episodes and at the end) and, with
``video=true``, policy.mp4. Ctrl-C (or SIGTERM) stops at the next step, saves
checkpoint.pt and prints the resume command. The last line printed is
machine-readable:
``VERDICT solved=<true|false> episodes=<n> measure=<task's measure> judge=<training|greedy>
value=<v> threshold=<v> best_rolling100=<v> greedy=<v> wall_s=<v> run_dir=<path>``.
"""

from __future__ import annotations

import dataclasses
import fcntl
import json
import os
import re
import signal
import sys
import threading
import traceback
from contextlib import contextmanager
from pathlib import Path
from typing import Callable, Iterator

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.errors import InstantiationException
from hydra.types import RunMode
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

import robots  # noqa: F401  (sets a headless GL backend before dm_control loads)
from learners.banner import banner_lines, tuned_changes
from learners.checkpoint import CheckpointError
from learners.console import tee_console
from learners.evaluate import describe_evaluation, greedy_evaluation, measure_of
from learners.loggers import log_hparams, make_logger
from learners.resume import (check_checkpoint, check_targets, load_run_config, load_training_state,
                             new_run_identity, read_run_json, save_training_state)
from learners.run import Run
from learners.seeding import seed_everything
from learners.settings import check_run_config
from learners.summary import summarize_run
from learners.sweep_state import SWEEP, compare_sweep
from learners.verdict import verdict_lines
from learners.video import record_video
from params import ConfigError, did_you_mean
from tasks.env import RobotTaskEnv
from tasks.factory import GROUPS, build_env, compose



def _if_run_folder(path, yes, no):
    """``yes`` if ``path`` is a run folder (has config.yaml), else ``no``."""
    return yes if path and (Path(str(path)) / "config.yaml").is_file() else no


# ``resume=<run folder>`` makes Hydra write into that folder (conf/config.yaml);
# a wrong path gets a fresh folder and the one-line error from ``resumed_config``.
OmegaConf.register_new_resolver("if_run_folder", _if_run_folder, replace=True)
# Default run and sweep folders end in the process id: two runs started in the same second
# get two folders.
OmegaConf.register_new_resolver("pid", lambda: str(os.getpid()), replace=True)
# A stopped run exits 128 + the signal's number, as shells report it: 130 (Ctrl-C), 143 (SIGTERM).
# Overrides a resumed run accepts; everything else comes from the run's own config.yaml.
RESUME_OVERRIDES = ("resume", "quiet", "verbose", "log_every", "torch_threads", "video", "video_steps",
                    "eval_episodes")
PICKS = GROUPS  # the config groups a run folder fixes


@contextmanager
def stop_on_signals(record: Run) -> Iterator[dict]:
    """Ctrl-C / SIGTERM ask ``record`` to stop after the current step; a second Ctrl-C aborts.
    Yields ``{"signal": None}``, where the stopping signal's number is put."""
    stopped: dict = {"signal": None}
    if threading.current_thread() is not threading.main_thread():
        yield stopped  # signal handlers live in the main thread only (e.g. joblib workers)
        return

    def handler(signum, frame):
        if record.stop_requested and signum == signal.SIGINT:
            raise KeyboardInterrupt
        stopped["signal"] = signum
        record.request_stop()
        print(f"\n{signal.Signals(signum).name}: stopping after this step and saving a checkpoint "
              "(Ctrl-C again aborts without saving)", file=sys.stderr)

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stopped
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def run(cfg: DictConfig, run_dir: Path, resume: bool = False,
        start: Callable[[], None] | None = None, choices: dict | None = None,
        changes: list[str] | None = None, progress=None) -> dict:
    """Trains or evaluates as ``cfg`` says; returns the summary (and prints the verdict).

    ``cfg`` has passed :func:`check_run_config` (``main`` checks it before the run folder is
    touched). ``resume``: continue the run in ``run_dir`` from its ``checkpoint.pt``. ``start()``
    is called once the learner and env are built (every value checked), before any file is written.
    ``choices`` (robot, task, learner, tuned) and the tuned file's ``changes`` go into the banner.
    ``progress``: a tuning trial's :class:`~learners.tuning.TrialLink` (reports, may prune).
    """
    torch.set_num_threads(int(cfg.torch_threads))
    generator = seed_everything(int(cfg.seed))
    learner = instantiate(cfg.learner, _convert_="all")
    env = build_env(cfg, int(cfg.num_envs), int(cfg.seed), learner.nsteps)
    success = env.task.success
    learner.build(env.task, generator)
    if cfg.checkpoint and not resume:
        learner.load(model_path(cfg.checkpoint))
    elif cfg.mode == "eval":
        raise CheckpointError("mode=eval needs checkpoint=<path to a saved model.pt>")
    if start is not None:
        start()
    for line in banner_lines(cfg, choices or {}, changes, success, run_dir, learner.nepisodes):
        print(line)
    (run_dir / "success.json").write_text(json.dumps(dataclasses.asdict(success), indent=1))
    eval_seed = int(cfg.seed) + 10_000
    n_eval = int(getattr(learner, "run_episodes", 0) or cfg.eval_episodes)
    eval_envs: dict[int, RobotTaskEnv] = {}  # greedy evaluation envs by copies, built when first used

    def greedy(copies: int) -> dict:
        if copies not in eval_envs:
            eval_envs[copies] = build_env(cfg, copies, eval_seed, learner.nsteps)
        return greedy_evaluation(learner, eval_envs[copies], eval_seed)

    summary: dict = {}
    result = None
    if cfg.mode == "train":
        state_path = run_dir / "checkpoint.pt"
        record = Run(run_dir, env.num_envs, learner.nepisodes, success, extra_fields=tuple(learner.stats),
                     quiet=bool(cfg.quiet), verbose=bool(cfg.get("verbose", False)),
                     log_every=int(cfg.get("log_every", 0)),
                     checkpoint_every=int(cfg.get("checkpoint_every", 0)),
                     eval_every=int(cfg.eval_every) if cfg.eval_episodes else 0, resume=resume,
                     max_env_steps=int(cfg.get("max_env_steps", 0)),
                     stop_when_solved=bool(cfg.get("stop_when_solved", True)))
        record.progress = progress
        if resume:
            record.resume_td = load_training_state(state_path, learner, env, record)
            print(f"resuming {run_dir} after episode {record.n_episodes} ({record.env_steps} env steps)")
        record.logger = make_logger(cfg.logger.kind, run_dir, exp_name=run_dir.name,
                                    **{k: v for k, v in cfg.logger.items() if k != "kind"})
        log_hparams(record.logger, cfg)
        record.checkpoint = lambda td: save_training_state(state_path, learner, env, record, td)
        record.greedy_eval = lambda: greedy(int(cfg.eval_episodes))
        finished = False
        try:
            with stop_on_signals(record) as stopped:
                learner.train(env, record)
                if n_eval > 0 and not record.stop_requested:
                    # The trained policy, judged like the evaluations during training (an
                    # evaluation of this very policy is reused); at the budget's end it may
                    # still solve a greedily judged task.
                    fresh = record.last_eval is not None and record.evals[-1]["episode"] == record.n_episodes
                    result = (record.last_eval if fresh and n_eval == int(cfg.eval_episodes)
                              else record.evaluate_greedy(lambda: greedy(n_eval)))
            finished = True
        finally:
            if finished:  # at a step boundary: the whole state is consistent
                record.checkpoint(record.last_td)
            summary = record.close()
            learner.save(run_dir / "model.pt", meta={
                "choices": json.loads((run_dir / "run.json").read_text()),
                "config": OmegaConf.to_container(cfg, resolve=True),
            })
        if record.stop_requested:
            env.close()
            print(f"stopped after episode {record.n_episodes}; the whole training state is in "
                  f"{state_path}\nresume with: python train.py resume={run_dir}")
            summary["interrupted"] = True
            summary["signal"] = stopped["signal"] or signal.SIGINT
            (run_dir / "summary.json").write_text(json.dumps(summary, indent=1))
            return summary
    elif n_eval > 0:
        result = greedy(n_eval)
    env.close()
    if result is not None:
        print(describe_evaluation(result, success))
        (run_dir / "eval.json").write_text(json.dumps(
            {"measure": success.measure, "value": measure_of(result, success.measure), **result},
            indent=1))
        summary["eval"] = result
    for eval_env in eval_envs.values():
        eval_env.close()
    if cfg.video:  # the greedy policy on a fresh one-copy env
        video_env = build_env(cfg, 1, int(cfg.seed) + 20_000, learner.nsteps)
        with learner.greedy():
            record_video(video_env, learner.policy, run_dir / "policy.mp4", n_steps=int(cfg.video_steps))
        video_env.close()
        print(f"policy video in {run_dir / 'policy.mp4'}")
    if cfg.mode == "train":
        (run_dir / "summary.json").write_text(json.dumps(
            {k: v for k, v in summary.items() if k != "eval"}, indent=1))
        for line in verdict_lines(summary, run_dir):
            print(line)
    return summary


def trial_link(cfg: DictConfig, run_dir: Path):
    """The Optuna study a ``trial=N`` job reports to (its sweeper's storage and study)."""
    if cfg.get("trial") is None or cfg.mode != "train":
        return None
    sweeper = HydraConfig.get().sweeper
    if "rl_optuna_sweeper" not in str(sweeper.get("_target_", "")):
        raise ConfigError(f"trial={cfg.trial} is set by hydra/sweeper=optuna for its own jobs; "
                          "tune with: python train.py -m hydra/sweeper=optuna ...")
    from learners.tuning import TrialLink

    try:
        return TrialLink(str(sweeper.storage), str(sweeper.study), int(cfg.trial),
                         lead=int(cfg.seed) == int(sweeper.seeds[0]), pruner=sweeper.pruner,
                         every=int(sweeper.report_every), run_dir=run_dir)
    except ConfigError:
        raise
    except Exception as err:  # noqa: BLE001 - a missing study or trial, a database error
        raise ConfigError(f"trial={cfg.trial}: study {sweeper.study} in {sweeper.storage} has no such "
                          f"trial to report to ({type(err).__name__}: {_one_line(err)})") from None


def _one_line(err: BaseException) -> str:
    """The innermost message of a config error, without Hydra's wrapping."""
    while isinstance(err, InstantiationException) and err.__cause__ is not None:
        err = err.__cause__
    return str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__


def resumed_config(cfg: DictConfig, overrides: list[str]) -> tuple[DictConfig, Path]:
    """The config of the run folder ``cfg.resume``, with the few overrides a resume accepts."""
    run_dir = Path(cfg.resume)
    if not (run_dir / "config.yaml").is_file() or not (run_dir / "run.json").is_file():
        raise CheckpointError(f"resume={run_dir} is not a run folder (it needs config.yaml and run.json)")
    if not (run_dir / "checkpoint.pt").is_file():
        raise CheckpointError(f"resume={run_dir} has no checkpoint.pt to continue from "
                              "(it was run with checkpoint_every=0, or stopped before its first one)")
    others = [o for o in overrides if o.split("=", 1)[0].lstrip("+~") not in RESUME_OVERRIDES]
    if others:
        raise ConfigError(f"resume= continues a run with its own config; drop {' '.join(others)} "
                          f"(allowed with resume: {', '.join(RESUME_OVERRIDES[1:])})")
    read_run_json(run_dir)  # a damaged run.json is refused now, not when model.pt is written
    saved = load_run_config(run_dir)
    for key in RESUME_OVERRIDES[1:]:
        if any(o.startswith(f"{key}=") for o in overrides):
            saved[key] = cfg[key]
    check_targets(saved)  # config.yaml is data: it may build only the project's own classes
    check_checkpoint(run_dir, saved)  # this run's, intact: refused before any file is touched
    return saved, run_dir


def model_path(checkpoint: str | Path) -> Path:
    """``checkpoint=``'s model file: the path itself, or a run folder's model.pt."""
    path = Path(checkpoint)
    if path.is_dir():
        if not (path / "model.pt").is_file():
            raise CheckpointError(f"checkpoint={path} is a folder without model.pt (a run folder "
                                  "holds one once its run ends or stops)")
        return path / "model.pt"
    return path


def run_folder_of(checkpoint: str | Path | None) -> Path | None:
    """The run folder ``checkpoint=`` points into (the folder or a model.pt in it), if any."""
    if not checkpoint:
        return None
    path = Path(checkpoint)
    folder = path if path.is_dir() else path.parent
    return folder if (folder / "config.yaml").is_file() and (folder / "run.json").is_file() else None


def eval_config(cfg: DictConfig, overrides: list[str]) -> DictConfig:
    """``mode=eval checkpoint=<run folder or its model.pt>``: the robot, task and learner of
    the run's own config.yaml; the run settings (``eval_episodes``, ``seed``, ``video``, ...)
    and every override of this command (a task parameter for a robustness test) on top."""
    folder = run_folder_of(cfg.checkpoint)
    saved = load_run_config(folder)
    check_targets(saved)  # config.yaml is data: it may build only the project's own classes
    evaluated = cfg.copy()
    for group in PICKS:
        if group in saved:
            evaluated[group] = saved[group]
    for override in overrides:  # robot./task./learner. values of this command, as composed
        key = override.split("=", 1)[0].lstrip("+")
        if "=" in override and not key.startswith("~") and key.split(".")[0] in PICKS and "." in key:
            OmegaConf.update(evaluated, key, OmegaConf.select(cfg, key), merge=False, force_add=True)
    evaluated.checkpoint = str(model_path(cfg.checkpoint))
    return evaluated


@contextmanager
def run_lock(run_dir: Path) -> Iterator[None]:
    """Holds ``run_dir/.lock`` exclusively while the run lives; another process asking for
    it gets a :class:`ConfigError`. The OS drops the lock when its holder dies, so a killed
    run's folder is taken over by the next run (or resume) without ceremony."""
    fd = os.open(run_dir / ".lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.read(fd, 32).decode(errors="replace").strip() or "?"
        os.close(fd)
        raise ConfigError(f"run folder {run_dir} is in use by another run (pid {holder}); let it "
                          "finish or pick another folder") from None
    try:
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        yield
    finally:
        os.close(fd)


def start_run(cfg: DictConfig, run_dir: Path, overrides: list[str]) -> None:
    """A new run's folder: refused if it already holds a run; then config.yaml and run.json."""
    if (run_dir / "config.yaml").exists() or (run_dir / "run.json").exists():
        raise ConfigError(f"hydra.run.dir={run_dir} already holds a run; continue it with "
                          f"resume={run_dir}, or pick another folder")
    OmegaConf.save(cfg, run_dir / "config.yaml", resolve=True)
    choices = HydraConfig.get().runtime.choices
    (run_dir / "run.json").write_text(json.dumps(
        {group: choices.get(group) for group in ("robot", "task", "learner", "tuned")}
        | {"seed": int(cfg.seed), "overrides": overrides} | new_run_identity(), indent=1))


def _fail(message: str, run_dir: Path, in_sweep: bool) -> None:
    """Prints ``message``; a sweep job keeps it in ``error.txt`` and lets the sweep go on."""
    print(message, file=sys.stderr)
    if not in_sweep:
        sys.exit(2)
    try:
        (run_dir / "error.txt").write_text(message + "\n")
    except OSError:
        pass


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> None:
    global _IN_JOB
    _IN_JOB = True  # from here on, an unexpected exception is a bug: its trace is shown
    in_sweep = HydraConfig.get().mode == RunMode.MULTIRUN
    # Unresolved: an override such as seed=${oops} is the validator's to report, not a crash here.
    overrides = list(OmegaConf.to_container(HydraConfig.get().overrides.task, resolve=False))
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    resume = bool(cfg.get("resume"))
    if in_sweep and sweep_stopped():
        return  # the sweep was stopped before this job began: it never starts
    choices = {k: v for k, v in HydraConfig.get().runtime.choices.items() if k in (*PICKS, "tuned")}
    try:
        if resume:
            if not isinstance(cfg.resume, str):
                raise ConfigError(f"resume must be the path of a run folder; got {cfg.resume!r}")
            cfg, run_dir = resumed_config(cfg, overrides)
            choices = read_run_json(run_dir)
        elif cfg.mode == "eval" and run_folder_of(cfg.get("checkpoint")) is not None:
            cfg = eval_config(cfg, overrides)
        check_run_config(cfg)  # every key, one line, before anything is written
        changes = None if resume or cfg.mode == "eval" else tuned_changes(cfg, choices, overrides)
        run_dir.mkdir(parents=True, exist_ok=True)
        with run_lock(run_dir), tee_console(run_dir / "train.log"):
            summary = run(cfg, run_dir, resume=resume, choices=choices, changes=changes,
                          start=None if resume else lambda: start_run(cfg, run_dir, overrides),
                          progress=None if resume else trial_link(cfg, run_dir))  # its study moved on
    except (ConfigError, CheckpointError, InstantiationException) as err:
        return _fail(f"error: {_one_line(err)}", run_dir, in_sweep)
    except OSError as err:  # the run folder: missing, read-only, full
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
    if summary.get("interrupted") and os.getpid() == _LAUNCHER_PID:
        # In a sweep too: Ctrl-C stops the sweep, not just this job (cli reports the jobs). A job
        # in a worker process (joblib) just returns: its launcher has the signal as well.
        sys.exit(128 + int(summary.get("signal", signal.SIGINT)))


_IN_JOB = False
_LAUNCHER_PID = None  # the process that runs Hydra's launcher (jobs in a joblib worker differ)
_SWEEP_STOP: dict = {"signal": None}


def _sweep_dir() -> Path | None:
    """The running sweep's folder: a job's own, else what the launcher recorded."""
    try:
        return Path(str(HydraConfig.get().sweep.dir))
    except Exception:  # noqa: BLE001 - the launching process has no job config
        return SWEEP["dir"]


def _stop_sweep(signum, frame) -> None:
    """The launcher's Ctrl-C / SIGTERM during a sweep: running jobs (which get the signal
    too) stop after their step and save; jobs not started yet are skipped (``.stop``)."""
    if _SWEEP_STOP["signal"] is not None and signum == signal.SIGINT:
        raise KeyboardInterrupt
    _SWEEP_STOP["signal"] = signum
    folder = _sweep_dir()
    if folder is not None and folder.is_dir():
        (folder / ".stop").write_text(signal.Signals(signum).name + "\n")
    print(f"\n{signal.Signals(signum).name}: the sweep's running jobs stop after their step and "
          "save a checkpoint; jobs not started are skipped (Ctrl-C again aborts)", file=sys.stderr)


def sweep_stopped() -> bool:
    """Inside a job: whether its sweep was asked to stop before the job began."""
    folder = _sweep_dir()
    return folder is not None and (folder / ".stop").exists()


def report_stopped_sweep(folder: Path) -> None:
    """One resume command per job the stop left unfinished."""
    for job in sorted(p for p in folder.iterdir() if p.is_dir()):
        state = summarize_run(job)  # the same reading of a job folder compare.py uses
        if state.get("resume"):
            print(f"resume with: {state['resume']}")
        elif state["status"] == "never started":
            print(f"not started: {job.name}")


def cli() -> None:
    """``main`` with Hydra's own errors (an override it cannot parse or apply, an unknown
    config choice, a run folder it cannot create) as one ``error:`` line and exit 2; a
    sweep stopped by Ctrl-C or SIGTERM prints the comparison of the jobs that finished
    and lists how to resume each unfinished job."""
    global _LAUNCHER_PID
    _LAUNCHER_PID = os.getpid()
    os.environ.setdefault("HYDRA_FULL_ERROR", "1")  # Hydra raises instead of printing a page
    sweep = any(a in ("-m", "--multirun") for a in sys.argv[1:])
    try:
        sys.argv[1:] = with_run_choices(sys.argv[1:])
    except ConfigError as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    if sweep:
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, _stop_sweep)
    try:
        main()
    except SystemExit as stop:  # a job in this process was stopped: the sweep stops too
        if sweep and stop.code in (128 + signal.SIGINT, 128 + signal.SIGTERM):
            _SWEEP_STOP["signal"] = stop.code - 128
        else:
            raise
    except Exception as err:  # noqa: BLE001 - before a job starts, any failure is the input's
        if _IN_JOB:
            raise
        print(f"error: {_hydra_error(err)}", file=sys.stderr)
        folder = _sweep_dir() if sweep else None
        if folder is not None and folder.is_dir():  # e.g. a joblib worker killed from outside
            compare_sweep(folder)  # Hydra skips on_multirun_end when the launcher raises
            report_stopped_sweep(folder)
            sys.exit(1)
        sys.exit(2)
    if sweep and _SWEEP_STOP["signal"] is not None:
        folder = _sweep_dir()
        if folder is not None and folder.is_dir():
            # What finished; done already unless a job's exit skipped on_multirun_end.
            compare_sweep(folder, stopped=signal.Signals(int(_SWEEP_STOP["signal"])).name)
            report_stopped_sweep(folder)
        sys.exit(128 + int(_SWEEP_STOP["signal"]))


def with_run_choices(args: list[str]) -> list[str]:
    """``mode=eval checkpoint=<run folder>``: the run's robot, task and learner (run.json's)
    put on the command line, so its other overrides compose as for that run; a different
    choice given with it is refused."""
    given = dict(a.split("=", 1) for a in args if "=" in a and not a.startswith(("+", "~", "-")))
    folder = run_folder_of(given.get("checkpoint")) if given.get("mode") == "eval" else None
    if folder is None:
        return args
    saved = read_run_json(folder)
    clash = [f"{k}={given[k]}" for k in PICKS if k in given and given[k] != saved.get(k)]
    if clash:
        raise ConfigError(f"checkpoint={folder} is a {'/'.join(str(saved.get(k)) for k in PICKS)} "
                          f"run, evaluated with its own robot, task and learner; drop {' '.join(clash)}")
    return [*(f"{k}={saved[k]}" for k in PICKS if k not in given and saved.get(k)), *args]


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
    names = [k for k in node if not str(k).startswith("_")] if isinstance(node, DictConfig) else []
    if not names:
        return None
    where = f"{parent}." if parent else ""
    hint = did_you_mean(key.rpartition(".")[2], names, where)
    return f"{key} is not a setting; {hint}allowed{' in ' + parent if parent else ''}: {', '.join(map(str, names))}"


def _hydra_error(err: Exception) -> str:
    """One line of what Hydra (or the OS, creating the run folder) refused."""
    unknown = _unknown_key(err)
    if unknown is not None:
        return unknown
    text = " ".join(line.strip() for line in str(err).splitlines() if line.strip())
    text = text.split(" Config search path:")[0]
    if isinstance(err, OSError) and err.filename:
        text = f"cannot create the run folder {err.filename}: {err.strerror}"
    cause = err.__cause__ or err.__context__
    if cause is not None and str(cause).strip() and str(cause).strip() not in text:
        text += f" ({' '.join(str(cause).split())})"
    return text or type(err).__name__


if __name__ == "__main__":
    cli()
