"""The private torch, tensordict, TorchRL and Hydra APIs the project relies on, in one place.

Each is reached only through this module, with why it is used. ``tests/test_private_api.py``
checks every one and fails naming the one an upgrade removed or changed. (This module sits
in the lowest layer, ``params``, so that every package may use it.)

- tensordict ``TensorDict._new_unsafe``: a tensordict of given entries without
  TensorDict's checks. The env makes each step's tensordicts from entries it made itself,
  and the learners add their actions to a step as a *new* tensordict (the step's own stays
  what a run holds for its checkpoint); the checked constructor or ``copy()`` cost many
  times more per step.
- tensordict ``TensorDictBase._set_str``, ``_get_str``, ``_has_names``: the env's one-pass
  step sets and reads entries by a plain string key without the checks of ``set``/``get``.
- TorchRL ``ReplayBuffer._storage``: every path of a ``ReplayBuffer`` (length, sample,
  extend, state) reads its storage through this attribute; :class:`learners.member.
  RowReplayBuffer` makes it a property that first writes the rows it queued.
- TorchRL ``RoundRobinWriter._cursor``: the row a ``ReplayBuffer``'s next write goes to;
  :class:`learners.member.RowReplayBuffer` writes its rows there itself (one ``extend``
  per put cost ~80 us) and reads it after the buffer is emptied or loaded.
- TorchRL ``EnvBase._step_and_maybe_reset``, ``_post_step_mdp_hooks``, ``_step_proc_data``
  and the ``_torchrl_native_autoreset`` flag: the env's one-pass step overrides the method
  and falls back to it whenever one of the others says ``EnvBase``'s own path applies.
- Hydra ``hydra._internal.core_plugins.basic_sweeper.BasicSweeper``: a sweep's job list
  is expanded as Hydra's basic sweeper expands it, and the multirun default
  (``hydra/sweeper=seeds``) is that sweeper, its pass composing every job left to the seeds
  launcher, which composes them itself.
- Hydra ``ConfigLoaderImpl._apply_overrides_to_config`` and ``get_overrides_dirname``
  (``hydra._internal.config_loader_impl``): the step of Hydra's composition that sets a
  job's ``key=value`` overrides on the composed config, and the job's
  ``hydra.job.override_dirname``. A sweep's jobs that differ only in such values are
  composed once and each copy given its own values this way
  (:func:`sweeps.seed_batch.compose_jobs`): Hydra's whole composition took ~0.25 s a job.
- Hydra's file and package config sources read each YAML file with
  ``OmegaConf.load(<open file>)`` (``hydra._internal.core_plugins``), at every composition:
  :func:`configs_parsed_once` serves a text read again from its first parse.
- Hydra ``Hydra.get_mode`` (``hydra._internal.hydra``): before a command's run or sweep,
  Hydra composes the whole config once more only to read ``hydra.mode`` (~0.35 s of a
  refused command's ~0.8 s); :func:`mode_of_the_flag` answers it without composing where
  nothing but the ``-m`` flag can set it.
"""

from __future__ import annotations

import copy
from collections import OrderedDict
from contextlib import contextmanager
from functools import cache
from typing import TYPE_CHECKING, Any, Iterator

if TYPE_CHECKING:  # tensordict (and torch) load at the first tensordict made: compare.py needs neither
    import torch
    from tensordict import TensorDictBase

# TorchRL's names (checked by tests/test_private_api.py).
REPLAY_BUFFER_STORAGE = "_storage"
WRITER_CURSOR = "_cursor"
ENV_BASE_NAMES = ("_step_and_maybe_reset", "_step_proc_data")
ENV_BASE_FLAGS = ("_post_step_mdp_hooks", "_torchrl_native_autoreset")


def new_tensordict(entries: dict[str, Any], batch_size: torch.Size | tuple[int, ...],
                   device: torch.device | None = None) -> TensorDictBase:
    """A tensordict of ``entries`` (each already of ``batch_size`` and on ``device``),
    made without TensorDict's checks."""
    return _tensordict()._new_unsafe(entries, batch_size=batch_size, device=device)


@cache
def _tensordict() -> type:
    from tensordict import TensorDict

    return TensorDict


def with_entries(td: TensorDictBase, **entries: torch.Tensor) -> TensorDictBase:
    """A new tensordict of ``td``'s entries and ``entries`` (``td`` unchanged), unchecked."""
    return new_tensordict({**dict(td.items()), **entries}, td.batch_size, td.device)


def set_entry(td: TensorDictBase, key: str, value: Any) -> None:
    """``td[key] = value`` without checks (``value`` made with ``td``'s shape and device)."""
    td._set_str(key, value, validated=True, inplace=False, non_blocking=False)


def get_entry(td: TensorDictBase, key: str, default: Any = None) -> Any:
    """``td.get(key, default)`` for a plain string key, without the key's parsing."""
    return td._get_str(key, default)


def has_names(td: TensorDictBase) -> bool:
    """Whether ``td``'s dimensions are named."""
    return td._has_names()


def basic_sweeper():
    """Hydra's ``BasicSweeper`` class."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper

    return BasicSweeper


def apply_value_overrides(overrides: list, cfg: Any) -> None:
    """Hydra's own step that sets parsed ``key=value`` ``overrides`` on a composed ``cfg``."""
    from hydra._internal.config_loader_impl import ConfigLoaderImpl

    ConfigLoaderImpl._apply_overrides_to_config(overrides, cfg)


def overrides_dirname(overrides: list, cfg: Any) -> str:
    """``hydra.job.override_dirname`` of a job's parsed (non-hydra) ``overrides``, by
    ``cfg.hydra.job.config.override_dirname``'s settings, as Hydra's composition sets it."""
    from hydra._internal.config_loader_impl import get_overrides_dirname

    settings = cfg.hydra.job.config.override_dirname
    return get_overrides_dirname(overrides=overrides, kv_sep=settings.kv_sep, item_sep=settings.item_sep,
                                 exclude_keys=settings.exclude_keys)


def writer_cursor(buffer: Any) -> int:
    """The storage row a TorchRL ``ReplayBuffer``'s round-robin writer writes next."""
    return int(getattr(buffer._writer, WRITER_CURSOR))


_PARSED: OrderedDict[str, Any] = OrderedDict()  # a YAML text -> its parse (never handed out)
_PARSED_MAX = 512


@contextmanager
def configs_parsed_once() -> Iterator[None]:
    """Within it, a YAML text Hydra's config sources read is parsed once per process: each
    later read of the same text gets a copy of that parse. Hydra re-reads and re-parses
    every file of a composition (its own ``hydra/`` configs and the project's, about 14)
    each time it composes, and a process that composes many configs (a sweep's jobs, the
    benchmark's pairs, the suite's tables of inputs) spent about a third of each
    composition in PyYAML; a copy costs a seventh of a parse. Hydra's file and package
    sources both read with ``OmegaConf.load(<open file>)``, which this replaces for file
    objects (anything else, and any text that does not parse, goes to the original, so
    errors read as before). Nested uses are one."""
    from omegaconf import OmegaConf

    if getattr(OmegaConf.load, "parsed_once", False):
        yield
        return
    saved, original = OmegaConf.__dict__["load"], OmegaConf.load

    def load(file_: Any) -> Any:
        if not hasattr(file_, "read") or not hasattr(file_, "seek"):
            return original(file_)
        start = file_.tell()
        text = file_.read()
        if isinstance(text, bytes):
            text = text.decode("utf-8")
        parsed = _PARSED.get(text)
        if parsed is not None:
            _PARSED.move_to_end(text)  # the least recently read goes first
        else:
            file_.seek(start)
            parsed = _PARSED[text] = original(file_)
            if len(_PARSED) > _PARSED_MAX:
                _PARSED.popitem(last=False)
        return copy.deepcopy(parsed)

    load.parsed_once = True  # type: ignore[attr-defined]
    OmegaConf.load = staticmethod(load)  # type: ignore[method-assign]
    try:
        yield
    finally:
        OmegaConf.load = saved  # type: ignore[method-assign]


@contextmanager
def mode_of_the_flag(own_configs_only: bool) -> Iterator[None]:
    """Within it, Hydra's ``Hydra.get_mode`` answers None (the mode is then ``-m``'s: a
    sweep with it, a run without) without composing, where no config may set
    ``hydra.mode``: ``own_configs_only`` (the project's ``conf/`` alone, which never sets it:
    tests/test_config.py) and no override naming ``hydra.mode`` or ``hydra.searchpath``.
    Otherwise Hydra's own composition answers, as without it."""
    from hydra._internal.hydra import Hydra

    original = Hydra.__dict__["get_mode"]

    def get_mode(self: Any, config_name: Any, overrides: list[str]) -> Any:
        if own_configs_only and not any("hydra.mode" in o or "hydra.searchpath" in o for o in overrides):
            return None
        return original(self, config_name, overrides)

    Hydra.get_mode = get_mode  # type: ignore[method-assign]
    try:
        yield
    finally:
        Hydra.get_mode = original  # type: ignore[method-assign]
