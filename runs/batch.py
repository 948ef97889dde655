"""Seeds in one process: runs that differ only in their seed, trained side by side.

    summaries = execute_batch([BatchJob(cfg_0, dir_0, ...), BatchJob(cfg_1, dir_1, ...)])

One env holds every seed's copies as seed blocks (``RobotTaskEnv(seed=[...])``):
each block starts its episodes as that seed's env alone would, and the physics of
all of them is one step. One learner holds every seed as a member (its own random
stream, table or networks, replay buffer, schedule); each seed keeps its own
:class:`Run` with its own folder, files, checkpoints and verdict, so a seed's run is the
run ``python train.py seed=<s>`` makes, file for file (wall-clock numbers aside), and
each folder resumes alone (``resume=<folder>``). The training loop is every run's
(:func:`runs.loop.train`); a checkpoint and a seed's end swap its torch, numpy and
``random`` global states in (a checkpoint holds them).

A seed that is done (solved, out of budget, stopped) ends there, as alone, and its
copies stop stepping (``BatchedPhysics.hold``) while the others go on. A seed whose own
work fails (its booking, its evaluation or checkpoint) ends alone, its trace in its
``error.txt``; a learner call that fails ends every seed still training with the trace
(they share its state). Each seed's console goes to its ``train.log`` and, its lines
prefixed with ``[seed N]``, to the terminal.
"""

from __future__ import annotations

import random
import signal
import sys
import traceback
from contextlib import ExitStack, contextmanager
from functools import partial
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Iterator, Mapping, Sequence

import numpy as np
import torch
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDictBase

from params import ConfigError
from runs import session as solo
from runs.console import banner_lines
from runs.console import Tee
from runs.evaluate import GreedyEvaluator, greedy_evaluations
from runs.folder import run_lock, start_run
from runs.loop import train
from runs.training_state import save_training_state
from runs.run import Run
from runs.training_state import seed_everything
from tasks.env import RobotTaskEnv
from tasks.factory import build_env

# Settings a batched job may not have: each makes a run that is not a fresh training run.
NOT_BATCHED = ("resume", "checkpoint", "trial")


@dataclass
class BatchJob:
    """One seed's job: its checked config, folder, choices (for the banner and run.json),
    command-line overrides and what its tuned file changed."""

    cfg: DictConfig
    run_dir: Path
    choices: Mapping[str, str | None]
    overrides: Sequence[str] = ()
    changes: Sequence[str] | None = None
    resume: bool = False  # continues the stopped run in run_dir (its cfg: the folder's, resume= set)


def batchable(cfg: DictConfig) -> bool:
    """Whether a job with ``cfg`` can train in a seed batch (a fresh training run)."""
    return cfg.mode == "train" and not any(cfg.get(key) not in (None, "", False) for key in NOT_BATCHED)


def check_batch(jobs: Sequence[BatchJob]) -> None:
    """One line unless ``jobs`` are fresh training runs whose configs differ only in an
    integer seed, each seed once."""
    seeds = [job.cfg.seed for job in jobs]
    if any(type(s) is not int for s in seeds):
        raise ConfigError(f"seed must be an integer in a seed batch; got {seeds}")
    twice = sorted({s for s in seeds if seeds.count(s) > 1})
    if twice:
        raise ConfigError(f"seed {twice[0]} appears twice in one sweep; give each seed once")
    if not all(batchable(job.cfg) for job in jobs if not job.resume) or not all(
            job.cfg.mode == "train" and not job.cfg.get("checkpoint") for job in jobs if job.resume):
        raise ConfigError(f"a seed batch trains fresh or resumed runs only (no {', '.join(NOT_BATCHED[1:])})")
    first = _without_seed(jobs[0].cfg)
    for job in jobs[1:]:
        if _without_seed(job.cfg) != first:
            raise ConfigError(f"jobs {jobs[0].run_dir.name} and {job.run_dir.name} differ in more "
                              "than their seed: they cannot share a seed batch")


def _without_seed(cfg: DictConfig) -> dict:
    """The config but its seed (and a resumed run's own folder)."""
    return {k: v for k, v in OmegaConf.to_container(cfg, resolve=True).items() if k not in ("seed", "resume")}


def same_batch(cfgs: Sequence[DictConfig]) -> list[list[int]]:
    """Indices of ``cfgs`` grouped by their config but the seed (first-seen order): the
    batches they may train in."""
    groups: dict[str, list[int]] = {}
    for i, cfg in enumerate(cfgs):
        groups.setdefault(repr(_without_seed(cfg)), []).append(i)
    return list(groups.values())


@dataclass
class _Slot:
    """One seed of the batch: its job, member, run, random streams and console (a
    :class:`runs.loop.Lane`)."""

    job: BatchJob
    index: int  # its member of the learner, its block of the env
    terminal: IO[str]
    session: solo.Session | None = None
    run: Run | None = None
    log: IO[str] | None = None
    # The seed's global random streams as its run alone leaves them: torch's (a generator
    # holding its state), numpy's and ``random``'s. Training draws from none of them (the
    # learner's members have their own streams); a checkpoint holds them.
    streams: tuple = ()
    failed: str | None = None
    result: dict | None = None  # the final greedy evaluation
    summary: dict = field(default_factory=dict)
    console: IO[str] | None = None

    @property
    def seed(self) -> int:
        return int(self.job.cfg.seed)

    @property
    def env(self):
        """Its block of the batch's env."""
        return self.session.env

    @property
    def done(self) -> bool:
        return self.failed is not None or self.run is None or self.run.done

    @contextmanager
    def active(self, full: bool = False) -> Iterator[None]:
        """This seed's console inside (``full``: its global random streams too, the others'
        kept outside)."""
        if full:
            torch.set_rng_state(self.streams[0].get_state())
            np.random.set_state(self.streams[1])
            random.setstate(self.streams[2])
        out, err = sys.stdout, sys.stderr
        sys.stdout = sys.stderr = self.console
        try:
            yield
        finally:
            sys.stdout, sys.stderr = out, err
            if full:
                self.streams[0].set_state(torch.get_rng_state())
                self.streams = (self.streams[0], np.random.get_state(), random.getstate())

    def guarded(self, work, full: bool = False) -> bool:
        """Runs ``work`` in the seed's context; an exception ends this seed alone (``error.txt``).
        Whether the seed is still sound."""
        with self.active(full):
            try:
                work()
            except Exception:  # noqa: BLE001 - one seed's failure must not cost the others
                self._failed(traceback.format_exc())
        return self.failed is None

    def fail(self, error: BaseException, trace: str) -> None:
        """A learner call shared with other seeds failed: this seed ends with its trace."""
        with self.active():
            self._failed(f"the seeds' learner failed:\n{trace}")

    def _failed(self, trace: str) -> None:
        self.failed = trace
        print(trace, file=sys.stderr)
        (self.job.run_dir / "error.txt").write_text(trace)

    def save(self, path, learner, env, run, td: TensorDictBase) -> None:
        """:func:`runs.training_state.save_training_state` with this seed's random states in place
        (a checkpoint holds them) and ``td`` its block (a step of the batch hands the batch's)."""
        if td.batch_size[0] != env.num_envs:
            td = td[env.rows]
        outside = torch.get_rng_state(), np.random.get_state(), random.getstate()
        torch.set_rng_state(self.streams[0].get_state())
        np.random.set_state(self.streams[1])
        random.setstate(self.streams[2])
        try:
            save_training_state(path, learner, env, run, td)
        finally:
            torch.set_rng_state(outside[0])
            np.random.set_state(outside[1])
            random.setstate(outside[2])


class _Prefixed:
    """A terminal stream that starts each line with ``prefix`` (never a tty: no progress bar)."""

    def __init__(self, stream: IO[str], prefix: str) -> None:
        self.stream, self.prefix, self._fresh = stream, prefix, True

    def write(self, text: str) -> int:
        for piece in text.splitlines(keepends=True):
            self.stream.write((self.prefix if self._fresh else "") + piece)
            self._fresh = piece.endswith("\n")
        return len(text)

    def flush(self) -> None:
        self.stream.flush()

    def isatty(self) -> bool:
        return False


def execute_batch(jobs: Sequence[BatchJob]) -> list[dict]:
    """Trains every job of ``jobs`` (checked by :func:`check_batch`) in one env; returns each
    seed's summary, in order (a failed seed's says ``failed``)."""
    check_batch(jobs)
    cfg = jobs[0].cfg
    torch.set_num_threads(int(cfg.torch_threads))
    slots = [_Slot(job, b, sys.stdout) for b, job in enumerate(jobs)]
    with ExitStack() as stack:
        for slot in slots:
            slot.job.run_dir.mkdir(parents=True, exist_ok=True)
            stack.enter_context(run_lock(slot.job.run_dir))
            slot.log = stack.enter_context(open(slot.job.run_dir / "train.log", "a", encoding="utf-8"))
            slot.console = Tee(_Prefixed(slot.terminal, f"[seed {slot.seed}] "), slot.log)
        learner, env = _build(slots)
        finals = _FinalEvaluations(cfg)
        try:
            _start(slots, env)
            _train(learner, slots, env, finals)
        finally:
            finals.close()
            env.close()
    return [slot.summary for slot in slots]


def _build(slots: list[_Slot]):
    """The learner of all seeds (each member's stream seeded as its run alone seeds it) and
    the one env of all seeds."""
    generators = []
    for slot in slots:
        generators.append(seed_everything(slot.seed))
        stream = torch.Generator()
        stream.set_state(torch.get_rng_state())
        slot.streams = (stream, np.random.get_state(), random.getstate())
    cfg = slots[0].job.cfg
    learner = instantiate(cfg.learner, _convert_="all")
    env = build_env(cfg, len(slots) * int(cfg.num_envs), [s.seed for s in slots], learner.nsteps)
    _check_memory(env, cfg, len(slots))
    learner.build(env.task, generators)
    for slot in slots:
        member = learner.member(slot.index)
        evaluator = GreedyEvaluator(slot.job.cfg, member, slot.seed + solo.EVAL_SEED_OFFSET)
        slot.session = solo.Session(slot.job.cfg, slot.job.run_dir, member, env.seed_block(slot.index), evaluator)
    return learner, env


def available_bytes() -> int | None:
    """``MemAvailable`` of ``/proc/meminfo`` (None where there is none)."""
    try:
        with open("/proc/meminfo") as f:
            return next(int(line.split()[1]) * 1024 for line in f if line.startswith("MemAvailable:"))
    except (OSError, StopIteration, ValueError, IndexError):
        return None


def _tensor_bytes(state) -> int:
    if isinstance(state, torch.Tensor):
        return state.nbytes
    if isinstance(state, dict):
        return sum(_tensor_bytes(v) for v in state.values())
    if isinstance(state, (list, tuple)):
        return sum(_tensor_bytes(v) for v in state)
    return 0


def _check_memory(env: RobotTaskEnv, cfg: DictConfig, seeds: int) -> None:
    """One line, before any training, when ``seeds`` members of ``cfg``'s learner (one
    member's training state's tensors, measured on a learner of one) and ``env``'s physics
    buffers would take most of the free memory."""
    one = instantiate(cfg.learner, _convert_="all")
    one.build(env.task, [torch.Generator()])
    physics = env.physics
    per_step = physics.nstate + physics.model.nsensordata + physics.model.nu
    need = env.num_envs * (env.task.n_substeps + 2) * per_step * 8 + seeds * _tensor_bytes(one.training_state(0))
    del one
    free = available_bytes()
    if free is not None and need > 0.8 * free:
        raise ConfigError(f"a batch of {seeds} seeds x {env.block_size} copies needs about {need / 2**30:.3g} "
                          f"GiB, more than 80% of the {free / 2**30:.3g} GiB free: fewer seeds per batch "
                          "(hydra.launcher.max_seeds=...) or fewer copies (num_envs=...)")


def _start(slots: list[_Slot], env: RobotTaskEnv) -> None:
    """Each seed's folder, banner and run, from its block of the first reset."""
    first = env.reset()
    for slot in slots:
        job, session = slot.job, slot.session
        with slot.active(full=True):
            if not job.resume:
                start_run(job.cfg, job.run_dir, job.choices, list(job.overrides))
            for line in banner_lines(job.cfg, dict(job.choices), job.changes, session.success,
                                          job.run_dir, session.learner.nepisodes):
                print(line)
            solo.write_success(session)
            # Resumed: its block, learner, run and random streams as its checkpoint holds them.
            slot.run = solo.make_run(session, resume=job.resume, progress=None, save=slot.save)
            if not job.resume:
                slot.run.continue_from(first[env.block(slot.index)])


def _train(learner, slots: list[_Slot], env: RobotTaskEnv, finals: _FinalEvaluations) -> None:
    """Steps every seed's copies together until each run is done (:func:`runs.loop.train`);
    a seed ends (its final evaluation, checkpoint, model and verdict) at the step its run is
    done, as alone."""
    with solo.stop_on_signals(*(slot.run for slot in slots if slot.run)) as stopped:
        train(learner, env, [slot for slot in slots if slot.run is not None],
              partial(_end_done, env=env, stopped=stopped, finals=finals))


def _end_done(live: list[_Slot], env: RobotTaskEnv, stopped: dict, finals: _FinalEvaluations) -> list[_Slot]:
    """Ends the seeds of ``live`` that are done, their copies held (the final evaluations of
    those that end at this step made together); the others."""
    done = [slot for slot in live if slot.done]
    results = finals(done)
    for slot in done:
        _finish(slot, stopped["signal"], results.get(slot.index))
        env.physics.hold(env.block_mask(slot.index))
    return [slot for slot in live if not slot.done]


class _FinalEvaluations:
    """The final greedy evaluations of the seeds that end at the same step (all of a
    budget's seeds, at its last step), made in one env of their seed blocks, stepped
    together (:func:`runs.evaluate.greedy_evaluations`): each seed's result is the one its
    own evaluator gives alone. Envs are kept per number of seeds."""

    def __init__(self, cfg: DictConfig) -> None:
        self.cfg = cfg
        self.envs: dict[int, RobotTaskEnv] = {}

    def __call__(self, done: list[_Slot]) -> dict[int, dict]:
        """Each seed's evaluation by its index, for the seeds of ``done`` that owe one, when
        two or more do (one alone evaluates in its own env, as before)."""
        owing = [slot for slot in done if slot.failed is None and slot.run is not None
                 and solo.owes_final_evaluation(slot.session, slot.run)]
        if len(owing) < 2:
            return {}
        seeds = [slot.session.evaluator.seed for slot in owing]
        if len(owing) not in self.envs:
            copies = owing[0].session.final_episodes
            self.envs[len(owing)] = build_env(self.cfg, len(owing) * copies, seeds,
                                              owing[0].session.learner.nsteps)
        try:
            results = greedy_evaluations([slot.session.learner for slot in owing], self.envs[len(owing)], seeds)
        except Exception:  # noqa: BLE001 - each seed then evaluates alone, a failure its own
            return {}
        return {slot.index: result for slot, result in zip(owing, results)}

    def close(self) -> None:
        for env in self.envs.values():
            env.close()


def _finish(slot: _Slot, interrupted: int | None, evaluation: dict | None = None) -> None:
    """A seed's end, as its run alone ends: final evaluation (``evaluation``, if made
    already), checkpoint, model, report."""
    if slot.run is None:
        return
    session, run = slot.session, slot.run
    if slot.failed is None:
        slot.guarded(lambda: setattr(slot, "result", solo.final_evaluation(session, run, evaluation)), full=True)
    with slot.active(full=True):
        summary = solo.close_run(session, run, finished=slot.failed is None)
        if slot.failed is not None:
            slot.summary = {**summary, "failed": slot.failed.strip().splitlines()[-1]}
        elif run.stop_requested:
            slot.summary = solo.stopped(session, run, summary, interrupted or signal.SIGINT)
        else:
            solo.report(session, summary, slot.result)
            slot.summary = summary
