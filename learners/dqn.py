"""The replay-buffer DQN family as one TorchRL learner; variants are configs.

Parts: an ``MLP`` Q-network (in a ``QValueActor`` for checkpoints), an epsilon-greedy
:class:`QPolicy` whose epsilon follows one of :mod:`learners.schedules`, a TD(0) loss
(MSE or Huber, optional double DQN) against an optional target network kept by hard
copies or Polyak averaging, and TorchRL's ``ReplayBuffer`` over one pre-allocated
tensor (:class:`RowReplayBuffer`).

The loss is :func:`td_loss`, the same number TorchRL's ``DQNLoss`` with a TD(0)
estimator computes (``tests/test_dqn.py`` checks it). Updates are most of a DQN run's
wall-clock, and on a 4x64x64x2 network nearly all of an update is per-call overhead,
so the hot path avoids it: transitions reach the buffer's storage in one write per
update rather than per env step, minibatches are plain tensors indexed from it (no TensorDict), the network runs layer by layer (:func:`layer_by_layer`),
gradients are clipped in two foreach calls and Adam is fused. The exploring policy is
one forward on the observation tensor. ``bench/update_rate.py`` times the parts.

When it trains (``train_every``):

- ``episode``: ``updates`` minibatches after each finished episode (n1try,
  ruippeixotog);
- ``step``: ``updates`` minibatches per collected transition (mbalunovic: 1),
  fractional values allowed, once the buffer holds ``learning_starts``.

``done_episode_reward`` replaces the reward of terminating transitions
(mbalunovic's -200); ``reward_scale`` then multiplies every reward the learner
stores (its Q-values in those units; the task's reward and measures unchanged).
``run_episodes`` greedy episodes follow training (ruippeixotog's "run" phase).

:meth:`DQN.train_stats` gives the numbers the logger shows as ``train/*``:
loss, mean Q of the taken actions, mean absolute TD error, gradient norm before
clipping, epsilon, learning rate, updates and updates per second. An update
only keeps its tensors for them (:class:`UpdateStats`: no host sync, ~1 us).
"""

from __future__ import annotations

import copy
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Mapping, NamedTuple

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.data import RandomSampler, ReplayBuffer, TensorStorage
from torchrl.modules import MLP, QValueActor

from learners.base import Loop, StateMismatch, train
from learners.device import DEVICE_NOTE, check_device, resolve_device
from params import require
from params.declare import REQUIRED, check_fields, param

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU}
LOSSES = {"l2": "l2", "mse": "l2", "huber": "smooth_l1", "smooth_l1": "smooth_l1"}
_DISTANCES = {"l2": nn.functional.mse_loss, "smooth_l1": nn.functional.smooth_l1_loss}
# The training state's layout. 2: the replay buffer holds one float row per transition
# (``pack``) and there is no ``last_loss``; 1 (unmarked): a TensorDict storage.
FORMAT = 2


class Transitions(NamedTuple):
    """Transitions as plain tensors: ``observation`` and ``next_observation`` ``[n, n_obs]``,
    ``action`` ``[n, 1]`` (int64), ``reward`` ``[n, 1]``, ``terminated`` ``[n, 1]`` (bool)."""

    observation: torch.Tensor
    action: torch.Tensor
    reward: torch.Tensor
    next_observation: torch.Tensor
    terminated: torch.Tensor

    @classmethod
    def of(cls, td: TensorDictBase) -> Transitions:
        """The transitions of a TorchRL tensordict (``observation``, ``action``, ``next``)."""
        n, nxt = td.numel(), td.get("next")
        return cls(td.get("observation").reshape(n, -1), td.get("action").reshape(n, 1),
                   nxt.get("reward").reshape(n, 1), nxt.get("observation").reshape(n, -1),
                   nxt.get("terminated").reshape(n, 1))


def pack(batch: Transitions) -> torch.Tensor:
    """One float row per transition: observation, next observation, action, reward, terminated."""
    dtype = batch.observation.dtype
    return torch.cat((batch.observation, batch.next_observation, batch.action.to(dtype),
                      batch.reward.to(dtype), batch.terminated.to(dtype)), dim=1)


def unpack(rows: torch.Tensor) -> Transitions:
    """The :class:`Transitions` of rows made by :func:`pack` (views, but action and terminated)."""
    n = (rows.shape[1] - 3) // 2
    return Transitions(rows[:, :n], rows[:, 2 * n:2 * n + 1].long(), rows[:, 2 * n + 1:2 * n + 2],
                       rows[:, n:2 * n], rows[:, 2 * n + 2:] != 0)


QFunction = Callable[[torch.Tensor], torch.Tensor]  # observations -> Q-values


def layer_by_layer(net: nn.Sequential) -> QFunction:
    """``net``'s forward calling each layer's ``forward`` directly: the same arithmetic
    without ``nn.Module.__call__``'s hook machinery around each layer (~3 us a layer, and an
    update runs three forwards of five layers)."""
    layers = [layer.forward for layer in net]

    def forward(x: torch.Tensor) -> torch.Tensor:
        for layer in layers:
            x = layer(x)
        return x
    return forward


def td_loss(net: QFunction, target_net: QFunction, batch: Transitions, gamma: float,
            double_dqn: bool, loss_function: str) -> torch.Tensor:
    """Mean TD(0) error of ``net`` on ``batch``; ``target_net`` values the next state."""
    return _DISTANCES[loss_function](*td_terms(net, target_net, batch, gamma, double_dqn))


def td_terms(net: QFunction, target_net: QFunction, batch: Transitions, gamma: float,
             double_dqn: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """``(q, target)``, each ``[batch, 1]``: ``net``'s value of the taken actions and their
    TD(0) targets (no gradient), where ``target_net`` values the next state.

    ``double_dqn``: the next action is ``net``'s argmax, valued by ``target_net``.
    Terminated transitions do not bootstrap; truncated ones do.
    """
    q = net(batch.observation).gather(-1, batch.action)
    with torch.no_grad():
        next_q = target_net(batch.next_observation)
        if double_dqn:
            next_value = next_q.gather(-1, net(batch.next_observation).argmax(-1, keepdim=True))
        else:
            next_value = next_q.amax(-1, keepdim=True)
        target = batch.reward + gamma * next_value * ~batch.terminated
    return q, target


class RowReplayBuffer(ReplayBuffer):
    """TorchRL's ``ReplayBuffer`` over a ``TensorStorage`` of one pre-allocated float tensor,
    ``rows``, a row per transition (:func:`pack`).

    ``extend``, ``sample``, indexing and ``state_dict`` are TorchRL's. The update's
    :meth:`sample_transitions` draws the indices itself, the very draw of TorchRL's
    ``RandomSampler`` (``torch.randint`` on torch's global generator), and indexes ``rows``:
    ~30 us for 128 rows on a busy 2-core machine, where ``sample()`` takes ~50 us and the
    ``TensorDictReplayBuffer`` this replaced ~200 us (``bench/update_rate.py``).

    :meth:`put` queues rows instead of writing them: TorchRL's ``extend`` costs ~60 us a
    call whatever its size, and a DQN adds a few rows per env step but reads the buffer
    only when it updates. The queue is written by one ``extend`` of its rows, in order, as
    soon as anything touches the storage (the length, a sample, ``rows``, the state,
    ``extend`` itself: every path of ``ReplayBuffer`` goes through ``_storage``), and
    before it would hold more rows than the buffer, so the buffer never sees the
    difference: the same rows at the same places, the same cursor and length.
    """

    def __init__(self, capacity: int, width: int, batch_size: int,
                 device: torch.device | str = "cpu") -> None:
        self._queue: list[torch.Tensor] = []
        self._queued = 0
        self._capacity = int(capacity)
        rows = torch.zeros(capacity, width, device=device)
        super().__init__(storage=TensorStorage(rows, device=device), sampler=RandomSampler(),
                         batch_size=batch_size)
        self.empty()  # a TensorStorage made from a tensor counts it full
        self._rows = rows

    @property
    def _storage(self):
        if self._queued:
            self.flush()
        return self.__dict__.get("_storage_")

    @_storage.setter
    def _storage(self, storage) -> None:
        self.__dict__["_storage_"] = storage

    @property
    def rows(self) -> torch.Tensor:
        """The storage tensor, queued rows written."""
        if self._queued:
            self.flush()
        return self._rows

    def put(self, rows: torch.Tensor) -> None:
        """Adds ``rows`` (``[n, width]``) after those stored, as ``extend`` would, by the
        next time the buffer is read."""
        if self._queued + len(rows) > self._capacity:
            self.flush()  # one extend never wraps onto its own rows
        self._queue.append(rows)
        self._queued += len(rows)

    def flush(self) -> None:
        """Writes the queued rows (one ``extend``)."""
        queue, self._queue, self._queued = self._queue, [], 0
        if queue:
            self.extend(queue[0] if len(queue) == 1 else torch.cat(queue))

    def sample_transitions(self, stored: int) -> Transitions:
        """A minibatch drawn uniformly from the first ``stored`` rows (``len(self)``)."""
        index = torch.randint(0, stored, (self.batch_size,))
        rows = self.rows
        return unpack(rows.index_select(0, index.to(rows.device)))

    def transitions(self) -> Transitions:
        """Every stored transition, in storage order."""
        return unpack(self.rows[: len(self)])


class QPolicy(TensorDictModuleBase):
    """Reads ``observation``, writes ``action``: the Q-network's argmax, or while ``explore``
    with probability ``epsilon`` a uniformly random action.

    One forward on the observation tensor, without ``QValueActor`` and ``EGreedyModule``'s
    per-call bookkeeping (on cart-pole's 16 copies ~0.1 ms, where they took ~0.4), drawing as
    ``EGreedyModule`` does: a uniform per copy, then a random action per copy, from torch's
    global generator. The greedy policy draws nothing.
    """

    in_keys = ["observation"]
    out_keys = ["action"]

    def __init__(self, net: nn.Sequential, n_actions: int, explore: bool,
                 device: torch.device | str = "cpu") -> None:
        super().__init__()
        self.net, self.n_actions, self.explore = net, int(n_actions), explore
        self.q = layer_by_layer(net)
        self.device = torch.device(device)
        self.epsilon = 0.0

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        with torch.no_grad():
            q = self.q(tensordict.get("observation").to(self.device))
        action = q.argmax(-1).cpu()
        if self.explore:
            explore = torch.rand(action.shape) < self.epsilon
            action = torch.where(explore, torch.randint(0, self.n_actions, action.shape), action)
        tensordict.set("action", action)
        return tensordict


class ObsScale(nn.Module):
    """Multiplies each observation entry by a fixed factor before the Q-network's layers
    (inputs of one size: a wheel speed of 100 beside an angle of 0.1 drowns the angle)."""

    def __init__(self, scale: torch.Tensor) -> None:
        super().__init__()
        self.register_buffer("scale", scale)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.scale


def grad_norm_of(params: list[nn.Parameter]) -> torch.Tensor:
    """Total 2-norm of ``params``' gradients (what ``clip_grad_norm_`` measures), as a tensor."""
    grads = [p.grad for p in params if p.grad is not None]
    return torch.linalg.vector_norm(torch.stack(torch._foreach_norm(grads)))


class UpdateStats:
    """The updates' losses, Q of the taken actions, TD targets and gradient norms since the
    last :meth:`read`. Per update it only keeps the tensors (no host sync, no arithmetic);
    they are reduced to sums every ``FOLD`` updates and when read."""

    FOLD = 256

    def __init__(self) -> None:
        self.latest: dict[str, float] = {}
        self.restart(0)

    def restart(self, updates: int) -> None:
        """A new interval, starting now after ``updates`` optimizer steps."""
        self.pending: list[tuple[torch.Tensor, torch.Tensor, torch.Tensor]] = []
        self.norms: list[torch.Tensor] = []
        self.loss_sum = self.q_sum = self.td_sum = self.norm_sum = 0.0
        self.count = self.values = self.n_norms = 0
        self.since, self.t0 = updates, time.perf_counter()

    def add(self, loss: torch.Tensor | float, q: torch.Tensor, target: torch.Tensor,
            grad_norm: torch.Tensor | None) -> None:
        """One update: its loss, ``q`` and ``target`` (detached), its gradient norm if known."""
        self.count += 1
        self.pending.append((torch.as_tensor(loss, device=q.device), q, target))
        if grad_norm is not None:
            self.norms.append(grad_norm)
        if len(self.pending) >= self.FOLD:
            self._fold()

    def _fold(self) -> None:
        if self.pending:
            losses, q, target = zip(*self.pending)
            q, target = torch.cat(q), torch.cat(target)
            sums = torch.stack((torch.stack(losses).sum(), q.sum(), (target - q).abs_().sum()))
            loss_sum, q_sum, td_sum = sums.tolist()
            self.loss_sum, self.q_sum, self.td_sum = (self.loss_sum + loss_sum, self.q_sum + q_sum,
                                                      self.td_sum + td_sum)
            self.values += q.numel()
            self.pending.clear()
        if self.norms:
            self.norm_sum += float(torch.stack(self.norms).sum())
            self.n_norms += len(self.norms)
            self.norms.clear()

    def read(self, updates: int, reset: bool = True) -> dict[str, float]:
        """The interval's means (see ``DQN.train_stats``); ``reset``: start a new one."""
        self._fold()
        if self.count:
            self.latest = {"loss": self.loss_sum / self.count, "q_mean": self.q_sum / self.values,
                           "td_error": self.td_sum / self.values}
        if self.n_norms:
            self.latest["grad_norm"] = self.norm_sum / self.n_norms
        rate = (updates - self.since) / max(time.perf_counter() - self.t0, 1e-9)
        stats = {**self.latest, "updates": float(updates), "updates_per_s": rate}
        if reset:
            self.restart(updates)
        return stats


@dataclass(eq=False)
class DQN:
    """A configurable DQN; ``build`` makes its networks for a task, ``train`` runs it."""

    epsilon: Any = param(REQUIRED, "exploration schedule: a node with _target_ "
                                   "learners.schedules.LinearEpsilon, MultiplicativeEpsilon or "
                                   "LogEpisodeEpsilon")
    hidden: list[int] = param([64, 64], "widths of the Q-network's hidden layers")
    activation: str = param("relu", "hidden layers' activation", choices=tuple(ACTIVATIONS))
    obs_scale: dict[str, float] | None = param(None, "per observation name, a factor its value is "
                                                     "multiplied by before the network (others 1)",
                                               note="null = none")
    lr: float = param(1e-3, "Adam's learning rate", gt=0)
    lr_decay: float = param(0.0, "Keras-style decay: lr / (1 + lr_decay * updates)", ge=0)
    gamma: float = param(0.99, "discount of the next state's value", ge=0, le=1)
    loss: str = param("huber", "TD error's loss", choices=tuple(LOSSES))
    double_dqn: bool = param(True, "the online network picks the next action, the target values it")
    target_update: int = param(0, "hard copies of the target network every N updates", ge=0,
                               note="0 = none")
    tau: float = param(0.01, "Polyak averaging rate of the target network", ge=0, lt=1,
                       note="0 = none")
    buffer_size: int = param(50_000, "replay buffer capacity, transitions", ge=1, le=10**7)
    batch_size: int = param(64, "transitions per minibatch", ge=1, le=65_536)
    train_every: str = param("step", "when it trains: per collected transition or per finished "
                                     "episode", choices=("step", "episode"))
    updates: float = param(0.5, "minibatches per transition (train_every=step) or per episode",
                           gt=0)
    learning_starts: int = param(500, "transitions in the buffer before the first update", ge=0)
    grad_clip: float = param(10.0, "gradient norm clip", ge=0, note="0 = no clipping")
    done_episode_reward: float | None = param(None, "reward that replaces a terminating "
                                                    "transition's (null: keep it)")
    reward_scale: float = param(1.0, "factor on every reward the learner stores, after "
                                     "done_episode_reward (its Q-values in those units)", gt=0)
    nepisodes: int = param(1000, "training episodes (the budget)", ge=1, le=10**8)
    nsteps: int = param(1000, "steps per episode at most (truncation)", ge=1, le=10**7)
    run_episodes: int = param(0, "greedy episodes after training (ruippeixotog's run phase)", ge=0,
                              le=4096)
    device: str = param("cpu", "where the networks, updates and replay buffer live",
                        note=DEVICE_NOTE, check=check_device)

    def __post_init__(self) -> None:
        check_fields(self, "learner")
        require(1 <= len(self.hidden) <= 16 and all(1 <= h <= 65_536 for h in self.hidden),
                "learner.hidden must list 1 to 16 layer widths in [1, 65536]", self.hidden)
        require(not (self.target_update and self.tau),
                "learner.target_update and learner.tau exclude each other",
                (self.target_update, self.tau))
        require(not self.double_dqn or self.target_update or self.tau,
                "learner.double_dqn needs a target network (target_update or tau)", self.double_dqn)
        require(self.batch_size <= self.buffer_size, "learner.batch_size must be in [1, buffer_size]",
                (self.batch_size, self.buffer_size))
        require(self.learning_starts <= self.buffer_size,
                f"learner.learning_starts must be <= learner.buffer_size ({self.buffer_size}), "
                "else it never trains", self.learning_starts)
        require(all(hasattr(self.epsilon, k) for k in ("value", "step", "episode_end")),
                "learner.epsilon must be a schedule node (_target_: learners.schedules."
                "LinearEpsilon, MultiplicativeEpsilon or LogEpisodeEpsilon)", self.epsilon)
        self.device = str(resolve_device(self.device))  # auto -> cuda or cpu
        self.schedule = self.epsilon
        self.hidden = [int(h) for h in self.hidden]
        self.loss_function = LOSSES[self.loss]
        self.optimizer_steps = 0
        self._credit = 0.0
        self._greedy = False
        self.tracker = UpdateStats()
        # Where the whole updates ``learn`` owes go instead of ``optimize`` (a seed stack,
        # :class:`learners.stack.DQNStack`, runs those of all its seeds together); None: run here.
        self.updates_sink: Callable[[int], None] | None = None

    # -- building ------------------------------------------------------------
    def _arch(self) -> dict:
        arch = {"n_obs": self.n_obs, "n_actions": self.n_actions, "hidden": self.hidden,
                "activation": self.activation}
        return arch | ({"obs_scale": dict(self.obs_scale)} if self.obs_scale else {})

    def build(self, task, generator: torch.Generator | None = None):
        """Creates network, policies, target network, optimiser and replay buffer. The DQN
        draws from torch's global generator (seeded by the run; checkpoints keep its state),
        not ``generator``."""
        from torchrl.data import Categorical

        self.n_obs, self.n_actions = len(task.observation_names), int(task.n_actions)
        self.net = MLP(in_features=self.n_obs, out_features=self.n_actions, num_cells=self.hidden,
                       activation_class=ACTIVATIONS[self.activation])
        if self.obs_scale:
            names = list(task.observation_names)
            unknown = sorted(set(self.obs_scale) - set(names))
            require(not unknown, f"learner.obs_scale names no observation of this task; its "
                                 f"observations: {', '.join(names)}", unknown)
            scale = torch.tensor([float(self.obs_scale.get(n, 1.0)) for n in names])
            self.net = nn.Sequential(ObsScale(scale), *self.net)
        self.net = self.net.to(self.device)
        # The greedy actor TorchRL's way, for checkpoints and callers wanting action values;
        # training and evaluation act through the lean QPolicy on the same network.
        self.actor = QValueActor(self.net, in_keys=["observation"],
                                 spec=Categorical(self.n_actions, dtype=torch.int64))
        self.explorer = QPolicy(self.net, self.n_actions, explore=True, device=self.device)
        self.greedy_policy = QPolicy(self.net, self.n_actions, explore=False, device=self.device)
        # Without a target network the online network values the next state itself.
        self.target_net = self.net
        if self.target_update or self.tau:
            self.target_net = copy.deepcopy(self.net).requires_grad_(False)
        self._q, self._target_q = layer_by_layer(self.net), layer_by_layer(self.target_net)
        self._params = list(self.net.parameters())
        self._target_params = list(self.target_net.parameters())
        # fused: one kernel for every parameter (torch's default on CPU loops over them,
        # ~3x the time); it rounds differently from the loop in the last bit.
        self.optimizer = torch.optim.Adam(self._params, lr=self.lr, fused=True)
        decay = self.lr_decay
        # Keras' legacy Adam ``decay``: lr_k = lr / (1 + decay * k) after k updates.
        self.lr_schedule = torch.optim.lr_scheduler.LambdaLR(
            self.optimizer, lambda k: 1.0 / (1.0 + decay * k))
        self.buffer = RowReplayBuffer(self.buffer_size, 2 * self.n_obs + 3, self.batch_size,
                                      self.device)
        self._sync_epsilon()
        return self.actor

    @property
    def policy(self) -> QPolicy:
        """The acting policy: epsilon-greedy while training, greedy inside ``greedy()``."""
        return self.greedy_policy if self._greedy else self.explorer

    @contextmanager
    def greedy(self) -> Iterator[None]:
        self._greedy = True
        try:
            yield
        finally:
            self._greedy = False

    @property
    def stats(self) -> dict[str, float]:
        return {"alpha": self.optimizer.param_groups[0]["lr"], "gamma": self.gamma,
                "epsilon": float(self.schedule.value)}

    # -- learning ------------------------------------------------------------
    def store(self, tensordict: TensorDictBase) -> None:
        """Adds the batched transitions of ``tensordict`` (holding ``next``) to the buffer."""
        self.buffer.put(self.rows_of(tensordict))

    def rows_of(self, tensordict: TensorDictBase) -> torch.Tensor:
        """The buffer's rows (:func:`pack`) of the transitions of ``tensordict``, the
        terminating rewards replaced if ``done_episode_reward`` says so and all of them
        scaled by ``reward_scale``, on ``device``."""
        batch = Transitions.of(tensordict)
        if self.done_episode_reward is not None:
            batch = batch._replace(reward=torch.where(
                batch.terminated, float(self.done_episode_reward), batch.reward))
        if self.reward_scale != 1.0:
            batch = batch._replace(reward=batch.reward * float(self.reward_scale))
        return pack(batch).to(self.device)

    def optimize(self, n: int) -> None:
        """``n`` gradient steps on minibatches from the replay buffer."""
        stored = len(self.buffer)
        for _ in range(n):
            self._update(self.buffer.sample_transitions(stored))

    def _update(self, batch: Transitions) -> None:
        """One gradient step on ``batch``; the target network follows. No host sync: the
        tracker keeps the loss and values as tensors."""
        q, target = td_terms(self._q, self._target_q, batch, self.gamma, self.double_dqn)
        loss = _DISTANCES[self.loss_function](q, target)
        for p in self._params:  # optimizer.zero_grad()'s effect, without its profiling wrapper
            p.grad = None
        loss.backward()
        grad_norm = self._clip() if self.grad_clip > 0 else None
        self.optimizer.step()
        if self.lr_decay:
            self.lr_schedule.step()
        self.optimizer_steps += 1
        self._update_target()
        self.tracker.add(loss.detach(), q.detach(), target, grad_norm)

    def _clip(self) -> torch.Tensor:
        """``clip_grad_norm_(params, grad_clip)``'s very arithmetic in two foreach calls (it
        loops over the tensors on CPU); returns the norm before clipping."""
        grads = [p.grad for p in self._params if p.grad is not None]
        norm = grad_norm_of(self._params)
        torch._foreach_mul_(grads, (self.grad_clip / (norm + 1e-6)).clamp_(max=1.0))
        return norm

    def train_stats(self, reset: bool = True) -> dict[str, float]:
        """``train/*``: ``loss``, ``q_mean`` (of the taken actions), ``td_error`` (mean
        absolute) and ``grad_norm`` (before clipping), means over the updates since the last
        reset (the previous values if none ran; absent before the first update), but with
        ``grad_clip=0`` ``grad_norm`` is the latest update's (measured now, not per update);
        ``epsilon``, ``lr``, ``updates`` (optimizer steps so far) and ``updates_per_s`` (per
        wall-clock second since the last reset). ``reset=False`` reads without starting a
        new interval (for a progress bar shown between the logger's reads)."""
        stats = self.tracker.read(self.optimizer_steps, reset)
        if self.grad_clip == 0 and self._params[0].grad is not None:
            stats["grad_norm"] = float(grad_norm_of(self._params))
        return {**stats, "epsilon": float(self.schedule.value),
                "lr": float(self.optimizer.param_groups[0]["lr"])}

    def _update_target(self) -> None:
        """Polyak-averages (``tau``) or copies (every ``target_update`` steps) the target."""
        with torch.no_grad():
            if self.tau:
                torch._foreach_lerp_(self._target_params, self._params, self.tau)
            elif self.target_update and self.optimizer_steps % self.target_update == 0:
                torch._foreach_copy_(self._target_params, self._params)

    def _ready(self) -> bool:
        return len(self.buffer) >= max(self.learning_starts, 1)

    def learn(self, updates: float) -> None:
        """Adds ``updates`` minibatch updates to those owed (fractions carry over) and runs
        the whole ones, once the buffer holds ``learning_starts`` transitions."""
        if not self._ready():
            return
        self._credit += updates
        whole = int(self._credit)
        self._credit -= whole
        (self.updates_sink or self.optimize)(whole)

    def _sync_epsilon(self) -> None:
        """The exploring policy acts with the schedule's current epsilon."""
        self.explorer.epsilon = float(self.schedule.value)

    def begin(self) -> None:
        """Before the first step of a training session (a fresh run or a resumed one)."""
        self._sync_epsilon()
        self.tracker.restart(self.optimizer_steps)

    def act(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Epsilon-greedy on the Q-network."""
        return self.explorer(tensordict)

    def observe(self, tensordict: TensorDictBase) -> None:
        """Stores the batch of transitions and, per transition, learns as ``train_every`` says."""
        self.observe_rows(self.rows_of(tensordict))

    def observe_rows(self, rows: torch.Tensor) -> None:
        """:meth:`observe` of transitions already packed (:meth:`rows_of`), one row each."""
        self.buffer.put(rows)
        self.schedule.step(len(rows))
        if self.train_every == "step":
            self.learn(self.updates * len(rows))
        self._sync_epsilon()

    def end_episode(self) -> None:
        """After each finished episode: the schedule's episode step and per-episode updates."""
        self.schedule.episode_end()
        if self.train_every == "episode":
            self.learn(self.updates)
        self._sync_epsilon()

    def train(self, env, run: Loop) -> None:
        """Collects from the batched ``env`` and learns until ``run`` is done."""
        train(self, env, run)

    # -- persistence ---------------------------------------------------------
    kind = "dqn"

    def training_state(self) -> dict:
        """Everything the next update depends on, replay buffer included (for resuming)."""
        return {
            "format": FORMAT, "arch": self._arch(), "net": self.net.state_dict(),
            "target_net": self.target_net.state_dict(), "optimizer": self.optimizer.state_dict(),
            "lr_schedule": self.lr_schedule.state_dict(), "schedule": self.schedule.state_dict(),
            "optimizer_steps": self.optimizer_steps, "credit": self._credit,
            "buffer": self.buffer.state_dict(),
        }

    def load_training_state(self, state: dict) -> None:
        if state.get("format", 1) != FORMAT:
            raise StateMismatch(
                f"the training checkpoint holds a DQN state of format {state.get('format', 1)}, "
                f"this code reads format {FORMAT} (its replay buffer changed); resume it with "
                "the version that wrote it, or start the run afresh")
        self._check_arch(state["arch"], "the training checkpoint")
        self.net.load_state_dict(state["net"])
        self.target_net.load_state_dict(state["target_net"])
        self._load_optimizer(state["optimizer"])
        self.lr_schedule.load_state_dict(state["lr_schedule"])
        self.schedule.load_state_dict(state["schedule"])
        self.optimizer_steps = int(state["optimizer_steps"])
        self._credit = float(state["credit"])
        self.buffer.load_state_dict(state["buffer"])
        self._sync_epsilon()

    def _load_optimizer(self, state: dict) -> None:
        """Adam's state from a checkpoint, staying fused (a saved param group's flags would
        replace ours, and models saved before this change were not fused)."""
        self.optimizer.load_state_dict(state)
        for group in self.optimizer.param_groups:
            group.update(fused=True, foreach=None)

    def _check_arch(self, arch: dict, path) -> None:
        if arch != self._arch():
            raise StateMismatch(
                f"checkpoint {path} does not fit this run: it has network {arch}, "
                f"this run builds {self._arch()}")

    def model_state(self) -> dict:
        """The trained network, its optimiser and schedule (``model.pt``)."""
        return {
            "kind": "dqn", "arch": self._arch(), "actor": self.actor.state_dict(),
            "optimizer": self.optimizer.state_dict(), "schedule": self.schedule.state_dict(),
            "optimizer_steps": self.optimizer_steps,
        }

    def load_model_state(self, ckpt: Mapping, where: str) -> None:
        """Loads saved weights (and optimiser, schedule) into the built learner; ``where``
        names the state's origin in a :class:`StateMismatch`."""
        self._check_arch(ckpt["arch"], where)
        self.actor.load_state_dict(ckpt["actor"])
        self._load_optimizer(ckpt["optimizer"])
        self.schedule.load_state_dict(ckpt["schedule"])
        self.optimizer_steps = int(ckpt["optimizer_steps"])
        if self.target_net is not self.net:
            self.target_net.load_state_dict(self.net.state_dict())
