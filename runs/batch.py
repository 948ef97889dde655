"""Seeds in one process: runs that differ only in their seed, trained side by side.

    summaries = execute_batch([BatchJob(cfg_0, dir_0, ...), BatchJob(cfg_1, dir_1, ...)])

One env holds every seed's copies as seed blocks (``RobotTaskEnv(seed=[...])``):
each block starts its episodes as that seed's env alone would, and the physics of
all of them is one step. Each seed keeps its own learner, its own :class:`Run`
with its own folder, files, checkpoints and verdict, and its own random streams, so a
seed's run is the run ``python train.py seed=<s>`` makes, file for file (wall-clock
numbers aside), and each folder resumes alone (``resume=<folder>``).

The seeds' learners are stacked (:func:`learners.stack.stack`: qlearn and the DQN
family): a step is one stacked call per phase for every seed (act, learn from the
step, the updates their episodes owed), and between them one visit to each seed's
context, where its run books its block of the step (``Run.record_arrays`` on its
block of the step's arrays), its learner ends its episodes and its run ends the step
(evaluation, checkpoint); in the order a run alone does them
(:func:`learners.base.train`). A stacked seed's draws come from its own generators
(its torch stream is a generator object, ``_Slot.streams[0]``), so no global random
state is swapped per step; a checkpoint and a seed's end swap its torch, numpy and
``random`` states in (a checkpoint holds them). Learners without a stack train seed by
seed: each seed's step is one visit to its context, torch's global stream swapped in.

A seed that is done (solved, out of budget, stopped) ends there, as alone, and its
copies stop stepping (``BatchedPhysics.hold``) while the others go on. A seed whose own
work fails (its booking, its learner's episode end, its evaluation or checkpoint, its
part of a stacked call: its draws, its replay buffer) ends alone, its trace in its
``error.txt``; a stacked call that fails as a whole ends every seed still training with
the trace (they share its state). Each seed's console goes to its ``train.log`` and,
its lines prefixed with ``[seed N]``, to the terminal.
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

from learners.stack import stack
from params import ConfigError
from runs import session as solo
from runs.banner import banner_lines
from runs.console import Tee
from runs.evaluate import GreedyEvaluator, greedy_evaluations
from runs.folder import run_lock, start_run
from runs.resume import save_training_state
from runs.run import Run
from runs.seeding import seed_everything
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
    """One seed of the batch: its job, parts, run, random streams and console."""

    job: BatchJob
    index: int
    terminal: IO[str]
    session: solo.Session | None = None
    run: Run | None = None
    td: TensorDictBase | None = None
    log: IO[str] | None = None
    # The seed's random streams: a torch generator holding its stream of torch's global
    # generator, and numpy's and ``random``'s global states.
    streams: tuple = ()
    stacked: bool = False  # its learner is in a stack, which draws from streams[0] itself
    failed: str | None = None
    result: dict | None = None  # the final greedy evaluation
    summary: dict = field(default_factory=dict)
    console: IO[str] | None = None

    @property
    def seed(self) -> int:
        return int(self.job.cfg.seed)

    @property
    def done(self) -> bool:
        return self.failed is not None or self.run is None or self.run.done

    @contextmanager
    def active(self, full: bool = False) -> Iterator[None]:
        """This seed's console and torch random stream inside (``full``: its numpy and
        ``random`` streams too); the others' kept outside. Nothing here draws from numpy's
        or ``random``'s global streams while training (their states, ~0.3 ms to swap, are
        only seeded and saved), so a step swaps torch's alone and a checkpoint all three
        (:meth:`save`). A stacked seed's step swaps none: its stack draws from its
        generator (``streams[0]``) itself, and nothing else it does draws."""
        swap = full or not self.stacked
        if swap:
            torch.set_rng_state(self.streams[0].get_state())
        if full:
            np.random.set_state(self.streams[1])
            random.setstate(self.streams[2])
        out, err = sys.stdout, sys.stderr
        sys.stdout = sys.stderr = self.console
        try:
            yield
        finally:
            sys.stdout, sys.stderr = out, err
            if swap:
                self.streams[0].set_state(torch.get_rng_state())
            if full:
                self.streams = (self.streams[0], np.random.get_state(), random.getstate())

    def save(self, path, learner, env, run, td: TensorDictBase) -> None:
        """:func:`runs.resume.save_training_state` with this seed's random states in place
        (a checkpoint holds them) and ``td`` its block (a stacked step hands the batch's)."""
        if td.batch_size[0] != env.num_envs:
            td = td[env.rows]
        outside = torch.get_rng_state(), np.random.get_state(), random.getstate()
        if self.stacked:
            torch.set_rng_state(self.streams[0].get_state())
        np.random.set_state(self.streams[1])
        random.setstate(self.streams[2])
        try:
            save_training_state(path, learner, env, run, td)
        finally:
            if self.stacked:
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
        env = _build(slots)
        finals = _FinalEvaluations(cfg)
        try:
            _start(slots, env)
            _train(slots, env, _stack(slots), finals)
        finally:
            finals.close()
            env.close()
    return [slot.summary for slot in slots]


def _build(slots: list[_Slot]) -> RobotTaskEnv:
    """Each seed's learner (after seeding as its run alone does) and the one env of all seeds."""
    learners = []
    for slot in slots:
        generator = seed_everything(slot.seed)
        learners.append((instantiate(slot.job.cfg.learner, _convert_="all"), generator))
        stream = torch.Generator()
        stream.set_state(torch.get_rng_state())
        slot.streams = (stream, np.random.get_state(), random.getstate())
    cfg = slots[0].job.cfg
    env = build_env(cfg, len(slots) * int(cfg.num_envs), [s.seed for s in slots], learners[0][0].nsteps)
    for slot, (learner, generator) in zip(slots, learners):
        with slot.active(full=True):
            learner.build(env.task, generator)
            if slot.index == 0:
                _check_memory(env, learner, len(slots))
            view = env.seed_block(slot.index)
            evaluator = GreedyEvaluator(slot.job.cfg, learner, slot.seed + solo.EVAL_SEED_OFFSET)
            slot.session = solo.Session(slot.job.cfg, slot.job.run_dir, learner, view, evaluator)
    return env


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


def _check_memory(env: RobotTaskEnv, learner, seeds: int) -> None:
    """One line, before any training, when ``seeds`` learners like ``learner`` (its training
    state's tensors) and ``env``'s physics buffers would take most of the free memory."""
    physics = env.physics
    per_step = physics.nstate + physics.model.nsensordata + physics.model.nu
    need = env.num_envs * (env.task.n_substeps + 2) * per_step * 8 + seeds * _tensor_bytes(learner.training_state())
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
            session.learner.begin()
            slot.td = slot.run.start(session.env)


def _stack(slots: list[_Slot]):
    """The seeds' learners as one stack (:func:`learners.stack.stack`), or None."""
    stacked = stack([slot.session.learner for slot in slots], [slot.streams[0] for slot in slots])
    for slot in slots:
        slot.stacked = stacked is not None
    return stacked


def _train(slots: list[_Slot], env: RobotTaskEnv, stacked, finals: _FinalEvaluations) -> None:
    """Steps every seed's copies together until each run is done; a seed ends (its final
    evaluation, checkpoint, model and verdict) at the step its run is done, as alone."""
    with solo.stop_on_signals(*(slot.run for slot in slots if slot.run)) as stopped:
        end = partial(_end_done, env=env, stopped=stopped, finals=finals)
        if stacked is None:
            _train_seed_by_seed(slots, env, end)
        else:
            _train_stacked(slots, env, stacked, end)


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


def _train_seed_by_seed(slots: list[_Slot], env: RobotTaskEnv, end_done) -> None:
    """Learners without a stack: a seed's step is one visit to its context: it books its
    block of the step, then picks its block's next actions."""
    for slot in slots:
        _guarded(slot, lambda s=slot: _act(s))
    live = slots
    while True:
        live = end_done(live)
        if not live:
            break
        td, next_td = env.step_and_maybe_reset(torch.cat([slot.td for slot in slots]))
        for slot in live:
            rows = env.block(slot.index)
            _guarded(slot, lambda s=slot: _book(s, td[rows], next_td[rows]) or _act(s))


def _train_stacked(slots: list[_Slot], env: RobotTaskEnv, stacked, end_done) -> None:
    """One call of the stack per phase of a step (act, observe, settle) for every seed,
    each seed's booking in its own context between them, in the order a run alone does
    them (:func:`learners.base.train`): act, step, learn, book the episodes (their
    ``end_episode``), the updates they owe, ``end_step`` (evaluation, checkpoint)."""

    def guard(b: int, work) -> bool:  # a seed's own part of a stacked call (it prints nothing)
        return _attempt(slots[b], work)

    def acting(live: list[_Slot]) -> list[_Slot]:  # a seed done at a step's end acts no more
        return [slot for slot in live if not slot.done]

    def sound(live: list[_Slot]) -> list[_Slot]:  # a seed stopped mid-step still ends it, as alone
        return [slot for slot in live if slot.failed is None]

    def indices(chosen: list[_Slot]) -> list[int]:
        return [slot.index for slot in chosen]

    live = acting(slots)
    td = _together(live, lambda: stacked.act(torch.cat([slot.td for slot in slots]), indices(live), guard))
    while True:
        live = end_done(live)
        if not live:
            break
        td, next_td = env.step_and_maybe_reset(td)
        nxt = td.get("next")
        reward, done, terminated = (nxt.get(key).reshape(-1).numpy() for key in ("reward", "done", "terminated"))
        _together(live, lambda: stacked.observe(td, indices(sound(live)), guard))
        owing = []  # seeds whose episodes owe updates: their end_step after the stack's settle
        for slot in sound(live):
            rows = env.block(slot.index)
            _guarded(slot, lambda s=slot, r=rows: _book_rows(s, reward[r], done[r], terminated[r], next_td,
                                                             stacked, owing))
        if owing:
            _together(owing, lambda: stacked.settle(indices(sound(owing)), guard))
            for slot in sound(owing):
                _guarded(slot, lambda s=slot: s.run.end_step(next_td))
        td = _together(acting(live), lambda: stacked.act(next_td, indices(acting(live)), guard))


def _together(live: list[_Slot], work):
    """A stacked call for the ``live`` seeds; if it fails (not in a seed's own part, which
    its guard ends alone), every one of them ends with its trace: they share its state."""
    try:
        return work()
    except Exception:  # noqa: BLE001 - reported in every seed's folder
        trace = traceback.format_exc()
        for slot in live:
            if slot.failed is None:
                _fail(slot, f"the seeds' stacked learner failed:\n{trace}")
        return None


def _act(slot: _Slot) -> None:
    """The seed's next actions, unless its run is done."""
    if not slot.run.done:
        slot.td = slot.session.learner.act(slot.td)


def _book(slot: _Slot, td: TensorDictBase, next_td: TensorDictBase) -> None:
    """What a seed's learner and run do with its block of the step, as :func:`learners.base.train`."""
    learner, run = slot.session.learner, slot.run
    learner.observe(td)
    for _ in run.record_step(slot.session.env, td, learner.stats):
        learner.end_episode()
    slot.td = run.end_step(next_td)


def _book_rows(slot: _Slot, reward: np.ndarray, done: np.ndarray, terminated: np.ndarray,
               next_td: TensorDictBase, stacked, owing: list[_Slot]) -> None:
    """A stacked seed's episodes of the step (its block's arrays), each then its learner's
    ``end_episode``, as ``record_step`` and :func:`learners.base.train` do alone; then its
    ``end_step``, unless its episodes owe updates (``owing`` then takes it: its stack runs
    them first). The seeds are independent: one's end may come before another's updates."""
    learner, run, view = slot.session.learner, slot.run, slot.session.env
    run.divergences = view.divergences
    for _ in run.record_arrays(reward, done, terminated, learner.stats, view.ended_info if done.any() else None):
        learner.end_episode()
    if stacked.owes(slot.index):
        owing.append(slot)
    else:
        run.end_step(next_td)


def _attempt(slot: _Slot, work) -> bool:
    """``work``, a seed's own part of a stacked call (it prints nothing), outside the seed's
    context; a failure ends the seed alone, as in :func:`_guarded`. Whether it worked."""
    try:
        work()
    except Exception:  # noqa: BLE001 - one seed's failure must not cost the others
        _fail(slot, traceback.format_exc())
    return slot.failed is None


def _guarded(slot: _Slot, work, full: bool = False) -> bool:
    """Runs ``work`` in the seed's context; an exception ends that seed alone (``error.txt``).
    Whether the seed is still sound. (A stacked seed's step swaps its console only: inline.)"""
    if full or not slot.stacked:
        with slot.active(full):
            _run_guarded(slot, work)
        return slot.failed is None
    out, err = sys.stdout, sys.stderr
    sys.stdout = sys.stderr = slot.console
    try:
        _run_guarded(slot, work)
    finally:
        sys.stdout, sys.stderr = out, err
    return slot.failed is None


def _run_guarded(slot: _Slot, work) -> None:
    try:
        work()
    except Exception:  # noqa: BLE001 - one seed's failure must not cost the others
        _failed(slot, traceback.format_exc())


def _failed(slot: _Slot, trace: str) -> None:
    """Ends ``slot`` with ``trace``, printed (in its context) and kept in its ``error.txt``."""
    slot.failed = trace
    print(trace, file=sys.stderr)
    (slot.job.run_dir / "error.txt").write_text(trace)


def _fail(slot: _Slot, trace: str) -> None:
    """:func:`_failed` from outside the seed's context."""
    _guarded(slot, lambda: _failed(slot, trace))


def _finish(slot: _Slot, interrupted: int | None, evaluation: dict | None = None) -> None:
    """A seed's end, as its run alone ends: final evaluation (``evaluation``, if made
    already), checkpoint, model, report."""
    if slot.run is None:
        return
    session, run = slot.session, slot.run
    if slot.failed is None:
        _guarded(slot, lambda: setattr(slot, "result", solo.final_evaluation(session, run, evaluation)), full=True)
    with slot.active(full=True):
        summary = solo.close_run(session, run, finished=slot.failed is None)
        if slot.failed is not None:
            slot.summary = {**summary, "failed": slot.failed.strip().splitlines()[-1]}
        elif run.stop_requested:
            slot.summary = solo.stopped(session, run, summary, interrupted or signal.SIGINT)
        else:
            solo.report(session, summary, slot.result)
            slot.summary = summary
