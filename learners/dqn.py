"""The replay-buffer DQN family as one TorchRL learner over a member axis; variants are configs.

Parts: an ``MLP`` Q-network (TorchRL's, in a ``QValueActor`` for checkpoints) whose
parameters are held for every member as one ``[members, P]`` tensor (:class:`StackedMLP`:
each linear layer a batched matrix product, ``baddbmm``, over the members), an
epsilon-greedy policy whose epsilon follows one of :mod:`learners.schedules` per member, a
TD(0) loss (MSE or Huber, optional double DQN; :func:`td_terms`) against an optional target
network kept by hard copies or Polyak averaging, gradients by autograd, Adam written over
the member axis (:func:`adam_step`: each member its own step count and learning rate), and
per member TorchRL's ``ReplayBuffer`` over one pre-allocated tensor (:class:`RowReplayBuffer`),
drawn uniformly or, with ``prioritized``, by TD error (:mod:`learners.priority`: the loss then
weighted by importance). Switches of Rainbow's parts: ``n_step`` (:mod:`learners.nstep`),
``dueling`` (:class:`DuelingHead`), ``prioritized``, ``noisy`` (TorchRL's ``NoisyLinear`` in
:class:`StackedMLP`) and ``distributional`` (:mod:`learners.distributional`).

A single run is one member. Every member's arithmetic is the same kernels whatever the
number of members (a batched product computes each matrix alone, a reduction each row
alone), so a member of a batch learns bit for bit as alone (``tests/test_members.py``).
Each member keeps its own random stream (its ``build`` generator: exploration draws,
minibatch indices and its network's initialisation), replay buffer, epsilon schedule,
update credit, counters and statistics.

When it trains (``train_every``):

- ``episode``: ``updates`` minibatches after each finished episode (n1try,
  ruippeixotog);
- ``step``: ``updates`` minibatches per collected transition (mbalunovic: 1),
  fractional values allowed, once the buffer holds ``learning_starts``.

The updates owed by the members run in rounds: a round updates every member that still
owes one, the others' parameters and optimizer state untouched.

``done_episode_reward`` replaces the reward of terminating transitions
(mbalunovic's -200); ``reward_scale`` then multiplies every reward the learner
stores (its Q-values in those units; the task's reward and measures unchanged).
``run_episodes`` greedy episodes follow training (ruippeixotog's "run" phase).

:meth:`DQN.train_stats` gives the numbers the logger shows as ``train/*``:
loss, mean Q of the taken actions, mean absolute TD error, gradient norm before
clipping, epsilon, learning rate, updates and updates per second. An update
only keeps its tensors for them (:class:`UpdateStats`: no host sync).
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
import time
import warnings
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.data import RandomSampler, ReplayBuffer, TensorStorage
from torchrl.modules import MLP, DistributionalQValueActor, NoisyLinear, QValueActor

from learners.base import Member, StateMismatch, check_state, everyone, member_settings, per_member, single
from params.private_api import with_entries
from learners.device import DEVICE_NOTE, check_device, resolve_device
from learners.distributional import c51_terms, expected, support
from learners.nstep import NStep
from learners.priority import Priorities, annealed_beta
from learners.transitions import Transitions, pack, unpack
from params import require
from params.declare import REQUIRED, check_fields, param

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU}
LOSSES = {"l2": "l2", "mse": "l2", "huber": "smooth_l1", "smooth_l1": "smooth_l1"}
_DISTANCES = {"l2": nn.functional.mse_loss, "smooth_l1": nn.functional.smooth_l1_loss}
# The training state's layout. 2: the replay buffer holds one float row per transition
# (``pack``) and there is no ``last_loss``; 1 (unmarked): a TensorDict storage.
FORMAT = 2
# The layers' gradients are views of one tensor (StackedMLP.layers), strided as their
# parameters are; autograd adds into them in place and notes that this is not its layout.
warnings.filterwarnings("ignore", message="grad and param do not obey the gradient layout contract")
ADAM_BETAS, ADAM_EPS = (0.9, 0.999), 1e-8  # torch.optim.Adam's defaults


QFunction = Callable[[torch.Tensor], torch.Tensor]  # observations -> Q-values


def td_loss(net: QFunction, target_net: QFunction, batch: Transitions, gamma: float,
            double_dqn: bool, loss_function: str) -> torch.Tensor:
    """Mean TD(0) error of ``net`` on ``batch``; ``target_net`` values the next state."""
    return _DISTANCES[loss_function](*td_terms(net, target_net, batch, gamma, double_dqn))


def td_terms(net: QFunction, target_net: QFunction, batch: Transitions, gamma: float,
             double_dqn: bool) -> tuple[torch.Tensor, torch.Tensor]:
    """``(q, target)``, each ``[..., batch, 1]``: ``net``'s value of the taken actions and
    their TD targets (no gradient: one step, or gamma^k for an n-step row of ``steps`` k),
    where ``target_net`` values the next state.

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
        discount = gamma if batch.steps is None else gamma ** batch.steps  # n-step rows: gamma^k
        target = batch.reward + discount * next_value * ~batch.terminated
    return q, target


class RowReplayBuffer(ReplayBuffer):
    """TorchRL's ``ReplayBuffer`` over a ``TensorStorage`` of one pre-allocated float tensor,
    ``rows``, a row per transition (:func:`pack`).

    ``extend``, ``sample``, indexing and ``state_dict`` are TorchRL's. The update's
    :meth:`sample_transitions` draws the indices itself, the very draw of TorchRL's
    ``RandomSampler`` (``torch.randint``), from a given generator, and indexes ``rows``
    (``bench/update_rate.py`` times it against ``sample()``).

    :meth:`put` queues rows instead of writing them: TorchRL's ``extend`` has a cost per
    call whatever its size, and a DQN adds a few rows per env step but reads the buffer
    only when it updates. The queue is written by one ``extend`` of its rows, in order, as
    soon as anything touches the storage (the length, a sample, ``rows``, the state,
    ``extend`` itself: every path of ``ReplayBuffer`` goes through ``_storage``), and
    before it would hold more rows than the buffer, so the buffer never sees the
    difference: the same rows at the same places, the same cursor and length.
    :meth:`stored` gives that length without writing them: a learner that updates every
    fourth env step writes once per update instead of once per step (TorchRL's ``extend``
    was ~12% of a cart-pole dqn run).
    """

    def __init__(self, capacity: int, width: int, batch_size: int,
                 device: torch.device | str = "cpu") -> None:
        self._queue: list[torch.Tensor] = []
        self._queued = 0
        self.priorities: Priorities | None = None  # prioritized replay: each written row gets one
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

    def stored(self) -> int:
        """``len(self)`` as it will be once the queued rows are written, without writing them
        (a DQN asks it every env step, and samples only every few)."""
        return min(len(self.__dict__["_storage_"]) + self._queued, self._capacity)

    def flush(self) -> None:
        """Writes the queued rows (one ``extend``)."""
        queue, self._queue, self._queued = self._queue, [], 0
        if queue:
            index = self.extend(queue[0] if len(queue) == 1 else torch.cat(queue))
            if self.priorities is not None:
                self.priorities.added(index)

    def sample_rows(self, stored: int, generator: torch.Generator | None = None,
                    out: torch.Tensor | None = None) -> torch.Tensor:
        """A minibatch of rows drawn uniformly from the first ``stored`` rows (``len(self)``)."""
        index = torch.randint(0, stored, (self.batch_size,), generator=generator)
        rows = self.rows
        return torch.index_select(rows, 0, index.to(rows.device), out=out)

    def sample_prioritized(self, stored: int, beta: float, generator: torch.Generator | None = None,
                           out: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """``(rows, index, weight)``: a minibatch drawn by :attr:`priorities` from the first
        ``stored`` rows, their indices and importance weights (``beta``)."""
        rows = self.rows
        index, weight = self.priorities.sample(stored, self.batch_size, beta, generator)
        return torch.index_select(rows, 0, index.to(rows.device), out=out), index, weight

    def sample_transitions(self, stored: int, generator: torch.Generator | None = None) -> Transitions:
        """:meth:`sample_rows` as :class:`Transitions`."""
        return unpack(self.sample_rows(stored, generator))

    def transitions(self) -> Transitions:
        """Every stored transition, in storage order."""
        return unpack(self.rows[: len(self)])


class ObsScale(nn.Module):
    """Multiplies each observation entry by a fixed factor before the Q-network's layers
    (inputs of one size: a wheel speed of 100 beside an angle of 0.1 drowns the angle)."""

    def __init__(self, scale: torch.Tensor) -> None:
        super().__init__()
        self.register_buffer("scale", scale)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.scale


def dueling(x: torch.Tensor, atoms: int = 1) -> torch.Tensor:
    """Q from a value and advantages (Wang et al. 2016, the mean-advantage form): ``x``'s
    first entry is V(s), the rest A(s, a); Q = V + A - mean_a A. With ``atoms`` > 1 (C51's
    logits, ``[atoms, 1 + actions]`` flat), each atom's alike.

    As one product with :func:`dueling_matrix` (a column per action: 1 for V, 1 - 1/n for its
    own advantage, -1/n for the others'): 2.8x faster forward and backward than slicing,
    averaging and adding on C51's strided ``[atoms, 1 + actions]`` views."""
    rows = x.unflatten(-1, (atoms, -1)) if atoms > 1 else x
    q = rows @ dueling_matrix(rows.shape[-1] - 1, x.dtype, x.device)
    return q.flatten(-2) if atoms > 1 else q


@functools.lru_cache(maxsize=16)
def dueling_matrix(actions: int, dtype: torch.dtype, device: torch.device) -> torch.Tensor:
    """``[1 + actions, actions]``: V and the advantages to Q, ``Q = [V, A] @ M`` (:func:`dueling`)."""
    return torch.cat([torch.ones(1, actions), torch.eye(actions) - 1.0 / actions]).to(dtype=dtype, device=device)


class DuelingHead(nn.Module):
    """The last layer's V(s) and A(s, .) (``learner.dueling``) as Q-values (or, per atom, as
    C51's logits): :func:`dueling`."""

    def __init__(self, atoms: int = 1) -> None:
        super().__init__()
        self.atoms = atoms

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return dueling(x, self.atoms)


_FUNCTIONS = {nn.Tanh: torch.tanh, nn.ReLU: torch.relu}


class StackedMLP:
    """The Q-networks of every member of a learner, all their parameters one ``[members, P]``
    tensor laid out as ``torch.nn.utils.parameters_to_vector`` lays out a ``template`` network's
    (its linear layers' weight and bias in order, after an optional :class:`ObsScale`).

    ``q(params, x)``: each member's network on its ``x`` (``[k, n, n_obs]`` with ``params``
    ``[k, P]``): every linear layer one ``baddbmm``, each member's matrix product computed
    alone whatever ``k``.

    A TorchRL ``NoisyLinear`` of the template (``learner.noisy``; Fortunato et al. 2018) holds
    its mean and standard deviation weights (``weight_mu``, ``weight_sigma``, ``bias_mu``,
    ``bias_sigma``, its parameters' order); ``q`` uses the mean weights unless given factorised
    noise (:meth:`noise`): ``w = mu_w + sigma_w * f(e_out) f(e_in)^T``, ``b = mu_b + sigma_b * f(e_out)``,
    ``f(x) = sign(x) sqrt|x|``, as ``NoisyLinear.reset_noise`` draws it."""

    def __init__(self, template: nn.Sequential, device: torch.device | str = "cpu") -> None:
        self.template = template  # on the CPU
        self.scale: torch.Tensor | None = None
        self.plan: list = []  # a linear layer's parameters ((start, end, shape), ...), or a function
        self.noisy_sizes: list[tuple[int, int]] = []  # (in, out) of each noisy layer
        offset = 0
        for layer in template:
            if isinstance(layer, ObsScale):
                self.scale = layer.scale.to(device)
            elif isinstance(layer, nn.Linear):
                out, inp = layer.out_features, layer.in_features
                noisy = isinstance(layer, NoisyLinear)
                shapes = [(out, inp), (out, inp), (out,), (out,)] if noisy else [(out, inp), (out,)]
                slots = []  # (start, end, shape) of each parameter of the layer
                for shape in shapes:
                    slots.append((offset, offset + math.prod(shape), shape))
                    offset += math.prod(shape)
                self.plan.append(tuple(slots))
                if noisy:
                    self.noisy_sizes.append((inp, out))
            elif isinstance(layer, DuelingHead):
                self.plan.append(layer.forward)
            elif not isinstance(layer, nn.Unflatten):  # (C51's [atoms, actions] for the saved model: q is flat)
                self.plan.append(_FUNCTIONS[type(layer)])
        self.size = offset

    def layers(self, params: torch.Tensor, grads: torch.Tensor | None = None) -> list:
        """Each linear layer's ``(weight [k, out, in], bias [k, 1, out])`` (a noisy layer's
        ``(weight_mu, weight_sigma, bias_mu, bias_sigma)``) as views of ``params`` (``[k, P]``).
        With ``grads`` (``[k, P]``) they are autograd leaves whose gradients are views of
        ``grads``: a backward adds every layer's gradient into that one tensor (zero it first),
        where clipping and Adam take them all at once."""
        k, found = len(params), []
        for layer in self.plan:
            if callable(layer):
                continue
            views = []
            for start, end, shape in layer:
                view = params[:, start:end].view(k, *shape)
                if grads is not None:
                    view.requires_grad_(True)
                    view.grad = grads[:, start:end].view(k, *shape)
                views.append(view if len(shape) == 2 else view.unsqueeze(1))
            found.append(tuple(views))
        return found

    def noise(self, generators: Sequence[torch.Generator | None], device: torch.device | str) -> list:
        """Factorised noise of each noisy layer for ``k`` members, ``(f(e_in) [k, in],
        f(e_out) [k, out])``, member ``j``'s drawn from ``generators[j]`` (None: zero noise,
        the mean weights)."""
        total = sum(inp + out for inp, out in self.noisy_sizes)
        drawn = torch.zeros(len(generators), total)
        for j, generator in enumerate(generators):
            if generator is not None:
                torch.randn(total, generator=generator, out=drawn[j])
        drawn = drawn.sign().mul_(drawn.abs().sqrt_()).to(device)
        found, offset = [], 0
        for inp, out in self.noisy_sizes:
            found.append((drawn[:, offset:offset + inp], drawn[:, offset + inp:offset + inp + out]))
            offset += inp + out
        return found

    def q(self, params: torch.Tensor | list, x: torch.Tensor, noise: list | None = None) -> torch.Tensor:
        """Each member's Q-values of its ``x`` (``[k, n, n_obs]``); ``params``: ``[k, P]`` or
        its :meth:`layers`; ``noise``: the noisy layers' (:meth:`noise`; None: mean weights)."""
        layers = self.layers(params) if isinstance(params, torch.Tensor) else params
        if self.noisy_sizes:
            layers = self.with_noise(layers, noise)
        layers = iter(layers)
        if self.scale is not None:
            x = x * self.scale
        for layer in self.plan:
            if callable(layer):
                x = layer(x)
                continue
            weight, bias = next(layers)
            x = torch.baddbmm(bias, x, weight.transpose(1, 2))
        return x

    def with_noise(self, layers: list, noise: list | None) -> list:
        """:meth:`layers` with each noisy layer's ``(weight, bias)`` for ``noise`` (None: its
        mean weights); a network evaluated twice with one noise (an update's online network)
        makes them once."""
        noises, found = iter(noise or ()), []
        for parts in layers:
            if len(parts) == 2:
                found.append(parts)
            elif noise is None:
                found.append((parts[0], parts[2]))
            else:
                (weight_mu, weight_sigma, bias_mu, bias_sigma), (e_in, e_out) = parts, next(noises)
                found.append((weight_mu + weight_sigma * (e_out.unsqueeze(2) * e_in.unsqueeze(1)),
                              bias_mu + bias_sigma * e_out.unsqueeze(1)))
        return found

    def vector(self) -> torch.Tensor:
        """The template's parameters as one ``[P]`` vector."""
        return nn.utils.parameters_to_vector(self.template.parameters()).detach().clone()

    def load(self, vector: torch.Tensor) -> nn.Sequential:
        """The template holding ``vector``'s parameters."""
        nn.utils.vector_to_parameters(vector.detach().cpu(), self.template.parameters())
        return self.template


def adam_step(params: torch.Tensor, grads: torch.Tensor, exp_avg: torch.Tensor, exp_avg_sq: torch.Tensor,
              steps: Sequence[int], lrs: Sequence[float]) -> None:
    """One Adam step (``torch.optim.Adam``'s arithmetic, default betas and eps) of each row of
    ``params`` (``[k, P]``, a member each), ``steps[j]`` its step count after this step and
    ``lrs[j]`` its learning rate; in place."""
    beta1, beta2 = ADAM_BETAS
    size = [[lr / (1 - beta1 ** s)] for lr, s in zip(lrs, steps)]
    root = [[math.sqrt(1 - beta2 ** s)] for s in steps]
    step_size = torch.tensor(size, dtype=params.dtype, device=params.device)
    correction = torch.tensor(root, dtype=params.dtype, device=params.device)
    exp_avg.lerp_(grads, 1 - beta1)
    exp_avg_sq.mul_(beta2).addcmul_(grads, grads, value=1 - beta2)
    denom = (exp_avg_sq.sqrt() / correction).add_(ADAM_EPS)
    params.sub_(exp_avg / denom * step_size)


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


def _one_target_kind(settings: Sequence[DQN]) -> None:
    """One line unless the members of ``settings`` all have a target network or none."""
    require(len({bool(v.target_update or v.tau) for v in settings}) == 1,
            "learner.tau and learner.target_update: members of one batch must all have a target network or none",
            [(v.tau, v.target_update) for v in settings])


@dataclass(eq=False)
class DQN:
    """A configurable DQN over a member axis (see the module docstring)."""

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
    n_step: int = param(1, "rewards summed before bootstrapping (n-step returns; 1: one-step TD)", ge=1, le=100)
    loss: str = param("huber", "TD error's loss", choices=tuple(LOSSES))
    double_dqn: bool = param(True, "the online network picks the next action, the target values it")
    dueling: bool = param(False, "value and advantage streams: the last layer gives V(s) and A(s, a), "
                                 "Q = V + A - mean A")
    distributional: bool = param(False, "C51: per action a distribution over atoms returns in [v_min, v_max], "
                                        "its mean the action's value, a cross-entropy loss to the projected target")
    atoms: int = param(51, "C51's number of returns (atoms)", ge=2, le=1001)
    v_min: float = param(-10.0, "C51's lowest return (of rewards after reward_scale)")
    v_max: float = param(10.0, "C51's highest return (above v_min)")
    noisy: bool = param(False, "noisy layers (factorised Gaussian) explore instead of epsilon, which is "
                               "then not used; greedy evaluations use the mean weights")
    noisy_sigma: float = param(0.5, "noisy layers' initial noise scale, sigma_0 (TorchRL NoisyLinear's std_init)",
                               gt=0, le=10)
    prioritized: bool = param(False, "prioritized replay: rows drawn in proportion to (|TD error| + "
                                     "priority_eps)^priority_alpha, the loss weighted by importance")
    priority_alpha: float = param(0.6, "prioritized replay's exponent (0: uniform)", ge=0, le=1)
    priority_beta: float = param(0.4, "importance weights' exponent at the start, raised linearly to 1",
                                 ge=0, le=1)
    priority_beta_updates: int = param(100_000, "updates over which priority_beta rises to 1", ge=1)
    priority_eps: float = param(1e-6, "added to each |TD error| so that no row is never drawn", gt=0)
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
    run_episodes: int = param(0, "greedy episodes after training (ruippeixotog's run phase)", ge=0,
                              le=4096)
    device: str = param("cpu", "where the networks, updates and replay buffer live",
                        note=DEVICE_NOTE, check=check_device)

    kind = "dqn"
    out_keys = ("action",)
    # Settings members of one batch may differ in (a tuning study's trials side by side):
    # none changes the network's shape (each member has its own replay buffer, and an update
    # round runs once per minibatch size among its members); all must have a target network
    # or none.
    MEMBER_WISE = ("lr", "lr_decay", "gamma", "tau", "target_update", "epsilon", "updates", "learning_starts",
                   "grad_clip", "done_episode_reward", "reward_scale", "priority_alpha", "priority_beta",
                   "priority_beta_updates", "priority_eps", "buffer_size", "batch_size")
    SIZING = ("buffer_size",)  # of MEMBER_WISE, those that size a member's training state

    def __post_init__(self) -> None:
        check_fields(self, "learner")
        require(1 <= len(self.hidden) <= 16 and all(1 <= h <= 65_536 for h in self.hidden),
                "learner.hidden must list 1 to 16 layer widths in [1, 65536]", self.hidden)
        require(not (self.target_update and self.tau),
                "learner.target_update and learner.tau exclude each other",
                (self.target_update, self.tau))
        require(not self.double_dqn or self.target_update or self.tau,
                "learner.double_dqn needs a target network (target_update or tau)", self.double_dqn)
        require(self.v_min < self.v_max, f"learner.v_max must be above learner.v_min ({self.v_min})", self.v_max)
        require(self.batch_size <= self.buffer_size, "learner.batch_size must be in [1, buffer_size]",
                (self.batch_size, self.buffer_size))
        require(self.learning_starts <= self.buffer_size,
                f"learner.learning_starts must be <= learner.buffer_size ({self.buffer_size}), "
                "else it never trains", self.learning_starts)
        require(all(hasattr(self.epsilon, k) for k in ("value", "step", "episode_end")),
                "learner.epsilon must be a schedule node (_target_: learners.schedules."
                "LinearEpsilon, MultiplicativeEpsilon or LogEpisodeEpsilon)", self.epsilon)
        self.device = str(resolve_device(self.device))  # auto -> cuda or cpu
        self.hidden = [int(h) for h in self.hidden]
        self.loss_function = LOSSES[self.loss]
        self.members = 0

    # -- building ------------------------------------------------------------
    def _arch(self) -> dict:
        arch = {"n_obs": self.n_obs, "n_actions": self.n_actions, "hidden": self.hidden,
                "activation": self.activation}
        return arch | ({"obs_scale": dict(self.obs_scale)} if self.obs_scale else {}) | (
            {"dueling": True} if self.dueling else {}) | ({"noisy": True} if self.noisy else {}) | (
            {"distributional": {"atoms": self.atoms, "v_min": self.v_min, "v_max": self.v_max}}
            if self.distributional else {})

    def _template(self, task) -> nn.Sequential:
        """One member's Q-network on the CPU (where each member's stream initialises it and
        its states are saved): TorchRL's ``MLP``, after an :class:`ObsScale` if asked, ending in
        a :class:`DuelingHead` with ``dueling``; its layers TorchRL's ``NoisyLinear`` with ``noisy``
        (their noise buffers zero: the saved model acts by its mean weights)."""
        noisy = {"layer_class": NoisyLinear, "layer_kwargs": {"std_init": self.noisy_sigma}} if self.noisy else {}
        atoms = self.atoms if self.distributional else 1
        net = MLP(in_features=self.n_obs, out_features=(self.n_actions + self.dueling) * atoms, num_cells=self.hidden,
                  activation_class=ACTIVATIONS[self.activation], **noisy)
        for layer in (m for m in net if isinstance(m, NoisyLinear)):  # noise is drawn per member, not kept
            layer.weight_epsilon.zero_()
            layer.bias_epsilon.zero_()
        if self.dueling:  # one more output, V(s), before the advantages
            net = nn.Sequential(*net, DuelingHead(atoms))
        if self.distributional:  # TorchRL's DistributionalQValueActor reads [atoms, actions]
            net = nn.Sequential(*net, nn.Unflatten(-1, (atoms, self.n_actions)))
        if self.obs_scale:
            names = list(task.observation_names)
            unknown = sorted(set(self.obs_scale) - set(names))
            require(not unknown, f"learner.obs_scale names no observation of this task; its "
                                 f"observations: {', '.join(names)}", unknown)
            scale = torch.tensor([float(self.obs_scale.get(n, 1.0)) for n in names])
            net = nn.Sequential(ObsScale(scale), *net)
        return net

    def build(self, task, generators: torch.Generator | Sequence[torch.Generator] | None = None,
              variants: Sequence[DQN] | None = None) -> None:
        """The networks, optimizer state and replay buffers of one member per generator: its
        stream initialises its network (as ``nn.Linear`` does from torch's global stream) and
        then draws its exploration and minibatches; ``variants``: each member's own settings
        (:data:`MEMBER_WISE`)."""
        from torchrl.data import Categorical

        self.generators = single(generators)
        self.members = m = len(self.generators)
        self.settings = own = member_settings(self, variants, m)
        _one_target_kind(own)
        self.n_obs, self.n_actions = len(task.observation_names), int(task.n_actions)
        with torch.random.fork_rng(devices=[]):  # its own init is replaced by each member's
            template = self._template(task)
        self.net = StackedMLP(template, self.device)
        spec = Categorical(self.n_actions, dtype=torch.int64)
        self.z = support(self.atoms, self.v_min, self.v_max).to(self.device) if self.distributional else None
        if self.distributional:  # model.pt's layout
            self.actor = DistributionalQValueActor(template, support=self.z.cpu(), in_keys=["observation"], spec=spec)
        else:
            self.actor = QValueActor(template, in_keys=["observation"], spec=spec)
        self.params = torch.empty(m, self.net.size, device=self.device)
        for b, generator in enumerate(self.generators):
            self.params[b] = self._initial(generator)
        self.has_target = bool(self.target_update or self.tau)
        self.target = self.params.clone() if self.has_target else self.params
        self.exp_avg = torch.zeros_like(self.params)
        self.exp_avg_sq = torch.zeros_like(self.params)
        self.grads = torch.zeros_like(self.params)  # each member's latest gradients
        # Every member's layers, and the target network's (without one: the online network
        # values the next state), as views (an update's autograd leaves are made anew each
        # round: a leaf whose storage Adam changed in place would not stay one).
        self._online = self.net.layers(self.params)
        self._valued = self.net.layers(self.target)
        self.steps = [0] * m  # optimizer steps per member
        self.credit = [0.0] * m  # updates owed, fractions carried over
        self.owed = [0] * m  # whole updates owed, run by settle
        self.schedules = [v.epsilon if b == 0 else copy.deepcopy(v.epsilon) for b, v in enumerate(own)]  # each its own
        self.trackers = [UpdateStats() for _ in range(m)]
        self.buffers = [self._buffer(v) for v in own]
        self._minibatch = self._minibatches()
        self.nsteps: list[NStep] = []  # each member's queues, made at its first step (copies known then)

    def _row_width(self) -> int:
        """A replay buffer row's numbers (:func:`pack`); n-step rows carry their steps."""
        return 2 * self.n_obs + 3 + (self.n_step > 1)

    def _buffer(self, own: DQN) -> RowReplayBuffer:
        """An empty replay buffer of a member with settings ``own`` (its priorities too)."""
        buffer = RowReplayBuffer(own.buffer_size, self._row_width(), own.batch_size, self.device)
        if self.prioritized:
            buffer.priorities = Priorities(own.buffer_size, own.priority_alpha, own.priority_eps, self.device)
        return buffer

    def _minibatches(self) -> dict[int, torch.Tensor]:
        """A round's minibatches, per minibatch size among the members: as many as members of it."""
        sizes = [v.batch_size for v in self.settings]
        return {size: torch.empty(sizes.count(size), size, self._row_width(), device=self.device) for size in sizes}

    @torch.no_grad()
    def renew(self, b: int, generator: torch.Generator, variant: DQN | None = None) -> None:
        """Member ``b`` made anew from ``generator`` and ``variant`` (None: this learner's
        settings), as :meth:`build` makes a member: a batch's freed member given another trial
        x seed. The other members are left as they are."""
        own = self if variant is None else member_settings(self, [variant], 1)[0]
        _one_target_kind([self.settings[0], own])
        self.generators[b], self.settings[b] = generator, own
        self.params[b] = self._initial(generator)
        if self.has_target:
            self.target[b] = self.params[b]
        for moments in (self.exp_avg, self.exp_avg_sq, self.grads):
            moments[b].zero_()
        self.steps[b], self.credit[b], self.owed[b] = 0, 0.0, 0
        self.schedules[b] = dataclasses.replace(own.epsilon)  # at its start, whatever own's has done
        self.trackers[b] = UpdateStats()
        self.buffers[b] = self._buffer(own)
        self._minibatch = self._minibatches()
        if self.nsteps:
            copies = len(self.nsteps[b].count)
            self.nsteps[b] = NStep(self.n_step, copies, self.n_obs, own.gamma)

    def _initial(self, generator: torch.Generator) -> torch.Tensor:
        """Fresh parameters of the template's layers drawn from ``generator`` (their own
        ``reset_parameters``, as on torch's global stream)."""
        with torch.random.fork_rng(devices=[]):
            torch.set_rng_state(generator.get_state())
            for layer in self.net.template:
                if isinstance(layer, nn.Linear):
                    layer.reset_parameters()
            generator.set_state(torch.get_rng_state())
        return self.net.vector()

    def member(self, b: int) -> Member:
        return Member(self, b)

    def lr_of(self, b: int, steps: int | None = None) -> float:
        """Member ``b``'s learning rate after ``steps`` updates (default: its updates so far;
        Keras' legacy decay: lr / (1 + decay * updates))."""
        own, steps = self.settings[b], self.steps[b] if steps is None else steps
        return own.lr * (1.0 / (1.0 + own.lr_decay * steps)) if own.lr_decay else own.lr

    def stats(self, b: int) -> dict[str, float]:
        epsilon = 0.0 if self.noisy else float(self.schedules[b].value)
        return {"alpha": self.lr_of(b), "gamma": self.settings[b].gamma, "epsilon": epsilon}

    def train_stats(self, b: int, reset: bool = True) -> dict[str, float]:
        """``train/*`` of member ``b``: ``loss``, ``q_mean`` (of the taken actions),
        ``td_error`` (mean absolute) and ``grad_norm`` (before clipping), means over the
        updates since the last reset (the previous values if none ran; absent before the
        first update), but with ``grad_clip=0`` ``grad_norm`` is the latest update's;
        ``epsilon``, ``lr``, ``updates`` (optimizer steps so far) and ``updates_per_s`` (per
        wall-clock second since the last reset). ``reset=False`` reads without starting a
        new interval (for a progress bar shown between the logger's reads)."""
        stats = self.trackers[b].read(self.steps[b], reset)
        if self.settings[b].grad_clip == 0 and self.steps[b]:
            stats["grad_norm"] = float(torch.linalg.vector_norm(self.grads[b]))
        return {**stats, "epsilon": float(self.schedules[b].value), "lr": self.lr_of(b)}

    # -- acting --------------------------------------------------------------
    def begin(self) -> None:
        """Before the first step of a training session (a fresh run or a resumed one)."""
        for b, tracker in enumerate(self.trackers):
            tracker.restart(self.steps[b])

    def act(self, td: TensorDictBase, live: Sequence[int] | None = None) -> TensorDictBase:
        """Every member's epsilon-greedy actions on its block; only ``live`` members draw."""
        if live is None or len(live) == self.members:
            return self.act_members(td, None, False, self.generators)
        live = set(live)
        return self.act_members(td, None, False, [g if b in live else None for b, g in enumerate(self.generators)])

    def act_members(self, td: TensorDictBase, members: Sequence[int] | None, greedy: bool,
                    generators: Sequence[torch.Generator | None]) -> TensorDictBase:
        """The actions of ``members`` (None: all) on their blocks of ``td`` (block ``j`` is
        member ``members[j]``'s): the Q-network's argmax, or unless ``greedy`` with probability
        epsilon a uniformly random action, drawn from ``generators[j]`` as TorchRL's
        ``EGreedyModule`` draws (a uniform per copy, then a random action per copy). Returns a
        new tensordict of ``td``'s entries and ``action``."""
        params = self._online if members is None else self.params[list(members)]
        members = range(self.members) if members is None else list(members)
        k = len(members)
        observation = td.get("observation")
        noise = self.net.noise(generators, self.device) if self.noisy and not greedy else None
        with torch.no_grad():
            q = self.net.q(params, observation.reshape(k, -1, self.n_obs).to(self.device), noise)
            if self.distributional:
                q = expected(q, self.z)
        action = q.argmax(-1).cpu()
        if not greedy and not self.noisy:
            n = action.shape[1]
            uniform = torch.ones(k, n)
            random_action = torch.zeros(k, n, dtype=torch.int64)
            for j, generator in enumerate(generators):
                if generator is not None:
                    torch.rand(n, generator=generator, out=uniform[j])
                    torch.randint(0, self.n_actions, (n,), generator=generator, out=random_action[j])
            epsilon = torch.tensor([[float(self.schedules[b].value)] for b in members])
            action = torch.where(uniform < epsilon, random_action, action)
        return with_entries(td, action=action.reshape(td.batch_size))

    # -- learning ------------------------------------------------------------
    def transitions_of(self, tensordict: TensorDictBase, own: DQN | None = None) -> Transitions:
        """The transitions of ``tensordict``, the terminating rewards replaced if
        ``done_episode_reward`` says so and all of them scaled by ``reward_scale`` (``own``'s:
        a member's settings; default the learner's)."""
        own = self if own is None else own
        batch = Transitions.of(tensordict)
        if own.done_episode_reward is not None:
            batch = batch._replace(reward=torch.where(
                batch.terminated, float(own.done_episode_reward), batch.reward))
        if own.reward_scale != 1.0:
            batch = batch._replace(reward=batch.reward * float(own.reward_scale))
        return batch

    def rows_of(self, tensordict: TensorDictBase, own: DQN | None = None) -> torch.Tensor:
        """The buffer's rows (:func:`pack`) of :meth:`transitions_of`, on ``device``."""
        return pack(self.transitions_of(tensordict, own)).to(self.device)

    def store(self, td: TensorDictBase, live: Sequence[int] | None = None) -> int:
        """Each live member adds its block's transitions to its replay buffer (with
        ``n_step`` > 1, the n-step rows that leave its queues); the block size."""
        n = td.numel() // self.members
        flat = td.reshape(-1)
        if self.n_step > 1:
            self._store_n_step(flat, n, live)
            return n
        alike = all(v is self.settings[0] for v in self.settings)
        rows = self.rows_of(td) if alike else None
        for b in everyone(self, live):
            block = rows[b * n:(b + 1) * n] if alike else self.rows_of(flat[b * n:(b + 1) * n], self.settings[b])
            self.buffers[b].put(block)
        return n

    def _queues(self, copies: int) -> None:
        """Each member's n-step queues for ``copies`` copies (made at the first step or the
        first loaded state, when the copies are known)."""
        if not self.nsteps:
            self.nsteps = [NStep(self.n_step, copies, self.n_obs, own.gamma) for own in self.settings]

    def _store_n_step(self, flat: TensorDictBase, n: int, live: Sequence[int] | None) -> None:
        self._queues(n)
        done = flat.get(("next", "done")).reshape(-1)
        for b in everyone(self, live):
            block = slice(b * n, (b + 1) * n)
            rows = self.nsteps[b].push(self.transitions_of(flat[block], self.settings[b]), done[block])
            if rows is not None:
                self.buffers[b].put(pack(rows).to(self.device))

    def observe(self, td: TensorDictBase, live: Sequence[int] | None = None) -> None:
        """Each live member stores its block's transitions and counts them (schedule, update
        credit with ``train_every=step``); then the updates owed run."""
        n = self.store(td, live)
        for b in everyone(self, live):
            self.schedules[b].step(n)
            if self.train_every == "step":
                self._owe(b, self.settings[b].updates * n)
        self.settle()

    def optimize(self, n: int, members: Sequence[int] | None = None) -> None:
        """``n`` updates of each of ``members`` (all by default) on its replay buffer, now."""
        for b in everyone(self, members):
            self.owed[b] += n
        self.settle()

    def end_episodes(self, ended: Mapping[int, int]) -> None:
        """After each finished episode of a member: the schedule's episode step and, with
        ``train_every=episode``, its updates; then the updates owed run."""
        for b, count in ended.items():
            for _ in range(count):
                self.schedules[b].episode_end()
                if self.train_every == "episode":
                    self._owe(b, self.settings[b].updates)
        self.settle()

    def _owe(self, b: int, updates: float) -> None:
        """Adds ``updates`` to member ``b``'s credit once its buffer holds ``learning_starts``
        transitions; the whole ones are owed."""
        if self.buffers[b].stored() < max(self.settings[b].learning_starts, 1):
            return
        self.credit[b] += updates
        whole = int(self.credit[b])
        self.credit[b] -= whole
        self.owed[b] += whole

    def settle(self) -> None:
        """Runs the updates the members owe, in rounds: a round updates every member that still
        owes one (each member's updates in its order, as alone)."""
        owed, self.owed = self.owed, [0] * self.members
        stored = {b: len(self.buffers[b]) for b in range(self.members) if owed[b]}
        for done in range(max(owed)):
            self._round([b for b in stored if owed[b] > done], stored)

    def _round(self, due: list[int], stored: Mapping[int, int]) -> None:
        """One update of each member of ``due``: those of one minibatch size together
        (:meth:`_update`)."""
        sizes = {self.settings[b].batch_size for b in due}
        if len(sizes) == 1:
            self._update(due, stored, self._minibatch[sizes.pop()])
            return
        for size in sorted(sizes):
            self._update([b for b in due if self.settings[b].batch_size == size], stored, self._minibatch[size])

    def _update(self, due: list[int], stored: Mapping[int, int], minibatch: torch.Tensor) -> None:
        """One update of each member of ``due`` (all of one minibatch size, ``minibatch`` a
        tensor of at least their number of minibatches): its minibatch, its TD loss's
        gradients by autograd, its clipped norm, its Adam step and its target network's."""
        k = len(due)
        drawn, weights = [], []  # prioritized replay: each member's rows and importance weights
        for j, b in enumerate(due):
            if self.prioritized:
                v = self.settings[b]
                beta = annealed_beta(v.priority_beta, self.steps[b], v.priority_beta_updates)
                _, index, weight = self.buffers[b].sample_prioritized(stored[b], beta, self.generators[b],
                                                                      out=minibatch[j])
                drawn.append(index)
                weights.append(weight)
            else:
                self.buffers[b].sample_rows(stored[b], self.generators[b], out=minibatch[j])
        batch = unpack(minibatch[:k])
        if k == self.members:  # every member: its own tensors, in place
            index, params, target, grads, valued = None, self.params, self.target, self.grads, self._valued
            grads.zero_()
        else:  # the due members' rows, written back after the step
            index = torch.tensor(due, device=self.params.device)
            params = self.params.index_select(0, index)
            grads = torch.zeros_like(params)
            target = self.target.index_select(0, index) if self.has_target else params
            valued = self.net.layers(target)
        online = self.net.layers(params, grads)
        own = [self.settings[b] for b in due]
        gamma = per_member([v.gamma for v in own], params.dtype, params.device)
        if self.noisy:  # fresh noise for each update: the online network's, then the target's
            streams = [self.generators[b] for b in due]
            noise = self.net.noise(streams, self.device)
            target_noise = self.net.noise(streams, self.device) if self.has_target else noise
            online, valued = self.net.with_noise(online, noise), self.net.with_noise(valued, target_noise)
        gamma = gamma.unsqueeze(-1) if isinstance(gamma, torch.Tensor) else gamma
        terms = c51_terms if self.distributional else td_terms
        found = terms(lambda x: self.net.q(online, x), lambda x: self.net.q(valued, x), batch,
                      gamma, self.double_dqn, *((self.z,) if self.distributional else ()))
        if self.distributional:  # each row's cross-entropy; its priority too (TorchRL's)
            loss, q, td_target, _ = found
            errors = loss.detach()
        else:
            q, td_target = found
            loss = _DISTANCES[self.loss_function](q, td_target, reduction="none")
            errors = td_target - q.detach() if self.prioritized else None
        if self.prioritized:  # importance-weighted; the rows take their new errors
            loss = loss * torch.stack(weights).to(loss.device).unsqueeze(-1)
            for j, b in enumerate(due):
                self.buffers[b].priorities.update(drawn[j], errors[j])
        loss = loss.mean((1, 2))
        loss.sum().backward()
        with torch.no_grad():
            norms = torch.linalg.vector_norm(grads, dim=1)
            clip = per_member([v.grad_clip for v in own], params.dtype, params.device)
            if isinstance(clip, torch.Tensor):  # members' own clips; 0 (none) scales by 1
                clip = clip.squeeze(1)
                factor = torch.where(clip > 0, (clip / (norms + 1e-6)).clamp_(max=1.0), 1.0)
                grads.mul_(factor.unsqueeze(1))
            elif clip > 0:
                grads.mul_((clip / (norms + 1e-6)).clamp_(max=1.0).unsqueeze(1))
            self._step(due, index, params, target, grads)
        for j, b in enumerate(due):
            self.trackers[b].add(loss[j].detach(), q[j].detach(), td_target[j],
                                 norms[j] if own[j].grad_clip > 0 else None)

    def _step(self, due: list[int], index: torch.Tensor | None, params: torch.Tensor, target: torch.Tensor,
              grads: torch.Tensor) -> None:
        """Adam and the target networks of the ``due`` members (``index``: their rows, None
        for all, whose tensors ``params``, ``target`` and ``grads`` then are); the others'
        rows written back."""
        for b in due:
            self.steps[b] += 1
        lrs = [self.lr_of(b, self.steps[b] - 1) for b in due]
        exp_avg = self.exp_avg if index is None else self.exp_avg.index_select(0, index)
        exp_avg_sq = self.exp_avg_sq if index is None else self.exp_avg_sq.index_select(0, index)
        adam_step(params, grads, exp_avg, exp_avg_sq, [self.steps[b] for b in due], lrs)
        own = [self.settings[b] for b in due]
        tau = per_member([v.tau for v in own], params.dtype, params.device)
        if isinstance(tau, torch.Tensor) or tau:  # (a member with tau 0 moves by 0: exactly not)
            target.lerp_(params, tau)
        for j, b in enumerate(due):
            if own[j].target_update and self.steps[b] % own[j].target_update == 0:
                target[j].copy_(params[j])
        if index is None:
            return
        for whole, part in ((self.params, params), (self.exp_avg, exp_avg), (self.exp_avg_sq, exp_avg_sq),
                            (self.grads, grads)):
            whole.index_copy_(0, index, part)
        if self.has_target:
            self.target.index_copy_(0, index, target)

    # -- persistence ---------------------------------------------------------
    def _net_state(self, vector: torch.Tensor) -> dict:
        return {k: v.clone() for k, v in self.net.load(vector).state_dict().items()}

    def _optimizer_state(self, b: int) -> dict:
        """Member ``b``'s Adam state in ``torch.optim.Adam``'s ``state_dict`` layout."""
        shapes = [p.shape for p in self.net.template.parameters()]
        state, offset = {}, 0
        for i, shape in enumerate(shapes):
            size = math.prod(shape)
            if self.steps[b]:
                state[i] = {"step": torch.tensor(float(self.steps[b])),
                            "exp_avg": self.exp_avg[b, offset:offset + size].reshape(shape).clone(),
                            "exp_avg_sq": self.exp_avg_sq[b, offset:offset + size].reshape(shape).clone()}
            offset += size
        group = {"lr": self.lr_of(b), "betas": ADAM_BETAS, "eps": ADAM_EPS, "weight_decay": 0,
                 "amsgrad": False, "maximize": False, "foreach": None, "capturable": False,
                 "differentiable": False, "fused": True, "decoupled_weight_decay": False,
                 "initial_lr": self.settings[b].lr, "params": list(range(len(shapes)))}
        return {"state": state, "param_groups": [group]}

    @torch.no_grad()
    def _load_optimizer(self, b: int, state: Mapping) -> None:
        """Member ``b``'s Adam moments from an Adam ``state_dict`` (none before a first step)."""
        moments = state.get("state", {})
        self.exp_avg[b].zero_()
        self.exp_avg_sq[b].zero_()
        if moments:
            self.exp_avg[b] = torch.cat([moments[i]["exp_avg"].reshape(-1) for i in sorted(moments)])
            self.exp_avg_sq[b] = torch.cat([moments[i]["exp_avg_sq"].reshape(-1) for i in sorted(moments)])

    def training_state(self, b: int) -> dict:
        """Everything member ``b``'s next update depends on, replay buffer and random stream
        included (for resuming)."""
        return {
            "format": FORMAT, "arch": self._arch(), "net": self._net_state(self.params[b]),
            "target_net": self._net_state(self.target[b]), "optimizer": self._optimizer_state(b),
            "lr_schedule": {"base_lrs": [self.settings[b].lr],
                            "last_epoch": self.steps[b] if self.settings[b].lr_decay else 0,
                            "_last_lr": [self.lr_of(b)]},
            "schedule": self.schedules[b].state_dict(), "optimizer_steps": self.steps[b],
            "credit": self.credit[b], "buffer": self.buffers[b].state_dict(),
            "generator": self.generators[b].get_state(),
            **({"n_step_queues": self.nsteps[b].state_dict()} if self.nsteps else {}),
            **({"priorities": self.buffers[b].priorities.state_dict()} if self.prioritized else {}),
        }

    @torch.no_grad()
    def load_training_state(self, b: int, state: Mapping) -> None:
        if state.get("format", 1) != FORMAT:
            raise StateMismatch(
                f"the training checkpoint holds a DQN state of format {state.get('format', 1)}, "
                f"this code reads format {FORMAT} (its replay buffer changed); resume it with "
                "the version that wrote it, or start the run afresh")
        own = {k: v for k, v in self.training_state(b).items() if k not in ("generator", "lr_schedule")}
        check_state(state, own, "the training checkpoint")
        self._check_arch(state["arch"], "the training checkpoint")
        check_state(state, own, "the training checkpoint", deep=("net", "target_net"))
        self.params[b] = self._vector_of(state["net"])
        if self.has_target:
            self.target[b] = self._vector_of(state["target_net"])
        self._load_optimizer(b, state["optimizer"])
        self.schedules[b].load_state_dict(state["schedule"])
        self.steps[b] = int(state["optimizer_steps"])
        self.credit[b] = float(state["credit"])
        self.buffers[b].load_state_dict(state["buffer"])
        if self.prioritized:
            self.buffers[b].priorities.load_state_dict(state["priorities"])
        if self.n_step > 1 and "n_step_queues" in state:
            queues = state["n_step_queues"]
            self._queues(len(queues["count"]))
            self.nsteps[b].load_state_dict(queues)
        if "generator" in state:  # a checkpoint of an earlier version: the run's torch stream
            self.generators[b].set_state(state["generator"])

    def _vector_of(self, net_state: Mapping) -> torch.Tensor:
        self.net.template.load_state_dict(net_state)
        return self.net.vector().to(self.device)

    def _check_arch(self, arch: dict, path) -> None:
        if arch != self._arch():
            raise StateMismatch(
                f"checkpoint {path} does not fit this run: it has network {arch}, "
                f"this run builds {self._arch()}")

    def model_state(self, b: int) -> dict:
        """Member ``b``'s trained network, its optimiser and schedule (``model.pt``)."""
        self.net.load(self.params[b])
        return {
            "kind": "dqn", "arch": self._arch(), "actor": {k: v.clone() for k, v in self.actor.state_dict().items()},
            "optimizer": self._optimizer_state(b), "schedule": self.schedules[b].state_dict(),
            "optimizer_steps": self.steps[b],
        }

    @torch.no_grad()
    def load_model_state(self, b: int, ckpt: Mapping, where: str) -> None:
        """Loads saved weights (and optimiser, schedule) into member ``b``; ``where`` names the
        state's origin in a :class:`StateMismatch`."""
        own = self.model_state(b)
        check_state(ckpt, own, where)  # every key there, before its values are read
        self._check_arch(ckpt["arch"], where)
        check_state(ckpt, own, where, deep=("actor",))
        self.actor.load_state_dict(ckpt["actor"])
        self.params[b] = self.net.vector().to(self.device)
        self._load_optimizer(b, ckpt["optimizer"])
        self.schedules[b].load_state_dict(ckpt["schedule"])
        self.steps[b] = int(ckpt["optimizer_steps"])
        if self.has_target:
            self.target[b] = self.params[b]


__all__ = ["DQN", "RowReplayBuffer", "StackedMLP", "Transitions", "UpdateStats", "adam_step", "pack",
           "td_loss", "td_terms", "unpack"]
