"""Each parameter declared once: type, default, allowed range and meaning.

A robot, task or learner is a dataclass whose parameter fields are made by
:func:`param`::

    @dataclass(eq=False)
    class CartPole(Robot):
        velocity_gain: float = param(1000.0, "velocity servo gain, N per m/s", gt=0)

From that one line come the constructor's signature (the dataclass's), its
check (:func:`check_fields` in ``__post_init__``), the config validator's check
before anything is built (:func:`check_values`, used by
``runs.settings``), the one-line error message, and the README's
parameter tables (:func:`table`). Checks that relate two parameters, or a
parameter and the robot, stay in the owner's ``__post_init__``.

The declarations of the project's own classes are also kept in ``params/declared.json``
(written by ``python -m readme_tables --write`` with the docs' tables, from the classes
themselves; a test keeps it current): :func:`declared` reads a class's there, without
importing it (its module imports torch or MuJoCo: seconds), so a refused value answers at
once. An entry whose source files changed since is not used: the class is imported.
"""

from __future__ import annotations

import copy
import dataclasses
import hashlib
import inspect
import json
import math
import sys
import types
import typing
from collections.abc import Mapping as AbcMapping, Sequence as AbcSequence
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import Any

from params import ConfigError, did_you_mean

_META = "param"
REQUIRED = dataclasses.MISSING


@dataclass(frozen=True)
class Range:
    """Bounds on a number (``gt``/``ge``/``lt``/``le``) or the allowed ``choices``."""

    gt: float | None = None
    ge: float | None = None
    lt: float | None = None
    le: float | None = None
    choices: tuple | None = None

    def holds(self, value: Any) -> bool:
        """Whether ``value`` (each entry of a list, each value of a mapping) lies in range."""
        if isinstance(value, (list, tuple)):
            return all(self.holds(v) for v in value)
        if isinstance(value, dict):
            return all(self.holds(v) for v in value.values())
        if self.choices is not None:
            return not isinstance(value, bool) and value in self.choices
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            return True  # not a number: the type check's business
        return ((self.gt is None or value > self.gt) and (self.ge is None or value >= self.ge)
                and (self.lt is None or value < self.lt) and (self.le is None or value <= self.le))

    def describe(self) -> str:
        """``"> 0"``, ``"in (0, 1]"``, ``"one of a, b"`` or ``""``."""
        if self.choices is not None:
            return "one of " + ", ".join(map(str, self.choices))
        low = (self.gt, "(") if self.gt is not None else (self.ge, "[")
        high = (self.lt, ")") if self.lt is not None else (self.le, "]")
        if low[0] is not None and high[0] is not None:
            return f"in {low[1]}{_num(low[0])}, {_num(high[0])}{high[1]}"
        if low[0] is not None:
            return f"{'>' if low[1] == '(' else '>='} {_num(low[0])}"
        if high[0] is not None:
            return f"{'<' if high[1] == ')' else '<='} {_num(high[0])}"
        return ""


def _num(value: float) -> str:
    return f"{value:.6g}" if isinstance(value, float) else str(value)


def param(default: Any, doc: str, *, gt: float | None = None, ge: float | None = None,
          lt: float | None = None, le: float | None = None, choices: tuple | None = None,
          note: str = "", check: typing.Callable[[Any], None] | None = None) -> Any:
    """A dataclass field declaring one parameter; ``default=REQUIRED`` for none.

    ``doc`` is its one-line meaning; ``note`` words the allowed range where
    that says more (``"0 = unlimited"``) and is shown after it. ``check(value)``, where
    a range cannot say what is allowed (a device that must exist here), raises
    :class:`ConfigError` after the type and range checks pass.
    """
    meta = {_META: (doc, Range(gt, ge, lt, le, tuple(choices) if choices else None), note, check)}
    if isinstance(default, (list, dict)):
        return dataclasses.field(default_factory=partial(copy.deepcopy, default), metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


@dataclass(frozen=True)
class Spec:
    """One declared parameter, read back from its owner's dataclass fields."""

    name: str
    hint: Any
    default: Any
    doc: str
    range: Range
    note: str = ""
    extra: typing.Callable[[Any], None] | None = None

    @property
    def required(self) -> bool:
        return self.default is REQUIRED

    def allowed(self) -> str:
        """What the value must be, in words: ``"a finite number > 0 (0 = unlimited)"``."""
        if self.range.choices is not None:
            words = self.range.describe()
        else:
            words = " ".join(w for w in (describe(self.hint), self.range.describe()) if w)
        return f"{words} ({self.note})" if self.note else words

    def check(self, value: Any, prefix: str) -> Any:
        """``value`` as the owner keeps it (an int as int, a float as float), or
        :class:`ConfigError` ``"<prefix>.<name> must be <allowed>; got <value>"``."""
        full = key_of(prefix, self.name)
        bad = mismatch(value, self.hint, full)
        if bad is not None:
            key, hint, got = bad
            if key != full:  # an entry of a mapping
                raise ConfigError(f"{key} must be {describe(hint)}; got {got!r}")
        if bad is None and isinstance(value, (list, tuple, dict)) and not self.range.holds(value):
            key, entry = self._first_out_of_range(value, full)  # an entry of a list or mapping
            raise ConfigError(f"{key} must be {describe(_entry_hint(self.hint))} {self.range.describe()}; "
                              f"got {entry!r}".replace("  ", " "))
        if bad is not None or not self.range.holds(value):
            raise ConfigError(f"{full} must be {self.allowed()}; got {value!r}")
        if isinstance(value, float) and value != 0 and abs(value) < sys.float_info.min:
            raise ConfigError(f"{full} must be {self.allowed()}; got {value!r}, below the smallest normal "
                              f"number ({sys.float_info.min:.3g}), which training's arithmetic takes for 0")
        if self.extra is not None:
            self.extra(value)
        if self.hint is float or (self.hint == (float | None) and value is not None):
            return float(value)
        if self.hint is int:
            return int(value)
        return value


    def _first_out_of_range(self, value: Any, full: str) -> tuple[str, Any]:
        """The key (``task.x.name``, ``task.x[2]``) and value of the first entry out of range."""
        items = value.items() if isinstance(value, dict) else enumerate(value)
        for key, entry in items:
            if not self.range.holds(entry):
                return (f"{full}.{key}" if isinstance(value, dict) else f"{full}[{key}]"), entry
        return full, value


def _entry_hint(hint: Any) -> Any:
    """The type of one entry of a list or mapping type (``int`` for ``int | list[int]``)."""
    for member in _union_args(hint) or (hint,):
        args = typing.get_args(member)
        if args:
            return args[-1]
    return hint


def key_of(prefix: str, name: str) -> str:
    """``"task.pos_step"``; just ``"seed"`` at the top level (``prefix`` empty)."""
    return f"{prefix}.{name}" if prefix else name


def specs(cls: type) -> tuple[Spec, ...]:
    """The declared parameters of ``cls`` (a dataclass), in declaration order."""
    hints = typing.get_type_hints(cls)
    out = []
    for f in dataclasses.fields(cls):
        if _META in f.metadata:
            doc, rng, note, extra = f.metadata[_META]
            default = f.default if f.default_factory is REQUIRED else f.default_factory()
            out.append(Spec(f.name, hints.get(f.name, Any), default, doc, rng, note, extra))
    return tuple(out)


def check_fields(obj: Any, prefix: str) -> None:
    """Checks every declared field of ``obj`` and stores it in its declared type."""
    for spec in specs(type(obj)):
        setattr(obj, spec.name, spec.check(getattr(obj, spec.name), prefix))


def check_values(cls: type | str, values: typing.Mapping[str, Any], prefix: str,
                 nested: typing.Callable[[dict, str], None] | None = None,
                 declared_specs: tuple[Spec, ...] | None = None) -> None:
    """Checks config ``values`` for ``cls`` before it is built: names, types, ranges.

    ``cls`` may be the class's dotted path with its ``declared_specs`` (:func:`declared`).
    A value that is itself a config node (a dict with ``_target_``) goes to
    ``nested(node, key)``.
    """
    path = cls if isinstance(cls, str) else f"{cls.__module__}.{cls.__name__}"
    declared = {s.name: s for s in (specs(cls) if declared_specs is None else declared_specs)}
    for key, value in values.items():
        if key not in declared:
            hint = did_you_mean(key, tuple(declared), key_of(prefix, ""))
            raise ConfigError(f"{key_of(prefix, key)} is not a parameter of {path}; {hint}allowed: "
                              f"{', '.join(declared)}; got {key_of(prefix, key)}={value!r}")
    for name, spec in declared.items():
        if name not in values:
            if spec.required:
                raise ConfigError(f"{key_of(prefix, name)} is missing; {path.rpartition('.')[2]} needs it")
            continue
        value = values[name]
        if isinstance(value, dict) and "_target_" in value and nested is not None:
            nested(value, key_of(prefix, name))
        else:
            spec.check(value, prefix)


def table(cls: type) -> str:
    """A Markdown table of ``cls``'s parameters: name, default, allowed, meaning."""
    rows = ["| parameter | default | allowed | meaning |", "| --- | --- | --- | --- |"]
    for s in specs(cls):
        default = "(required)" if s.required else _show(s.default)
        cells = (f"`{s.name}`", default, s.allowed(), s.doc)
        rows.append("| " + " | ".join(c.replace("|", "\\|") for c in cells) + " |")
    return "\n".join(rows)


def _show(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_show(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_show(v) for v in value) + "]"
    if isinstance(value, float):
        return f"{value:.6g}"
    return f"`{value!r}`" if isinstance(value, str) else str(value)


# -- types ----------------------------------------------------------------------
def is_integer(value: Any) -> bool:
    """An int, or a float with a whole value (``1e5`` on the command line); not a bool."""
    if isinstance(value, bool):
        return False
    if isinstance(value, int):
        return True
    return isinstance(value, float) and math.isfinite(value) and value.is_integer()


def _union_args(hint: Any) -> tuple | None:
    if typing.get_origin(hint) in (typing.Union, types.UnionType):
        return typing.get_args(hint)
    return None


def fits(value: Any, hint: Any) -> bool:
    """Whether a config value has the annotated type (a float must be finite)."""
    if hint is Any:
        return True
    members = _union_args(hint)
    if members is not None:
        return any(fits(value, m) for m in members)
    if hint is type(None) or hint is None:
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return is_integer(value)
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if hint is str:
        return isinstance(value, str)
    origin, args = typing.get_origin(hint) or hint, typing.get_args(hint)
    if origin in (list, tuple, AbcSequence):
        return isinstance(value, (list, tuple)) and (not args or all(fits(v, args[0]) for v in value))
    if origin in (dict, AbcMapping):
        return isinstance(value, dict) and (
            len(args) != 2 or all(fits(k, args[0]) and fits(v, args[1]) for k, v in value.items()))
    return not isinstance(origin, type) or isinstance(value, origin)


def mismatch(value: Any, hint: Any, key: str) -> tuple[str, Any, Any] | None:
    """``None`` if ``value`` fits ``hint``; else the innermost (key, hint, value) that does not:
    an entry of a mapping is named by its own key (``task.ring.segments``)."""
    if fits(value, hint):
        return None
    if isinstance(value, dict):
        for member in _union_args(hint) or (hint,):
            args = typing.get_args(member)
            if (typing.get_origin(member) or member) in (dict, AbcMapping) and len(args) == 2:
                for k, v in value.items():
                    if not fits(v, args[1]):
                        return mismatch(v, args[1], f"{key}.{k}")
    return key, hint, value


def describe(hint: Any) -> str:
    """A type in words: ``"a finite number"``, ``"an integer"``, ``"a list of integers"``."""
    members = _union_args(hint)
    if members is not None:
        words = [describe(m) for m in members]
        return ", ".join(words[:-1]) + " or " + words[-1] if len(words) > 1 else words[0]
    plain = {type(None): "null", bool: "true or false", int: "an integer", float: "a finite number",
             str: "a string", Any: ""}
    if hint in plain:
        return plain[hint]
    origin, args = typing.get_origin(hint) or hint, typing.get_args(hint)
    if origin in (list, tuple, AbcSequence):
        return f"a list of {_plural(args[0])}" if args else "a list"
    if origin in (dict, AbcMapping):
        return f"a mapping of names to {_plural(args[1])}" if len(args) == 2 else "a mapping"
    return f"a {getattr(origin, '__name__', origin)}"


def _plural(hint: Any) -> str:
    plain = {int: "integers", float: "finite numbers", str: "strings", bool: "booleans"}
    if hint in plain:
        return plain[hint]
    origin, args = typing.get_origin(hint) or hint, typing.get_args(hint)
    if origin in (list, tuple, AbcSequence) and args:
        return f"lists of {_plural(args[0])}"
    return f"values that are {describe(hint)}"


# -- declarations read without importing their owners ---------------------------
DECLARED = Path(__file__).with_name("declared.json")
ROOT = DECLARED.parents[1]
_HINT_NAMES = {"Any": Any, "Mapping": typing.Mapping, "Sequence": typing.Sequence, "None": None,
               **{t.__name__: t for t in (bool, int, float, str, dict, list, tuple, object)}}
_DECLARED: dict | None = None


def hint_text(hint: Any) -> str:
    """A declared type as the text :func:`declared` reads back (``"Mapping[str, float] | None"``)."""
    members = _union_args(hint)
    if members is not None:
        return " | ".join(hint_text(m) for m in members)
    if hint is Any:
        return "Any"
    if hint is type(None) or hint is None:
        return "None"
    args = typing.get_args(hint)
    if args:
        name = getattr(hint, "_name", None) or typing.get_origin(hint).__name__
        return f"{name}[{', '.join(hint_text(a) for a in args)}]"
    if isinstance(hint, type) and _HINT_NAMES.get(hint.__name__) is hint:
        return hint.__name__
    raise TypeError(f"a declared type params.declared.json cannot hold: {hint!r}")


def _sources(cls: type) -> dict[str, str]:
    """The project's files that declare ``cls``'s fields (its module and its bases'), by
    path from the project's root, with each one's SHA-1."""
    out = {}
    for klass in cls.__mro__:
        try:
            path = Path(inspect.getsourcefile(klass) or "").resolve()
        except TypeError:  # a builtin
            continue
        if path.is_file() and ROOT in path.parents and dataclasses.is_dataclass(klass):
            out[str(path.relative_to(ROOT))] = hashlib.sha1(path.read_bytes()).hexdigest()
    return dict(sorted(out.items()))


def declaration_record(cls: type) -> dict:
    """``cls``'s declarations as ``params/declared.json`` keeps them (a task's also the robot
    class it needs, its ``ROBOT``)."""
    robot = getattr(cls, "ROBOT", None)
    return {"sources": _sources(cls), **({"robot": f"{robot.__module__}.{robot.__qualname__}"} if robot else {}),
            "params": [
        {"name": s.name, "hint": hint_text(s.hint), "default": None if s.required else s.default,
         "required": s.required, "doc": s.doc, "note": s.note, "has_check": s.extra is not None,
         "range": {k: v for k, v in dataclasses.asdict(s.range).items() if v is not None}}
        for s in specs(cls)]}


def _record(path: str) -> dict | None:
    """The record of the class named ``path`` in ``params/declared.json``, or None where it is
    not there or a file it was read from has changed since."""
    global _DECLARED
    if _DECLARED is None:
        try:
            _DECLARED = json.loads(DECLARED.read_text())
        except (OSError, ValueError):
            _DECLARED = {}
    record = _DECLARED.get(path)
    if not isinstance(record, dict):
        return None
    for source, digest in record.get("sources", {}).items():
        try:
            if hashlib.sha1((ROOT / source).read_bytes()).hexdigest() != digest:
                return None
        except OSError:
            return None
    return record


def declared_robot(path: str) -> str | None:
    """The robot class (``robots.turtlebot.TurtleBot``) the task class named ``path`` needs,
    from ``params/declared.json`` without importing it; None where it is not known there."""
    record = _record(path)
    return None if record is None else record.get("robot")


def robot_name(robot: type | str) -> str:
    """A robot class's name on the command line (``robot=<name>``): its module's
    (``robots.turtlebot.TurtleBot``, or the class itself: ``turtlebot``)."""
    path = robot if isinstance(robot, str) else f"{robot.__module__}.{robot.__qualname__}"
    return path.rsplit(".", 2)[-2]


def declared(path: str) -> tuple[Spec, ...] | None:
    """The declared parameters of the class named ``path``, from ``params/declared.json``
    without importing it; None where it is not there, or where a file it was read from has
    changed since (then the class itself is the one to ask). A parameter with its own
    ``check`` (a device that must exist) has it run by the class, imported then, for any
    value but its default."""
    record = _record(path)
    if record is None:
        return None
    out = []
    for p in record["params"]:
        rng = dict(p["range"])
        if "choices" in rng:
            rng["choices"] = tuple(rng["choices"])
        default = REQUIRED if p["required"] else p["default"]
        extra = _owners_check(path, p["name"], default) if p.get("has_check") else None
        out.append(Spec(p["name"], eval(p["hint"], {"__builtins__": {}}, _HINT_NAMES), default,  # noqa: S307
                        p["doc"], Range(**rng), p["note"], extra))
    return tuple(out)


def _owners_check(path: str, name: str, default: Any) -> typing.Callable[[Any], None]:
    """Parameter ``name``'s own ``check``, run by the class ``path`` (imported for it) on any
    value but the default (which the class holds valid)."""
    def check(value: Any) -> None:
        if value == default:
            return
        from params import locate

        for spec in specs(locate(path)):
            if spec.name == name and spec.extra is not None:
                spec.extra(value)
    return check
