"""The learner contract: one learning algorithm over a leading *member* axis.

A member is one independent learning run: a seed of a seed batch, or the one seed of a
single run (a batch of one). A learner is a dataclass made from its config node
(``conf/learner/<name>.yaml``, its parameters checked in ``__post_init__``); everything
it learns is held for all its members at once (a Q-table ``[members, states, actions]``,
a network's parameters ``[members, ...]``), and each call serves every member:

1. ``build(task, generators, variants)``: sizes the table or networks from the task, one
   member per generator (each member's own random stream: its exploration, its minibatch
   draws); ``variants``, where given, is each member's own learner made from its config
   (a tuning trial's): they may differ in the learner's ``MEMBER_WISE`` settings only
   (learning rates, discount, exploration, ...: what keeps every shape), which each member
   then takes from its own (:func:`member_settings`);
2. ``act(td, live)``: every member's actions on its block of rows (block ``b`` is rows
   ``b * n`` to ``(b + 1) * n``), the members of ``live`` drawing from their streams;
3. ``observe(td, live)``: each live member learns from its block of the transitions;
4. ``end_episodes(ended)``: per member, how many of its episodes the step finished
   (epsilon schedules, per-episode updates);
5. per member ``b``: ``stats(b)``, ``train_stats(b)``, ``model_state(b)`` (what
   ``model.pt`` holds) and ``training_state(b)`` (all the next update depends on), with the
   matching ``load_*`` raising :class:`StateMismatch` for a state of another shape, and
   ``act_members`` for the greedy policy of some members.

:meth:`member` gives member ``b`` seen alone (:class:`Member`): what a run's files, its
evaluations and its video read. A learner knows nothing of folders, files or consoles,
and never drives the training loop (:mod:`runs.loop` does).
"""

from __future__ import annotations

import dataclasses
from contextlib import contextmanager
from typing import Any, Iterator, Mapping, Protocol, Sequence, runtime_checkable

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from params import ConfigError


class StateMismatch(ValueError):
    """A saved learner state that does not fit this learner (another shape or format)."""


def check_state(saved: Any, mine: Mapping, where: str, deep: Sequence[str] = ()) -> None:
    """Raises :class:`StateMismatch` naming the first way ``saved`` differs from this
    learner's own state ``mine``: a key it lacks, or, under the keys ``deep``, a tensor of
    another shape or dtype (or not a tensor). Nothing is loaded before it passes."""

    def differ(what: str) -> StateMismatch:
        return StateMismatch(f"checkpoint {where} does not fit this run: {what}")

    def walk(s: Any, m: Any, path: str) -> None:
        if isinstance(m, Mapping):
            if not isinstance(s, Mapping):
                raise differ(f"{path or 'its state'} is a {type(s).__name__}, not a mapping")
            missing = [str(k) for k in m if k not in s]
            if missing:
                raise differ(f"it lacks {', '.join(path + k for k in missing[:3])}")
            for key in m:
                if not path and key not in deep:
                    continue
                walk(s[key], m[key], f"{path}{key}.")
        elif isinstance(m, torch.Tensor):
            name = path.rstrip(".")
            if not isinstance(s, torch.Tensor):
                raise differ(f"{name} is a {type(s).__name__}, not a tensor")
            if s.shape != m.shape or s.dtype != m.dtype:
                raise differ(f"{name} is {s.dtype} {list(s.shape)}, this run's is {m.dtype} {list(m.shape)}")

    walk(saved, mine, "")


def member_settings(learner: Any, variants: Sequence[Any] | None, members: int) -> list[Any]:
    """Each member's settings: ``variants`` (one learner of ``learner``'s class per member,
    unbuilt) or ``learner`` itself for every member. One line naming the first setting
    outside ``learner.MEMBER_WISE`` in which a variant differs (those change shapes or what
    the learner builds: such members cannot share it)."""
    if variants is None:
        return [learner] * members
    variants = list(variants)
    if len(variants) != members:
        raise ValueError(f"{len(variants)} variants for {members} members")
    for variant in variants:
        if type(variant) is not type(learner):
            raise ConfigError(f"members of one batch must share a learner; got {type(learner).__name__} "
                              f"and {type(variant).__name__}")
        for field in dataclasses.fields(learner):
            if field.name not in learner.MEMBER_WISE and getattr(variant, field.name) != getattr(learner, field.name):
                raise ConfigError(
                    f"learner.{field.name} differs between members ({getattr(learner, field.name)!r}, "
                    f"{getattr(variant, field.name)!r}): only {', '.join(learner.MEMBER_WISE)} may differ in one batch")
    return variants


def per_member(values: Sequence[float], dtype: torch.dtype, device: Any = "cpu") -> float | torch.Tensor:
    """One value per member: the value itself where every member has the same (the
    arithmetic of a learner alone), else a ``[members, 1]`` tensor to scale each member's
    rows."""
    first = values[0]
    if all(v == first for v in values):
        return first
    return torch.tensor([[float(v)] for v in values], dtype=dtype, device=device)


@runtime_checkable
class Learner(Protocol):
    """A learning algorithm over a member axis, as the run package uses it."""

    kind: str  # the learner family a saved state belongs to ("qlearn", "dqn")
    MEMBER_WISE: tuple[str, ...]  # settings members of one batch may differ in
    members: int  # set by build

    def build(self, task, generators: Sequence[torch.Generator], variants: Sequence[Any] | None = None) -> None: ...

    def begin(self) -> None: ...

    def act(self, td: TensorDictBase, live: Sequence[int] | None = None) -> TensorDictBase: ...

    def act_members(self, td: TensorDictBase, members: Sequence[int] | None, greedy: bool,
                    generators: Sequence[torch.Generator | None]) -> TensorDictBase: ...

    def observe(self, td: TensorDictBase, live: Sequence[int] | None = None) -> None: ...

    def end_episodes(self, ended: Mapping[int, int]) -> None: ...

    def stats(self, b: int) -> dict[str, float]: ...

    def train_stats(self, b: int, reset: bool = True) -> dict[str, float]: ...

    def model_state(self, b: int) -> dict: ...

    def load_model_state(self, b: int, state: Mapping, where: str) -> None: ...

    def training_state(self, b: int) -> dict: ...

    def load_training_state(self, b: int, state: Mapping) -> None: ...

    def member(self, b: int) -> Member: ...


def everyone(learner: Learner, live: Sequence[int] | None) -> list[int]:
    """``live`` as a list, every member when None."""
    return list(range(learner.members)) if live is None else list(live)


def single(generator: torch.Generator | Sequence[torch.Generator] | None) -> list[torch.Generator]:
    """``build``'s generators from one generator, a sequence of them or None (one fresh stream)."""
    if generator is None:
        return [torch.Generator()]
    if isinstance(generator, torch.Generator):
        return [generator]
    return list(generator)


class MemberPolicy(TensorDictModuleBase):
    """A member's policy as a TensorDict module: reads ``observation``, writes ``action`` (and
    what else its learner writes): epsilon-greedy from the member's own stream, or greedy
    inside :meth:`Member.greedy`."""

    in_keys = ["observation"]

    def __init__(self, member: Member) -> None:
        super().__init__()
        self.out_keys = list(member.learner.out_keys)
        self._member = member

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        member = self._member
        greedy = member.greedy_draws is not None
        generator = member.greedy_draws if greedy else member.learner.generators[member.index]
        return member.learner.act_members(tensordict, [member.index], greedy, [generator])


class Member:
    """Member ``index`` of ``learner`` seen alone: its numbers, its policy, its saved states.

    Config values (``lr``, ``gamma``, ...) read through to the learner, a member-wise one
    from the member's own settings.
    """

    def __init__(self, learner: Learner, index: int) -> None:
        self.learner, self.index = learner, int(index)
        # Inside greedy(): the stream that breaks its ties (seeded the same each time, so an
        # evaluation neither draws from training's stream nor varies between two of one policy).
        self.greedy_draws: torch.Generator | None = None
        self.policy = MemberPolicy(self)

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__") or name in ("learner", "index"):
            raise AttributeError(name)
        if name in self.learner.MEMBER_WISE:
            return getattr(self.learner.settings[self.index], name)
        return getattr(self.learner, name)

    @contextmanager
    def greedy(self) -> Iterator[None]:
        """Within the block ``policy`` acts greedily (no exploration)."""
        saved, self.greedy_draws = self.greedy_draws, torch.Generator().manual_seed(0)
        try:
            yield
        finally:
            self.greedy_draws = saved

    @property
    def stats(self) -> dict[str, float]:
        return self.learner.stats(self.index)

    def train_stats(self, reset: bool = True) -> dict[str, float]:
        return self.learner.train_stats(self.index, reset)

    def model_state(self) -> dict:
        return self.learner.model_state(self.index)

    def load_model_state(self, state: Mapping, where: str) -> None:
        self.learner.load_model_state(self.index, state, where)

    def training_state(self) -> dict:
        return self.learner.training_state(self.index)

    def load_training_state(self, state: Mapping) -> None:
        self.learner.load_training_state(self.index, state)
