"""The terms a declared task is made of, parsed from its YAML (Isaac Lab's manager-based
terms, dm_control's suite observations): named quantities of the robot, reward terms,
the discrete action set, termination bounds, episode measures.

A quantity is a mapping with one source and what to take of it::

    {joint_pos: shoulder}                     # a hinge's angle, rad
    {joint_pos: shoulder, apply: sin}         # its sine (apply: sin, cos, abs, square)
    {site_pos: tip, axis: z}                  # a site's height (axis: x, y or z; index: i)
    {body_zaxis: torso, axis: z}              # the body's uprightness (cos of its tilt)
    {sensor: accelerometer}                   # a sensor of the model, all its numbers

Sources: :data:`robots.mjcf_robot.SOURCES`. Every term reads the robot by name.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np

from params import ConfigError, finite, require
from robots.mjcf_robot import SOURCES, MjcfRobot, Reader
from robots.physics import BatchedPhysics

AXES = {"x": 0, "y": 1, "z": 2}
APPLY = {"sin": np.sin, "cos": np.cos, "abs": np.abs, "square": np.square}
_PICKS = ("axis", "index", "apply")
_BOUNDED = ("quat", "zaxis")  # sources whose every entry lies in [-1, 1]
REDUCE = ("max", "min", "last", "sum", "mean")


@dataclass
class Term:
    """A named quantity: a robot reader, optionally one entry of it and a function."""

    name: str
    reader: Reader
    pick: int | None = None
    apply: str | None = None

    @property
    def size(self) -> int:
        return 1 if self.pick is not None else self.reader.size

    def labels(self) -> list[str]:
        """Observation names of its entries: the term's own name, or ``name_0``, ``name_1``, ..."""
        return [self.name] if self.size == 1 else [f"{self.name}_{i}" for i in range(self.size)]

    def value(self, physics: BatchedPhysics) -> np.ndarray:
        """``(num_envs, size)``."""
        value = self.reader.read(physics)
        if self.pick is not None:
            value = value[:, self.pick : self.pick + 1]
        return APPLY[self.apply](value) if self.apply else value

    def bounded(self) -> bool:
        """Whether every entry lies in [-1, 1] (sin, cos, a quaternion, an axis)."""
        return self.apply in ("sin", "cos") or self.reader.source.split("_")[-1] in _BOUNDED


def _mapping(spec: Any, where: str, what: str) -> Mapping:
    require(isinstance(spec, Mapping), f"{where} must be {what}", spec)
    return spec


def quantity(robot: MjcfRobot, name: str, spec: Any, where: str) -> Term:
    """The :class:`Term` of a quantity spec (see the module docstring)."""
    what = (f"a mapping with one source ({', '.join(SOURCES)}): a name of the model, and "
            f"optionally axis (x, y, z), index and apply ({', '.join(APPLY)})")
    spec = _mapping(spec, where, what)
    sources = [k for k in spec if k in SOURCES]
    other = sorted(set(spec) - set(SOURCES) - set(_PICKS))
    require(len(sources) == 1 and not other, f"{where} must be {what}", dict(spec))
    reader = robot.reader(sources[0], spec[sources[0]], where)
    pick = _pick(spec, reader.size, where)
    apply = spec.get("apply")
    require(apply is None or apply in APPLY, f"{where}.apply must be one of {', '.join(APPLY)}",
            apply)
    return Term(name, reader, pick, apply)


def _pick(spec: Mapping, size: int, where: str) -> int | None:
    """The entry ``axis`` or ``index`` picks, checked against ``size``."""
    require(not ("axis" in spec and "index" in spec), f"{where} takes axis or index, not both",
            dict(spec))
    if "axis" in spec:
        require(spec["axis"] in AXES and size == 3, f"{where}.axis must be x, y or z of a "
                f"3-vector (this source has {size} numbers)", spec["axis"])
        return AXES[spec["axis"]]
    if "index" in spec:
        index = spec["index"]
        require(isinstance(index, int) and not isinstance(index, bool) and 0 <= index < size,
                f"{where}.index must be an integer in [0, {size - 1}]", index)
        return index
    return None


def named_terms(robot: MjcfRobot, specs: Mapping | None, where: str) -> dict[str, Term]:
    """``name -> Term`` of a mapping of quantity specs (``task.observations``, ``task.terms``)."""
    specs = _mapping(specs or {}, where, "a mapping of names to quantities")
    return {str(k): quantity(robot, str(k), v, f"{where}.{k}") for k, v in specs.items()}


# -- reward ------------------------------------------------------------------------
@dataclass
class RewardTerm:
    """``weight * value`` per step: ``alive`` (1), ``action_cost`` (the sum of the squared
    commands), or a one-number term (its distance to ``target`` if given)."""

    name: str
    weight: float
    kind: str
    term: Term | None = None
    target: float | None = None
    kernel: str = "abs"

    def value(self, physics: BatchedPhysics, command: np.ndarray) -> np.ndarray:
        if self.kind == "alive":
            return np.ones(physics.num_envs)
        if self.kind == "action_cost":
            return np.square(command).sum(axis=1)
        value = self.term.value(physics)[:, 0]
        if self.target is None:
            return value
        gap = value - self.target
        return np.abs(gap) if self.kernel == "abs" else np.square(gap)


def reward_term(robot: MjcfRobot, name: str, spec: Any, terms: Mapping[str, Term],
                where: str) -> RewardTerm:
    """One entry of ``task.rewards``: ``{alive: true}``, ``{action_cost: true}``, ``{term: <a
    declared term>}`` or an inline quantity; with ``weight`` (1), ``target``, ``kernel``."""
    spec = dict(_mapping(spec, where, "a mapping: alive, action_cost, term or a quantity, "
                                      "with weight, target and kernel (abs or square)"))
    weight, target = spec.pop("weight", 1.0), spec.pop("target", None)
    kernel = spec.pop("kernel", "abs")
    require(finite(weight), f"{where}.weight must be a finite number", weight)
    require(target is None or finite(target), f"{where}.target must be a finite number", target)
    require(kernel in ("abs", "square"), f"{where}.kernel must be abs or square", kernel)
    for kind in ("alive", "action_cost"):
        if kind in spec:
            require(spec == {kind: True}, f"{where}: {kind} takes only weight", dict(spec))
            return RewardTerm(name, float(weight), kind)
    if "term" in spec:
        require(set(spec) == {"term"} and spec["term"] in terms, f"{where}.term must be one of "
                f"the declared terms: {', '.join(terms)}", spec.get("term"))
        term = terms[spec["term"]]
    else:
        term = quantity(robot, name, spec, where)
    require(term.size == 1, f"{where} must be one number per step; {term.name} has {term.size} "
            f"(pick one with axis or index)", term.size)
    return RewardTerm(name, float(weight), "term", term, target, kernel)


# -- actions -----------------------------------------------------------------------
def action_set(robot: MjcfRobot, spec: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(columns, commands)``: the actuators the actions drive (indices in the model's order)
    and one row of their commands per action. ``task.actions`` is either
    ``{actuators: [a, b], commands: [[..], [..]]}`` or ``{values: {a: [..], b: [..]}}``
    (every combination of the per-actuator values)."""
    spec = _mapping(spec, "task.actions", "{actuators: [names], commands: [[values], ...]} or "
                                          "{values: {actuator: [values], ...}}")
    if "values" in spec:
        require(set(spec) == {"values"}, "task.actions takes values or actuators and commands",
                sorted(spec))
        values = _mapping(spec["values"], "task.actions.values",
                          "a mapping of actuator names to lists of commands")
        names = list(values)
        rows = [list(r) for r in itertools.product(*(list(values[n] or []) for n in names))]
    else:
        require(set(spec) == {"actuators", "commands"}, "task.actions takes values or "
                "actuators and commands", sorted(spec))
        names, rows = list(spec["actuators"] or []), [list(r) for r in (spec["commands"] or [])]
    require(len(names) > 0, "task.actions must name at least one actuator", names)
    require(len(rows) > 0, "task.actions must hold at least one action (an empty action set)", rows)
    for row in rows:
        require(len(row) == len(names) and all(finite(v) for v in row), f"task.actions: each "
                f"action must be {len(names)} finite numbers, one per actuator {names}", row)
    order = robot.actuators()
    columns = [order.index(robot.element("actuator", n, "task.actions").name) for n in names]
    return np.asarray(columns, dtype=np.int64), np.asarray(rows, dtype=np.float64)


# -- termination and measures ---------------------------------------------------------
def bounds(spec: Any, terms: Mapping[str, Term]) -> dict[str, tuple[float, float]]:
    """``task.termination``: ``term name -> [low, high]``; outside them the episode terminates."""
    spec = _mapping(spec or {}, "task.termination", "a mapping of term names to [low, high]")
    out = {}
    for name, pair in spec.items():
        if name not in terms:
            raise ConfigError(f"task.termination.{name}: no such term; the declared terms "
                              f"(task.observations and task.terms): {', '.join(terms)}")
        require(isinstance(pair, (list, tuple)) and len(pair) == 2
                and all(isinstance(v, (int, float)) and not np.isnan(v) for v in pair)
                and pair[0] < pair[1], f"task.termination.{name} must be [low, high] with "
                f"low < high (.inf for none)", pair)
        out[str(name)] = (float(pair[0]), float(pair[1]))
    return out


@dataclass
class Measure:
    """What an episode achieved: a term reduced over its steps (``max``, ``min``, ``last``,
    ``sum``, ``mean``), then, with ``above``, 1 if that reached it and 0 if not."""

    name: str
    term: Term
    reduce: str
    unit: str
    description: str
    above: float | None = None


def measures(spec: Any, terms: Mapping[str, Term]) -> dict[str, Measure]:
    """``task.measures``: ``name -> {term, reduce, unit, description, above}``."""
    spec = _mapping(spec or {}, "task.measures", "a mapping of names to {term, reduce, unit, "
                                                 "description, above}")
    out = {}
    for name, m in spec.items():
        where = f"task.measures.{name}"
        m = _mapping(m, where, "{term, reduce, unit, description, above}")
        require(set(m) <= {"term", "reduce", "unit", "description", "above"} and "term" in m,
                f"{where} must be {{term, reduce, unit, description, above}}", dict(m))
        require(m["term"] in terms and terms[m["term"]].size == 1, f"{where}.term must be a "
                f"one-number declared term: {', '.join(terms)}", m["term"])
        require(m.get("reduce", "max") in REDUCE, f"{where}.reduce must be one of "
                f"{', '.join(REDUCE)}", m.get("reduce"))
        require(m.get("above") is None or finite(m["above"]), f"{where}.above must be a number",
                m.get("above"))
        out[str(name)] = Measure(str(name), terms[m["term"]], m.get("reduce", "max"),
                                 str(m.get("unit", "")), str(m.get("description", name)),
                                 m.get("above"))
    return out
