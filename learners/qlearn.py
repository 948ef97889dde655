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

The Q-table is a ``[prod(splits), n_actions]`` float64 tensor; unseen pairs hold
``initial_q`` (0 as in the original; an optimistic value, such as the largest
return there is, makes the learner try every action before trusting one).

Update, for a batch of transitions at once::

    Q(s,a) <- Q(s,a) + alpha * (r + gamma * max_a' Q(s',a') * (1 - terminated) - Q(s,a))

Transitions of one batch that hit the same (s, a) have their increments
averaged (with ``num_envs=1`` this is the ordinary sequential update).
Exploration is epsilon-greedy; epsilon is multiplied by ``epsilon_discount``
after each finished episode while it is above ``epsilon_min``.

The original learner's quirks are options, off by default:
``first_visit_reward`` (a pair's first update sets Q <- r),
``bootstrap_terminal`` (bootstrap through terminal states) and
``noise_exploration`` (instead of a random action, with probability epsilon
add uniform noise of the Q-values' magnitude and act greedily on the result).
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator, Mapping, Sequence

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from learners.base import Loop, StateMismatch, train
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

    def __call__(self, observation: torch.Tensor) -> torch.Tensor:
        if self._prefix:  # the observation's first entries, in order: a view, no gather
            x = observation[..., : len(self._index)].to(torch.float64, copy=True)
        else:
            x = observation.index_select(-1, self._index).to(torch.float64)
        bins = x.sub_(self._low).div_(self._width).mul_(self._splits).floor_().long()
        return torch.minimum(bins.clamp_min_(0), self._top) @ self._radix

    def describe(self) -> dict:
        return {
            "names": list(self.bounds.names),
            "low": self.bounds.low.tolist(),
            "high": self.bounds.high.tolist(),
            "splits": self.splits,
        }


class QTablePolicy(TensorDictModuleBase):
    """Reads ``observation``, writes ``state_index``, ``action_value`` and ``action``.

    Acts epsilon-greedily (or greedily when ``epsilon`` is 0), breaking ties
    between equal Q-values uniformly at random.
    """

    in_keys = ["observation"]
    out_keys = ["state_index", "action_value", "action"]

    def __init__(self, discretizer: Discretizer, n_actions: int, epsilon: float = 0.0,
                 noise_exploration: bool = False, generator: torch.Generator | None = None) -> None:
        super().__init__()
        self.discretizer = discretizer
        self.n_actions = int(n_actions)
        self.register_buffer("table", torch.zeros(discretizer.n_states, n_actions, dtype=torch.float64))
        self.register_buffer("visited", torch.zeros(discretizer.n_states, n_actions, dtype=torch.bool))
        self.epsilon = float(epsilon)
        self.noise_exploration = noise_exploration
        self.generator = generator if generator is not None else torch.Generator()

    def _rand(self, *shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=self.generator, dtype=torch.float64)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        state = self.discretizer(tensordict.get("observation"))
        q = self.table.index_select(0, state.reshape(-1)).reshape(*state.shape, self.n_actions)
        explore = self._rand(*state.shape) < self.epsilon
        if self.noise_exploration:
            magnitude = q.abs().amax(-1, keepdim=True)
            noise = (self._rand(*q.shape) * 2 - 1) * magnitude
            scored = torch.where(explore.unsqueeze(-1), q + noise, q)
        else:
            scored = q
        # Random tie-break: among the maxima, pick by a random key.
        best = scored == scored.amax(-1, keepdim=True)
        action = torch.where(best, self._rand(*q.shape), -1.0).argmax(-1)
        if not self.noise_exploration:
            random_action = (self._rand(*state.shape) * self.n_actions).long().clamp_max(self.n_actions - 1)
            action = torch.where(explore, random_action, action)
        tensordict.set("state_index", state)
        tensordict.set("action_value", q.to(torch.float32))
        tensordict.set("action", action)
        return tensordict


@dataclass(eq=False)
class QLearn:
    """Tabular Q-learning; ``train`` runs it on a batched :class:`RobotTaskEnv`."""

    alpha: float = param(0.1, "learning rate of the Q update", gt=0, le=1)
    gamma: float = param(0.7, "discount of the next state's value", ge=0, le=1)
    epsilon: float = param(0.9, "exploration probability at the start", ge=0, le=1)
    epsilon_discount: float = param(0.999, "epsilon is multiplied by it after each episode", gt=0,
                                    le=1)
    epsilon_min: float = param(0.05, "epsilon stops decaying once at or below it", ge=0, le=1)
    nepisodes: int = param(500, "training episodes (the budget)", ge=1, le=10**8)
    nsteps: int = param(1000, "steps per episode at most (truncation)", ge=1, le=10**7)
    number_splits: int | Sequence[int] | Mapping[str, int] = param(
        10, "bins per tabular_state entry: one int, a list, or name: bins (1 = ignored)", ge=1,
        le=MAX_SPLITS)
    first_visit_reward: bool = param(False, "original quirk: a pair's first update sets Q <- r")
    bootstrap_terminal: bool = param(False, "original quirk: bootstrap through terminal states")
    noise_exploration: bool = param(False, "original quirk: explore by noisy Q-values")
    initial_q: float = param(0.0, "Q of unseen pairs (an optimistic value tries every action)")

    def __post_init__(self) -> None:
        check_fields(self, "learner")
        self.epsilon_start = self.epsilon
        if isinstance(self.number_splits, Mapping):
            self.number_splits = {str(k): int(v) for k, v in self.number_splits.items()}
        elif isinstance(self.number_splits, (int, float, np.integer)):  # 1e3 on the command line
            self.number_splits = int(self.number_splits)
        else:
            self.number_splits = [int(v) for v in self.number_splits]
        self.policy: QTablePolicy | None = None

    # -- building ------------------------------------------------------------
    def build(self, task, generator: torch.Generator | None = None) -> QTablePolicy:
        """Creates the Q-table policy for ``task``'s tabular state and actions."""
        discretizer = Discretizer(task.tabular_bounds, self.number_splits)
        table_bytes = discretizer.n_states * task.n_actions * 9  # float64 values + visited flags
        require(table_bytes <= TABLE_BYTES,
                f"learner.number_splits must keep the Q-table within {TABLE_BYTES / 2**30:g} GiB; "
                f"{discretizer.splits} bins make {discretizer.n_states} states x {task.n_actions} "
                f"actions = {table_bytes / 2**30:.3g} GiB", self.number_splits)
        self.policy = QTablePolicy(discretizer, task.n_actions, self.epsilon_start,
                                   self.noise_exploration, generator)
        self.policy.table.fill_(self.initial_q)
        return self.policy

    @property
    def stats(self) -> dict[str, float]:
        return {"alpha": self.alpha, "gamma": self.gamma, "epsilon": self.policy.epsilon}

    def train_stats(self, reset: bool = True) -> dict[str, float]:
        """``train/*``: ``epsilon`` and ``visited_fraction``, the share of the table's
        (state, action) pairs updated at least once (counted now: one pass over the visited
        flags, less than one update's passes over the table). Reading changes nothing
        (``reset`` is there for the learners' common signature)."""
        visited = self.policy.visited
        return {"epsilon": self.policy.epsilon,
                "visited_fraction": int(visited.count_nonzero()) / visited.numel()}

    # -- learning ------------------------------------------------------------
    def update(self, tensordict: TensorDictBase) -> None:
        """One Q-update from a batch of transitions (``tensordict`` holds ``next``)."""
        policy = self.policy
        state = tensordict.get("state_index").reshape(-1)
        action = tensordict.get("action").reshape(-1)
        reward = tensordict.get(("next", "reward")).reshape(-1).to(torch.float64)
        terminated = tensordict.get(("next", "terminated")).reshape(-1)
        next_state = policy.discretizer(tensordict.get(("next", "observation"))).reshape(-1)
        bootstrap = policy.table.index_select(0, next_state).amax(-1)
        if not self.bootstrap_terminal:
            bootstrap.masked_fill_(terminated, 0.0)
        target = reward + self.gamma * bootstrap
        pair = state * policy.n_actions + action  # (s, a)'s index in the flat table
        old = policy.table.view(-1).index_select(0, pair)
        new = old + self.alpha * (target - old)
        if self.first_visit_reward:
            new = torch.where(policy.visited.view(-1).index_select(0, pair), new, reward)
        self._add_mean_increments(pair, new - old)

    def _add_mean_increments(self, pair: torch.Tensor, increment: torch.Tensor) -> None:
        """Adds to each flat table entry in ``pair`` the mean of its ``increment``s and marks
        it visited. Work in the batch's size, not the table's: distinct pairs by ``unique``
        (the sums in batch order, as an ``index_add_`` over the whole table gave them)."""
        table, visited = self.policy.table.view(-1), self.policy.visited.view(-1)
        if pair.numel() > 1:
            pair, slot, count = torch.unique(pair, return_inverse=True, return_counts=True)
            total = torch.zeros(len(pair), dtype=torch.float64).index_add_(0, slot, increment)
            increment = total / count
        table.index_add_(0, pair, increment)
        visited.index_fill_(0, pair, True)

    @contextmanager
    def greedy(self) -> Iterator[None]:
        """Within the block the policy acts greedily (epsilon 0, no noise).

        Ties between equal Q-values are broken by a generator of its own, seeded
        the same each time: an evaluation neither draws from the training
        stream (training goes on exactly as without it) nor varies between two
        evaluations of the same table.
        """
        saved = self.policy.epsilon, self.policy.generator
        self.policy.epsilon = 0.0
        self.policy.generator = torch.Generator().manual_seed(0)
        try:
            yield
        finally:
            self.policy.epsilon, self.policy.generator = saved

    def end_episode(self) -> None:
        """After each finished episode: epsilon decays (down to ``epsilon_min``)."""
        if self.policy.epsilon > self.epsilon_min:
            self.policy.epsilon *= self.epsilon_discount

    def begin(self) -> None:
        """Before the first step of a training session: nothing to prepare."""

    def act(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Epsilon-greedy on the table."""
        return self.policy(tensordict)

    def observe(self, tensordict: TensorDictBase) -> None:
        """Learns from the batch of transitions."""
        self.update(tensordict)

    def train(self, env, run: Loop) -> None:
        """Runs episodes on ``env`` until ``run`` is done (budget or win)."""
        train(self, env, run)

    # -- persistence ---------------------------------------------------------
    kind = "qlearn"

    def training_state(self) -> dict:
        """Everything the next update depends on (for resuming a run)."""
        return {**self.model_state(), "generator": self.policy.generator.get_state()}

    def load_training_state(self, state: dict) -> None:
        self.load_model_state(state, "the training checkpoint")
        self.policy.epsilon = float(state["epsilon"])
        self.policy.generator.set_state(state["generator"])

    def model_state(self) -> dict:
        """The Q-table, its visited flags, epsilon and the state mapping (``model.pt``)."""
        return {
            "kind": "qlearn",
            "table": self.policy.table.clone(),
            "visited": self.policy.visited.clone(),
            "epsilon": self.policy.epsilon,
            "discretizer": self.policy.discretizer.describe(),
            "n_actions": self.policy.n_actions,
        }

    def load_model_state(self, ckpt: Mapping, where: str) -> None:
        """Loads a saved Q-table into the built policy, checking it fits; ``where`` names the
        state's origin in a :class:`StateMismatch`."""
        mine = self.policy.discretizer.describe()
        if ckpt["discretizer"] != mine or ckpt["n_actions"] != self.policy.n_actions:
            raise StateMismatch(
                f"checkpoint {where} does not fit this run: it has state {ckpt['discretizer']} "
                f"x {ckpt['n_actions']} actions, this run has {mine} x {self.policy.n_actions}"
            )
        self.policy.table.copy_(ckpt["table"])
        self.policy.visited.copy_(ckpt["visited"])


__all__ = ["Discretizer", "QTablePolicy", "QLearn"]
