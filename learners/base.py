"""The learner contract: one learning algorithm over a leading *member* axis.

A member is one independent learning run: a seed of a seed batch, or the one seed of a
single run (a batch of one). A learner is a dataclass made from its config node
(``conf/learner/<name>.yaml``, its parameters checked in ``__post_init__``), written for
one member over :mod:`learners.member`, which holds every member's table or networks,
streams and bookkeeping. The training loop sees :class:`Learner`: ``build`` (one member
per random stream, each with its own settings where a tuning batch gives them), ``act``
and ``observe`` (every member's block of rows in one call), ``end_episodes`` and
``renew`` (a batch's freed member made anew). Everything of one member (its numbers,
policy, ``model.pt`` and training state, loaded with :class:`StateMismatch` for a state of
another shape) is :meth:`Learner.member`'s :class:`Member`. A learner knows nothing of
folders, files or consoles, and never drives the training loop (:mod:`runs.loop` does).
"""

from __future__ import annotations

import dataclasses
from contextlib import contextmanager
from typing import Any, Hashable, Iterator, Mapping, Protocol, Sequence, runtime_checkable

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from params import ConfigError


class StateMismatch(ValueError):
    """A saved learner state that does not fit this learner (another shape or format)."""


def check_state(saved: Any, mine: Mapping, where: str, deep: Sequence[str] = ()) -> None:
    """Raises :class:`StateMismatch` naming the first way ``saved`` differs from this
    learner's own state ``mine``. Nothing is loaded before it passes.

    Args:
        saved: the state read from a file.
        mine: this learner's own state of the same kind (its ``model_state`` or ``training_state``).
        where: the state's origin, named in the message (``checkpoint <where> does not fit this run``).
        deep: top-level keys whose contents are compared down to each tensor's shape and dtype; under
            the other keys, only their presence is checked.

    Raises:
        StateMismatch: if ``saved`` lacks a key of ``mine`` (below the top level: under the keys ``deep``
            only), or there holds a tensor of another shape or dtype, or something else where ``mine`` has
            a tensor or a mapping.
    """

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
    """Each member's settings: its variant, or ``learner`` itself for every member.

    Args:
        learner: the learner being built.
        variants: one learner of ``learner``'s class per member, unbuilt (a tuning trial's each);
            None: every member takes ``learner``'s settings.
        members: the number of members.

    Returns:
        ``members`` learners, item ``b`` member ``b``'s settings.

    Raises:
        ValueError: if ``variants`` does not hold ``members`` learners.
        ConfigError: if a variant is of another class, or differs from ``learner`` in a setting outside
            ``learner.MEMBER_WISE`` (those change shapes or what the learner builds: such members cannot
            share it); the message names the first such setting.
    """
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
    """One value per member, in the form a learner's arithmetic takes.

    Args:
        values: each member's value, in member order.
        dtype: the tensor's dtype, where one is made.
        device: the tensor's device, where one is made.

    Returns:
        The value itself where every member has the same (the arithmetic of a learner alone),
            else a ``[members, 1]`` tensor to scale each member's rows.
    """
    first = values[0]
    if all(v == first for v in values):
        return first
    return torch.tensor([[float(v)] for v in values], dtype=dtype, device=device)


@runtime_checkable
class Learner(Protocol):
    """A learning algorithm over a member axis, as the training loop sees it: every member's
    act and observe in one call, the end of its episodes, and a member seen alone
    (:meth:`member`: its numbers, policy and saved states, :class:`Member`). A learner is
    written for one member over :mod:`learners.member`, which answers the member-wise calls."""

    kind: str  # the learner family a saved state belongs to ("qlearn", "dqn")
    MEMBER_WISE: tuple[str, ...]  # settings members of one batch may differ in
    SIZING: tuple[str, ...]  # of MEMBER_WISE, those that size a member's training state
    members: int  # set by build

    def build(self, task, generators: Sequence[torch.Generator], variants: Sequence[Any] | None = None) -> None:
        """Sizes the table or networks from ``task``, one member per generator.

        Args:
            task (tasks.base.Task): the task every member learns; its actions and observation set the shapes.
            generators: one random stream per member: its exploration, its minibatch draws.
            variants: each member's own learner made from its config (a tuning trial's), unbuilt; they
                may differ in ``MEMBER_WISE`` settings only (:func:`member_settings`). None: every
                member takes this learner's settings.

        Raises:
            ConfigError: if a variant differs in another setting, or the task does not fit the learner.
        """

    def renew(self, b: int, generator: torch.Generator, variant: Any | None = None) -> None:
        """Member ``b`` made anew, as :meth:`build` makes a member of ``generator`` and
        ``variant``: a batch's freed member given another trial x seed. The other members are
        left as they are.

        Args:
            b: the member's index.
            generator: its new random stream (seeded as a run of its seed seeds it).
            variant: its own learner made from its config, unbuilt, differing from this one in
                ``MEMBER_WISE`` settings only; None: this learner's settings.

        Raises:
            ConfigError: if the variant differs in another setting.
        """

    def begin(self) -> None:
        """Before the first step of a training session (a fresh run or a resumed one)."""

    def phase(self, b: int) -> tuple[Hashable, Hashable] | None:
        """Where member ``b`` is in its cycle of updates: members of one phase make their updates
        at the same steps, in one round. The loop resumes a member after its evaluation in the
        phase of the others where it can (a few steps' wait costs nothing; a round a member
        makes alone costs most of a round of all).

        Args:
            b: the member's index.

        Returns:
            ``(cycle, position)``: members of one cycle (the same updates a step) pass through the
                same positions, those at one position update together; None where its updates do
                not follow its steps (no update yet, per-episode updates, a table's every step).
        """

    def act(self, td: TensorDictBase, live: Sequence[int] | None = None) -> TensorDictBase:
        """Every member's actions on its block of rows, the members of ``live`` drawing from their streams.

        Args:
            td: the env's step input, ``observation`` among its entries, one row per env copy; with ``n``
                copies per member, member ``b``'s block is rows ``b * n`` to ``(b + 1) * n``.
            live: the members still training; the others act without drawing from their streams.
                None: every member.

        Returns:
            A new tensordict of ``td``'s entries and ``action`` (and what else the learner writes).
        """

    def act_members(self, td: TensorDictBase, members: Sequence[int] | None, greedy: bool,
                    generators: Sequence[torch.Generator | None]) -> TensorDictBase:
        """The actions of some members, each on its own block of ``td`` (their greedy evaluations).

        Args:
            td: one block of rows per member acting, in the order of ``members``, ``observation`` among
                its entries.
            members: the members that act (block ``j`` is ``members[j]``'s); None: every member, in order.
            greedy: act greedily (no exploration) rather than exploring.
            generators: block ``j``'s random stream, one per block; None for a block that draws from none.

        Returns:
            A new tensordict of ``td``'s entries and ``action`` (and what else the learner writes).
        """

    def observe(self, td: TensorDictBase, live: Sequence[int] | None = None) -> None:
        """Each live member learns from its block of the step's transitions.

        Args:
            td: the step: what :meth:`act` returned, with the env's ``next`` (``observation``, ``reward``,
                ``terminated``, ``done``) added; blocks as in :meth:`act`.
            live: the members that learn; None: every member.
        """

    def end_episodes(self, ended: Mapping[int, int]) -> None:
        """After a step that finished episodes (epsilon schedules, per-episode updates).

        Args:
            ended: member index mapped to how many of its episodes the step finished; members that
                finished none are left out.
        """

    def member(self, b: int) -> Member:
        """Member ``b`` seen alone: its numbers, its policy, its saved states (:class:`Member`).

        Args:
            b: the member's index.
        """


def everyone(learner: Learner, live: Sequence[int] | None) -> list[int]:
    """``live`` as a list, every member when None.

    Args:
        learner: the learner whose members these are (built).
        live: member indices, or None.

    Returns:
        The member indices.
    """
    return list(range(learner.members)) if live is None else list(live)


def single(generator: torch.Generator | Sequence[torch.Generator] | None) -> list[torch.Generator]:
    """``build``'s generators from what it was given.

    Args:
        generator: one generator, a sequence of them, or None (one fresh stream).

    Returns:
        The generators, one per member.
    """
    if generator is None:
        return [torch.Generator()]
    if isinstance(generator, torch.Generator):
        return [generator]
    return list(generator)


def greedy_stream() -> torch.Generator:
    """The stream that breaks a greedy policy's ties in one evaluation: seeded the same each
    time, so an evaluation neither draws from training's stream nor varies between two of
    one policy."""
    return torch.Generator().manual_seed(0)


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
        """The member's actions on ``tensordict``'s rows.

        Args:
            tensordict: the rows the member acts on, ``observation`` among their entries.

        Returns:
            A new tensordict of ``tensordict``'s entries and the learner's ``out_keys``.
        """
        member = self._member
        greedy = member.greedy_draws is not None
        generator = member.greedy_draws if greedy else member.learner.generators[member.index]
        return member.learner.act_members(tensordict, [member.index], greedy, [generator])


class Member:
    """Member ``index`` of ``learner`` seen alone: its numbers, its policy, its saved states;
    all a run reads of one member. It asks the learner's member-wise calls, which a learner
    answers for one member index ``b``: ``stats(b)``, ``train_stats(b, reset)``, ``advice(b)``,
    ``model_state(b)``, ``load_model_state(b, state, where)``, ``training_state(b)`` and
    ``load_training_state(b, state)``.

    Config values (``lr``, ``gamma``, ...) read through to the learner, a member-wise one
    from the member's own settings.
    """

    def __init__(self, learner: Learner, index: int) -> None:
        self.learner, self.index = learner, int(index)
        # Inside greedy(): the stream that breaks its ties (greedy_stream()).
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
        saved, self.greedy_draws = self.greedy_draws, greedy_stream()
        try:
            yield
        finally:
            self.greedy_draws = saved

    @property
    def stats(self) -> dict[str, float]:
        """The member's numbers recorded with each episode it finishes (:meth:`Learner.stats`)."""
        return self.learner.stats(self.index)

    def advice(self) -> dict[str, str]:
        """What the member's numbers so far say about its settings, a line per subject (a
        value range its returns lie beyond, ...): the run prints each subject once."""
        return self.learner.advice(self.index)

    def train_stats(self, reset: bool = True) -> dict[str, float]:
        """The member's ``train/*`` numbers (:meth:`Learner.train_stats`).

        Args:
            reset: whether reading starts a new interval for the numbers that are means over one.

        Returns:
            Name mapped to value.
        """
        return self.learner.train_stats(self.index, reset)

    def model_state(self) -> dict:
        """The member's trained model, as ``model.pt`` holds it (:meth:`Learner.model_state`).

        Returns:
            Tensors and plain values by name, ``kind`` among them.
        """
        return self.learner.model_state(self.index)

    def load_model_state(self, state: Mapping, where: str) -> None:
        """Loads a saved model into the member (:meth:`Learner.load_model_state`).

        Args:
            state: a :meth:`model_state`, as read from a file.
            where: the state's origin, named in a :class:`StateMismatch`.

        Raises:
            StateMismatch: if the state has another shape or format than the learner's.
        """
        self.learner.load_model_state(self.index, state, where)

    def training_state(self) -> dict:
        """Everything the member's next update depends on (:meth:`Learner.training_state`).

        Returns:
            Tensors and plain values by name.
        """
        return self.learner.training_state(self.index)

    def load_training_state(self, state: Mapping) -> None:
        """Restores the member from a saved training state (:meth:`Learner.load_training_state`).

        Args:
            state: a :meth:`training_state`, as read from the training checkpoint.

        Raises:
            StateMismatch: if the state has another shape or format than the learner's.
        """
        self.learner.load_training_state(self.index, state)
