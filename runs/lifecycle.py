"""A run's life, from its config to its verdict: one run, or seeds side by side, the same way.

    summary = execute(cfg, run_dir, choices=..., overrides=[...])   # train.py: a single run
    summaries = run_jobs([Job(cfg_0, dir_0, ...), Job(cfg_1, dir_1, ...)])   # a seed batch

Every run, alone or in a batch, goes through the same steps: build (:func:`_build`: seed
each member's streams, one learner with a member per seed, one env holding every seed's
copies as seed blocks, each seed's :class:`Seed`; every value checked before the first
file is written), start (:func:`_start`: each seed's folder, banner and
:class:`~runs.run.Run`), train (:func:`runs.loop.train`), finish (:func:`_finish`: its
final greedy evaluation, checkpoint, ``model.pt``, video on request and verdict). A single
run is a batch of one, on the process's own console (train.py holds its folder and tees
its console: the job is ``held``). What a job is (fresh, resumed, evaluating a checkpoint, reporting to a
tuning trial) is a property of the :class:`Job`, not another path.

In a batch each seed keeps its own run with its own folder, files, checkpoints and
verdict, so a seed's run is the run ``python train.py seed=<s>`` makes, file for file
(wall-clock numbers aside), and each folder resumes alone (``resume=<folder>``). A seed
that is done (solved, out of budget, stopped) ends at that step, its copies held
(``BatchedPhysics.hold``) while the others go on; the final evaluations of seeds ending at
one step run together. A seed whose own work fails ends alone, its trace in its
``error.txt``; a learner call that fails ends every seed still training (they share its
state). Each seed's console goes to its ``train.log`` and, its lines prefixed with
``[seed N]``, to the terminal. A tuning trial's report (``progress``) is handed in: this
package never imports the sweeps.
"""

from __future__ import annotations

import dataclasses
import json
import random
import signal
import sys
import traceback
from contextlib import ExitStack, contextmanager
from functools import partial
from pathlib import Path
from typing import IO, Callable, Iterator, Mapping, Sequence

import numpy as np
import torch
from hydra.utils import get_class, instantiate
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDict, TensorDictBase

from learners.base import Member
from params import ConfigError
from runs.checkpoint import CheckpointError, load_model, save_model
from runs.console import Tee, Ticker, banner_lines, copies, tee_console
from runs.evaluate import MemberEvaluations, describe_evaluation, measure_of, pass_rate, starts_seed
from runs.folder import WRITE_FAILED, cannot_write, check_new_run, model_path, run_lock, start_run, taken
from runs.job import NOT_BATCHED, Job, batchable
from runs.layout import train_command
from runs.loggers import log_hparams, make_logger, run_scalar_names
from runs.loop import train
from runs.run import Hooks, Progress, Run
from runs.signals import stop_on_signals
from runs.summary import eval_verdict_lines, verdict_lines
from runs.training_state import (load_training_state, restore_training_state, save_training_state,
                                 seed_everything)
from tasks.base import Success
from tasks.env import RobotTaskEnv
from tasks.factory import build_env

EVAL_SEED_OFFSET = 10_000  # greedy evaluations start from seed + this (never the training streams)
VIDEO_SEED_OFFSET = 20_000  # the policy video's env
# Keys in which the jobs of one batch may differ, besides the learner's MEMBER_WISE settings:
# what names the run, and when its own Run evaluates, saves and prints (a searched
# ``eval_every`` no longer splits a study's trials into a batch per value).
OWN_KEYS = ("seed", "resume", "trial", "eval_every", "eval_every_steps", "checkpoint_every", "log_every")
# ``run_jobs``'s source of jobs for freed members: (the jobs that ended, members free) -> new jobs.
More = Callable[[Sequence["Job"], int], Sequence["Job"]]


# -- what may share a batch ----------------------------------------------------
def check_batch(jobs: Sequence[Job]) -> None:
    """One line unless every job of ``jobs`` may train in one batch (:func:`refusal`). A lone
    job shares its batch with none: any run may be one."""
    if len(jobs) == 1:
        return
    for i, job in enumerate(jobs):
        why = refusal(job, jobs[0], jobs[:i])
        if why is not None:
            raise ConfigError(why)


def refusal(job: Job, first: Job, others: Sequence[Job], freed: bool = False) -> str | None:
    """Why ``job`` cannot train in the batch of ``first`` beside ``others`` (None: it can): its
    seed is not an integer, it is not a training run (fresh, or resumed at a batch's start;
    ``freed``: taking a freed member, fresh only), its config differs from ``first``'s in more
    than an integer seed, a tuning trial, its own Run's schedules (:data:`OWN_KEYS`) and the
    learner's member-wise settings (:func:`batch_key`), or it is the run of one of ``others``."""
    cfg = job.cfg
    if type(cfg.seed) is not int:
        return f"seed must be an integer in a seed batch; got {cfg.seed!r}"
    if freed and (job.resume or not batchable(cfg)):
        return f"a freed member trains a fresh training run only; {job.run_dir.name} is not one"
    resumable = job.resume and cfg.mode == "train" and not cfg.get("checkpoint")
    if not (resumable or (not job.resume and batchable(cfg))):
        return f"a seed batch trains fresh or resumed runs only (no {', '.join(NOT_BATCHED[1:])})"
    if job is not first and batch_key(cfg) != batch_key(first.cfg):
        return (f"jobs {first.run_dir.name} and {job.run_dir.name} differ in more than their seed, trial, schedules "
                "and the learner's member-wise settings: they cannot share a batch")
    if any(repr(_own(other.cfg)) == repr(_own(cfg)) for other in others):
        return f"seed {cfg.seed} of these settings appears twice in one batch; give each seed once"
    return None


def member_wise(cfg: DictConfig) -> tuple[str, ...]:
    """The learner settings (``learner.<key>``) in which members of one batch may differ: its
    class's ``MEMBER_WISE`` (none for a class that does not say)."""
    try:
        return tuple(getattr(get_class(str(cfg.learner._target_)), "MEMBER_WISE", ()))
    except Exception:  # noqa: BLE001 - a learner that cannot be found is refused when built
        return ()


def batch_key(cfg: DictConfig) -> dict:
    """What the jobs of one batch share: the config but its :data:`OWN_KEYS` and the
    learner's member-wise settings."""
    shared = {k: v for k, v in OmegaConf.to_container(cfg, resolve=True).items() if k not in OWN_KEYS}
    own = member_wise(cfg)
    shared["learner"] = {k: v for k, v in shared["learner"].items() if k not in own}
    return shared


def _own(cfg: DictConfig) -> dict:
    """What makes a job's run its own in a batch: its config but a resumed run's folder."""
    return {k: v for k, v in OmegaConf.to_container(cfg, resolve=True).items() if k != "resume"}


def same_batch(cfgs: Sequence[DictConfig]) -> list[list[int]]:
    """Indices of ``cfgs`` grouped by :func:`batch_key` (first-seen order): the batches they
    may train in."""
    groups: dict[str, list[int]] = {}
    for i, cfg in enumerate(cfgs):
        groups.setdefault(repr(batch_key(cfg)), []).append(i)
    return list(groups.values())


# -- a seed in the lifecycle -----------------------------------------------------
@dataclasses.dataclass
class Seed:
    """One seed's run, alone or in a batch (a :class:`runs.loop.Lane`): its job, its member of
    the learner and block of the env, the seed its greedy evaluations start from, its
    :class:`~runs.run.Run`, global random streams, console and end."""

    job: Job
    index: int  # its member of the learner, its block of the env
    member: Member | None = None
    env: RobotTaskEnv | None = None  # its block of the batch's env
    eval_seed: int = 0
    # A run's periodic evaluations are made beside its training (runs.evaluate.MemberEvaluations):
    # this starts the seed's, its run waiting for the result. None: made at once by ``evaluate``.
    side_eval: Callable[[int], None] | None = None
    evaluations: dict[int, MemberEvaluations] = dataclasses.field(default_factory=dict)  # by episodes
    run: Run | None = None
    # The seed's global random streams as its run alone leaves them: torch's (a generator
    # holding its state), numpy's and ``random``'s. Training draws from none of them (the
    # learner's members have their own streams); a checkpoint holds them.
    streams: tuple = ()
    failed: str | None = None
    status: int = 1  # the exit status a failed single run ends with (a write's: WRITE_FAILED)
    result: dict | None = None  # the final greedy evaluation
    summary: dict = dataclasses.field(default_factory=dict)
    console: IO[str] | None = None
    closed: bool = False  # its model saved and its files closed
    restored: dict | None = None  # a resumed seed's checkpoint, checked and loaded when built

    @property
    def seed(self) -> int:
        return int(self.job.cfg.seed)

    @property
    def cfg(self) -> DictConfig:
        return self.job.cfg

    @property
    def run_dir(self) -> Path:
        return self.job.run_dir

    @property
    def success(self) -> Success:
        return self.env.task.success

    @property
    def state_path(self) -> Path:
        return self.run_dir / "checkpoint.pt"

    @property
    def final_episodes(self) -> int:
        """Episodes of the final greedy evaluation (ruippeixotog's run phase, else eval_episodes)."""
        return int(getattr(self.member, "run_episodes", 0) or self.cfg.eval_episodes)

    @property
    def done(self) -> bool:
        return self.failed is not None or self.run is None or self.run.done

    def evaluate(self, episodes: int, k: int = 0) -> dict:
        """A greedy evaluation of ``episodes`` episodes from the seed's ``k``-th evaluation
        starts (:func:`runs.evaluate.starts_seed`), made now."""
        if episodes not in self.evaluations:
            self.evaluations[episodes] = MemberEvaluations(self.cfg, self.member.learner, 1, episodes)
        return self.evaluations[episodes].alone(self.member.index, starts_seed(self.eval_seed, k),
                                                Ticker("greedy evaluation", episodes, "episodes ended"))

    def close_evaluations(self) -> None:
        for evaluations in self.evaluations.values():
            evaluations.close()
        self.evaluations.clear()

    @contextmanager
    def active(self, full: bool = False) -> Iterator[None]:
        """This seed's console inside (``full``: its global random streams too, the others'
        kept outside)."""
        if full:
            torch.set_rng_state(self.streams[0].get_state())
            np.random.set_state(self.streams[1])
            random.setstate(self.streams[2])
        out, err = sys.stdout, sys.stderr
        sys.stdout = sys.stderr = self.console or out
        try:
            yield
        finally:
            sys.stdout, sys.stderr = out, err
            if full:
                self.streams[0].set_state(torch.get_rng_state())
                self.streams = (self.streams[0], np.random.get_state(), random.getstate())

    def guarded(self, work: Callable[[], object], full: bool = False) -> bool:
        """Runs ``work`` in the seed's context; an exception ends this seed alone (its trace
        on its console and in ``error.txt``). Whether the seed is still sound. (Twice a step for every seed: the
        console is swapped inline, the random streams only when ``full``.)"""
        if full:
            with self.active(full):
                return self._run(work)
        if self.console is None:  # a single run: the process's own console
            return self._run(work)
        out, err = sys.stdout, sys.stderr
        sys.stdout = sys.stderr = self.console or out
        try:
            return self._run(work)
        finally:
            sys.stdout, sys.stderr = out, err

    def _run(self, work: Callable[[], object]) -> bool:
        try:
            work()
        except OSError as err:  # its folder could not be written (a full disk): one line
            self._failed(cannot_write(err, self.job.run_dir), WRITE_FAILED)
        except Exception:  # noqa: BLE001 - one seed's failure must not cost the others
            self._failed(traceback.format_exc())
        return self.failed is None

    def fail(self, error: BaseException, trace: str) -> None:
        """A learner call (shared with the other seeds) failed: this seed ends with its trace."""
        with self.active():
            self._failed(f"the seeds' learner failed:\n{trace}")

    def _failed(self, trace: str, status: int = 1) -> None:
        self.failed, self.status = trace, status
        print(trace, file=sys.stderr)
        try:
            (self.job.run_dir / "error.txt").write_text(trace)
        except OSError:  # (a full disk) the console has it
            pass

    def save(self, path, learner, env, run, td: TensorDictBase) -> None:
        """:func:`runs.training_state.save_training_state` with this seed's random states in
        place (a checkpoint holds them) and ``td`` its block (a batch's step hands the batch's)."""
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


# -- the lifecycle ----------------------------------------------------------------
def execute(cfg: DictConfig, run_dir: Path, resume: bool = False, choices: Mapping[str, str | None] | None = None,
            changes: Sequence[str] | None = None, overrides: Sequence[str] = (),
            progress: Progress | None = None) -> dict:
    """A single run (train.py's): trains, or evaluates ``checkpoint=`` with ``mode=eval``, as
    ``cfg`` says; returns the summary (and prints the verdict). ``resume``: continue the run
    in ``run_dir`` from its ``checkpoint.pt``; else the folder is started (config.yaml,
    run.json) once every part is built. The caller holds the folder's lock and console."""
    job = Job(cfg, run_dir, dict(choices or {}), overrides, changes, resume, progress, held=True)
    return run_jobs([job])[0]


def train_alone(job: Job, record: Callable[[], None] | None, refusals: tuple[type[BaseException], ...],
                progress: Callable[[], Progress | None] = lambda: None) -> dict:
    """Makes ``job`` as a single run: its folder locked (a refusal leaves it as it was), Hydra's
    record of the command written (``record``; None: the sweep wrote it), its console teed
    to ``train.log``; the run's summary.

    Args:
        job: a job of :func:`runs.job.compose_job`.
        record: writes Hydra's record of the command into the folder, once locked.
        refusals: the errors that leave the folder byte for byte as it was.
        progress: makes the run's tuning report, inside its console (None: it reports to none).
    """
    run_dir = job.run_dir
    run_dir.mkdir(parents=True, exist_ok=True)
    if not job.resume:
        check_new_run(run_dir)  # before the lock too: a finished run's .lock is not touched
    with taken(run_dir, refusals):  # one run's record per folder: nothing written before the lock
        if not job.resume:
            check_new_run(run_dir)
        if record is not None:
            record()
        with tee_console(run_dir / "train.log"):
            return execute(job.cfg, run_dir, resume=job.resume, choices=job.choices, changes=job.changes,
                           overrides=job.overrides, progress=progress())


@contextmanager
def denormals_flushed() -> Iterator[None]:
    """Float results below float32's smallest normal number (~1.2e-38) are 0 while inside
    (``torch.set_flush_denormal``, on the calling thread). Adam's first moment of a weight
    whose gradient stays 0 (a dead ReLU unit) decays into denormal numbers and stays there
    (0.9 times the smallest one rounds back to it), and the CPU's arithmetic on them is
    several times slower: after 165 cart-pole episodes a rainbow network had 10-11k of them
    in each large layer's moment and its Adam step took 1.35 ms instead of ~0.28
    (``bench/update_rate.py --denormals``). The steps such a moment makes (~1e-30 x the
    learning rate) move no parameter of a normal size: the runs measured ended with the
    same weights, bit for bit. Off again on the way out."""
    torch.set_flush_denormal(True)
    try:
        yield
    finally:
        torch.set_flush_denormal(False)


def run_jobs(jobs: Sequence[Job], more: More | None = None) -> list[dict]:
    """Makes every run of ``jobs`` (a batch: checked by :func:`check_batch`; a single run: a
    batch of one) in one env; returns each seed's summary, in order (a failed seed's says
    ``failed``, and ``status``: the exit status it ends a single run with). A job's folder
    is locked and its console teed here unless the job is ``held``. ``more(ended, free)``: called at each step where runs ended (their
    jobs ``ended``) with the number of members then free; the fresh jobs it returns (at most
    ``free``, each fitting this batch) train in the freed members from their first step,
    each as its run alone, their summaries after the first ones' in the order they start."""
    check_batch(jobs)
    torch.set_num_threads(int(jobs[0].cfg.torch_threads))
    slots = [Seed(job, b) for b, job in enumerate(jobs)]
    with ExitStack() as stack:
        stack.enter_context(denormals_flushed())
        _consoles(slots, stack)
        learner, env = _build(slots)
        finals = _FinalEvaluations(jobs[0].cfg)
        stack.callback(env.close)
        stack.callback(finals.close)
        side = _side_evaluations(jobs[0].cfg, learner, slots)
        if side is not None:
            stack.callback(side.close)
        _start(slots, env)
        if jobs[0].cfg.mode == "eval":
            _evaluate(slots[0])
        else:
            _train(learner, slots, env, finals, more, stack, side)
    return [slot.summary for slot in slots]


def _side_evaluations(cfg: DictConfig, learner, slots: list[Seed]) -> MemberEvaluations | None:
    """A training batch's periodic evaluations (a single run's too), made beside its
    training (none without them), each seed's started by its run."""
    if cfg.mode != "train" or not int(cfg.eval_episodes):
        return None
    side = MemberEvaluations(cfg, learner, learner.members, int(cfg.eval_episodes))
    for slot in slots:
        _side_eval(slot, side)
    return side


def _side_eval(slot: Seed, side: MemberEvaluations | None) -> None:
    """The seed's periodic evaluations made by ``side`` (if any), from its evaluation seed."""
    if side is not None:
        slot.side_eval = lambda k: side.start(slot.index, starts_seed(slot.eval_seed, k))


def _consoles(slots: list[Seed], stack: ExitStack) -> None:
    """A batch's seeds: each folder locked, each console its train.log and the terminal (a
    ``held`` job's are its caller's)."""
    for slot in slots:
        if not slot.job.held:
            _console(slot, stack)


def _console(slot: Seed, stack: ExitStack) -> None:
    slot.job.run_dir.mkdir(parents=True, exist_ok=True)
    stack.enter_context(run_lock(slot.job.run_dir))
    log = stack.enter_context(open(slot.job.run_dir / "train.log", "a", encoding="utf-8"))
    slot.console = Tee(_Prefixed(sys.stdout, f"[seed {slot.seed}] "), log)


def _build(slots: list[Seed]):
    """The learner of all seeds (each member's streams seeded as its run alone seeds them),
    the one env of all seeds and each seed's parts; ``checkpoint=``'s model loaded into a
    fresh run. Writes nothing."""
    generators = [_seeded(slot) for slot in slots]
    cfg = slots[0].job.cfg
    seeds = [slot.seed for slot in slots]
    try:
        env = build_env(cfg, len(slots) * int(cfg.num_envs), seeds)
    except ConfigError as err:  # "task maze needs ..." for task=wall (a maze layout): say which was picked
        picked = slots[0].job.choices.get("task")
        if picked and str(err).startswith("task ") and not str(err).startswith(f"task {picked} "):
            raise ConfigError(f"task={picked}: {err}") from None
        raise
    if len(slots) > 1:  # members multiply the memory (one run alone: its learner's own bounds)
        _check_memory(env, [slot.job.cfg for slot in slots])
    learner = instantiate(cfg.learner, _convert_="all")
    alike = all(not _own_settings(slot.job.cfg, cfg) for slot in slots)
    variants = None if alike else [instantiate(slot.job.cfg.learner, _convert_="all") for slot in slots]
    learner.build(env.task, generators, variants)
    for slot in slots:
        member = learner.member(slot.index)
        if slot.job.cfg.checkpoint and not slot.job.resume:
            load_model(model_path(slot.job.cfg.checkpoint), member)
        elif slot.job.cfg.mode == "eval":
            raise CheckpointError("mode=eval needs checkpoint=<path to a saved model.pt>")
        _place(slot, member, env.seed_block(slot.index))
        if slot.job.resume:  # every tensor checked before the folder is written
            slot.restored = restore_training_state(slot.state_path, slot.job.run_dir, member,
                                                   slot.env)
    return learner, env


def _seeded(slot: Seed) -> torch.Generator:
    """Seeds the process's streams as the seed's run alone seeds them and keeps them in the
    slot (its global streams); the member's own stream."""
    generator = seed_everything(slot.seed)
    stream = torch.Generator()
    stream.set_state(torch.get_rng_state())
    slot.streams = (stream, np.random.get_state(), random.getstate())
    return generator


def _own_settings(cfg: DictConfig, learner_cfg: DictConfig) -> bool:
    """Whether ``cfg``'s learner differs from ``learner_cfg``'s (the batch's learner) in a
    member-wise setting: its member then takes a variant of its own."""
    own = member_wise(cfg)
    return {k: cfg.learner.get(k) for k in own} != {k: learner_cfg.learner.get(k) for k in own}


def _place(slot: Seed, member: Member, env) -> None:
    """The seed's member, its block of the env and the seed its evaluations start from."""
    slot.member, slot.env, slot.eval_seed = member, env, slot.seed + EVAL_SEED_OFFSET


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


def member_bytes(env: RobotTaskEnv, cfg: DictConfig, sizes: dict[str, int]) -> int:
    """The bytes of a member's training state's tensors with ``cfg``'s learner on ``env``'s
    task, measured on a learner of one for each value of the settings that size it (the
    class's ``SIZING``: members may differ in their replay buffer's size or their table's
    bins), kept in ``sizes`` by that value."""
    sizing = getattr(get_class(str(cfg.learner._target_)), "SIZING", ())
    size = repr([OmegaConf.to_container(cfg.learner, resolve=True).get(k) for k in sizing])
    if size not in sizes:
        one = instantiate(cfg.learner, _convert_="all")
        one.build(env.task, [torch.Generator()])
        sizes[size] = _tensor_bytes(one.training_state(0))
    return sizes[size]


def _check_memory(env: RobotTaskEnv, cfgs: Sequence[DictConfig]) -> None:
    """One line, before any training, when the members of ``cfgs`` (each member's training
    state's tensors, measured on a learner of one for each value of the settings that size
    it, the class's ``SIZING``: members may differ in their replay buffer's size or their
    table's bins) and ``env``'s physics buffers would take most of the free memory."""
    sizes: dict[str, int] = {}
    seeds = len(cfgs)
    physics = env.physics
    per_step = physics.nstate + physics.model.nsensordata + physics.model.nu
    need = env.num_envs * (env.task.n_substeps + 2) * per_step * 8 + sum(member_bytes(env, cfg, sizes) for cfg in cfgs)
    free = available_bytes()
    if free is not None and need > 0.8 * free:
        raise ConfigError(f"a batch of {seeds} seeds x {copies(env.block_size)} needs about {need / 2**30:.3g} "
                          f"GiB, more than 80% of the {free / 2**30:.3g} GiB free: fewer seeds per batch "
                          "(hydra.launcher.max_seeds=...) or fewer copies (num_envs=...)")


def _start(slots: list[Seed], env: RobotTaskEnv) -> None:
    """Each seed's folder, banner and run (none to evaluate a checkpoint), from its block of
    the first reset (a resumed seed: from its checkpoint)."""
    fresh = slots[0].job.cfg.mode == "train" and not all(slot.job.resume for slot in slots)
    first = env.reset() if fresh else None  # a resumed seed starts from its checkpoint
    for slot in slots:
        _begin(slot, None if first is None else first[env.block(slot.index)])


def _begin(slot: Seed, first: TensorDictBase | None) -> None:
    """The seed's folder, banner and run; a fresh one's first step acts on ``first``."""
    job = slot.job
    with slot.active(full=True):
        if not job.resume:
            start_run(job.cfg, job.run_dir, job.choices, list(job.overrides))
        for line in banner_lines(job.cfg, dict(job.choices), job.changes, slot.success,
                                 job.run_dir):
            print(line)
        write_success(slot)
        if job.cfg.mode != "train":
            return
        slot.run = make_run(slot, resume=job.resume, progress=job.progress, save=slot.save,
                            restored=slot.restored)
        slot.restored = None
        if not job.resume:
            slot.run.continue_from(first)


class _Refill:
    """Gives the members freed at a step the fresh jobs ``more`` hands in (see
    :func:`run_jobs`): each member made anew (``Learner.renew``) and its seed block started
    anew as the job's seed (``RobotTaskEnv.renew_block``), so the job trains as its run
    alone from its first step. A job that does not fit the batch ends at once, its
    ``error.txt`` saying why; none is taken after a stop was asked."""

    def __init__(self, more: More, learner, env: RobotTaskEnv, slots: list[Seed], stack: ExitStack,
                 stopped: dict, runs: list[Run], side: MemberEvaluations | None = None) -> None:
        self.more, self.learner, self.env, self.slots, self.stack = more, learner, env, slots, stack
        self.side = side  # the batch's periodic evaluations
        self.cfg = slots[0].job.cfg
        self.stopped, self.runs = stopped, runs  # stop_on_signals' signal, and the runs it stops
        self.sizes: dict[str, int] = {}  # a member's bytes by the settings that size it (member_bytes)

    def __call__(self, td: TensorDictBase, ended: list[Seed], live: list[Seed]) -> tuple[TensorDictBase, list]:
        """The next step's input with the new jobs' first observations in their blocks, and
        the new jobs' slots (to train from this step on)."""
        busy = {slot.index for slot in live}
        free = [b for b in range(self.learner.members) if b not in busy]
        if self.stopped["signal"] is not None:
            return td, []
        jobs = list(self.more([slot.job for slot in ended], len(free)))
        if len(jobs) > len(free):
            raise ValueError(f"{len(jobs)} jobs for {len(free)} free members")
        if self.stopped["signal"] is not None:  # asked to stop while they were made: none starts
            for job, b in zip(jobs, free):
                slot = Seed(job, b, summary={"interrupted": True, "signal": self.stopped["signal"]})
                self.slots.append(slot)
            return td, []
        added = []
        for job, b in zip(jobs, free):
            slot = Seed(job, b)
            self.slots.append(slot)
            _console(slot, self.stack)
            refused = self._refused(job)
            if refused:
                with slot.active():
                    slot._failed(f"error: {refused}")
                slot.summary = {"failed": f"error: {refused}"}
                continue
            if not added:
                td = td.clone()  # its tensors are the step's own, which the runs have booked
            try:
                self._start(slot, td)
            except Exception:  # noqa: BLE001 - the job fails alone; its member stays free, its copies held
                with slot.active():
                    slot._failed(traceback.format_exc())
                slot.summary = {"failed": slot.failed.strip().splitlines()[-1]}
                self.env.physics.hold(self.env.block_mask(b))
                continue
            added.append(slot)
            self.runs.append(slot.run)
        return td, added

    def _start(self, slot: Seed, td: TensorDictBase) -> None:
        """The slot's member and seed block made anew for its job, its run started, and its
        block of ``td`` (the next step's input) its first step's."""
        b, job = slot.index, slot.job
        generator = _seeded(slot)
        self.learner.renew(b, generator, instantiate(job.cfg.learner, _convert_="all")
                           if _own_settings(job.cfg, self.cfg) else None)
        observation = self.env.renew_block(b, slot.seed)
        _place(slot, self.learner.member(b), self.env.seed_block(b))
        _side_eval(slot, self.side)
        _begin(slot, _first(observation))
        first, rows = slot.run.start(slot.env), self.env.block(b)
        for key, value in td.items():
            value[rows] = first.get(key) if key in first.keys() else 0

    def _refused(self, job: Job) -> str | None:
        """Why ``job`` cannot train in this batch (None: it can): :func:`refusal`, or its
        member's memory."""
        why = refusal(job, self.slots[0].job, [slot.job for slot in self.slots if slot.job is not job], freed=True)
        if why is not None:
            return why
        need, free = member_bytes(self.env, job.cfg, self.sizes), available_bytes()
        if free is not None and need > 0.8 * free:
            return (f"job {job.run_dir.name}'s member needs about {need / 2**30:.3g} GiB, more than 80% of the "
                    f"{free / 2**30:.3g} GiB free: a smaller replay buffer or table (learner.buffer_size, "
                    "learner.number_splits), or fewer trials a batch")
        return None


def _first(observation: torch.Tensor) -> TensorDictBase:
    """A fresh block's first step input: its first observations, its done flags false (a reset's)."""
    false = torch.zeros(len(observation), 1, dtype=torch.bool)
    return TensorDict({"observation": observation, "done": false, "terminated": false.clone(),
                       "truncated": false.clone()}, batch_size=[len(observation)])


def write_success(seed: Seed) -> None:
    """``success.json``: the task's rule, as the run judges it."""
    (seed.run_dir / "success.json").write_text(json.dumps(dataclasses.asdict(seed.success), indent=1))


def _tags(run_dir: Path) -> dict:
    """The run's robot, task, learner and seed (run.json's), for a logger that keeps tags."""
    try:
        saved = json.loads((run_dir / "run.json").read_text())
    except (OSError, ValueError):
        return {}
    return {k: saved.get(k) for k in ("robot", "task", "learner", "seed")}


def make_run(seed: Seed, resume: bool, progress: Progress | None,
             save: Callable[..., None] | None = None, restored: dict | None = None) -> Run:
    """Training's :class:`Run` with its logger and hooks (``save``: writes the training
    state, :func:`runs.training_state.save_training_state`'s arguments); a resumed run continues
    from its checkpoint (``restored``: as read when the run was built; its metrics files cut
    back to it)."""
    cfg, learner, env = seed.cfg, seed.member, seed.env
    logger = make_logger(cfg.logger.kind, seed.run_dir, exp_name=seed.run_dir.name, tags=_tags(seed.run_dir),
                         **{k: v for k, v in cfg.logger.items() if k != "kind"})
    hooks = Hooks(checkpoint=partial(save or save_training_state, seed.state_path, learner, env),
                  greedy_eval=(seed.side_eval or partial(seed.evaluate, int(cfg.eval_episodes)))
                  if cfg.eval_episodes else None,
                  final_eval=seed.side_eval if seed.final_episodes == int(cfg.eval_episodes) else None,
                  train_stats=learner.train_stats, advice=learner.advice, progress=progress)
    run = Run(seed.run_dir, env.num_envs, int(cfg.max_episodes), seed.success, logger=logger,
              extra_fields=tuple(learner.stats), quiet=bool(cfg.quiet), verbose=bool(cfg.get("verbose", False)),
              log_every=int(cfg.get("log_every", 0)), checkpoint_every=int(cfg.get("checkpoint_every", 0)),
              eval_every=int(cfg.eval_every) if cfg.eval_episodes else 0, resume=resume,
              eval_every_steps=int(cfg.get("eval_every_steps", 0)) if cfg.eval_episodes else 0,
              max_env_steps=int(cfg.get("max_env_steps", 0)),
              stop_when_solved=bool(cfg.get("stop_when_solved", True)), hooks=hooks)
    if resume:
        run.continue_from(load_training_state(seed.state_path, learner, env, run, restored))
        print(f"resuming {seed.run_dir} after episode {run.n_episodes} ({run.env_steps} env steps)")
    log_hparams(logger, cfg, run_scalar_names(seed.success.measure, seed.success.window))
    return run


def _evaluate(slot: Seed) -> None:
    """``mode=eval``: the checkpoint's greedy policy judged, reported."""
    result = slot.evaluate(slot.final_episodes) if slot.final_episodes > 0 else None
    report(slot, slot.summary, result)


def _train(learner, slots: list[Seed], env: RobotTaskEnv, finals: _FinalEvaluations,
           more: More | None = None, stack: ExitStack | None = None, side: MemberEvaluations | None = None) -> None:
    """Steps every seed's copies together until each run is done (:func:`runs.loop.train`);
    a seed ends (its final evaluation, checkpoint, model and verdict) at the step its run is
    done; ``more`` hands freed members new jobs (:class:`_Refill`, their consoles kept open
    in ``stack``); ``side`` makes the periodic evaluations. A batch stopped by an exception
    (one that is not a seed's own failure) still saves each seed's model and closes its files;
    a second Ctrl-C aborts as it lands."""
    runs = [slot.run for slot in slots]
    with stop_on_signals(runs) as stopped:
        refill = None if more is None else _Refill(more, learner, env, slots, stack, stopped, runs, side)
        try:
            train(learner, env, slots, partial(_end_done, env=env, stopped=stopped, finals=finals), refill, side)
        except KeyboardInterrupt:  # a second Ctrl-C aborts: nothing more is saved, whatever it cut
            raise
        except BaseException:
            for slot in slots:
                if slot.run is not None and not slot.closed:
                    try:
                        close_run(slot, slot.run, finished=False)
                    except OSError:  # (a full disk) the first failure is the one raised
                        pass
            raise


def _end_done(live: list[Seed], env: RobotTaskEnv, stopped: dict, finals: _FinalEvaluations) -> list[Seed]:
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
    budget's seeds, at its last step), made together (:class:`runs.evaluate.MemberEvaluations`
    of their blocks, kept per number of seeds and episodes): each seed's result is the one
    its own evaluation gives alone."""

    def __init__(self, cfg: DictConfig) -> None:
        self.cfg = cfg
        self.sides: dict[tuple[int, int], MemberEvaluations] = {}

    def __call__(self, done: list[Seed]) -> dict[int, dict]:
        """Each seed's evaluation by its index, for the seeds of ``done`` that owe one, where
        two or more owe as many episodes (one alone evaluates in its own env, as before)."""
        owing = [slot for slot in done if slot.failed is None and slot.run is not None
                 and owes_final_evaluation(slot, slot.run)]
        results: dict[int, dict] = {}
        for episodes in {slot.final_episodes for slot in owing}:
            alike = [slot for slot in owing if slot.final_episodes == episodes]
            if len(alike) > 1:
                results.update(self._together(alike, episodes))
        return results

    def _together(self, slots: list[Seed], episodes: int) -> dict[int, dict]:
        """The evaluations of ``slots``, ``episodes`` each, in one env of a block each."""
        key = (len(slots), episodes)
        if key not in self.sides:
            self.sides[key] = MemberEvaluations(self.cfg, slots[0].member.learner, len(slots), episodes)
        side, results = self.sides[key], {}
        try:
            for block, slot in enumerate(slots):
                side.start(slot.index, starts_seed(slot.eval_seed, len(slot.run.evals)), block)
            while side.members:
                results.update(side.step())
        except Exception:  # noqa: BLE001 - each seed then evaluates alone, a failure its own
            for slot in slots:
                side.drop(slot.index)
            return {}
        return results

    def close(self) -> None:
        for side in self.sides.values():
            side.close()


def _finish(slot: Seed, interrupted: int | None, evaluation: dict | None = None) -> None:
    """A seed's end: final evaluation (``evaluation``, if made already), checkpoint, model,
    report."""
    if slot.run is None:
        return
    run = slot.run
    if slot.failed is None:
        slot.guarded(lambda: setattr(slot, "result", final_evaluation(slot, run, evaluation)), full=True)
    with slot.active(full=True):
        try:
            summary = close_run(slot, run, finished=slot.failed is None)
        except OSError as err:  # (a full disk) its first failure is the one it reports
            if slot.failed is None:
                slot._failed(cannot_write(err, slot.job.run_dir), WRITE_FAILED)
            summary = {}
        slot.closed = True
        if slot.failed is not None:
            slot.summary = {**summary, "failed": slot.failed.strip().splitlines()[-1], "status": slot.status}
        elif run.stop_requested:
            slot.summary = stopped(slot, run, summary, interrupted or signal.SIGINT)
        else:
            report(slot, summary, slot.result)
            slot.summary = summary


def final_evaluation(seed: Seed, run: Run, result: dict | None = None) -> dict | None:
    """The trained policy, judged like the evaluations during training (an evaluation of this
    very policy is reused); at the budget's end it may still solve a greedily judged task.
    None when the run was stopped, pruned by its tuning study (which asks no value of it:
    ruippeixotog's 500-episode run phase was over a third of a cart-pole study's copy-steps)
    or evaluates nothing. ``result``: that evaluation, made already (a seed batch evaluates
    the seeds that end at one step together)."""
    if not _makes_final_evaluation(seed, run):
        return None
    if _evaluated_already(seed, run):
        return run.last_eval
    run.record_evaluation(result if result is not None else seed.evaluate(seed.final_episodes, len(run.evals)))
    while run.judge.owed:  # it passed: confirmed from fresh starts before the run is solved
        run.record_evaluation(seed.evaluate(seed.final_episodes, len(run.evals)))
    return run.last_eval


def owes_final_evaluation(seed: Seed, run: Run) -> bool:
    """Whether :func:`final_evaluation` runs a new evaluation: not when the run was stopped,
    pruned or evaluates nothing, nor when its last evaluation was of this very policy."""
    return _makes_final_evaluation(seed, run) and not _evaluated_already(seed, run)


def _makes_final_evaluation(seed: Seed, run: Run) -> bool:
    """Whether the run ends with a final evaluation at all: one evaluates something, and was
    neither stopped nor pruned."""
    return seed.final_episodes > 0 and not run.stop_requested and run.pruned_at is None


def _evaluated_already(seed: Seed, run: Run) -> bool:
    """Whether the run's last evaluation is its final one: of this very policy, as many
    episodes (also a resumed run killed after its final evaluation was saved: never a
    second row)."""
    last = run.last_eval
    return (last is not None and run.evals[-1]["episode"] == run.n_episodes
            and last["episodes"] == seed.final_episodes)


def close_run(seed: Seed, run: Run, finished: bool) -> dict:
    """The training state (``finished``: at a step boundary, so consistent), ``model.pt``, then
    the run's files closed (the reward curve drawn last: a run stopped by its launcher has its
    states saved first); returns the run's summary."""
    if finished:
        run.checkpoint(run.last_td)
    save_model(seed.run_dir / "model.pt", seed.member, meta={
        "choices": json.loads((seed.run_dir / "run.json").read_text()),
        "config": OmegaConf.to_container(seed.cfg, resolve=True),
    })
    return run.close()


def stopped(seed: Seed, run: Run, summary: dict, signum: int) -> dict:
    """A run stopped by ``signum``: how to resume it, and its summary saying so."""
    print(f"stopped after episode {run.n_episodes}; the whole training state is in "
          f"{seed.state_path}\nresume with: {train_command()} resume={seed.run_dir}")
    summary["interrupted"] = True
    summary["signal"] = signum
    (seed.run_dir / "summary.json").write_text(json.dumps(summary, indent=1))
    return summary


def report(seed: Seed, summary: dict, result: dict | None) -> None:
    """The final evaluation (eval.json), the video on request, the summary and the verdict."""
    cfg, run_dir, success = seed.cfg, seed.run_dir, seed.success
    if result is not None:
        print(describe_evaluation(result, success))
        rate = pass_rate(result, success)
        record = {"measure": success.measure, "value": measure_of(result, success.measure),
                  "threshold": success.threshold, "greedy_rate": rate, "rate": success.rate,
                  "passed": success.rate_met(rate),
                  **({"mode": "eval", "checkpoint": str(cfg.checkpoint)} if cfg.mode == "eval" else {}), **result}
        (run_dir / "eval.json").write_text(json.dumps(record, indent=1))
        summary["eval"] = result
    seed.close_evaluations()
    if cfg.video:  # the greedy policy on a fresh one-copy env
        from runs.video import record_video  # loaded when a video is asked for

        video_env = build_env(cfg, 1, int(cfg.seed) + VIDEO_SEED_OFFSET)
        with seed.member.greedy():
            record_video(video_env, seed.member.policy, run_dir / "policy.mp4", n_steps=int(cfg.video_steps),
                         progress=Ticker("recording the policy's video", int(cfg.video_steps), "steps"))
        video_env.close()
        print(f"policy video in {run_dir / 'policy.mp4'}")
    if cfg.mode == "train":
        (run_dir / "summary.json").write_text(json.dumps(
            {k: v for k, v in summary.items() if k != "eval"}, indent=1))
        for line in verdict_lines(summary, run_dir):
            print(line)
    elif result is not None:  # mode=eval: the checkpoint's evaluation, its own verdict
        for line in eval_verdict_lines(record, run_dir):
            print(line)
