"""Saving and loading learner state: atomic writes, one-line errors."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import torch


class CheckpointError(ValueError):
    """A checkpoint that is missing, unreadable, or does not fit the run."""


def save_checkpoint(path: Path | str, payload: dict) -> None:
    """Writes ``payload`` to ``path`` via a temporary file and a rename."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes it private; give it a normal file's mode
        with os.fdopen(fd, "wb") as f:
            torch.save(payload, f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load_checkpoint(path: Path | str, kind: str) -> dict:
    """Reads a checkpoint written by :func:`save_checkpoint` for learner ``kind``."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} does not exist")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many types for a damaged file
        raise CheckpointError(f"checkpoint {path} is not a readable checkpoint ({type(err).__name__})") from None
    if not isinstance(payload, dict) or "kind" not in payload:
        raise CheckpointError(f"checkpoint {path} is not a checkpoint of this toolkit")
    if payload["kind"] != kind:
        raise CheckpointError(
            f"checkpoint {path} holds a {payload['kind']!r} learner, but this run's learner is {kind!r}"
        )
    return payload
