"""Tabular Q-learning over a discretised observation, written for one member.

The state is the task's tabular observation in bins (:class:`learners.discretizer.Discretizer`,
``number_splits`` per entry). Unseen pairs hold ``initial_q`` (0 as in the original; an
optimistic value, such as the largest return there is, makes the learner try every action
before trusting one). Update, for a batch of transitions at once::

    Q(s,a) <- Q(s,a) + alpha * (r + gamma * max_a' Q(s',a') * (1 - terminated) - Q(s,a))

Transitions of one member's step that hit the same (s, a) have their increments averaged
(with ``num_envs=1`` this is the ordinary sequential update). Exploration is
epsilon-greedy, ties broken at random; epsilon is multiplied by ``epsilon_discount`` after
each finished episode while it is above ``epsilon_min``. A member's policy writes
``state_index``, ``action_value`` and ``action``.

The members are one layer beneath (:mod:`learners.member`): their tables are the rows of
one tensor (:class:`learners.member.MemberTables`), each member indexing its own, and each
draws from its own stream, so every member's step is one call.

The original learner's quirks are options, off by default: ``first_visit_reward`` (a
pair's first update sets Q <- r), ``bootstrap_terminal`` (bootstrap through terminal
states) and ``noise_exploration`` (instead of a random action, with probability epsilon
add uniform noise of the Q-values' magnitude and act greedily on the result).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Sequence

import numpy as np
import torch
from tensordict import TensorDictBase

from learners.base import StateMismatch, check_state
from learners.discretizer import MAX_SPLITS, MemberDiscretizers
from learners.member import MemberLearner, MemberTables, draws
from learners.schedules import EpisodeDecayEpsilon
from params import require
from params.declare import check_fields, param
from params.private_api import with_entries

TABLE_BYTES = 2 * 2**30  # the largest Q-table a run may allocate


@dataclass(eq=False)
class QLearn(MemberLearner):
    """Tabular Q-learning (see the module docstring)."""

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

    # -- building ------------------------------------------------------------
    def build(self, task, generators: torch.Generator | Sequence[torch.Generator] | None = None,
              variants: Sequence[QLearn] | None = None) -> None:
        """The Q-tables of one member per generator (its stream) for ``task``'s tabular state
        and actions; ``variants``: each member's own settings (:data:`MEMBER_WISE`)."""
        self._members(generators, variants)
        self._bounds, self.n_actions = task.tabular_bounds, int(task.n_actions)
        self._lay_out()
        self.schedules = [self._schedule(own) for own in self.settings]

    def renew(self, b: int, generator: torch.Generator, variant: QLearn | None = None) -> None:
        """Member ``b`` made anew from ``generator`` and ``variant`` (None: this learner's
        settings); the other members' tables kept as they are."""
        self.generators[b], self.settings[b] = generator, self.variant(variant)
        self._lay_out({i: (self.table[i], self.visited[i]) for i in range(self.members) if i != b})
        self.schedules[b] = self._schedule(self.settings[b])

    @staticmethod
    def _schedule(own: QLearn) -> EpisodeDecayEpsilon:
        """A member's exploration from its settings: the original's decay per episode."""
        return EpisodeDecayEpsilon(own.epsilon, own.epsilon_min, own.epsilon_discount)

    def _lay_out(self, kept: Mapping[int, tuple[torch.Tensor, torch.Tensor]] | None = None) -> None:
        """Every member's discretizer and its table, fresh (at its ``initial_q``, unvisited)
        but the members of ``kept`` (index: their table and visited flags, copied in)."""
        self._states = MemberDiscretizers(self._bounds, [own.number_splits for own in self.settings])
        self.discretizers = self._states.each
        self.discretizer = self.discretizers[0]
        self.n_states = self.discretizer.n_states
        largest = max(self.discretizers, key=lambda d: d.n_states)
        table_bytes = largest.n_states * self.n_actions * 9  # float64 values + visited flags
        # A run's table (a member's); a batch's members together: runs.lifecycle's memory check.
        require(table_bytes <= TABLE_BYTES,
                f"learner.number_splits must keep the Q-table within {TABLE_BYTES / 2**30:g} GiB; "
                f"{largest.splits} bins make {largest.n_states} states x {self.n_actions} actions = "
                f"{table_bytes / 2**30:.3g} GiB", largest.splits)
        self.tables = MemberTables([d.n_states for d in self.discretizers], self.n_actions,
                                   [own.initial_q for own in self.settings])
        self.table, self.visited = self.tables.table, self.tables.visited
        for b, (values, seen) in (kept or {}).items():
            self.table[b].copy_(values)
            self.visited[b].copy_(seen)

    def stats(self, b: int) -> dict[str, float]:
        own = self.settings[b]
        return {"alpha": own.alpha, "gamma": own.gamma, "epsilon": self.schedules[b].value}

    def train_stats(self, b: int, reset: bool = True) -> dict[str, float]:
        """``train/*``: ``epsilon`` and ``visited_fraction``, the share of member ``b``'s
        (state, action) pairs updated at least once (``reset``: the common signature's)."""
        visited = self.visited[b]
        return {"epsilon": self.schedules[b].value, "visited_fraction": int(visited.count_nonzero()) / visited.numel()}

    # -- acting --------------------------------------------------------------
    def act_members(self, td: TensorDictBase, members: Sequence[int] | None, greedy: bool,
                    generators: Sequence[torch.Generator | None]) -> TensorDictBase:
        """The actions of ``members`` (None: all) on their blocks of ``td`` (block ``j`` is
        member ``members[j]``'s), drawn from ``generators[j]``; epsilon-greedy unless ``greedy``.
        Returns a new tensordict of ``td``'s entries and :data:`out_keys`."""
        some = None if members is None else list(members)
        members = range(self.members) if some is None else some
        k, a = len(members), self.n_actions
        n = td.numel() // k
        state = self._states(td.get("observation"), some, n)
        q = self.tables.values.index_select(0, state.reshape(-1) + self.tables.offset(some, n)).view(k, n, a)
        size = n + 2 * n * a if self.noise_exploration else 2 * n + n * a
        drawn = draws(generators, size, lambda g, out: torch.rand(size, generator=g, dtype=torch.float64, out=out),
                      torch.float64)
        if greedy or k == 1:  # one epsilon: a Python number (the comparison is the same)
            epsilon = 0.0 if greedy else self.schedules[members[0]].value
        else:
            epsilon = torch.from_numpy(np.array([[self.schedules[b].value] for b in members], dtype=np.float64))
        action = self.choose(q, epsilon, drawn)
        shape = td.batch_size
        return with_entries(td, state_index=state.reshape(shape), action_value=q.reshape(*shape, a).to(torch.float32),
                            action=action.reshape(shape))

    def choose(self, q: torch.Tensor, epsilon: float | torch.Tensor, drawn: torch.Tensor) -> torch.Tensor:
        """Epsilon-greedy actions for Q-values ``q`` (``[..., n, actions]``), ties broken at
        random, from one step's uniform draws (``[..., d]``: explore, then noise or ties,
        then ties or random actions)."""
        n, a = q.shape[-2:]
        explore = drawn[..., :n] < epsilon
        if self.noise_exploration:
            magnitude = q.abs().amax(-1, keepdim=True)
            noise = (drawn[..., n:n + n * a].unflatten(-1, (n, a)) * 2 - 1) * magnitude
            scored, tie = torch.where(explore.unsqueeze(-1), q + noise, q), drawn[..., n + n * a:]
        else:
            scored, tie = q, drawn[..., n:n + n * a]
        best = scored == scored.amax(-1, keepdim=True)  # random tie-break: the best by a random key
        action = torch.where(best, tie.unflatten(-1, (n, a)), -1.0).argmax(-1)
        if self.noise_exploration:
            return action
        return torch.where(explore, (drawn[..., n + n * a:] * a).long().clamp_max(a - 1), action)

    # -- learning ------------------------------------------------------------
    def observe(self, td: TensorDictBase, live: Sequence[int] | None = None) -> None:
        """One Q update of each live member's table from its block of ``td`` (holding ``next``)."""
        n = td.numel() // self.members
        pick = self.rows(live, n)
        offset = pick(self.tables.offset(None, n))
        state, action = pick(td.get("state_index")) + offset, pick(td.get("action"))
        reward, terminated = pick(td.get(("next", "reward"))).to(torch.float64), pick(td.get(("next", "terminated")))
        next_state = pick(self._states(td.get(("next", "observation")), None, n)) + offset
        alpha, gamma = (self.own(name, dtype=torch.float64) for name in ("alpha", "gamma"))
        alpha, gamma = (pick(v.expand(self.members, n)) if isinstance(v, torch.Tensor) else v for v in (alpha, gamma))
        self.update(state, action, reward, terminated, next_state, alpha, gamma, n)

    def update(self, state: torch.Tensor, action: torch.Tensor, reward: torch.Tensor, terminated: torch.Tensor,
               next_state: torch.Tensor, alpha: float | torch.Tensor, gamma: float | torch.Tensor, n: int) -> None:
        """The Q update of transitions (rows of the table), ``n`` a step's transitions of one member."""
        values, seen = self.tables.values, self.tables.seen
        bootstrap = values.index_select(0, next_state).amax(-1)
        if not self.bootstrap_terminal:
            bootstrap.masked_fill_(terminated, 0.0)
        target = reward + gamma * bootstrap
        pair = state * self.n_actions + action  # (s, a)'s index in the flat table
        old = values.view(-1).index_select(0, pair)
        new = old + alpha * (target - old)
        if self.first_visit_reward:
            new = torch.where(seen.view(-1).index_select(0, pair), new, reward)
        increment = new - old
        if n > 1:  # one mean increment per distinct pair (members' pairs never meet), in the step's order
            pair, slot, count = torch.unique(pair, return_inverse=True, return_counts=True)
            increment = torch.zeros(len(pair), dtype=torch.float64).index_add_(0, slot, increment) / count
        values.view(-1).index_add_(0, pair, increment)
        seen.view(-1).index_fill_(0, pair, True)

    # -- persistence ---------------------------------------------------------
    def model_state(self, b: int) -> dict:
        """Member ``b``'s Q-table, its visited flags, epsilon and the state mapping (``model.pt``)."""
        return {"kind": "qlearn", "table": self.table[b].clone(), "visited": self.visited[b].clone(),
                "epsilon": self.schedules[b].value, "discretizer": self.discretizers[b].describe(),
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
                f"x {ckpt['n_actions']} actions, this run has {mine} x {self.n_actions}")
        check_state(ckpt, own, where, deep=("table", "visited"))
        self.table[b].copy_(ckpt["table"])
        self.visited[b].copy_(ckpt["visited"])

    def load_training_state(self, b: int, state: Mapping) -> None:
        self.load_model_state(b, state, "the training checkpoint")
        self.schedules[b].load_state_dict({"value": state["epsilon"]})
        self.generators[b].set_state(state["generator"])


__all__ = ["QLearn"]
