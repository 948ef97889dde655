"""The terms a declared task is made of, parsed from its YAML (Isaac Lab's manager-based
terms, dm_control's suite observations): named quantities of the robot, reward terms,
the action set (discrete, continuous or both), termination bounds, episode measures.

A quantity is a mapping with one source and what to take of it::

    {joint_pos: shoulder}                     # a hinge's angle, rad
    {joint_pos: shoulder, apply: sin}         # its sine (apply: sin, cos, abs, square)
    {site_pos: tip, axis: z}                  # a site's height (axis: x, y or z; index: i)
    {body_zaxis: torso, axis: z}              # the body's uprightness (cos of its tilt)
    {geom_pos: target}                        # a geom's position (geom_quat, geom_zaxis, ...)
    {sensor: accelerometer}                   # a sensor of the model, all its numbers
    {distance: [tip, target]}                 # between two frames (site, geom or body), m
    {distance: [tip, target], axes: [x, y]}   # ... along some world axes only
    {from: tip, to: target}                   # target minus tip, a world-frame 3-vector

A frame is named bare (``tip``) or with its kind (``site:tip``, ``geom:target``,
``body:torso``) where two kinds share the name. Sources: :data:`robots.mjcf_robot.SOURCES`.
Every term reads the robot by name.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Any, Mapping

import numpy as np
from dm_control.utils import rewards

from params import ConfigError, finite, require
from robots.mjcf_robot import SOURCES, MjcfRobot, Reader
from robots.physics import BatchedPhysics

AXES = {"x": 0, "y": 1, "z": 2}
APPLY = {"sin": np.sin, "cos": np.cos, "abs": np.abs, "square": np.square,
         "log1p": lambda x: np.sign(x) * np.log1p(np.abs(x))}  # dm_control's touch scaling, sign kept
_PICKS = ("axis", "index", "apply")
_RELATIVE = ("distance", "from", "to", "axes")  # a term between two frames
_BOUNDED = ("quat", "zaxis")  # sources whose every entry lies in [-1, 1]
REDUCE = ("max", "min", "last", "sum", "mean")


@dataclass
class Relative:
    """``to``'s position minus ``from``'s (a world-frame 3-vector), or with ``norm`` its length
    over ``axes``: a term between two frames, read from two frame sensors."""

    start: Reader
    end: Reader
    norm: bool = False
    axes: tuple[int, ...] = (0, 1, 2)

    @property
    def source(self) -> str:
        return "distance" if self.norm else "difference"

    @property
    def size(self) -> int:
        return 1 if self.norm else 3

    def read(self, physics: BatchedPhysics) -> np.ndarray:
        gap = self.end.read(physics) - self.start.read(physics)
        if not self.norm:
            return gap
        return np.linalg.norm(gap[:, list(self.axes)], axis=1, keepdims=True)


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
            f"optionally axis (x, y, z), index and apply ({', '.join(APPLY)}); or distance: "
            f"[frame, frame] (optionally axes), or from: frame and to: frame")
    spec = _mapping(spec, where, what)
    if any(k in spec for k in _RELATIVE):
        reader = _relative(robot, spec, where)
    else:
        sources = [k for k in spec if k in SOURCES]
        other = sorted(set(spec) - set(SOURCES) - set(_PICKS))
        require(len(sources) == 1 and not other, f"{where} must be {what}", dict(spec))
        reader = robot.reader(sources[0], spec[sources[0]], where)
    pick = _pick(spec, reader.size, where)
    apply = spec.get("apply")
    require(apply is None or apply in APPLY, f"{where}.apply must be one of {', '.join(APPLY)}",
            apply)
    return Term(name, reader, pick, apply)


def _relative(robot: MjcfRobot, spec: Mapping, where: str) -> Relative:
    """The reader of ``distance: [a, b]`` (``axes``), or of ``from: a`` and ``to: b``."""
    if "distance" in spec:
        pair = spec["distance"]
        require(isinstance(pair, (list, tuple)) and len(pair) == 2 and not set(spec) - {"distance", "axes", "apply"},
                f"{where} must be {{distance: [frame, frame]}} with optionally axes: [x, y, z]", dict(spec))
        axes = spec.get("axes", ["x", "y", "z"])
        require(isinstance(axes, (list, tuple)) and len(axes) > 0 and all(a in AXES for a in axes)
                and len(set(axes)) == len(axes), f"{where}.axes must be a list of x, y and z", axes)
        start, end = (robot.frame_reader("pos", f, f"{where}.distance") for f in pair)
        return Relative(start, end, norm=True, axes=tuple(AXES[a] for a in axes))
    require({"from", "to"} <= set(spec) and not set(spec) - {"from", "to", *_PICKS},
            f"{where} must be {{from: frame, to: frame}} with optionally axis, index, apply", dict(spec))
    return Relative(robot.frame_reader("pos", spec["from"], f"{where}.from"),
                    robot.frame_reader("pos", spec["to"], f"{where}.to"))


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
SIGMOIDS = ("gaussian", "hyperbolic", "long_tail", "reciprocal", "cosine", "linear", "quadratic",
            "tanh_squared")  # dm_control.utils.rewards.tolerance's
TOLERANCE_KEYS = ("bounds", "margin", "sigmoid", "value_at_margin")


@dataclass
class RewardTerm:
    """``weight * value`` per step: ``alive`` (1), ``action_cost`` (the sum of the squared
    commands), or a one-number term (its distance to ``target`` if given; or, with
    ``tolerance``, dm_control's shaping of it: 1 inside ``bounds``, falling off over ``margin``
    as ``sigmoid`` says)."""

    name: str
    weight: float
    kind: str
    term: Term | None = None
    target: float | None = None
    kernel: str = "abs"
    tolerance: dict | None = None

    def value(self, physics: BatchedPhysics, command: np.ndarray) -> np.ndarray:
        if self.kind == "alive":
            return np.ones(physics.num_envs)
        if self.kind == "action_cost":
            return np.square(command).sum(axis=1)
        value = self.term.value(physics)[:, 0]
        if self.tolerance is not None:
            return rewards.tolerance(value, **self.tolerance)
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
    kernel, tolerance = spec.pop("kernel", "abs"), spec.pop("tolerance", None)
    if tolerance is not None:
        require(target is None, f"{where} takes target or tolerance, not both", target)
        tolerance = _tolerance(tolerance, f"{where}.tolerance")
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
    return RewardTerm(name, float(weight), "term", term, target, kernel, tolerance)


def _tolerance(spec: Any, where: str) -> dict:
    """dm_control's ``tolerance`` arguments: ``bounds`` [low, high] (.inf for none), ``margin``
    (0: a step), ``sigmoid`` and ``value_at_margin``."""
    spec = dict(_mapping(spec, where, "{bounds: [low, high], margin, sigmoid, value_at_margin}"))
    require(set(spec) <= set(TOLERANCE_KEYS) and "bounds" in spec,
            f"{where} must be {{bounds: [low, high], margin, sigmoid, value_at_margin}}", spec)
    low_high = spec["bounds"]
    require(isinstance(low_high, (list, tuple)) and len(low_high) == 2
            and all(isinstance(v, (int, float)) and not isinstance(v, bool) and not np.isnan(v) for v in low_high)
            and low_high[0] <= low_high[1], f"{where}.bounds must be [low, high] with low <= high", low_high)
    margin = spec.get("margin", 0.0)
    require(finite(margin) and margin >= 0, f"{where}.margin must be a number >= 0", margin)
    sigmoid = spec.get("sigmoid", "gaussian")
    require(sigmoid in SIGMOIDS, f"{where}.sigmoid must be one of {', '.join(SIGMOIDS)}", sigmoid)
    at_margin = spec.get("value_at_margin", 0.1)
    require(finite(at_margin) and 0 < at_margin < 1, f"{where}.value_at_margin must be in (0, 1)", at_margin)
    return {"bounds": (float(low_high[0]), float(low_high[1])), "margin": float(margin), "sigmoid": sigmoid,
            "value_at_margin": float(at_margin)}


# -- actions -----------------------------------------------------------------------
ACTIONS_SHAPE = ("{values: {actuator: [values], ...}} or {actuators: [names], commands: [[values], ...]} "
                 "(the discrete set), optionally with continuous: [actuators] or {actuator: [low, high]} "
                 "(the continuous form); or continuous alone")


@dataclass
class ActionSet:
    """A declared task's actions: the actuators they drive (``columns``, indices in the model's
    order), one row of commands per discrete action (``commands``, ``[n_actions, columns]``;
    none: ``[0, columns]``) and the continuous form (``continuous``: for each of its
    actuators its column's place in ``columns`` and its ``[low, high]``; None: no such form)."""

    columns: np.ndarray
    commands: np.ndarray
    continuous: tuple[np.ndarray, dict[str, tuple[float, float]]] | None


def action_set(robot: MjcfRobot, spec: Any) -> ActionSet:
    """The :class:`ActionSet` of ``task.actions``: ``{actuators: [a, b], commands: [[..], [..]]}``
    or ``{values: {a: [..], b: [..]}}`` (every combination of the per-actuator values), with
    optionally ``continuous``: actuator names (each ranging over the model's control range) or
    ``{name: [low, high]}``. Without ``continuous``, the discrete set's actuators are the
    continuous form too, each over the model's control range where it has one, else over its
    discrete values' span."""
    spec = _mapping(spec, "task.actions", ACTIONS_SHAPE)
    kinds = set(spec) - {"continuous"}
    require(kinds in ({"values"}, {"actuators", "commands"}, set()) and (kinds or "continuous" in spec),
            f"task.actions must be {ACTIONS_SHAPE}", sorted(spec))
    names, rows = [], []
    if "values" in spec:
        values = _mapping(spec["values"], "task.actions.values",
                          "a mapping of actuator names to lists of commands")
        names = list(values)
        rows = [list(r) for r in itertools.product(*(list(values[n] or []) for n in names))]
    elif kinds:
        names, rows = list(spec["actuators"] or []), [list(r) for r in (spec["commands"] or [])]
    if kinds:
        require(len(names) > 0, "task.actions must name at least one actuator", names)
        require(len(rows) > 0, "task.actions must hold at least one action (an empty action set)", rows)
        for row in rows:
            require(len(row) == len(names) and all(finite(v) for v in row), f"task.actions: each "
                    f"action must be {len(names)} finite numbers, one per actuator {names}", row)
    ranges = _continuous(robot, spec.get("continuous"), names, rows)
    every = list(dict.fromkeys([*names, *(ranges or {})]))
    columns = np.asarray([robot.actuator_column(n, "task.actions") for n in every], dtype=np.int64)
    commands = np.zeros((len(rows), len(every)))
    if rows:
        commands[:, :len(names)] = np.asarray(rows, dtype=np.float64)
    continuous = None if ranges is None else (np.asarray([every.index(n) for n in ranges], dtype=np.int64), ranges)
    return ActionSet(columns, commands, continuous)


def _continuous(robot: MjcfRobot, spec: Any, names: list[str], rows: list[list[float]]
                ) -> dict[str, tuple[float, float]] | None:
    """``{actuator: (low, high)}`` of the continuous form (None: none can be made)."""
    where = "task.actions.continuous"
    ranges = robot.control_ranges()
    if spec is None:  # the discrete set's actuators: the model's range, else the values' span
        found = {}
        for i, name in enumerate(names):
            span = (min(r[i] for r in rows), max(r[i] for r in rows))
            found[name] = ranges.get(name, span)
        return found if all(low < high for low, high in found.values()) else None
    if isinstance(spec, Mapping):
        found = {}
        for name, pair in spec.items():
            robot.actuator_column(str(name), where)
            require(isinstance(pair, (list, tuple)) and len(pair) == 2 and all(finite(v) for v in pair)
                    and pair[0] < pair[1], f"{where}.{name} must be [low, high], two finite numbers with "
                    "low < high", pair)
            found[str(name)] = (float(pair[0]), float(pair[1]))
    else:
        require(isinstance(spec, (list, tuple)) and all(isinstance(n, str) for n in spec),
                f"{where} must list actuator names or map them to [low, high]", spec)
        found = {}
        for name in spec:
            robot.actuator_column(name, where)  # one line for a name the model lacks
            require(name in ranges, f"{where}: actuator {name!r} has no control range in the model; "
                    f"give one: continuous: {{{name}: [low, high]}}", name)
            found[name] = ranges[name]
    require(len(found) > 0, f"{where} must name at least one actuator", spec)
    return found


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
    """What an episode achieved, from a one-number term over a window of steps (the whole
    episode, or its last ``window`` steps): reduced (``max``, ``min``, ``last``, ``sum``,
    ``mean``), then, with ``above`` or ``below``, 1 if that passed it and 0 if not; or, with
    ``held``, 1 if the term passed ``above`` / ``below`` on at least that fraction of the
    window's steps (steps an episode ended before count as not held)."""

    name: str
    term: Term
    reduce: str
    unit: str
    description: str
    above: float | None = None
    below: float | None = None
    window: int | None = None
    held: float | None = None

    def passes(self, value: np.ndarray) -> np.ndarray:
        """Whether ``value`` passes the measure's bound (above: >=, below: <=)."""
        return value >= self.above if self.above is not None else value <= self.below

    def judged(self, value: np.ndarray) -> np.ndarray:
        """The reduced value, or 1 / 0 for one that passes / fails the bound."""
        if self.above is None and self.below is None:
            return value
        return self.passes(value).astype(np.float64)


MEASURE_KEYS = ("term", "reduce", "unit", "description", "above", "below", "last", "seconds", "held")


def measures(spec: Any, terms: Mapping[str, Term], running_step: float = 1.0) -> dict[str, Measure]:
    """``task.measures``: ``name -> {term, reduce, unit, description, above or below, last (steps)
    or seconds, held}``; ``seconds`` count in ``running_step``s."""
    shape = "{term, reduce, unit, description, above or below, last or seconds, held}"
    spec = _mapping(spec or {}, "task.measures", f"a mapping of names to {shape}")
    out = {}
    for name, m in spec.items():
        where = f"task.measures.{name}"
        m = _mapping(m, where, shape)
        require(set(m) <= set(MEASURE_KEYS) and "term" in m, f"{where} must be {shape}", dict(m))
        require(m["term"] in terms and terms[m["term"]].size == 1, f"{where}.term must be a "
                f"one-number declared term: {', '.join(terms)}", m["term"])
        require(m.get("reduce", "max") in REDUCE, f"{where}.reduce must be one of "
                f"{', '.join(REDUCE)}", m.get("reduce"))
        for bound in ("above", "below"):
            require(m.get(bound) is None or finite(m[bound]), f"{where}.{bound} must be a number", m.get(bound))
        require(m.get("above") is None or m.get("below") is None, f"{where} takes above or below, not both",
                dict(m))
        out[str(name)] = Measure(str(name), terms[m["term"]], m.get("reduce", "max"), str(m.get("unit", "")),
                                 str(m.get("description", name)), m.get("above"), m.get("below"),
                                 _window(m, where, running_step), _held(m, where))
    return out


def _window(m: Mapping, where: str, running_step: float) -> int | None:
    """The window in steps: ``last: N`` or ``seconds: T`` (None: the whole episode)."""
    require(not ("last" in m and "seconds" in m), f"{where} takes last (steps) or seconds, not both", dict(m))
    if "last" in m:
        last = m["last"]
        require(isinstance(last, int) and not isinstance(last, bool) and 1 <= last <= 10**6,
                f"{where}.last must be a whole number of steps in [1, 1000000]", last)
        return last
    if "seconds" in m:
        require(finite(m["seconds"]) and m["seconds"] > 0, f"{where}.seconds must be a number > 0", m["seconds"])
        return max(1, round(float(m["seconds"]) / running_step))
    return None


def _held(m: Mapping, where: str) -> float | None:
    """The fraction of the window a bound must hold on (None: the window is reduced instead)."""
    if "held" not in m:
        return None
    require(finite(m["held"]) and 0 < m["held"] <= 1, f"{where}.held must be a fraction in (0, 1]", m["held"])
    require(m.get("above") is not None or m.get("below") is not None, f"{where}.held needs above or below "
            "(what must hold)", dict(m))
    require("reduce" not in m, f"{where} takes reduce or held, not both (held counts the steps that pass)",
            dict(m))
    return float(m["held"])
