"""``learner.device``: where a torch learner keeps its networks, updates and replay buffer.

``cpu``, ``cuda`` (torch's current GPU), ``cuda:N`` (GPU N) or ``auto`` (``cuda`` where torch
sees a GPU, else ``cpu``). A GPU this machine does not have is refused in one line when the
config is checked, before anything is built or written.
"""

from __future__ import annotations

import re

import torch

from params import ConfigError

DEVICE_NOTE = "cpu, cuda, cuda:N (GPU N) or auto (cuda where torch sees a GPU, else cpu)"


def check_device(value: str) -> None:
    """Refuses a ``learner.device`` that is not a device name or not on this machine."""
    found = re.fullmatch(r"cpu|auto|cuda(?::(\d+))?", str(value))
    if found is None:
        raise ConfigError(f"learner.device must be {DEVICE_NOTE}; got {value!r}")
    if not str(value).startswith("cuda"):
        return
    if not torch.cuda.is_available():
        raise ConfigError(f"learner.device={value} needs a GPU that torch can use; this torch sees none "
                          "(learner.device=auto uses the cpu here)")
    count = torch.cuda.device_count()
    if found.group(1) is not None and int(found.group(1)) >= count:
        raise ConfigError(f"learner.device={value}: this torch sees {count} GPU(s), cuda:0 to cuda:{count - 1}")


def resolve_device(value: str) -> torch.device:
    """The torch device ``value`` (checked) names; ``auto`` becomes ``cuda`` or ``cpu``."""
    check_device(value)
    if value == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(value)
