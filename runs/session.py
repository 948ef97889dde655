"""One run, from its config to its verdict: built in one place, trained or evaluated, reported.

    summary = execute(cfg, run_dir, choices=..., overrides=[...])   # what train.py calls

:func:`build` makes the parts from the config (the learner, the env, the greedy
evaluator), every value checked before the first file is written. :func:`execute`
then starts the run folder and, for training, makes the :class:`~runs.run.Run`
with its logger and hooks (:func:`make_run`), trains, saves the model and the
whole training state, films the policy on request and prints the verdict. A tuning trial's report
(``progress``) is handed in: this package never imports the sweeps.
"""

from __future__ import annotations

import dataclasses
import json
import signal
import sys
import threading
from contextlib import contextmanager
from functools import partial
from pathlib import Path
from typing import Callable, Iterator, Mapping, Sequence

import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

from learners.base import Member
from runs.console import banner_lines
from runs.checkpoint import CheckpointError, load_model, save_model
from runs.evaluate import GreedyEvaluator, describe_evaluation, measure_of
from runs.folder import model_path, start_run
from runs.loop import train_single
from runs.loggers import log_hparams, make_logger, run_scalar_names
from runs.training_state import load_training_state, save_training_state
from runs.run import Hooks, Progress, Run
from runs.training_state import seed_everything
from runs.summary import verdict_lines
from runs.video import record_video
from tasks.base import Success
from tasks.env import RobotTaskEnv
from tasks.factory import build_env

EVAL_SEED_OFFSET = 10_000  # greedy evaluations start from seed + this (never the training streams)
VIDEO_SEED_OFFSET = 20_000  # the policy video's env


@dataclasses.dataclass
class Session:
    """The parts of one run, made from its config by :func:`build`."""

    cfg: DictConfig
    run_dir: Path
    learner: Member  # the run's member of its learner
    env: RobotTaskEnv
    evaluator: GreedyEvaluator

    @property
    def success(self) -> Success:
        return self.env.task.success

    @property
    def state_path(self) -> Path:
        return self.run_dir / "checkpoint.pt"

    @property
    def final_episodes(self) -> int:
        """Episodes of the final greedy evaluation (ruippeixotog's run phase, else eval_episodes)."""
        return int(getattr(self.learner, "run_episodes", 0) or self.cfg.eval_episodes)


def build(cfg: DictConfig, run_dir: Path, resume: bool = False) -> Session:
    """The parts of the run of ``cfg`` (checked by :func:`runs.settings.check_run_config`),
    ``checkpoint=``'s model loaded unless resuming; writes nothing."""
    torch.set_num_threads(int(cfg.torch_threads))
    generator = seed_everything(int(cfg.seed))
    learner = instantiate(cfg.learner, _convert_="all")
    env = build_env(cfg, int(cfg.num_envs), int(cfg.seed), learner.nsteps)
    learner.build(env.task, [generator])
    learner = learner.member(0)  # a single run is a batch of one
    if cfg.checkpoint and not resume:
        load_model(model_path(cfg.checkpoint), learner)
    elif cfg.mode == "eval":
        raise CheckpointError("mode=eval needs checkpoint=<path to a saved model.pt>")
    evaluator = GreedyEvaluator(cfg, learner, int(cfg.seed) + EVAL_SEED_OFFSET)
    return Session(cfg, run_dir, learner, env, evaluator)


def make_run(session: Session, resume: bool, progress: Progress | None,
             save: Callable[..., None] | None = None) -> Run:
    """Training's :class:`Run` with its logger and hooks (``save``: writes the training
    state, :func:`runs.training_state.save_training_state`'s arguments); a resumed run continues
    from its checkpoint (its metrics files cut back to it)."""
    cfg, learner, env = session.cfg, session.learner, session.env
    logger = make_logger(cfg.logger.kind, session.run_dir, exp_name=session.run_dir.name,
                         **{k: v for k, v in cfg.logger.items() if k != "kind"})
    hooks = Hooks(checkpoint=partial(save or save_training_state, session.state_path, learner, env),
                  greedy_eval=partial(session.evaluator, int(cfg.eval_episodes)) if cfg.eval_episodes else None,
                  train_stats=learner.train_stats, progress=progress)
    run = Run(session.run_dir, env.num_envs, learner.nepisodes, session.success, logger=logger,
              extra_fields=tuple(learner.stats), quiet=bool(cfg.quiet), verbose=bool(cfg.get("verbose", False)),
              log_every=int(cfg.get("log_every", 0)), checkpoint_every=int(cfg.get("checkpoint_every", 0)),
              eval_every=int(cfg.eval_every) if cfg.eval_episodes else 0, resume=resume,
              max_env_steps=int(cfg.get("max_env_steps", 0)),
              stop_when_solved=bool(cfg.get("stop_when_solved", True)), hooks=hooks)
    if resume:
        run.continue_from(load_training_state(session.state_path, learner, env, run))
        print(f"resuming {session.run_dir} after episode {run.n_episodes} ({run.env_steps} env steps)")
    log_hparams(logger, cfg, run_scalar_names(session.success.measure, session.success.window))
    return run


def execute(cfg: DictConfig, run_dir: Path, resume: bool = False, choices: Mapping[str, str | None] | None = None,
            changes: Sequence[str] | None = None, overrides: Sequence[str] = (),
            progress: Progress | None = None) -> dict:
    """Trains or evaluates as ``cfg`` says; returns the summary (and prints the verdict).

    ``resume``: continue the run in ``run_dir`` from its ``checkpoint.pt``; else the
    folder is started (config.yaml, run.json) once every part is built. ``choices``
    (robot, task, learner, tuned) and the tuned file's ``changes`` go into the banner.
    """
    choices = dict(choices or {})
    session = build(cfg, run_dir, resume)
    if not resume:
        start_run(cfg, run_dir, choices, list(overrides))
    for line in banner_lines(cfg, choices, changes, session.success, run_dir, session.learner.nepisodes):
        print(line)
    write_success(session)
    if cfg.mode == "train":
        summary, result = _train(session, make_run(session, resume, progress))
        if summary.get("interrupted"):
            return summary
    else:
        summary = {}
        result = session.evaluator(session.final_episodes) if session.final_episodes > 0 else None
    session.env.close()
    report(session, summary, result)
    return summary


def write_success(session: Session) -> None:
    """``success.json``: the task's rule, as the run judges it."""
    (session.run_dir / "success.json").write_text(json.dumps(dataclasses.asdict(session.success), indent=1))


def _train(session: Session, run: Run) -> tuple[dict, dict | None]:
    """Trains until ``run`` is done, then judges the trained policy; saves the training state
    and ``model.pt`` however it ends. A stopped run's summary says ``interrupted``."""
    result, finished = None, False
    try:
        with stop_on_signals(run) as signalled:
            train_single(session.learner.learner, session.env, run)
            result = final_evaluation(session, run)
        finished = True
    finally:
        summary = close_run(session, run, finished)
    if run.stop_requested:
        session.env.close()
        summary = stopped(session, run, summary, signalled["signal"] or signal.SIGINT)
    return summary, result


def final_evaluation(session: Session, run: Run, result: dict | None = None) -> dict | None:
    """The trained policy, judged like the evaluations during training (an evaluation of this
    very policy is reused); at the budget's end it may still solve a greedily judged task.
    None when the run was stopped or evaluates nothing. ``result``: that evaluation, made
    already (a seed batch evaluates the seeds that end at one step together)."""
    if session.final_episodes <= 0 or run.stop_requested:
        return None
    if _evaluated_already(session, run):
        return run.last_eval
    evaluation = partial(session.evaluator, session.final_episodes) if result is None else lambda: result
    return run.evaluate_greedy(evaluation)


def owes_final_evaluation(session: Session, run: Run) -> bool:
    """Whether :func:`final_evaluation` runs a new evaluation: not when the run was stopped
    or evaluates nothing, nor when its last evaluation was of this very policy."""
    return session.final_episodes > 0 and not run.stop_requested and not _evaluated_already(session, run)


def _evaluated_already(session: Session, run: Run) -> bool:
    """Whether the run's last evaluation is its final one: of this very policy, as many
    episodes (also a resumed run killed after its final evaluation was saved: never a
    second row)."""
    last = run.last_eval
    return (last is not None and run.evals[-1]["episode"] == run.n_episodes
            and last["episodes"] == session.final_episodes)


def close_run(session: Session, run: Run, finished: bool) -> dict:
    """The training state (``finished``: at a step boundary, so consistent), ``model.pt``, then
    the run's files closed (the reward curve drawn last: a run stopped by its launcher has its
    states saved first); returns the run's summary."""
    if finished:
        run.checkpoint(run.last_td)
    save_model(session.run_dir / "model.pt", session.learner, meta={
        "choices": json.loads((session.run_dir / "run.json").read_text()),
        "config": OmegaConf.to_container(session.cfg, resolve=True),
    })
    return run.close()


def stopped(session: Session, run: Run, summary: dict, signum: int) -> dict:
    """A run stopped by ``signum``: how to resume it, and its summary saying so."""
    print(f"stopped after episode {run.n_episodes}; the whole training state is in "
          f"{session.state_path}\nresume with: python train.py resume={session.run_dir}")
    summary["interrupted"] = True
    summary["signal"] = signum
    (session.run_dir / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def report(session: Session, summary: dict, result: dict | None) -> None:
    """The final evaluation (eval.json), the video on request, the summary and the verdict."""
    cfg, run_dir, success = session.cfg, session.run_dir, session.success
    if result is not None:
        print(describe_evaluation(result, success))
        (run_dir / "eval.json").write_text(json.dumps(
            {"measure": success.measure, "value": measure_of(result, success.measure), **result},
            indent=1))
        summary["eval"] = result
    session.evaluator.close()
    if cfg.video:  # the greedy policy on a fresh one-copy env
        video_env = build_env(cfg, 1, int(cfg.seed) + VIDEO_SEED_OFFSET, session.learner.nsteps)
        with session.learner.greedy():
            record_video(video_env, session.learner.policy, run_dir / "policy.mp4", n_steps=int(cfg.video_steps))
        video_env.close()
        print(f"policy video in {run_dir / 'policy.mp4'}")
    if cfg.mode == "train":
        (run_dir / "summary.json").write_text(json.dumps(
            {k: v for k, v in summary.items() if k != "eval"}, indent=1))
        for line in verdict_lines(summary, run_dir):
            print(line)


@contextmanager
def stop_on_signals(*records: Run) -> Iterator[dict]:
    """Ctrl-C / SIGTERM ask each of ``records`` to stop after the current step; a second
    Ctrl-C aborts. Yields ``{"signal": None}``, where the stopping signal's number is put."""
    stopped: dict = {"signal": None}
    if threading.current_thread() is not threading.main_thread():
        yield stopped  # signal handlers live in the main thread only (e.g. joblib workers)
        return

    def handler(signum, frame):
        if any(r.stop_requested for r in records) and signum == signal.SIGINT:
            raise KeyboardInterrupt
        stopped["signal"] = signum
        for record in records:
            record.request_stop()
        print(f"\n{signal.Signals(signum).name}: stopping after this step and saving a checkpoint "
              "(Ctrl-C again aborts without saving)", file=sys.stderr)

    previous = {sig: signal.signal(sig, handler) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield stopped
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)
