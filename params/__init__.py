"""The bottom layer: parameter checks every other layer may use.

``ConfigError`` is the one exception a bad parameter value raises, with a
one-line message ``"<key> must be <allowed>; got <value>"``; :func:`require`
raises it. Declaring parameters (type, default, range, meaning, once) is
:mod:`params.declare`.
"""

from __future__ import annotations

import importlib
import math
import numbers
from collections.abc import Mapping
from typing import Any


def locate(path: str) -> Any:
    """The object a dotted path names (``package.module.Class``, nested attributes too),
    imported quietly (Hydra's ``get_object`` logs its failures before raising); raises
    ``ImportError`` or ``AttributeError`` when there is none."""
    parts = path.split(".")
    for cut in range(len(parts) - 1, 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ModuleNotFoundError as err:
            if err.name is None or not ".".join(parts[:cut]).startswith(err.name):
                raise  # the module exists but imports a missing one: say so
            continue
        for part in parts[cut:]:
            obj = getattr(obj, part)
        return obj
    raise ImportError(f"no module in {path!r}")


class ConfigError(ValueError):
    """A parameter value a robot, task or learner cannot honour."""


class CheckpointError(ValueError):
    """A checkpoint that is missing, unreadable, damaged, or does not fit the run (here, not
    in :mod:`runs.checkpoint`, so a command refuses one without importing torch)."""


def require(condition: bool, what: str, got: Any) -> None:
    """Raises :class:`ConfigError` ``"<what>; got <got>"`` unless ``condition``."""
    if not condition:
        raise ConfigError(f"{what}; got {got!r}")


def finite(value: Any) -> bool:
    """Whether ``value`` is a real number (not a bool), neither NaN nor infinite."""
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and math.isfinite(value)


def whole(value: Any) -> bool:
    """Whether ``value`` is a finite number with an integer value (``3`` or ``3.0``)."""
    return finite(value) and float(value).is_integer()


def dotted(node: Any, prefix: str = "") -> dict[str, Any]:
    """A nested mapping's leaves by dotted key (``{"a": {"b": 1}}`` -> ``{"a.b": 1}``)."""
    if not isinstance(node, Mapping):
        return {prefix[:-1]: node}
    out: dict[str, Any] = {}
    for key, value in node.items():
        out.update(dotted(value, f"{prefix}{key}."))
    return out


def did_you_mean(word: str, choices: "list[str] | tuple[str, ...]", prefix: str = "") -> str:
    """``"did you mean <prefix><closest>? "`` for a mistyped name, or ``""``."""
    import difflib

    close = difflib.get_close_matches(word, list(choices), n=1, cutoff=0.6)
    return f"did you mean {prefix}{close[0]}? " if close else ""
