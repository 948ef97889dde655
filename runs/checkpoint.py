"""Saving and loading learner state: atomic, durable writes; checksummed contents; one-line errors.

Every checkpoint is a dict of tensors and plain values (so it loads with
``torch.load(weights_only=True)``) with a ``"kind"`` and a ``"checksum"``:
``"sha256:<hex>"`` of :func:`content_checksum` over every other entry (the
bytes of each tensor, every value, every key). Loading recomputes it, so a
damaged file is refused even where torch would read it (torch's zip reader
does not check its records' CRCs, and a flipped byte in a tensor's data reads
back as a different number). A checkpoint without its checksum is refused (it
cannot be told from a damaged or hand-made one), and so is a model whose
numbers are not all finite (NaN or infinite weights or Q-values).
"""

from __future__ import annotations

import errno
import hashlib
import os
import shutil
import tempfile
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import torch

from learners.base import Learner, StateMismatch
from params import CheckpointError  # noqa: F401 - its home for the readers of checkpoints

CHECKSUM = "checksum"  # the payload entry that holds content_checksum(everything else)


def _feed(h, obj) -> None:
    """Feeds ``obj`` to the hash ``h`` unambiguously: a type tag, a length where needed, the value."""
    if obj is None:
        h.update(b"N")
    elif isinstance(obj, bool):
        h.update(b"T" if obj else b"F")
    elif isinstance(obj, int):
        h.update(b"i%d;" % obj)
    elif isinstance(obj, float):
        h.update(b"f" + obj.hex().encode() + b";")
    elif isinstance(obj, str):
        data = obj.encode("utf-8", "surrogatepass")
        h.update(b"s%d:" % len(data) + data)
    elif isinstance(obj, (bytes, bytearray)):
        h.update(b"b%d:" % len(obj) + bytes(obj))
    elif isinstance(obj, torch.Tensor):
        t = obj.detach().cpu().resolve_conj().resolve_neg().contiguous()
        h.update(f"t{t.dtype}{tuple(t.shape)}:".encode())
        h.update(t.reshape(-1).view(torch.uint8).numpy())
    elif isinstance(obj, np.ndarray):
        a = np.ascontiguousarray(obj)
        h.update(f"a{a.dtype.str}{a.shape}:".encode())
        h.update(a.reshape(-1).view(np.uint8))
    elif isinstance(obj, Mapping):
        h.update(b"d%d:" % len(obj))
        for key, value in obj.items():
            _feed(h, key)
            _feed(h, value)
    elif isinstance(obj, (list, tuple)):
        h.update(b"%s%d:" % (b"l" if isinstance(obj, list) else b"u", len(obj)))
        for item in obj:
            _feed(h, item)
    else:  # torch.dtype, torch.device, complex, ...: small values whose repr is exact
        h.update(f"o{type(obj).__qualname__}:{obj!r};".encode())


def content_checksum(payload: Mapping) -> str:
    """``"sha256:<hex>"`` of ``payload``'s entries other than ``"checksum"``, as they load back."""
    h = hashlib.sha256()
    _feed(h, {k: v for k, v in payload.items() if k != CHECKSUM})
    return "sha256:" + h.hexdigest()


def _fsync_dir(folder: Path) -> None:
    """Makes a rename in ``folder`` durable (the folder's entry, not only the file's bytes)."""
    if os.name != "posix":  # Windows cannot open a folder; its rename is journaled by NTFS
        return
    fd = os.open(folder, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _failed_write(path: Path, err: RuntimeError) -> OSError:
    """The OSError under torch's ``RuntimeError`` of a write that failed (``unexpected pos``:
    the file is shorter than written): out of space where the disk has no room left."""
    try:
        full = shutil.disk_usage(path.parent).free < (1 << 20)
    except OSError:
        full = False
    code = errno.ENOSPC if full else errno.EIO
    return OSError(code, os.strerror(code), str(path))


def save_checkpoint(path: Path | str, payload: dict) -> None:
    """Writes ``payload`` with its checksum to ``path``: a temporary file, fsynced, renamed
    over ``path``, then the folder fsynced, so a crash leaves the old checkpoint or the new one."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    payload = {**{k: v for k, v in payload.items() if k != CHECKSUM}, CHECKSUM: content_checksum(payload)}
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name + ".", suffix=".tmp")
    try:
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes it private; give it a normal file's mode
        with os.fdopen(fd, "wb") as f:
            try:
                torch.save(payload, f)
            except RuntimeError as err:  # torch's zip writer says a failed write (a full disk) so
                raise _failed_write(path, err) from err
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    _fsync_dir(path.parent)


def load_checkpoint(path: Path | str, kind: str) -> dict:
    """Reads a checkpoint written by :func:`save_checkpoint` for learner ``kind``, checking its
    checksum. Reads only; touches no file."""
    path = Path(path)
    if not path.exists():
        raise CheckpointError(f"checkpoint {path} does not exist")
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} is not a file; allowed: a model.pt or checkpoint.pt "
                              "this toolkit wrote, or a run folder")
    try:
        with warnings.catch_warnings():  # (a TorchScript archive: torch warns before it fails) the line says it
            warnings.simplefilter("ignore")
            payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # torch raises many types for a damaged file
        raise CheckpointError(f"checkpoint {path} cannot be read ({type(err).__name__}: truncated or damaged); "
                              "nothing was changed: restore it from a copy, or start a new run") from None
    if not isinstance(payload, dict) or "kind" not in payload:
        raise CheckpointError(f"checkpoint {path} is not a checkpoint of this toolkit")
    if CHECKSUM not in payload:
        raise CheckpointError(f"checkpoint {path} has no checksum, so its contents cannot be trusted "
                              "(this toolkit writes one into every checkpoint)")
    if payload[CHECKSUM] != content_checksum(payload):
        raise CheckpointError(f"checkpoint {path} is damaged: its contents do not match its checksum")
    if payload["kind"] != kind:
        raise CheckpointError(
            f"checkpoint {path} holds a {payload['kind']!r} learner, but this run's learner is {kind!r}"
        )
    return payload


def save_model(path: Path | str, learner: Learner, meta: dict) -> None:
    """``model.pt``: the learner's :meth:`~learners.base.Learner.model_state` and ``meta``
    (the run's choices and resolved config)."""
    save_checkpoint(path, {**learner.model_state(), "meta": meta})


def non_finite(obj, where: str = "") -> str | None:
    """The key path of the first NaN or infinite number in ``obj`` (tensors, floats, nested
    mappings and lists), or None if every number is finite."""
    if isinstance(obj, torch.Tensor) and (obj.is_floating_point() or obj.is_complex()):
        return where if not bool(torch.isfinite(obj).all()) else None
    if isinstance(obj, float):
        return where if not np.isfinite(obj) else None
    items = obj.items() if isinstance(obj, Mapping) else enumerate(obj) if isinstance(obj, (list, tuple)) else ()
    for key, value in items:
        found = non_finite(value, f"{where}.{key}" if where else str(key))
        if found is not None:
            return found
    return None


def load_model(path: Path | str, learner: Learner) -> None:
    """Loads a ``model.pt`` into the built ``learner``; refused with one line if it is not
    one of this learner's kind, holds a number that is not finite, or does not fit it."""
    payload = load_checkpoint(path, kind=learner.kind)
    bad = non_finite({k: v for k, v in payload.items() if k != "meta"})
    if bad is not None:
        raise CheckpointError(f"checkpoint {path} holds values that are not finite (NaN or infinite) "
                              f"in {bad}: a diverged or damaged model cannot be evaluated or trained on")
    try:
        learner.load_model_state(payload, str(path))
    except StateMismatch as err:
        raise CheckpointError(str(err)) from None
