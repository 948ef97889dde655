"""A training run's bookkeeping: finished episodes, the success judge, and when to
evaluate, checkpoint and stop.

Episodes in a batch end at different times; :class:`Run` turns each batched
step into one :class:`~runs.metrics_files.Episode` per finished episode, in the
order they finish (ties by copy index), so the metrics read the same for any
``num_envs``. Each episode goes to the CSV files (:mod:`runs.metrics_files`),
the console (:mod:`runs.console`) and the logger (:mod:`runs.loggers`);
``close`` gives the summary (:mod:`runs.summary`) and draws the reward
curve (:mod:`runs.plot`).

The training loop (:func:`runs.loop.train`) hands a run its block of each step
(:meth:`Run.record`) and then ends the step (:meth:`Run.end_step`: greedy evaluation and
checkpoint when due).

A run can be stopped at a step boundary (``request_stop``, e.g. on Ctrl-C)
and saves its whole state every ``checkpoint_every`` episodes through the
``checkpoint`` hook ``end_step`` calls (see :mod:`runs.training_state`).
"""

from __future__ import annotations

import csv
import ctypes
import math
import os
import time
from array import array
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Mapping, Protocol, Sequence

import numpy as np
import torch
from tensordict import TensorDictBase

from runs.console import Console
from runs.metrics_files import Episode
from runs.evaluate import measure_of, pass_rate
from runs.loggers import csv_sizes, cut_csv_files, finish_log, log_episode, log_evaluation, log_train
from runs.metrics_files import MetricsFiles
from runs.summary import run_summary
from tasks.base import Success

# Every this many episodes the C heap's free pages go back to the system (glibc's malloc_trim):
# a long run's many small tensors otherwise leave its resident memory creeping up (bench/soak.py).
TRIM_EPISODES = 1000
_LIBC = None  # glibc's malloc_trim once looked up (False: not there)


def _release_free_memory() -> None:
    """Returns the C heap's free memory to the system where the C library can (glibc)."""
    global _LIBC
    if _LIBC is None:
        try:
            _LIBC = ctypes.CDLL("libc.so.6").malloc_trim
        except (OSError, AttributeError):
            _LIBC = False
    if _LIBC:
        _LIBC(0)


# train/* scalars: at the step boundary after a step that finished an episode, and at least
# every TRAIN_LOG_STEPS env steps (long episodes), and once at the end.
TRAIN_LOG_STEPS = 1000


class Progress(Protocol):
    """A tuning trial's link (:class:`sweeps.tuning.TrialLink`): called with the env steps
    so far and the rolling measure every ``every`` env steps (0: no more; env steps, as a
    trial's budget is: trials of long and short episodes are compared at equal cost); True
    stops the run, as does ``pruned`` at any step (the trial stopped by another of its runs'
    reports). ``solved`` is told once, when the run stops solved: the env steps and the
    value it holds from then on (its rolling measure, at least the threshold)."""

    every: int
    pruned: bool

    def __call__(self, env_steps: int, rolling: float) -> bool: ...

    def solved(self, env_steps: int, value: float) -> None: ...


@dataclass(frozen=True)
class Hooks:
    """What a :class:`Run` calls out to, all given when it is built (each optional):

    - ``checkpoint(run, td)``: saves the whole training state at a step boundary;
    - ``greedy_eval(k)``: the run's ``k``-th greedy evaluation's result (from its ``k``-th
      starts: :func:`runs.evaluate.starts_seed`), or None when it is made later (the run
      waits for it: :meth:`Run.end_step`);
    - ``final_eval()``: starts the final greedy evaluation of a run whose budget is spent, made
      later as ``greedy_eval``'s are (None: the caller makes it once the run has ended);
    - ``train_stats(reset=True)``: the learner's ``train/*`` numbers;
    - ``advice()``: what the learner's numbers say about its settings, a line per subject
      (each subject printed once);
    - ``progress``: a tuning trial's :class:`Progress` report.
    """

    checkpoint: Callable[[Run, TensorDictBase], None] | None = None
    greedy_eval: Callable[[int], dict | None] | None = None
    final_eval: Callable[[int], None] | None = None
    train_stats: Callable[..., dict[str, float]] | None = None
    advice: Callable[[], dict[str, str]] | None = None
    progress: Progress | None = None


def process_age() -> float | None:
    """Seconds since this process started, by the kernel's clock (``/proc``, to 10 ms:
    interpreter start and imports included); None where there is no ``/proc``."""
    try:
        with open("/proc/self/stat") as f:
            ticks = int(f.read().rsplit(")", 1)[1].split()[19])  # field 22, starttime
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return None
    return max(0.0, uptime - ticks / os.sysconf("SC_CLK_TCK"))


class EpisodeLog:
    """The training episodes a run has booked, and each copy's episode in progress.

    Per booked episode its length, the task's measure and its return, packed (24 bytes an
    episode, not ~90 as Python lists: long runs stay small); per copy the return and length
    of its running episode; the env steps of all copies so far."""

    def __init__(self, num_envs: int) -> None:
        self.num_envs = num_envs
        self.n_episodes = self.env_steps = 0
        self.lengths, self.values, self.returns = array("q"), array("d"), array("d")
        self.running_return = np.zeros(num_envs)
        self.running_length = np.zeros(num_envs, dtype=np.int64)

    def step(self, reward: np.ndarray) -> None:
        """Every copy's step: its reward added to its running episode."""
        self.running_return += reward
        self.running_length += 1
        self.env_steps += self.num_envs

    def book(self, i: int, value: float) -> tuple[int, float]:
        """Copy ``i``'s finished episode, its measure ``value``: (its length, its return)."""
        length, ret = int(self.running_length[i]), float(self.running_return[i])
        self.lengths.append(length)
        self.values.append(value)
        self.returns.append(ret)
        self.n_episodes += 1
        return length, ret

    def restart(self, done: np.ndarray) -> None:
        """The ``done`` copies start new episodes."""
        self.running_return[done] = 0.0
        self.running_length[done] = 0

    def rolling(self, window: int) -> float:
        """Mean measure of the last ``window`` episodes (of all, while fewer ran)."""
        return float(np.mean(self.values[-window:])) if self.values else float("nan")

    def load(self, state: Mapping, returns) -> None:
        """From a checkpoint's run state (``returns``: the episodes' returns)."""
        self.n_episodes = int(state["n_episodes"])
        self.lengths = array("q", np.asarray(state["lengths"], dtype=np.int64).tobytes())
        self.values = array("d", np.asarray(state["values"], dtype=np.float64).tobytes())
        self.returns = array("d", np.asarray(returns, dtype=np.float64).tobytes())
        self.env_steps = int(state["env_steps"])
        self.running_return[:] = state["ret"].numpy()
        self.running_length[:] = state["len"].numpy()


class SuccessJudge:
    """Whether and when a run is solved, by its task's :class:`~tasks.base.Success` rule.

    A verdict is proposed by the training episodes (``judge="training"``: the mean of the
    last ``window`` meets the threshold, :attr:`candidate`) or by a periodic greedy
    evaluation (``judge="greedy"``). Where there is a greedy policy to ask (``confirm``),
    it holds only when a greedy evaluation passes (at least ``rate`` of its episodes
    reach the threshold) and a second one from fresh starts, made at once, passes too
    (:attr:`owed`: the run makes it before it steps again). A proposal that fails waits:
    a training one ``window`` episodes, a greedy one the next periodic evaluation. Without
    a greedy policy the training mean alone decides.
    """

    CONFIRMATIONS = 2  # passing greedy evaluations in a row that solve: the first and its confirmation

    def __init__(self, success: Success, confirm: bool) -> None:
        self.success, self.confirm = success, confirm
        self.solved_at: int | None = None
        self.decided_by: str | None = None  # "training" or "greedy", once solved
        self.solved_value: float | None = None  # the judged mean that solved it
        self.candidate: float | None = None  # a training mean that met the rule, to confirm greedily
        self.passed = 0  # passing greedy evaluations in a row of the proposal under way
        self.next_try = 0  # the episode count from which a training verdict may be tried again

    @property
    def owed(self) -> bool:
        """Whether the proposal under way needs a greedy evaluation now (a training
        candidate's first, or the confirmation of one that passed)."""
        return self.solved_at is None and (self.candidate is not None or self.passed > 0)

    def training(self, rolling: float, episodes: int) -> None:
        """A training episode was booked: ``rolling`` is the mean of its window."""
        if (self.solved_at is None and self.success.judge == "training" and not self.owed
                and episodes >= self.next_try and self.success.met(rolling, episodes)):
            if self.confirm:  # at the step's end, once its episodes are booked
                self.candidate = rolling
            else:
                self._solve("training", rolling, episodes)

    def evaluated(self, value: float, rate: float, episodes: int) -> None:
        """A greedy evaluation: its mean measure ``value`` and pass ``rate``, after
        ``episodes`` training episodes. It proposes (a greedily judged task), confirms or
        turns down a verdict."""
        if self.solved_at is None and (self.owed or (self.success.judge == "greedy"
                                                     and episodes >= self.success.min_episodes)):
            if self.success.rate_met(rate):
                self.passed += 1
                if self.passed >= self.CONFIRMATIONS:
                    training = self.candidate is not None
                    self._solve("training" if training else "greedy", self.candidate if training else value,
                                episodes)
                return
            if self.candidate is not None:
                self.next_try = episodes + self.success.window
            self.candidate, self.passed = None, 0

    def _solve(self, judge: str, value: float, episodes: int) -> None:
        self.solved_at, self.decided_by, self.solved_value = episodes, judge, value
        self.candidate, self.passed = None, 0

    def state_dict(self) -> dict:
        return {"solved_at": self.solved_at, "decided_by": self.decided_by, "solved_value": self.solved_value,
                "next_confirm": self.next_try}

    def load_state_dict(self, state: Mapping) -> None:
        self.solved_at, self.decided_by = state["solved_at"], state["decided_by"]
        self.solved_value = state["solved_value"]
        self.next_try = int(state.get("next_confirm", 0))


class StartWatch:
    """Whether a run left its untrained level, and at which env step: the mean measure of
    its last :data:`EPISODES` training episodes, or a greedy evaluation's, first above that of
    its first training episodes by a tenth of the way to the threshold (issue 65: a cart-pole
    rainbow seed ran 4-step episodes for 98k env steps before it escaped; on the wall an
    exploring Q-learner's training episodes stay short while its greedy policy drives). A run
    that stayed there for :data:`SHARE` of its budget or more had a *stuck start*
    (:meth:`stuck`)."""

    EPISODES = 20
    SHARE = 0.25

    def __init__(self, threshold: float) -> None:
        self.threshold = threshold
        self.level: float | None = None  # the mean measure of the first EPISODES episodes
        self.left_at: int | None = None  # env steps when the run first left that level
        self.known = True  # False: resumed from a checkpoint made before the watch (it tells nothing)

    def booked(self, values: Sequence[float], env_steps: int) -> None:
        """After each training episode (``values``: every episode's measure so far)."""
        n = len(values)
        if not self.known or self.left_at is not None or n < self.EPISODES:
            return
        if self.level is None:
            self.level = float(np.mean(values[:self.EPISODES]))
        if n >= 2 * self.EPISODES and float(np.mean(values[-self.EPISODES:])) > self.level + self._margin():
            self.left_at = env_steps

    @classmethod
    def of_folder(cls, run_dir: Path, measure: str, threshold: float) -> StartWatch:
        """The watch of a run, replayed from its folder's metrics.csv (each training episode's
        measure) and evals.csv (each greedy evaluation's mean), in the order the run made
        them: what a run made before the watch read greedy evaluations says today."""
        watch, values = cls(threshold), []
        with open(run_dir / "metrics.csv", newline="") as f:
            episodes = [(float(r[measure]), int(r["env_steps"])) for r in csv.DictReader(f)]
        evals_csv = run_dir / "evals.csv"
        evals = []
        if evals_csv.is_file():
            with open(evals_csv, newline="") as f:
                evals = [(float(r[measure]), int(r["env_steps"])) for r in csv.DictReader(f)]
        for i, (value, steps) in enumerate(episodes):
            values.append(value)
            watch.booked(values, steps)
            later = episodes[i + 1][1] if i + 1 < len(episodes) else math.inf
            while evals and evals[0][1] < later:  # an evaluation follows the episodes of its step
                watch.evaluated(*evals.pop(0))
        return watch

    def evaluated(self, value: float, env_steps: int) -> None:
        """A greedy evaluation's mean measure ``value`` at ``env_steps``."""
        if self.known and self.left_at is None and self.level is not None and value > self.level + self._margin():
            self.left_at = env_steps

    def _margin(self) -> float:
        gap = self.threshold - self.level
        return 0.1 * gap if math.isfinite(gap) and gap > 0 else 0.1 * abs(self.level) + 1e-9

    def stuck_steps(self, env_steps: int) -> int | None:
        """Env steps the run spent at its untrained level (None: too few episodes to tell)."""
        if not self.known:
            return None
        if self.left_at is not None:
            return self.left_at
        return env_steps if self.level is not None else None

    def stuck(self, env_steps: int, budget: int) -> bool:
        """Whether the run stayed at its untrained level for :data:`SHARE` of ``budget``
        env steps or more (``budget`` 0: of the env steps it made)."""
        steps = self.stuck_steps(env_steps)
        return steps is not None and steps >= self.SHARE * (budget or env_steps) and steps > 0


class Run:
    """Records finished episodes of a batched env, judges them, and reports them.

    "Solved" follows the task's :class:`~tasks.base.Success`: with
    ``judge="training"`` the mean measure of the last ``window`` training
    episodes, with ``judge="greedy"`` the mean measure of a greedy evaluation
    (``greedy_eval``, run every ``eval_every`` episodes or ``eval_every_steps`` env
    steps, whichever comes first); either way the run
    stops once it is met. Every evaluation is kept (``evals``, evals.csv),
    whichever judge decides.

    A run called solved leaves a solved policy: when the training episodes meet the
    rule, the greedy policy is evaluated at once and the run is solved only if it meets
    the threshold too (that evaluation is its row in ``evals``); otherwise training goes on and the next try waits
    ``window`` episodes. Without ``greedy_eval`` the training rule alone decides. The
    rule is applied by the run's :class:`SuccessJudge` (``judge``); the run books the
    episodes and evaluations, says what is due at a step's end and writes the outputs.
    """

    def __init__(self, run_dir: Path | str, num_envs: int, max_episodes: int, success: Success,
                 extra_fields: tuple[str, ...] = (), quiet: bool = False, logger=None,
                 checkpoint_every: int = 0, eval_every: int = 0, resume: bool = False,
                 verbose: bool = False, log_every: int = 0, max_env_steps: int = 0,
                 stop_when_solved: bool = True, hooks: Hooks | None = None, eval_every_steps: int = 0) -> None:
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.num_envs, self.max_episodes, self.success = num_envs, int(max_episodes), success
        self.extra_fields, self.quiet, self.logger = tuple(extra_fields), quiet, logger
        self.checkpoint_every, self.eval_every = int(checkpoint_every), int(eval_every)
        self.eval_every_steps = int(eval_every_steps)
        self.max_env_steps, self.stop_when_solved = int(max_env_steps), bool(stop_when_solved)
        hooks = hooks or Hooks()
        self._save, self.greedy_eval, self.final_eval = hooks.checkpoint, hooks.greedy_eval, hooks.final_eval
        self.train_stats, self.progress, self.advice = hooks.train_stats, hooks.progress, hooks.advice
        self._advised: set[str] = set()  # the subjects of the learner's advice already printed
        self._next_progress = 0
        self._told = False  # the progress hook was told the run stopped solved
        self.pruned_at: int | None = None  # the episode a tuning study stopped the run at
        self._train_logged: int | None = None  # env steps at the last train/* point
        self._train_due = False  # an episode finished since
        self.resume_td: TensorDictBase | None = None  # where a resumed run's first step starts
        self.last_td: TensorDictBase | None = None  # where the next step would start
        self._owed: str | None = None  # the evaluation a waiting run's boundary waits for
        self._quiet_until = 0  # env steps before which a boundary after no finished episode has nothing due
        self.episodes = EpisodeLog(num_envs)
        self.evals: list[dict] = []  # one row per greedy evaluation (evals.csv's, "value" the measure)
        self.last_eval: dict | None = None  # the newest evaluation's full result
        self._log_sizes: dict[str, int] | None = None  # a resumed run's CSV logger bytes to keep
        self.judge = SuccessJudge(success, confirm=self.greedy_eval is not None)
        self.start_watch = StartWatch(success.threshold)
        self.stop_requested = False
        self.first_step_s: float | None = None  # process start to the first step (``start``)
        self.divergences = 0  # the env's count of physics divergences (truncated episodes)
        self._last_checkpoint = 0
        self._last_trim = 0
        self._t0 = time.perf_counter()
        self.console = Console(self.max_episodes, success, quiet, verbose, log_every)
        self.files = MetricsFiles(self.run_dir, success, self.extra_fields)
        if not resume:  # a resumed run opens its files in ``load_state_dict``
            self.files.open(0, self.evals)

    # -- the training loop's steps --------------------------------------------
    @property
    def finished(self) -> bool:
        """True once a budget (episodes, env steps) is spent, the task counts as solved
        (with ``stop_when_solved``) or a tuning study pruned the run."""
        steps_spent = self.max_env_steps > 0 and self.env_steps >= self.max_env_steps
        return self._closed or steps_spent or self.pruned_at is not None

    @property
    def _closed(self) -> bool:
        """No further episode is booked: the episode budget is spent, or solved and stopping."""
        spent = 0 < self.max_episodes <= self.n_episodes
        return (self.solved_at is not None and self.stop_when_solved) or spent

    @property
    def done(self) -> bool:
        """True when the run is finished or a stop was asked."""
        return self.finished or self.stop_requested

    def checkpoint(self, td: TensorDictBase) -> None:
        """Saves the whole run, about to act on ``td``, through the ``checkpoint`` hook (if any)."""
        if self._save is not None:
            self._save(self, td)

    def continue_from(self, td: TensorDictBase) -> None:
        """A resumed run's first step acts on ``td`` (where the checkpoint stopped)."""
        self.resume_td = td

    def request_stop(self) -> None:
        """Ends the run after the current step (the trainer then saves a checkpoint)."""
        self.stop_requested = True

    def start(self, env) -> TensorDictBase:
        """The first step's input: where a resumed run stopped (``resume_td``), else a reset."""
        self.last_td = self.resume_td if self.resume_td is not None else env.reset()
        self.first_step_s = process_age()
        return self.last_td

    def end_step(self, td: TensorDictBase) -> TensorDictBase:
        """At the step boundary before ``td``: a greedy evaluation every ``eval_every``
        episodes or ``eval_every_steps`` env steps, then a checkpoint every
        ``checkpoint_every`` (so it holds the evaluation). Returns ``td``, the next step's input.

        A ``greedy_eval`` hook that returns None makes its evaluation later (a batch's,
        beside the other members' training): the run then waits at this boundary
        (:attr:`waiting`), taking no step, until :meth:`evaluated` hands it the result and
        ends the boundary as if the evaluation had been made here."""
        self.last_td = td
        self.log_train()
        if self.progress is not None and self.progress.every and self.env_steps >= self._next_progress:
            self._report_progress()
        if self.progress is not None and self.pruned_at is None and not self.done and self.progress.pruned:
            self.pruned_at = self.n_episodes  # pruned by another seed's report: stop now
        self._owed = self._evaluation_owed()
        if self._evaluate_owed():
            self._close_boundary(td)
        return td

    def end_quiet_step(self, td: TensorDictBase) -> bool:
        """Ends the step before ``td`` if it finished none of the run's episodes and its
        boundary has nothing due (:meth:`end_step` would only keep ``td``): whether it did
        (False: :meth:`end_step` must run). What a boundary does changes with episodes,
        evaluations and a few env-step marks (the train/* point, a progress report, a
        periodic evaluation by env steps, the budget: :meth:`_quiet_horizon`), or with a stop
        asked or a trial pruned at any step."""
        if (self.env_steps >= self._quiet_until or self.stop_requested
                or (self.progress is not None and self.progress.pruned)):
            return False
        self.last_td = td
        return True

    def _quiet_horizon(self) -> float:
        """The env steps before which a boundary that follows no finished episode has nothing
        due (the boundary just ended did everything due until then); 0: none is known."""
        if (self._owed is not None or self.done
                or (self._train_due and self.logger is not None and self.train_stats is not None)):
            return 0
        marks = [self.max_env_steps or math.inf]
        if self.logger is not None and self.train_stats is not None:
            marks.append((self._train_logged or 0) + TRAIN_LOG_STEPS)
        if self.progress is not None and self.progress.every:
            marks.append(self._next_progress)
        if self.greedy_eval is not None and self.eval_every_steps:
            marks.append((self.evals[-1]["env_steps"] if self.evals else 0) + self.eval_every_steps)
        return min(marks)

    def _evaluate_owed(self) -> bool:
        """Makes the boundary's evaluations while one is owed (a passing one owes its
        confirmation at once), each from fresh starts (the run's ``len(evals)``-th); whether
        they are all made (False: one was started elsewhere and the run waits for it)."""
        while self._owed is not None:
            hook = self.final_eval if self._owed == "final" else self.greedy_eval
            result = hook(len(self.evals))
            if result is None:
                return False
            self._take_evaluation(result)
        return True

    @property
    def waiting(self) -> bool:
        """Whether the run waits at its step boundary for an evaluation made elsewhere."""
        return self._owed is not None

    def evaluated(self, result: dict) -> None:
        """The evaluation the run waited for (see :meth:`end_step`): recorded and judged; a
        confirmation it owes is started (the run waits on, :attr:`waiting`). Then
        :meth:`end_boundary`."""
        self._take_evaluation(result)
        self._evaluate_owed()

    def end_boundary(self) -> None:
        """Ends the boundary the run waited at, its evaluations made: a checkpoint when due, at
        the step input it stopped at."""
        self._close_boundary(self.last_td)

    def _evaluation_owed(self) -> str | None:
        """Which greedy evaluation the boundary makes: ``"confirm"`` (the training episodes
        met the rule: does the greedy policy?), ``"due"`` (its schedule), ``"final"`` (the
        budget is spent and this policy was not evaluated yet: ``final_eval``) or None."""
        if self.judge.owed and not self.stop_requested:
            return "confirm"
        if self.greedy_eval is not None and not self.done and self._evaluation_due():
            return "due"
        if (self.final_eval is not None and self.finished and not self.stop_requested and self.pruned_at is None
                and not (self.evals and self.evals[-1]["episode"] == self.n_episodes)):
            return "final"
        return None

    def _take_evaluation(self, result: dict) -> None:
        """Records the boundary's evaluation ``result`` (judged); the next one it owes now, if any."""
        self.record_evaluation(result)
        self._owed = self._evaluation_owed()  # after it, only a confirmation can be owed

    def _close_boundary(self, td: TensorDictBase) -> None:
        """The rest of a step boundary, after its evaluation: a solved run told to the
        ``progress`` hook, the periodic checkpoint and the memory trim."""
        if self.progress is not None and self.solved_at is not None and self.stop_when_solved and not self._told:
            self._told = True
            self.progress.solved(self.env_steps, max(self.rolling(), self.success.threshold))
        due = self.checkpoint_every and self.n_episodes - self._last_checkpoint >= self.checkpoint_every
        if due and not self.done:  # the session saves the end
            self.checkpoint(td)
            self._last_checkpoint = self.n_episodes
        if self.n_episodes - self._last_trim >= TRIM_EPISODES:  # after the checkpoint's garbage
            _release_free_memory()
            self._last_trim = self.n_episodes
        self._quiet_until = self._quiet_horizon()

    # -- episodes and evaluations ---------------------------------------------
    def _evaluation_due(self) -> bool:
        """Whether ``eval_every`` episodes or ``eval_every_steps`` env steps (each where
        set) have passed since the last evaluation (or the start)."""
        last = self.evals[-1] if self.evals else {}
        episodes, steps = self.n_episodes - last.get("episode", 0), self.env_steps - last.get("env_steps", 0)
        return bool((self.eval_every and episodes >= self.eval_every)
                    or (self.eval_every_steps and steps >= self.eval_every_steps))

    def record(self, reward: np.ndarray, done: np.ndarray, terminated: np.ndarray,
               stats: Mapping[str, float] | None = None,
               ended_info: Mapping[str, np.ndarray] | None = None) -> list[Episode]:
        """Accounts one batched step from its ``reward``, ``done`` and ``terminated`` arrays
        (``(num_envs,)`` each: the run's block of the step); returns the episodes it finished.
        ``stats``: the learner's numbers for their rows. ``ended_info``: the env's
        ``ended_info`` after this step (the task's ``episode_info`` of each copy whose episode
        just ended), where the task's measure is read unless it is the episode length."""
        self.episodes.step(reward)
        ended = np.flatnonzero(done)
        if not len(ended):  # most steps: no episode ended
            return []
        finished = []
        for i in ended:
            if self._closed:
                break
            finished.append(self._finish(int(i), bool(terminated[i]), stats, ended_info))
        self.episodes.restart(done)
        self._train_due = self._train_due or bool(finished)
        return finished

    def _finish(self, i: int, terminated: bool, stats, ended_info) -> Episode:
        """Books copy ``i``'s finished episode, reports it and judges the training episodes."""
        measure = self.success.measure
        value = float(self.episodes.running_length[i]) if measure == "length" else float(ended_info[measure][i])
        length, ret = self.episodes.book(i, value)
        ep = Episode(episode=self.n_episodes, env_index=i, reward=ret, length=length,
                     terminated=terminated, env_steps=self.env_steps, wall_s=round(self.wall_s, 3),
                     value=value, rolling=self.rolling(), extra=dict(stats or {}))
        self.files.write_episode(ep)
        log_episode(self.logger, ep, self.success)
        self.console.episode(ep, self.evals[-1] if self.evals else None, self._peek_train_stats)
        self.judge.training(ep.rolling, self.n_episodes)
        self.start_watch.booked(self.episodes.values, self.env_steps)
        return ep

    def record_evaluation(self, result: dict) -> dict:
        """Records a greedy evaluation's ``result`` (evals.csv, the logger, the console) and
        judges it (:meth:`SuccessJudge.evaluated`): it may propose, confirm or turn down a verdict."""
        value = measure_of(result, self.success.measure)
        rate = pass_rate(result, self.success)
        row = {"episode": self.n_episodes, "env_steps": self.env_steps, "episodes": result["episodes"],
               "length": result["mean_length"], "return": result["mean_return"], "value": value, "rate": rate}
        self.evals.append(row)
        self.last_eval = result
        self.files.write_evals(self.evals)
        self.judge.evaluated(value, rate, self.n_episodes)
        self.start_watch.evaluated(value, self.env_steps)
        log_evaluation(self.logger, row, self.success)
        self.console.evaluation(row)
        return result

    def _report_progress(self) -> None:
        """The rolling measure to the ``progress`` hook at the last multiple of ``progress.every``
        env steps passed (the same steps for every run it is compared with); it may stop the run."""
        every = self.progress.every
        step = self.env_steps // every * every
        self._next_progress = step + every
        if step > 0 and not self.done and self.progress(step, self.rolling()):
            self.pruned_at = self.n_episodes

    @property
    def solved_at(self) -> int | None:
        """The episode the run was solved at (None: not solved)."""
        return self.judge.solved_at

    @property
    def decided_by(self) -> str | None:
        return self.judge.decided_by

    @property
    def solved_value(self) -> float | None:
        return self.judge.solved_value

    def _peek_train_stats(self) -> dict[str, float] | None:
        """The learner's current numbers for the console, without starting a new interval."""
        return None if self.train_stats is None else self.train_stats(reset=False)

    def log_train(self, final: bool = False) -> None:
        """``train/*`` (the ``train_stats`` hook's numbers) to the logger, if due (see
        ``TRAIN_LOG_STEPS``); ``final``: the run's last point, unless one is at these steps."""
        if self.logger is None or self.train_stats is None or self._train_logged == self.env_steps:
            return
        since = self.env_steps - (self._train_logged or 0)
        if final or self._train_due or since >= TRAIN_LOG_STEPS:
            log_train(self.logger, self.train_stats(), self.env_steps)
            self._train_logged, self._train_due = self.env_steps, False
            for subject, line in (self.advice() if self.advice is not None else {}).items():
                if subject not in self._advised:  # once a run
                    self._advised.add(subject)
                    self.console.write(f"warning: {line}")

    @property
    def wall_s(self) -> float:
        return time.perf_counter() - self._t0

    def rolling(self) -> float:
        """Mean measure of the last ``success.window`` episodes (of all, while fewer ran)."""
        return self.episodes.rolling(self.success.window)

    @property
    def n_episodes(self) -> int:
        return self.episodes.n_episodes

    @property
    def env_steps(self) -> int:
        return self.episodes.env_steps

    @property
    def lengths(self) -> array:
        return self.episodes.lengths

    @property
    def values(self) -> array:
        """Each booked episode's measure."""
        return self.episodes.values

    @property
    def returns(self) -> array:
        return self.episodes.returns

    # -- saving, resuming, ending ---------------------------------------------
    def state_dict(self) -> dict:
        # Tensors, not lists: no Python object per episode (a long run's checkpoint stays cheap).
        return {"n_episodes": self.n_episodes, "lengths": torch.tensor(np.frombuffer(self.lengths, np.int64)),
                "values": torch.tensor(np.frombuffer(self.values, np.float64)),
                "returns": torch.tensor(np.frombuffer(self.returns, np.float64)),
                "evals": [dict(r) for r in self.evals],
                "env_steps": self.env_steps, **self.judge.state_dict(),
                "start_level": self.start_watch.level, "left_start_at": self.start_watch.left_at,
                "wall_s": self.wall_s, "last_eval": self.last_eval, "log_sizes": csv_sizes(self.run_dir, self.logger),
                "train_logged": self._train_logged, "train_due": self._train_due,
                "ret": torch.from_numpy(self.episodes.running_return.copy()),
                "len": torch.from_numpy(self.episodes.running_length.copy())}

    def load_state_dict(self, state: Mapping, reopen: bool = True) -> None:
        """Continues from ``state``; metrics files are cut back to its episodes (with
        ``reopen=False`` not yet: :meth:`reopen` does, once every other part has loaded)."""
        if len(state["ret"]) != self.num_envs:
            raise ValueError(f"the checkpoint has {len(state['ret'])} copies, this run {self.num_envs}")
        episodes = int(state["n_episodes"])
        returns = state["returns"] if "returns" in state else self._returns_from_metrics(episodes)
        self.episodes.load(state, returns)
        self._last_checkpoint = episodes
        self.evals = [dict(r) for r in state["evals"]]
        self.judge.load_state_dict(state)
        if "left_start_at" in state:
            self.start_watch.level, self.start_watch.left_at = state["start_level"], state["left_start_at"]
        else:  # a checkpoint from before the watch: where its start left is not known
            self.start_watch.known = False
        self.last_eval = state.get("last_eval")  # the final evaluation's, once it ran
        self._log_sizes = state.get("log_sizes")
        self._train_logged, self._train_due = state.get("train_logged"), bool(state.get("train_due", False))
        self._t0 = time.perf_counter() - float(state["wall_s"])
        if reopen:
            self.reopen()

    def _returns_from_metrics(self, episodes: int) -> list[float]:
        """The first ``episodes`` returns in metrics.csv (its ``reward`` column): a checkpoint
        saved before the run kept its returns; ValueError where the file has fewer."""
        path = self.run_dir / "metrics.csv"
        try:
            with open(path, newline="") as f:
                rows = [float(r["reward"]) for _, r in zip(range(episodes), csv.DictReader(f))]
        except OSError as err:
            raise ValueError(f"{path} is unreadable ({type(err).__name__})") from None
        if len(rows) != episodes:
            raise ValueError(f"{path} has {len(rows)} episode rows, the checkpoint needs {episodes}")
        return rows

    def reopen(self) -> None:
        """Continues a resumed run's outputs after its loaded episodes: metrics.csv and
        timing.csv cut back to them (rows of episodes after the checkpoint dropped),
        evals.csv rewritten, the CSV logger's files cut back to the checkpoint's rows, the
        progress bar moved past them."""
        self.files.open(self.n_episodes, self.evals)
        if self._log_sizes is not None:
            cut_csv_files(self.run_dir, self._log_sizes)
        self.console.skip(self.n_episodes)

    @property
    def process_s(self) -> float | None:
        """Seconds this process has run so far (imports, building and every run it made
        included): what a user waited, beside the run's own clock (:attr:`wall_s`)."""
        return process_age()

    def summary(self) -> dict:
        """Solved or not and by which judge; the measure's headline numbers; the cost."""
        return run_summary(self)

    def close(self) -> dict:
        """Flushes metrics, draws the reward curve and returns the summary."""
        self.console.close()
        self.files.close()
        summary = self.summary()
        self.log_train(final=True)
        finish_log(self.logger, summary)
        from runs.plot import plot_reward_curve  # matplotlib loads when the curve is drawn, not at the start

        plot_reward_curve(self.run_dir / "metrics.csv", self.run_dir / "reward_curve.png",
                          self.success, self.run_dir / "evals.csv")
        return summary
