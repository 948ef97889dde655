"""The task contract (:class:`Task`) and the small pieces every task uses.

A task *has* a robot and turns it into a decision problem over a batch of
copies (dm_control's ``composer.Task``): the arena it lives in, what an action
does, what is observed, the reward, when an episode ends, how one starts, and
what "solved" means (:class:`Success`). Its parameters are dataclass fields
declared with :func:`params.declare.param`.
"""

from __future__ import annotations

import abc
import math
import numbers
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from params import finite, require, whole
from params.declare import check_fields, param, robot_name
from robots.base import Robot
from robots.physics import BatchedPhysics


MAX_SUBSTEPS = 10_000  # a step of more would take seconds of simulation per call


def substeps_for(running_step: float, timestep: float) -> int:
    """How many physics steps of ``timestep`` make one control step.

    Args:
        running_step: simulated time per control step, s (``task.running_step``).
        timestep: simulated time per physics step, s (``task.physics_timestep``).

    Returns:
        ``running_step / timestep``, a whole number from 1 to ``MAX_SUBSTEPS`` (10000).

    Raises:
        ConfigError: if either is not a finite number > 0, or ``running_step`` is not a whole multiple of
            ``timestep`` (to within 1e-9 s) or is more than ``MAX_SUBSTEPS`` of them.
    """
    require(finite(running_step) and running_step > 0,
            "task.running_step must be a finite number > 0", running_step)
    require(finite(timestep) and timestep > 0,
            "task.physics_timestep must be a finite number > 0", timestep)
    n = round(running_step / timestep)
    require(n <= MAX_SUBSTEPS,
            f"task.running_step / task.physics_timestep must be at most {MAX_SUBSTEPS} physics steps "
            f"per env step (task.physics_timestep = {timestep:g})", running_step / timestep)
    require(
        n >= 1 and abs(n * timestep - running_step) < 1e-9,
        f"task.running_step must be a whole multiple of task.physics_timestep ({timestep})",
        running_step,
    )
    return int(n)


@dataclass(frozen=True)
class Bounds:
    """Which observation entries form a tabular state, and the range of each."""

    names: tuple[str, ...]
    indices: tuple[int, ...]
    low: np.ndarray
    high: np.ndarray

    @classmethod
    def from_config(cls, spec: Mapping[str, Sequence[float]], observation_names: Sequence[str]):
        """The entries and ranges ``task.tabular_state`` names.

        Args:
            spec: ``task.tabular_state``: observation names, each mapped to ``[low, high]``, two finite
                numbers with ``low < high``.
            observation_names: the task's observation entries, in order.

        Returns:
            (Bounds): The named entries in ``spec``'s order, their indices in the observation and their ranges.

        Raises:
            ConfigError: if ``spec`` is not a mapping, is empty, names an entry not among
                ``observation_names`` or holds a pair that is not ``[low, high]`` as above.
        """
        require(isinstance(spec, Mapping),
                "task.tabular_state must map observation names to [low, high]", spec)
        names, indices, low, high = [], [], [], []
        for name, pair in spec.items():
            require(name in observation_names,
                    f"task.tabular_state entries must be among {list(observation_names)}", name)
            require(isinstance(pair, (Sequence, np.ndarray)) and not isinstance(pair, str)
                    and len(pair) == 2 and all(finite(v) for v in pair),
                    f"task.tabular_state.{name} must be [low, high], two finite numbers", pair)
            lo, hi = pair
            require(lo < hi, f"task.tabular_state.{name} must be [low, high] with low < high",
                    [lo, hi])
            names.append(name)
            indices.append(list(observation_names).index(name))
            low.append(float(lo))
            high.append(float(hi))
        require(len(names) > 0, "task.tabular_state must name at least one observation", dict(spec))
        return cls(tuple(names), tuple(indices), np.asarray(low), np.asarray(high))


@dataclass(frozen=True)
class ActionRange:
    """A task's continuous actions: one number in [-1, 1] per named command, scaled to the
    command's ``[low, high]`` (a TorchRL ``Bounded`` spec of ``len(names)``, as a model's
    control range is scaled for SAC, TD3 and PPO)."""

    names: tuple[str, ...]
    low: np.ndarray
    high: np.ndarray

    @property
    def dims(self) -> int:
        """The number of continuous actions."""
        return len(self.names)

    def command(self, action: np.ndarray) -> np.ndarray:
        """Each copy's commands for its actions.

        Args:
            action: ``(num_envs, dims)``, each in [-1, 1] (values outside are clipped to it).

        Returns:
            ``(num_envs, dims)``: ``low + (action + 1) / 2 * (high - low)``.
        """
        action = np.clip(np.asarray(action, dtype=np.float64).reshape(-1, self.dims), -1.0, 1.0)
        return self.low + (action + 1.0) * 0.5 * (self.high - self.low)

    @classmethod
    def of(cls, ranges: Mapping[str, Sequence[float]]) -> "ActionRange":
        """The range of ``{name: [low, high]}``, each a pair of finite numbers with low < high.

        Raises:
            ConfigError: if a pair is not that.
        """
        for name, pair in ranges.items():
            require(isinstance(pair, (Sequence, np.ndarray)) and len(pair) == 2 and all(finite(v) for v in pair)
                    and pair[0] < pair[1], f"the continuous action {name} must range over [low, high], two "
                    "finite numbers with low < high", pair)
        return cls(tuple(str(n) for n in ranges), np.asarray([float(p[0]) for p in ranges.values()]),
                   np.asarray([float(p[1]) for p in ranges.values()]))


ACTION_FORMS = ("discrete", "continuous")


def action_forms(task: Any) -> tuple[str, ...]:
    """The action forms ``task`` offers: ``discrete`` (``n_actions`` > 0) and ``continuous``
    (an ``action_range``)."""
    found = ("discrete",) if int(getattr(task, "n_actions", 0) or 0) > 0 else ()
    return found + (("continuous",) if getattr(task, "action_range", None) is not None else ())


def check_action_form(task: Any, form: str, learner: str = "") -> None:
    """One line unless ``task`` offers actions of ``form`` (the learner's).

    Args:
        task: the task.
        form: ``discrete`` or ``continuous``.
        learner: the learner's name, for the message.

    Raises:
        ConfigError: if ``form`` is not an action form or the task does not offer it.
    """
    require(form in ACTION_FORMS, f"actions must be one of {', '.join(ACTION_FORMS)}", form)
    offered = action_forms(task)
    who = f"learner={learner}" if learner else f"a {form} learner"
    other = {"discrete": "learner=qlearn, dqn or rainbow", "continuous": "learner=sac"}
    require(form in offered, f"{who} acts on {form} actions and task {getattr(task, 'name', type(task).__name__)} "
            f"declares none (it offers {', '.join(offered) or 'no actions'}: use "
            f"{' or '.join(other[f] for f in offered)})", form)


JUDGES = ("training", "greedy")


@dataclass(frozen=True)
class Success:
    """What "solved" means for a task: a per-episode measure, a threshold on it and the
    share of greedy episodes that must reach it.

    ``measure`` names the value an episode is judged by: ``"length"`` (its number of
    steps) or a key of the task's ``episode_info``. An episode *passes* when its measure
    is ``>= threshold``. ``judge`` says which episodes propose a verdict: ``"training"``,
    the mean over the last ``window`` training (exploring) episodes (after at least
    ``min_episodes`` of them), or ``"greedy"``, a greedy evaluation. Where the run has a
    greedy policy to ask, a verdict holds only when at least ``rate`` of one greedy
    evaluation's episodes pass and a second evaluation from fresh starts confirms it
    (:class:`runs.run.SuccessJudge`). An infinite threshold never solves (the whole
    budget runs).
    """

    measure: str
    unit: str
    description: str
    threshold: float
    judge: str = "training"
    window: int = 100
    min_episodes: int = 100
    rate: float = 0.9

    KEYS = ("measure", "threshold", "judge", "window", "min_episodes", "rate")

    @classmethod
    def from_config(cls, win: Mapping[str, Any] | None, default: "Success",
                    measures: Mapping[str, tuple[str, str]]) -> "Success":
        """``default`` with the entries of ``task.win`` applied.

        Args:
            win: ``task.win``: some of ``measure``, ``threshold``, ``judge``, ``window``, ``min_episodes`` (or None).
            default: the task's own rule, which gives each entry ``win`` leaves out.
            measures: each measure the task offers, mapped to its ``(unit, description)``.

        Returns:
            The rule, with the unit and description of its measure.

        Raises:
            ConfigError: if ``win`` holds another key or a value out of its range (a measure not in ``measures``,
                a judge not in ``JUDGES``, a NaN threshold, a window outside [1, 1000000], ...).
        """
        win = dict(win or {})
        unknown = sorted(set(win) - set(cls.KEYS))
        require(not unknown, f"task.win entries must be among {', '.join(cls.KEYS)}",
                ", ".join(map(str, unknown)))
        measure = win.get("measure", default.measure)
        require(measure in measures, f"task.win.measure must be one of {', '.join(measures)}", measure)
        threshold = win.get("threshold", default.threshold)
        require(isinstance(threshold, numbers.Real) and not isinstance(threshold, bool) and not math.isnan(threshold),
                "task.win.threshold must be a number (inf: never solved, the whole budget runs)", threshold)
        judge = win.get("judge", default.judge)
        require(judge in JUDGES, f"task.win.judge must be one of {', '.join(JUDGES)}", judge)
        window = win.get("window", default.window)
        require(whole(window) and 1 <= window <= 1_000_000,
                "task.win.window must be an integer in [1, 1000000]", window)
        min_episodes = win.get("min_episodes", default.min_episodes)
        require(whole(min_episodes) and min_episodes >= 0, "task.win.min_episodes must be an integer >= 0",
                min_episodes)
        rate = win.get("rate", default.rate)
        require(isinstance(rate, numbers.Real) and not isinstance(rate, bool) and 0 < rate <= 1,
                "task.win.rate must be a number in (0, 1]: the share of greedy episodes that must pass", rate)
        unit, description = measures[measure]
        return cls(measure, unit, description, float(threshold), judge, int(window), int(min_episodes),
                   float(rate))

    def met(self, value: float, episodes: int) -> bool:
        """Whether a mean ``value`` of the measure, after ``episodes`` training episodes, solves.

        Args:
            value: the mean of the measure over the episodes ``judge`` names, in ``unit``.
            episodes: the training episodes finished so far.

        Returns:
            True when ``episodes`` >= ``min_episodes`` (and >= 1) and ``value`` >= ``threshold``.
        """
        return episodes >= max(self.min_episodes, 1) and value >= self.threshold

    def pass_rate(self, values: Sequence[float]) -> float:
        """The share of episodes whose measure (``values``, one per episode) passes: ``>= threshold``."""
        values = np.asarray(values, dtype=float)
        return float(np.mean(values >= self.threshold)) if values.size else 0.0

    def rate_met(self, rate: float) -> bool:
        """Whether a greedy evaluation whose episodes pass at ``rate`` meets the rule."""
        return rate >= self.rate - 1e-12

    def describe(self) -> str:
        """The rule in words.

        Returns:
            The measure's description, ``>=``, the threshold and its unit: ``"distance walked towards +y >= 1 m"``.
        """
        return f"{self.description} >= {self.threshold:g} {self.unit}".rstrip()


class PerCopy:
    """A task's per-copy state between steps: named arrays with one row per copy.

    ``PerCopy(command=(), start_xy=(2,), action=((), np.int64))`` declares the
    arrays by their shape after the copy axis (and dtype, default float64);
    ``allocate(n)`` makes them zeros for ``n`` copies. They are attributes
    (``state.command``) and are what a training checkpoint saves.
    """

    def __init__(self, **declared: tuple) -> None:
        self._declared = {name: self._spec(spec) for name, spec in declared.items()}
        self.allocate(0)

    @staticmethod
    def _spec(spec: tuple) -> tuple[tuple[int, ...], type]:
        if len(spec) == 2 and isinstance(spec[0], tuple):
            return spec[0], spec[1]
        return tuple(spec), np.float64

    def allocate(self, n: int) -> None:
        """Makes every declared array zeros for ``n`` copies (the values held before are dropped).

        Args:
            n: the number of copies (each array's rows).
        """
        for name, (shape, dtype) in self._declared.items():
            setattr(self, name, np.zeros((n, *shape), dtype=dtype))

    def state_dict(self) -> dict[str, np.ndarray]:
        """The declared arrays, copied, for a training checkpoint.

        Returns:
            Each declared name mapped to a copy of its array.
        """
        return {name: getattr(self, name).copy() for name in self._declared}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restores what :meth:`state_dict` returned, each array in its declared dtype.

        Args:
            state: every declared name mapped to an array of the shape it has now.

        Raises:
            ConfigError: if ``state`` names other arrays than the declared ones, or one has another shape.
        """
        require(set(state) == set(self._declared),
                f"per-copy task state must hold {sorted(self._declared)}", sorted(state))
        for name, value in state.items():
            current = getattr(self, name)
            require(np.shape(value) == current.shape,
                    f"per-copy task state {name} must have shape {current.shape}", np.shape(value))
            setattr(self, name, np.array(value, dtype=current.dtype))


class Task(abc.ABC):
    """The task contract. Besides the methods below, a task has these attributes:

    - ``robot`` (:class:`~robots.base.Robot`): the robot it has;
    - ``n_actions`` (int): the discrete actions are ``Discrete(n_actions)`` (0: none);
    - ``action_range`` (:class:`ActionRange` or None): the continuous actions, one per
      command in [-1, 1] (None: none); a task offers one form or both;
    - ``observation_names`` (tuple of str): the observation's entries, in order;
    - ``running_step`` (s of simulated time per step), ``physics_timestep`` (s)
      and ``n_substeps`` (physics steps per env step);
    - ``max_episode_steps`` (int): the time limit (the env truncates);
    - ``tabular_bounds`` (:class:`Bounds`): entries and ranges a tabular learner may bin;
    - ``success`` (:class:`Success`): what "solved" means for it;
    - ``per_copy`` (:class:`PerCopy`): its state between steps, saved with checkpoints.

    Every method works on the whole batch of copies at once.
    """

    action_range: ActionRange | None = None  # no continuous form unless the task gives one

    @staticmethod
    def continuous(action: np.ndarray) -> bool:
        """Whether ``action`` (as :meth:`apply_action` gets it) is of the continuous form."""
        return np.asarray(action).dtype.kind == "f"

    @abc.abstractmethod
    def build_arena(self) -> Any:
        """The MJCF arena with the robot attached (compiled once by the env).

        Returns:
            The arena's ``dm_control.mjcf`` root element, ``robot.mjcf_model`` attached to it.
        """

    def bind(self, physics: BatchedPhysics) -> None:
        """Resolves the robot's names in the compiled model; sizes ``per_copy`` for ``physics.num_envs``.

        A task that resolves names of its own (arena bodies, sites) extends this.

        Args:
            physics: the batch of copies of the compiled arena, passed on to the robot's
                :meth:`~robots.base.Robot.bind`.
        """
        self.robot.bind(physics)
        self.per_copy.allocate(physics.num_envs)

    @abc.abstractmethod
    def initialize_episode(self, physics: BatchedPhysics, mask: np.ndarray,
                           rng: np.random.Generator) -> None:
        """Starts a new episode in the copies where ``mask`` is true.

        Args:
            physics: the batch of copies, the ``mask`` copies just put back to the model's initial state
                (the env recomputes their sensor readings afterwards).
            mask: bool ``(num_envs,)``: the copies that start an episode.
            rng: the stream every random draw of the start comes from (one per seed block of the env).
        """

    @abc.abstractmethod
    def apply_action(self, physics: BatchedPhysics, action: np.ndarray) -> None:
        """Turns each copy's action into robot commands.

        Args:
            physics: the batch of copies, whose controls the robot sets.
            action: int ``(num_envs,)``: each copy's action, an index among ``n_actions``; or, for
                the continuous form, float ``(num_envs, action_range.dims)`` in [-1, 1].
        """

    @abc.abstractmethod
    def observation(self, physics: BatchedPhysics) -> np.ndarray:
        """Each copy's observation, after a step or an episode's start.

        Args:
            physics: the batch of copies.

        Returns:
            ``(num_envs, len(observation_names))``, entries in ``observation_names`` order (the env passes
                them on as float32).
        """

    @abc.abstractmethod
    def terminated(self, physics: BatchedPhysics, observation: np.ndarray) -> np.ndarray:
        """Which copies' episodes the step ended by failure or success (not by time).

        Args:
            physics: the batch of copies after the step.
            observation: the step's :meth:`observation`, ``(num_envs, len(observation_names))``.

        Returns:
            Bool ``(num_envs,)``, true where the episode ended.
        """

    @abc.abstractmethod
    def reward(self, physics: BatchedPhysics, observation: np.ndarray,
               terminated: np.ndarray) -> np.ndarray:
        """The rewards of the step just taken.

        Args:
            physics: the batch of copies after the step.
            observation: the step's :meth:`observation`, ``(num_envs, len(observation_names))``.
            terminated: bool ``(num_envs,)``: the step's :meth:`terminated` (false in a copy whose physics
                diverged).

        Returns:
            ``(num_envs,)``, one reward per copy (the env makes a diverged copy's 0).
        """

    @abc.abstractmethod
    def episode_info(self, physics: BatchedPhysics) -> dict[str, np.ndarray]:
        """Per copy, what its episode has achieved so far.

        Args:
            physics: the batch of copies (read as a copy's episode ends).

        Returns:
            Named ``(num_envs,)`` arrays, ``success.measure`` among them unless it is the episode length;
                ``{}`` if nothing.
        """

    def state_dict(self) -> dict[str, np.ndarray]:
        """The per-copy state (``per_copy``) as arrays, for a training checkpoint.

        Returns:
            Each of ``per_copy``'s names mapped to a copy of its array.
        """
        return self.per_copy.state_dict()

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restores what :meth:`state_dict` returned.

        Args:
            state: each of ``per_copy``'s names mapped to an array of the shape it has now.

        Raises:
            ConfigError: if ``state`` names other arrays than ``per_copy``'s, or one has another shape.
        """
        self.per_copy.load_state_dict(state)

    def observation_range(self) -> tuple[np.ndarray, np.ndarray]:
        """The values each observation entry can take.

        True bounds, which Gymnasium's observation space declares; ``tabular_bounds``
        are only the ranges a tabular learner bins, and values leave them.

        Returns:
            ``(low, high)``, each ``(len(observation_names),)``, ``-inf`` / ``inf`` where nothing bounds
                the entry (this default: all).
        """
        n = len(self.observation_names)
        return np.full(n, -np.inf), np.full(n, np.inf)


#: Every member a task provides.
CONTRACT = (
    "robot", "n_actions", "observation_names", "running_step", "physics_timestep", "n_substeps",
    "max_episode_steps", "tabular_bounds", "success", "per_copy",
    "build_arena", "bind", "initialize_episode", "apply_action", "observation", "terminated",
    "reward", "episode_info", "state_dict", "load_state_dict",
)
_TYPES = {"robot": Robot, "action_range": (ActionRange, type(None)), "tabular_bounds": Bounds, "success": Success, "per_copy": PerCopy}


def check_task(task: Any) -> None:
    """Raises ``TypeError`` naming what ``task`` lacks of the contract.

    Args:
        task: the object to check.

    Raises:
        TypeError: if ``task`` lacks a member of :data:`CONTRACT`, its ``robot``, ``tabular_bounds``,
            ``success`` or ``per_copy`` is of another type, or it does not derive from :class:`Task`.
    """
    missing = [m for m in CONTRACT if not hasattr(task, m)]
    wrong = [f"{m} is not a {(t[0] if isinstance(t, tuple) else t).__name__}" for m, t in _TYPES.items()
             if hasattr(task, m) and not isinstance(getattr(task, m), t)]
    if not isinstance(task, Task):
        wrong.append("it does not derive from tasks.base.Task")
    if missing or wrong:
        raise TypeError(f"{type(task).__name__} does not fulfil the task contract (tasks.base.Task): "
                        + "; ".join(([f"missing {', '.join(missing)}"] if missing else []) + wrong))


def setup(task: Task, success: Success, measures: Mapping[str, tuple[str, str]]) -> None:
    """What every task's ``__post_init__`` does first: checks its declared parameters and
    that its robot fits (an instance of the class's ``ROBOT``, named in the message by its
    module: ``task <name> needs robot=<module>``); sets ``n_substeps`` and ``success``.

    Args:
        task: the task being made.
        success: the task's own rule for "solved", which ``task.win`` adjusts.
        measures: each measure the task offers, mapped to its ``(unit, description)``.

    Raises:
        ConfigError: if a declared parameter is out of its range, ``task.robot`` is not a ``robot``, or
            ``task.running_step``, ``task.physics_timestep`` or ``task.win`` is one it cannot honour.
    """
    check_fields(task, "task")
    robot = type(task).ROBOT
    require(isinstance(task.robot, robot), f"task {task.name} needs robot={robot_name(robot)}",
            type(task.robot).__name__)
    task.n_substeps = substeps_for(task.running_step, task.physics_timestep)
    task.success = Success.from_config(task.win, success, measures)


class common:
    """Declarations of the parameters every task has; each task picks its default."""

    @staticmethod
    def running_step(default: float) -> Any:
        """Declares ``running_step``, the simulated time per step (> 0).

        Args:
            default: the task's default, s.

        Returns:
            The dataclass field.
        """
        return param(default, "simulated time per step, s", gt=0)

    @staticmethod
    def physics_timestep(default: float) -> Any:
        """Declares ``physics_timestep``, the physics step (> 0; ``running_step`` a whole multiple of it).

        Args:
            default: the task's default, s.

        Returns:
            The dataclass field.
        """
        return param(default, "physics step, s (running_step must be a whole multiple)", gt=0)

    @staticmethod
    def max_episode_steps(default: int) -> Any:
        """Declares ``max_episode_steps``, the time limit after which the episode is truncated.

        Args:
            default: the task's default, steps (1 to 10**7).

        Returns:
            The dataclass field.
        """
        return param(default, "time limit, steps (the episode is truncated)", ge=1, le=10**7)

    @staticmethod
    def tabular_state(when_null: str) -> Any:
        """Declares ``tabular_state``, the observation entries a tabular learner bins (default null).

        Args:
            when_null: what null means for the task, shown in the parameter's description.

        Returns:
            The dataclass field.
        """
        return param(None, f"observation entries a tabular learner bins: name: [low, high] "
                           f"(null: {when_null})")

    @staticmethod
    def win(when_null: str) -> Any:
        """Declares ``win``: the measure, threshold, judge, window and min_episodes of solved (default null).

        Args:
            when_null: what null means for the task, shown in the parameter's description.

        Returns:
            The dataclass field.
        """
        return param(None, f"what solved means: measure, threshold, judge, window, min_episodes "
                           f"(null: {when_null})")
