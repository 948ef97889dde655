"""Tabular Q-learning over a discretised observation.

State -> index mapping (:class:`Discretizer`): the task names which
observation entries may form the tabular state and the range ``[low, high]``
of each (``task.tabular_state``, read as ``task.tabular_bounds``); the learner's ``number_splits`` says how many
equal bins each gets: one int for all, or a mapping from entry name to bins
(entries it leaves out get 1 bin, i.e. are ignored), or a list in
``tabular_state`` order. Values outside a range fall into the end bins, and
the bins combine mixed-radix, first entry fastest::

    bin_i  = clip(floor((x_i - low_i) / (high_i - low_i) * splits_i), 0, splits_i - 1)
    index  = bin_0 + splits_0 * (bin_1 + splits_1 * (bin_2 + ...))

The Q-tables of all members are the rows of one ``[states, n_actions]`` float64 tensor,
each member's ``prod(splits)`` rows from its start (members may have their own
``number_splits``; a single run: one member); ``table[b]`` is member ``b``'s. Unseen pairs hold
``initial_q`` (0 as in the original; an optimistic value, such as the largest
return there is, makes the learner try every action before trusting one).

Update, for a batch of transitions at once::

    Q(s,a) <- Q(s,a) + alpha * (r + gamma * max_a' Q(s',a') * (1 - terminated) - Q(s,a))

Transitions of one member's block that hit the same (s, a) have their increments
averaged (with ``num_envs=1`` this is the ordinary sequential update); members never
share a pair. Exploration is epsilon-greedy, each member drawing from its own
generator (one call per step); epsilon is multiplied by ``epsilon_discount`` after each
of the member's finished episodes while it is above ``epsilon_min``. A member's policy
(:meth:`QLearn.member`'s ``policy``) is a TensorDict module writing ``state_index``,
``action_value`` and ``action``.

The original learner's quirks are options, off by default:
``first_visit_reward`` (a pair's first update sets Q <- r),
``bootstrap_terminal`` (bootstrap through terminal states) and
``noise_exploration`` (instead of a random action, with probability epsilon
add uniform noise of the Q-values' magnitude and act greedily on the result).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
import torch
from tensordict import TensorDictBase

from learners.base import Member, StateMismatch, check_state, member_settings, per_member, single
from params.private_api import with_entries
from params import require
from params.declare import check_fields, param
from tasks.base import Bounds


TABLE_BYTES = 2 * 2**30  # the largest Q-table a run may allocate
MAX_SPLITS = 2**31 - 1  # bins of one entry (torch's int32 indices); the table's size limits them further


class Discretizer:
    """Maps observations to tabular state indices (see the module docstring)."""

    def __init__(self, bounds: Bounds, splits: int | Sequence[int] | Mapping[str, int]) -> None:
        n = len(bounds.names)
        if isinstance(splits, Mapping):
            unknown = sorted(set(splits) - set(bounds.names))
            require(not unknown, f"learner.number_splits names must be among {list(bounds.names)}",
                    unknown)
            splits = [splits.get(name, 1) for name in bounds.names]
        elif isinstance(splits, (int, np.integer)):
            splits = [splits] * n
        splits = [int(s) for s in splits]
        require(len(splits) == n,
                f"learner.number_splits must be one int or one per tabular_state entry {list(bounds.names)}",
                splits)
        for name, s in zip(bounds.names, splits):
            require(1 <= s <= MAX_SPLITS, f"learner.number_splits.{name} must be an integer in "
                    f"[1, {MAX_SPLITS}] (1 = ignored)", s)
        self.bounds = bounds
        self.splits = splits
        self.n_states = math.prod(splits)  # Python ints: no overflow before the size check
        self._index = torch.as_tensor(bounds.indices)
        self._prefix = tuple(bounds.indices) == tuple(range(len(bounds.indices)))
        self._low = torch.as_tensor(bounds.low)
        self._width = torch.as_tensor(bounds.high - bounds.low)
        self._splits = torch.as_tensor(splits)
        self._top = self._splits - 1
        self._radix = torch.as_tensor(np.concatenate([[1], np.cumprod(splits)[:-1]]).astype(np.int64))

    def __call__(self, observation: torch.Tensor, rows: tuple[torch.Tensor, ...] | None = None) -> torch.Tensor:
        """Each observation's state index; ``rows``: each row's own ``(splits, top, radix)``
        (``[rows, entries]``: members of other bins side by side, :meth:`rows_of`), each row's
        index the one its own discretizer gives."""
        if self._prefix:  # the observation's first entries, in order: a view, no gather
            x = observation[..., : len(self._index)].to(torch.float64, copy=True)
        else:
            x = observation.index_select(-1, self._index).to(torch.float64)
        splits, top, radix = (self._splits, self._top, self._radix) if rows is None else rows
        bins = torch.minimum(x.sub_(self._low).div_(self._width).mul_(splits).floor_().long().clamp_min_(0), top)
        return bins @ radix if rows is None else (bins * radix).sum(-1)

    @staticmethod
    def rows_of(discretizers: Sequence[Discretizer], owner: torch.Tensor) -> tuple[torch.Tensor, ...]:
        """``(splits, top, radix)`` of each row, row ``i`` discretized by
        ``discretizers[owner[i]]`` (all over the same bounds)."""
        return tuple(torch.stack([getattr(d, key) for d in discretizers]).index_select(0, owner)
                     for key in ("_splits", "_top", "_radix"))

    def describe(self) -> dict:
        return {
            "names": list(self.bounds.names),
            "low": self.bounds.low.tolist(),
            "high": self.bounds.high.tolist(),
            "splits": self.splits,
        }


@dataclass(eq=False)
class QLearn:
    """Tabular Q-learning over a member axis (see the module docstring).

    Each member's Q-table is a block of rows of one ``[states, actions]`` tensor; acting,
    the Q update and the epsilon decay are one call for every member."""

    alpha: float = param(0.1, "learning rate of the Q update", gt=0, le=1)
    gamma: float = param(0.7, "discount of the next state's value", ge=0, le=1)
    epsilon: float = param(0.9, "exploration probability at the start", ge=0, le=1)
    epsilon_discount: float = param(0.999, "epsilon is multiplied by it after each episode", gt=0,
                                    le=1)
    epsilon_min: float = param(0.05, "epsilon stops decaying once at or below it", ge=0, le=1)
    number_splits: int | Sequence[int] | Mapping[str, int] = param(
        10, "bins per tabular_state entry: one int, a list, or name: bins (1 = ignored)", ge=1,
        le=MAX_SPLITS)
    first_visit_reward: bool = param(False, "original quirk: a pair's first update sets Q <- r")
    bootstrap_terminal: bool = param(False, "original quirk: bootstrap through terminal states")
    noise_exploration: bool = param(False, "original quirk: explore by noisy Q-values")
    initial_q: float = param(0.0, "Q of unseen pairs (an optimistic value tries every action)")

    kind = "qlearn"
    out_keys = ("state_index", "action_value", "action")
    # Settings members of one batch may differ in (a tuning study's trials side by side); a
    # member's ``number_splits`` sizes its own block of the table.
    MEMBER_WISE = ("alpha", "gamma", "epsilon", "epsilon_discount", "epsilon_min", "initial_q", "number_splits")
    SIZING = ("number_splits",)  # of MEMBER_WISE, those that size a member's training state

    def __post_init__(self) -> None:
        check_fields(self, "learner")
        if isinstance(self.number_splits, Mapping):
            self.number_splits = {str(k): int(v) for k, v in self.number_splits.items()}
        elif isinstance(self.number_splits, (int, float, np.integer)):  # 1e3 on the command line
            self.number_splits = int(self.number_splits)
        else:
            self.number_splits = [int(v) for v in self.number_splits]
        self.members = 0

    # -- building ------------------------------------------------------------
    def build(self, task, generators: torch.Generator | Sequence[torch.Generator] | None = None,
              variants: Sequence[QLearn] | None = None) -> None:
        """The Q-tables of one member per generator (its stream) for ``task``'s tabular state
        and actions; ``variants``: each member's own settings (:data:`MEMBER_WISE`)."""
        self.generators = single(generators)
        self.members = len(self.generators)
        self.settings = member_settings(self, variants, self.members)
        self._bounds, self.n_actions = task.tabular_bounds, int(task.n_actions)
        self._lay_out()
        self.epsilons = [float(own.epsilon) for own in self.settings]

    def renew(self, b: int, generator: torch.Generator, variant: QLearn | None = None) -> None:
        """Member ``b`` made anew from ``generator`` and ``variant`` (None: this learner's
        settings), as :meth:`build` makes a member: a batch's freed member given another trial
        x seed. The other members' tables are kept as they are (the table is laid out again
        where ``variant`` has other bins)."""
        own = self if variant is None else member_settings(self, [variant], 1)[0]
        kept = {i: (self.table[i], self.visited[i]) for i in range(self.members) if i != b}
        self.generators[b], self.settings[b] = generator, own
        self._lay_out(kept)
        self.epsilons[b] = float(own.epsilon)

    def _lay_out(self, kept: Mapping[int, tuple[torch.Tensor, torch.Tensor]] | None = None) -> None:
        """Every member's discretizer and its rows of one table, fresh (at its ``initial_q``,
        unvisited) but the members of ``kept`` (index: their table and visited flags, copied
        in); the members' learning rates and discounts."""
        made: dict[str, Discretizer] = {}  # one per distinct number_splits
        self.discretizers = [made.setdefault(repr(own.number_splits), Discretizer(self._bounds, own.number_splits))
                             for own in self.settings]
        self.discretizer = self.discretizers[0]
        self.n_states = self.discretizer.n_states
        sizes = [d.n_states for d in self.discretizers]
        self._alike = len(made) == 1
        total = sum(sizes)
        largest = max(self.discretizers, key=lambda d: d.n_states)
        table_bytes = largest.n_states * self.n_actions * 9  # float64 values + visited flags
        # A run's table (a member's); a batch's members together: runs.lifecycle's memory check.
        require(table_bytes <= TABLE_BYTES,
                f"learner.number_splits must keep the Q-table within {TABLE_BYTES / 2**30:g} GiB; "
                f"{largest.splits} bins make {largest.n_states} states x {self.n_actions} actions = "
                f"{table_bytes / 2**30:.3g} GiB", largest.splits)
        # Every member's table: its rows of one [states of all members, actions] tensor, from its start.
        self._starts = [sum(sizes[:b]) for b in range(self.members)]
        self._values = torch.full((total, self.n_actions), float(self.initial_q), dtype=torch.float64)
        self._seen = torch.zeros((total, self.n_actions), dtype=torch.bool)
        self.table = [self._values[start:start + size] for start, size in zip(self._starts, sizes)]
        self.visited = [self._seen[start:start + size] for start, size in zip(self._starts, sizes)]
        kept = kept or {}
        for b, own in enumerate(self.settings):
            if b in kept:
                self.table[b].copy_(kept[b][0])
                self.visited[b].copy_(kept[b][1])
            elif own.initial_q != self.initial_q:
                self.table[b].fill_(float(own.initial_q))
        self._alpha = per_member([own.alpha for own in self.settings], torch.float64)
        self._gamma = per_member([own.gamma for own in self.settings], torch.float64)
        self._offsets: torch.Tensor | None = None
        self._rows: tuple[torch.Tensor, ...] | None = None  # every member's rows' bins, kept between steps
        self._draw_buffer: torch.Tensor | None = None

    def _states(self, observation: torch.Tensor, members: Sequence[int] | None, n: int) -> torch.Tensor:
        """The state index of each row of ``observation``, ``n`` rows a member of ``members``
        (None: all), each by its member's own discretizer."""
        if self._alike:
            return self.discretizer(observation)
        if members is None:
            if self._rows is None or len(self._rows[0]) != self.members * n:
                self._rows = Discretizer.rows_of(self.discretizers, torch.arange(self.members).repeat_interleave(n))
            return self.discretizer(observation, self._rows)
        if len(members) == 1:  # a member's own policy (its greedy evaluations): its own bins
            return self.discretizers[members[0]](observation)
        owner = torch.as_tensor(list(members)).repeat_interleave(n)
        return self.discretizer(observation, Discretizer.rows_of(self.discretizers, owner))

    def member(self, b: int) -> Member:
        return Member(self, b)

    def stats(self, b: int) -> dict[str, float]:
        own = self.settings[b]
        return {"alpha": own.alpha, "gamma": own.gamma, "epsilon": self.epsilons[b]}

    def train_stats(self, b: int, reset: bool = True) -> dict[str, float]:
        """``train/*``: ``epsilon`` and ``visited_fraction``, the share of member ``b``'s
        (state, action) pairs updated at least once. Reading changes nothing (``reset`` is
        there for the learners' common signature)."""
        visited = self.visited[b]
        return {"epsilon": self.epsilons[b], "visited_fraction": int(visited.count_nonzero()) / visited.numel()}

    # -- acting --------------------------------------------------------------
    def begin(self) -> None:
        """Before the first step of a training session: nothing to prepare."""

    def act(self, td: TensorDictBase, live: Sequence[int] | None = None) -> TensorDictBase:
        """Every member's epsilon-greedy actions on its block; only ``live`` members draw."""
        if live is None or len(live) == self.members:
            return self.act_members(td, None, False, self.generators)
        live = set(live)
        return self.act_members(td, None, False, [g if b in live else None for b, g in enumerate(self.generators)])

    def _draws(self, n: int, generators: Sequence[torch.Generator | None]) -> torch.Tensor:
        """``[k, d]`` float64 uniforms, a row per block: one step's draws of its member, in one
        call on its generator (torch's CPU generator fills serially: one call of d numbers is
        the calls for explore, noise, ties and random actions one after another); zeros for a
        block without a generator."""
        a = self.n_actions
        d = n + 2 * n * a if self.noise_exploration else 2 * n + n * a
        if self._draw_buffer is None or self._draw_buffer.shape != (len(generators), d):
            self._draw_buffer = torch.zeros(len(generators), d, dtype=torch.float64)
        draws = self._draw_buffer
        for j, generator in enumerate(generators):
            if generator is not None:
                torch.rand(d, generator=generator, dtype=torch.float64, out=draws[j])
            else:
                draws[j].zero_()
        return draws

    def act_members(self, td: TensorDictBase, members: Sequence[int] | None, greedy: bool,
                    generators: Sequence[torch.Generator | None]) -> TensorDictBase:
        """The actions of ``members`` (None: all) on their blocks of ``td`` (block ``j`` is
        member ``members[j]``'s), ties broken by ``generators[j]``; epsilon-greedy unless ``greedy``.
        Returns a new tensordict of ``td``'s entries and ``state_index``, ``action_value`` and
        ``action``."""
        members = range(self.members) if members is None else list(members)
        k, a = len(members), self.n_actions
        n = td.numel() // k
        state = self._states(td.get("observation"), None if isinstance(members, range) else members, n)
        offset = self._offset(None if isinstance(members, range) else members, n)
        q = self._values.index_select(0, state.reshape(-1) + offset).view(k, n, a)
        draws = self._draws(n, generators)
        if greedy or k == 1:  # one epsilon: a Python number (the comparison is the same)
            epsilon = 0.0 if greedy else self.epsilons[members[0]]
        else:
            epsilon = torch.from_numpy(np.array([[self.epsilons[b]] for b in members], dtype=np.float64))
        explore = draws[:, :n] < epsilon
        if self.noise_exploration:
            magnitude = q.abs().amax(-1, keepdim=True)
            noise = (draws[:, n:n + n * a].view(k, n, a) * 2 - 1) * magnitude
            scored = torch.where(explore.unsqueeze(-1), q + noise, q)
            tie = draws[:, n + n * a:]
        else:
            scored, tie = q, draws[:, n:n + n * a]
        best = scored == scored.amax(-1, keepdim=True)  # random tie-break: the best by a random key
        action = torch.where(best, tie.view(k, n, a), -1.0).argmax(-1)
        if not self.noise_exploration:
            random_action = (draws[:, n + n * a:] * a).long().clamp_max(a - 1)
            action = torch.where(explore, random_action, action)
        shape = td.batch_size
        return with_entries(td, state_index=state.reshape(shape), action_value=q.reshape(*shape, a).to(torch.float32),
                            action=action.reshape(shape))

    def _offset(self, members: list[int] | None, n: int) -> torch.Tensor | int:
        """Each row's member's first row in the flat ``[members * states, actions]`` table
        (``members`` None: all, kept between steps; one member: one number)."""
        if members is None:
            if self._offsets is None or len(self._offsets) != self.members * n:
                self._offsets = torch.as_tensor(self._starts).repeat_interleave(n)
            return self._offsets
        if len(members) == 1:  # one member (its greedy policy)
            return self._starts[members[0]]
        return torch.as_tensor([self._starts[b] for b in members]).repeat_interleave(n)

    # -- learning ------------------------------------------------------------
    def observe(self, td: TensorDictBase, live: Sequence[int] | None = None) -> None:
        """One Q update of each live member's table from its block of ``td`` (holding
        ``next``); each member's rows index its own slice of the table."""
        n = td.numel() // self.members
        rows = None if live is None or len(live) == self.members else (
            torch.as_tensor(list(live)).unsqueeze(1) * n + torch.arange(n)).reshape(-1)

        def pick(value: torch.Tensor) -> torch.Tensor:
            value = value.reshape(self.members * n)
            return value if rows is None else value.index_select(0, rows)

        def each(value: float | torch.Tensor) -> float | torch.Tensor:  # a member's value on each of its rows
            return pick(value.expand(self.members, n)) if isinstance(value, torch.Tensor) else value

        offset = pick(self._offset(None, n))
        state = pick(td.get("state_index")) + offset
        action = pick(td.get("action"))
        reward = pick(td.get(("next", "reward"))).to(torch.float64)
        terminated = pick(td.get(("next", "terminated")))
        next_state = pick(self._states(td.get(("next", "observation")), None, n)) + offset
        a = self.n_actions
        bootstrap = self._values.index_select(0, next_state).amax(-1)
        if not self.bootstrap_terminal:
            bootstrap.masked_fill_(terminated, 0.0)
        target = reward + each(self._gamma) * bootstrap
        pair = state * a + action  # (s, a)'s index in the flat table
        old = self._values.view(-1).index_select(0, pair)
        new = old + each(self._alpha) * (target - old)
        if self.first_visit_reward:
            new = torch.where(self._seen.view(-1).index_select(0, pair), new, reward)
        self._add_mean_increments(pair, new - old, n)

    def _add_mean_increments(self, pair: torch.Tensor, increment: torch.Tensor, n: int) -> None:
        """Adds to each flat table entry in ``pair`` the mean of its ``increment``s and marks
        it visited. Members' pairs never meet (each indexes its own slice); within a block,
        distinct pairs by ``unique``, their sums in the block's order. Work in the batch's
        size, not the table's."""
        table, visited = self._values.view(-1), self._seen.view(-1)
        if n > 1:
            pair, slot, count = torch.unique(pair, return_inverse=True, return_counts=True)
            total = torch.zeros(len(pair), dtype=torch.float64).index_add_(0, slot, increment)
            increment = total / count
        table.index_add_(0, pair, increment)
        visited.index_fill_(0, pair, True)

    def end_episodes(self, ended: Mapping[int, int]) -> None:
        """After each finished episode of a member: its epsilon decays (down to ``epsilon_min``)."""
        for b, count in ended.items():
            own = self.settings[b]
            for _ in range(count):
                if self.epsilons[b] > own.epsilon_min:
                    self.epsilons[b] *= own.epsilon_discount

    # -- persistence ---------------------------------------------------------
    def model_state(self, b: int) -> dict:
        """Member ``b``'s Q-table, its visited flags, epsilon and the state mapping (``model.pt``)."""
        return {"kind": "qlearn", "table": self.table[b].clone(), "visited": self.visited[b].clone(),
                "epsilon": self.epsilons[b], "discretizer": self.discretizers[b].describe(),
                "n_actions": self.n_actions}

    def training_state(self, b: int) -> dict:
        """Everything member ``b``'s next update depends on (for resuming a run)."""
        return {**self.model_state(b), "generator": self.generators[b].get_state()}

    def load_model_state(self, b: int, ckpt: Mapping, where: str) -> None:
        """Loads a saved Q-table into member ``b``, checking it fits; ``where`` names the
        state's origin in a :class:`StateMismatch`."""
        own = self.model_state(b)
        check_state(ckpt, own, where)  # every key there, before its values are read
        mine = self.discretizers[b].describe()
        if ckpt["discretizer"] != mine or ckpt["n_actions"] != self.n_actions:
            raise StateMismatch(
                f"checkpoint {where} does not fit this run: it has state {ckpt['discretizer']} "
                f"x {ckpt['n_actions']} actions, this run has {mine} x {self.n_actions}"
            )
        check_state(ckpt, own, where, deep=("table", "visited"))
        self.table[b].copy_(ckpt["table"])
        self.visited[b].copy_(ckpt["visited"])

    def load_training_state(self, b: int, state: Mapping) -> None:
        self.load_model_state(b, state, "the training checkpoint")
        self.epsilons[b] = float(state["epsilon"])
        self.generators[b].set_state(state["generator"])


__all__ = ["Discretizer", "QLearn"]
