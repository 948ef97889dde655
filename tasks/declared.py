"""A task declared in YAML, over any :class:`~robots.mjcf_robot.MjcfRobot`: no Python.

``conf/task/<name>.yaml`` says, by the model's names (the grammar: :mod:`tasks.terms`):

- ``observations``: named quantities (joint angle, sin/cos of it, site height, sensor, ...),
  in order; a vector quantity gives ``name_0``, ``name_1``, ...;
- ``terms``: more named quantities, not observed, for reward, termination and measures;
- ``actions``: the discrete action set, command vectors of some actuators (every step
  sets them; an actuator no action names keeps 0), and the continuous form (``continuous``:
  actuators, each driven by one action in [-1, 1] scaled to its control range; by default
  the discrete set's actuators), or the continuous form alone;
- ``rewards``: the reward is a weighted sum of named terms (``alive``, ``action_cost``, a term, a term's
  distance to a target);
- ``termination``: ``[low, high]`` per term; outside, the episode terminates;
- ``reset``: the start state (:mod:`tasks.start`): each joint's position and velocity, a
  number or a uniform range (the model's ``qpos0`` for the others), a pair of slides over a
  disc, and a uniform noise on the other hinges' and slides' positions and velocities;
- ``measures``: what an episode achieved (a term's max, min, last, sum or mean), for ``win``;
- ``running_step``, ``physics_timestep`` (null: the model's), ``max_episode_steps``,
  ``tabular_state`` and ``win`` as every task has them.

Every name is checked against the model when the task is built, before anything runs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from params import require
from params.declare import REQUIRED, check_fields, param
from robots.mjcf_robot import MjcfRobot
from robots.physics import BatchedPhysics
from tasks import terms as T
from tasks.start import StartState
from tasks.base import ActionRange, Bounds, PerCopy, Success, Task, common, substeps_for



@dataclass(eq=False)
class DeclaredTask(Task):
    """A task declared by terms in YAML; it has an :class:`MjcfRobot`."""

    name: ClassVar[str] = "declared"

    robot: MjcfRobot
    observations: dict = param(REQUIRED, "observed quantities, name: {source: model name, axis, "
                                         "index, apply} (docs/own-robot.md)")
    actions: dict = param(REQUIRED, "the discrete action set: {actuators: [..], commands: [[..]]} "
                                    "or {values: {actuator: [..]}} (every combination); continuous: "
                                    "[actuator, ..] or {actuator: [low, high]} for the continuous form "
                                    "(default: the discrete set's actuators over their control ranges)")
    rewards: dict = param(REQUIRED, "reward terms, name: {alive | action_cost | term | a quantity, "
                                   "weight, target, kernel}; the reward is their weighted sum")
    terms: dict | None = param(None, "more named quantities (not observed) for reward, "
                                     "termination and measures")
    termination: dict | None = param(None, "term name: [low, high]; outside, the episode "
                                           "terminates (null: only the time limit ends it)")
    reset: dict | None = param(None, "the start state: joints: {name: position or {position, velocity, "
                                     "within_limits}}, disc: {joints: [a, b], radius, center}, position_noise, "
                                     "velocity_noise (tasks/start.py)")
    measures: dict | None = param(None, "episode measures for win, name: {term, reduce: max, "
                                        "min, last, sum or mean, unit, description, above}")
    cameras: dict | None = param(None, "cameras to add to the world, name: {pos: [x, y, z], xyaxes: "
                                       "[6 numbers]} (videos use the first camera of the model)")
    running_step: float = common.running_step(0.05)
    physics_timestep: float | None = param(None, "physics step, s (null: the model's timestep; "
                                                 "running_step must be a whole multiple)", gt=0)
    max_episode_steps: int = common.max_episode_steps(1000)
    tabular_state: dict | None = common.tabular_state("every observation entry over [-1, 1]")
    win: dict | None = common.win("the greedy policy lasts max_episode_steps")

    def __post_init__(self) -> None:
        check_fields(self, "task")
        require(isinstance(self.robot, MjcfRobot), "a declared task needs robot=<a robot made "
                "from a model: robots.mjcf_robot.MjcfRobot>", type(self.robot).__name__)
        self.physics_timestep = self.physics_timestep or self.robot.timestep
        self._obs_terms = T.named_terms(self.robot, self.observations, "task.observations")
        self._terms = {**self._obs_terms, **T.named_terms(self.robot, self.terms, "task.terms")}
        self.observation_names = tuple(n for t in self._obs_terms.values() for n in t.labels())
        require(len(self.observation_names) > 0, "task.observations must name at least one "
                "quantity", self.observations)
        actions = T.action_set(self.robot, self.actions)
        self._columns, self._commands = actions.columns, actions.commands
        self.n_actions = len(self._commands)
        if actions.continuous is not None:
            self._continuous_columns, ranges = actions.continuous
            self.action_range = ActionRange.of(ranges)
        # After the names: a task written for another model says so before its timing does.
        self.n_substeps = substeps_for(self.running_step, self.physics_timestep)
        self._rewards = [T.reward_term(self.robot, str(k), v, self._terms, f"task.rewards.{k}")
                         for k, v in self.rewards.items()]
        self._bounds = T.bounds(self.termination, self._terms)
        self._measures = T.measures(self.measures, self._terms, self.running_step)
        self._start = StartState(self.robot, self.reset)
        self._setup_success()
        self.per_copy = PerCopy(command=(len(self._columns),), steps=(),
                                **{f"m_{m}": () for m in self._measures},
                                **{f"w_{m}": (x.window,) for m, x in self._measures.items() if x.window})

    def _setup_success(self) -> None:
        offered = {"length": ("steps", "steps lasted")}
        offered.update({m.name: (m.unit, m.description) for m in self._measures.values()})
        default = Success("length", "steps", "steps lasted", float(self.max_episode_steps),
                          "greedy", 100, 0)
        self.success = Success.from_config(self.win, default, offered)
        self.tabular_bounds = Bounds.from_config(
            self.tabular_state or {n: [-1.0, 1.0] for n in self.observation_names},
            self.observation_names)

    # -- the contract --------------------------------------------------------------
    def build_arena(self):
        """The robot's own model is the world: the task sets its timestep, adds its cameras and
        an offscreen buffer for full-HD frames."""
        model = self.robot.mjcf_model
        model.option.timestep = self.physics_timestep
        for name, spec in (self.cameras or {}).items():
            require(isinstance(spec, dict) and set(spec) == {"pos", "xyaxes"},
                    f"task.cameras.{name} must be {{pos: [x, y, z], xyaxes: [6 numbers]}}", spec)
            model.worldbody.add("camera", name=str(name), pos=spec["pos"], xyaxes=spec["xyaxes"])
        offscreen = getattr(model.visual, "global")
        offscreen.offwidth, offscreen.offheight = 1920, 1080
        return model

    def initialize_episode(self, physics: BatchedPhysics, mask: np.ndarray,
                           rng: np.random.Generator) -> None:
        """Joints at the declared start (else where the model puts them), plus uniform noise."""
        self._start.start(self.robot, physics, mask, rng)
        self.per_copy.command[mask] = 0.0
        self.per_copy.steps[mask] = 0
        for name, m in self._measures.items():
            getattr(self.per_copy, f"m_{name}")[mask] = 0.0
            if m.window:
                getattr(self.per_copy, f"w_{name}")[mask] = 0.0
        self.robot.command(physics, self._columns, self.per_copy.command)

    def apply_action(self, physics: BatchedPhysics, action: np.ndarray) -> None:
        if self.continuous(action):
            self.per_copy.command[:, self._continuous_columns] = self.action_range.command(action)
        else:
            self.per_copy.command[:] = self._commands[action]
        self.robot.command(physics, self._columns, self.per_copy.command)

    def observation(self, physics: BatchedPhysics) -> np.ndarray:
        return np.concatenate([t.value(physics) for t in self._obs_terms.values()], axis=1)

    def terminated(self, physics: BatchedPhysics, observation: np.ndarray) -> np.ndarray:
        out = np.zeros(physics.num_envs, dtype=bool)
        for name, (low, high) in self._bounds.items():
            value = self._terms[name].value(physics)
            out |= ((value < low) | (value > high)).any(axis=1)
        return out

    def reward(self, physics: BatchedPhysics, observation: np.ndarray,
               terminated: np.ndarray) -> np.ndarray:
        """The weighted sum of the reward terms (the step's measures are booked here too)."""
        self._book_measures(physics)
        total = np.zeros(physics.num_envs)
        for term in self._rewards:
            total += term.weight * term.value(physics, self.per_copy.command)
        return total

    def _book_measures(self, physics: BatchedPhysics) -> None:
        steps = self.per_copy.steps
        steps += 1
        for name, m in self._measures.items():
            acc, value = getattr(self.per_copy, f"m_{name}"), m.term.value(physics)[:, 0]
            if m.window:  # the last ``window`` values, a ring per copy
                getattr(self.per_copy, f"w_{name}")[np.arange(len(steps)), (steps.astype(np.int64) - 1) % m.window] = value
            elif m.held is not None:
                acc += m.passes(value)
            elif m.reduce in ("max", "min"):
                pick = np.maximum if m.reduce == "max" else np.minimum
                acc[:] = np.where(steps == 1, value, pick(acc, value))
            elif m.reduce == "last":
                acc[:] = value
            else:
                acc += value

    def episode_info(self, physics: BatchedPhysics) -> dict[str, np.ndarray]:
        """Each declared measure of the episode so far."""
        out, steps = {}, self.per_copy.steps
        for name, m in self._measures.items():
            if m.window:
                out[name] = self._windowed(m, getattr(self.per_copy, f"w_{name}"))
                continue
            value = getattr(self.per_copy, f"m_{name}").copy()
            if m.held is not None:
                out[name] = (value / np.maximum(steps, 1) >= m.held).astype(np.float64)
                continue
            if m.reduce == "mean":
                value = value / np.maximum(steps, 1)
            out[name] = m.judged(value)
        return out

    def _windowed(self, m: T.Measure, ring: np.ndarray) -> np.ndarray:
        """A measure over each copy's last ``m.window`` steps (fewer in a shorter episode; for
        ``held``, the steps it did not reach count as not held)."""
        steps = self.per_copy.steps
        valid = np.arange(m.window)[None, :] < np.minimum(steps, m.window)[:, None]
        if m.held is not None:
            return ((m.passes(ring) & valid).sum(axis=1) / m.window >= m.held).astype(np.float64)
        if m.reduce == "last":
            value = ring[np.arange(len(steps)), (np.maximum(steps, 1).astype(np.int64) - 1) % m.window]
        elif m.reduce in ("max", "min"):
            fill = -np.inf if m.reduce == "max" else np.inf
            value = getattr(np, m.reduce)(np.where(valid, ring, fill), axis=1)
        else:
            value = np.where(valid, ring, 0.0).sum(axis=1)
            value = value / np.maximum(valid.sum(axis=1), 1) if m.reduce == "mean" else value
        return m.judged(np.where(steps > 0, value, 0.0))

    def observation_range(self) -> tuple[np.ndarray, np.ndarray]:
        """[-1, 1] for sines, cosines, quaternions and axes; unbounded otherwise."""
        edge = np.concatenate([np.full(t.size, 1.0 if t.bounded() else np.inf)
                               for t in self._obs_terms.values()])
        return -edge, edge
