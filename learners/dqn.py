"""The replay-buffer DQN family as one TorchRL learner; variants are configs.

Parts: an ``MLP`` Q-network in a ``QValueActor``, TorchRL's ``EGreedyModule``
whose epsilon follows one of :mod:`learners.schedules`, a TD(0) loss (MSE or
Huber, optional double DQN) against an optional target network kept by hard
copies or Polyak averaging, and a ``ReplayBuffer`` over ``LazyTensorStorage``.

The loss is :func:`td_loss`, the same number TorchRL's ``DQNLoss`` with a TD(0)
estimator computes (``tests/test_dqn.py`` checks it), written on plain tensors:
on cart-pole a ``DQNLoss`` + ``SoftUpdate`` update costs ~2.5 ms (mostly
tensordict bookkeeping around a 4x64x64x2 network), this one ~0.7 ms, and
updates are most of a DQN run's wall-clock.

When it trains (``train_every``):

- ``episode``: ``updates`` minibatches after each finished episode (n1try,
  ruippeixotog);
- ``step``: ``updates`` minibatches per collected transition (mbalunovic: 1),
  fractional values allowed, once the buffer holds ``learning_starts``.

``done_episode_reward`` replaces the reward of terminating transitions
(mbalunovic's -200). ``run_episodes`` greedy episodes follow training
(ruippeixotog's "run" phase).

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
from pathlib import Path
from typing import Any, Iterator

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictSequential
from torch import nn
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.modules import MLP, EGreedyModule, QValueActor

from learners.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from learners.run import Run
from params import require
from params.declare import REQUIRED, check_fields, param

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU}
LOSSES = {"l2": "l2", "mse": "l2", "huber": "smooth_l1", "smooth_l1": "smooth_l1"}
_DISTANCES = {"l2": nn.functional.mse_loss, "smooth_l1": nn.functional.smooth_l1_loss}
_KEYS = ("observation", "action", ("next", "observation"), ("next", "reward"),
         ("next", "done"), ("next", "terminated"))


def td_loss(net: nn.Module, target_net: nn.Module, batch: TensorDictBase, gamma: float,
            double_dqn: bool, loss_function: str) -> torch.Tensor:
    """Mean TD(0) error of ``net`` on ``batch``; ``target_net`` values the next state."""
    return _DISTANCES[loss_function](*td_terms(net, target_net, batch, gamma, double_dqn))


def td_terms(net: nn.Module, target_net: nn.Module, batch: TensorDictBase, gamma: float,
             double_dqn: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """``(q, target)``, each ``[batch, 1]``: ``net``'s value of the taken actions and their
    TD(0) targets (no gradient), where ``target_net`` values the next state.

    ``double_dqn``: the next action is ``net``'s argmax, valued by ``target_net``.
    Terminated transitions do not bootstrap; truncated ones do.
    """
    action = batch.get("action").reshape(-1, 1)
    q = net(batch.get("observation")).gather(-1, action)
    with torch.no_grad():
        next_obs = batch.get(("next", "observation"))
        next_q = target_net(next_obs)
        if double_dqn:
            next_value = next_q.gather(-1, net(next_obs).argmax(-1, keepdim=True))
        else:
            next_value = next_q.amax(-1, keepdim=True)
        alive = (~batch.get(("next", "terminated"))).reshape(-1, 1)
        target = batch.get(("next", "reward")).reshape(-1, 1) + gamma * next_value * alive
    return q, target


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
        self.pending: list[tuple[torch.Tensor, torch.Tensor]] = []
        self.norms: list[torch.Tensor] = []
        self.loss_sum = self.q_sum = self.td_sum = self.norm_sum = 0.0
        self.count = self.values = self.n_norms = 0
        self.since, self.t0 = updates, time.perf_counter()

    def add(self, loss: float, q: torch.Tensor, target: torch.Tensor,
            grad_norm: torch.Tensor | None) -> None:
        """One update: its loss, ``q`` and ``target`` (detached), its gradient norm if known."""
        self.loss_sum += loss
        self.count += 1
        self.pending.append((q, target))
        if grad_norm is not None:
            self.norms.append(grad_norm)
        if len(self.pending) >= self.FOLD:
            self._fold()

    def _fold(self) -> None:
        if self.pending:
            q, target = (torch.cat(parts) for parts in zip(*self.pending))
            q_sum, td_sum = torch.stack((q.sum(), (target - q).abs_().sum())).tolist()
            self.q_sum, self.td_sum = self.q_sum + q_sum, self.td_sum + td_sum
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
    nepisodes: int = param(1000, "training episodes (the budget)", ge=1, le=10**8)
    nsteps: int = param(1000, "steps per episode at most (truncation)", ge=1, le=10**7)
    run_episodes: int = param(0, "greedy episodes after training (ruippeixotog's run phase)", ge=0,
                              le=4096)

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
        self.schedule = self.epsilon
        self.hidden = [int(h) for h in self.hidden]
        self.loss_function = LOSSES[self.loss]
        self.optimizer_steps = 0
        self._credit = 0.0
        self._greedy = False
        self.last_loss = float("nan")
        self.tracker = UpdateStats()

    # -- building ------------------------------------------------------------
    def _arch(self) -> dict:
        return {"n_obs": self.n_obs, "n_actions": self.n_actions, "hidden": self.hidden,
                "activation": self.activation}

    def build(self, task, generator: torch.Generator | None = None):
        """Creates network, exploration, loss, target updater, optimiser and buffer."""
        from torchrl.data import Categorical

        self.n_obs, self.n_actions = len(task.observation_names), int(task.n_actions)
        spec = Categorical(self.n_actions, dtype=torch.int64)
        self.net = MLP(in_features=self.n_obs, out_features=self.n_actions, num_cells=self.hidden,
                       activation_class=ACTIVATIONS[self.activation])
        self.actor = QValueActor(self.net, in_keys=["observation"], spec=spec)
        self.egreedy = EGreedyModule(spec, eps_init=float(self.schedule.value),
                                     eps_end=float(self.schedule.value), annealing_num_steps=1)
        self.explorer = TensorDictSequential(self.actor, self.egreedy)
        # Without a target network the online network values the next state itself.
        self.target_net = self.net
        if self.target_update or self.tau:
            self.target_net = copy.deepcopy(self.net).requires_grad_(False)
        self._params = list(self.net.parameters())
        self._target_params = list(self.target_net.parameters())
        self.optimizer = torch.optim.Adam(self._params, lr=self.lr)
        decay = self.lr_decay
        # Keras' legacy Adam ``decay``: lr_k = lr / (1 + decay * k) after k updates.
        self.lr_schedule = torch.optim.lr_scheduler.LambdaLR(
            self.optimizer, lambda k: 1.0 / (1.0 + decay * k))
        self.buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(self.buffer_size),
                                             batch_size=self.batch_size)
        return self.actor

    @property
    def policy(self):
        """The acting policy: epsilon-greedy while training, greedy inside ``greedy()``."""
        return self.actor if self._greedy else self.explorer

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
        batch = tensordict.select(*_KEYS).reshape(-1)  # extend() copies into storage
        if self.done_episode_reward is not None:
            term = batch.get(("next", "terminated"))
            reward = batch.get(("next", "reward"))
            batch.set(("next", "reward"),
                      torch.where(term, torch.full_like(reward, float(self.done_episode_reward)), reward))
        self.buffer.extend(batch)

    def optimize(self, n: int) -> None:
        """``n`` gradient steps on minibatches from the replay buffer."""
        for _ in range(n):
            q, target = td_terms(self.net, self.target_net, self.buffer.sample(), self.gamma,
                                 self.double_dqn)
            loss = _DISTANCES[self.loss_function](q, target)
            self.optimizer.zero_grad()
            loss.backward()
            grad_norm = None  # without clipping, measured only when read (train_stats)
            if self.grad_clip > 0:
                grad_norm = nn.utils.clip_grad_norm_(self._params, self.grad_clip)
            self.optimizer.step()
            self.lr_schedule.step()
            self.optimizer_steps += 1
            self._update_target()
            self.last_loss = float(loss.detach())
            self.tracker.add(self.last_loss, q.detach(), target, grad_norm)

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
        self.optimize(whole)

    def _sync_epsilon(self) -> None:
        """The exploration module acts with the schedule's current epsilon."""
        self.egreedy.eps.fill_(self.schedule.value)

    def train(self, env, run: Run) -> None:
        """Collects from the batched ``env`` and learns until ``run`` is done."""
        self._sync_epsilon()
        run.train_stats = self.train_stats
        self.tracker.restart(self.optimizer_steps)
        td = run.start(env)
        while not run.done:
            td = self.explorer(td)  # act: epsilon-greedy on the Q-network
            td, td_next = env.step_and_maybe_reset(td)
            self.store(td)
            self.schedule.step(td.numel())
            if self.train_every == "step":
                self.learn(self.updates * td.numel())
            self._sync_epsilon()
            for _ in run.record_step(env, td, self.stats):
                self.schedule.episode_end()
                if self.train_every == "episode":
                    self.learn(self.updates)
                self._sync_epsilon()
            td = run.end_step(td_next)

    # -- persistence ---------------------------------------------------------
    kind = "dqn"

    def training_state(self) -> dict:
        """Everything the next update depends on, replay buffer included (for resuming)."""
        return {
            "arch": self._arch(), "net": self.net.state_dict(),
            "target_net": self.target_net.state_dict(), "optimizer": self.optimizer.state_dict(),
            "lr_schedule": self.lr_schedule.state_dict(), "schedule": self.schedule.state_dict(),
            "optimizer_steps": self.optimizer_steps, "credit": self._credit,
            "last_loss": self.last_loss, "buffer": self.buffer.state_dict(),
        }

    def load_training_state(self, state: dict) -> None:
        self._check_arch(state["arch"], "the training checkpoint")
        self.net.load_state_dict(state["net"])
        self.target_net.load_state_dict(state["target_net"])
        self.optimizer.load_state_dict(state["optimizer"])
        self.lr_schedule.load_state_dict(state["lr_schedule"])
        self.schedule.load_state_dict(state["schedule"])
        self.optimizer_steps = int(state["optimizer_steps"])
        self._credit = float(state["credit"])
        self.last_loss = float(state["last_loss"])
        self.buffer.load_state_dict(state["buffer"])
        self._sync_epsilon()

    def _check_arch(self, arch: dict, path) -> None:
        if arch != self._arch():
            raise CheckpointError(
                f"checkpoint {path} does not fit this run: it has network {arch}, "
                f"this run builds {self._arch()}")

    def save(self, path: Path, meta: dict) -> None:
        save_checkpoint(path, {
            "kind": "dqn", "arch": self._arch(), "actor": self.actor.state_dict(),
            "optimizer": self.optimizer.state_dict(), "schedule": self.schedule.state_dict(),
            "optimizer_steps": self.optimizer_steps, "meta": meta,
        })

    def load(self, path: Path) -> None:
        """Loads saved weights (and optimiser, schedule) into the built learner."""
        ckpt = load_checkpoint(path, kind="dqn")
        self._check_arch(ckpt["arch"], path)
        self.actor.load_state_dict(ckpt["actor"])
        self.optimizer.load_state_dict(ckpt["optimizer"])
        self.schedule.load_state_dict(ckpt["schedule"])
        self.optimizer_steps = int(ckpt["optimizer_steps"])
        if self.target_net is not self.net:
            self.target_net.load_state_dict(self.net.state_dict())
