"""The bottom layer: parameter checks every other layer may use.

``ConfigError`` is the one exception a bad parameter value raises, with a
one-line message ``"<key> must be <allowed>; got <value>"``; :func:`require`
raises it. Declaring parameters (type, default, range, meaning, once) is
:mod:`params.declare`.
"""

from __future__ import annotations

import math
import numbers
from collections.abc import Mapping
from typing import Any


class ConfigError(ValueError):
    """A parameter value a robot, task or learner cannot honour."""


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
