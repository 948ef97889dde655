"""The replay-buffer DQN family, written for one member; Rainbow's parts are switches.

One member's algorithm (Mnih et al. 2015; CleanRL's ``dqn.py`` reads alike): a Q-network
(TorchRL's ``MLP``; ``QValueActor`` in ``model.pt``), epsilon-greedy acting with epsilon
from one of :mod:`learners.schedules`, and per minibatch the TD(0) loss (MSE or Huber,
optional double DQN: :func:`td_terms`) against a target network kept by hard copies or
Polyak averaging, then Adam. Rainbow's switches (Hessel et al. 2018): ``n_step``
(:mod:`learners.nstep`), ``dueling`` (:class:`DuelingHead`), ``prioritized``
(:mod:`learners.priority`), ``noisy`` (TorchRL's ``NoisyLinear``) and ``distributional``
(C51, :mod:`learners.distributional`).

The members (seeds, trials) are one layer beneath: :class:`learners.member.ReplayLearner`
stacks their networks, optimizer state and replay buffers, draws each member's numbers
from its own stream, runs the updates each owes and saves one member. The TD terms are
:func:`td_terms` rather than TorchRL's ``DQNLoss``: the same numbers
(``tests/test_dqn.py``), computed for every member in one call.

``done_episode_reward`` replaces the reward of terminating transitions (mbalunovic's
-200); ``reward_scale`` then multiplies every reward the learner stores (its Q-values in
those units; the task's reward and measures unchanged). ``run_episodes`` greedy episodes
follow training (ruippeixotog's "run" phase).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Any, Callable

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.modules import MLP, DistributionalQValueActor, NoisyLinear, QValueActor

from learners.device import DEVICE_NOTE, check_device, resolve_device
from learners.member import ReplayLearner, check_replay_settings, obs_scale_param, with_obs_scale
from learners.transitions import Transitions, unpack
from params import require
from params.declare import REQUIRED, check_fields, param

ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU}
LOSSES = {"l2": "l2", "mse": "l2", "huber": "smooth_l1", "smooth_l1": "smooth_l1"}
_DISTANCES = {"l2": nn.functional.mse_loss, "smooth_l1": nn.functional.smooth_l1_loss}

QFunction = Callable[[torch.Tensor], torch.Tensor]  # observations -> Q-values


def td_loss(net: QFunction, target_net: QFunction, batch: Transitions, gamma: float,
            double_dqn: bool, loss_function: str) -> torch.Tensor:
    """Mean TD(0) error of ``net`` on ``batch``; ``target_net`` values the next state."""
    return _DISTANCES[loss_function](*td_terms(net, target_net, batch, gamma, double_dqn))


def td_terms(net: QFunction, target_net: QFunction, batch: Transitions, gamma: float | torch.Tensor,
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


@dataclass(eq=False)
class DQN(ReplayLearner):
    """A configurable DQN (see the module docstring); its members: :class:`ReplayLearner`."""

    epsilon: Any = param(REQUIRED, "exploration schedule: a node with _target_ "
                                   "learners.schedules.LinearEpsilon, MultiplicativeEpsilon or "
                                   "LogEpisodeEpsilon")
    hidden: list[int] = param([64, 64], "widths of the Q-network's hidden layers")
    activation: str = param("relu", "hidden layers' activation", choices=tuple(ACTIVATIONS))
    obs_scale: dict[str, float] | None = obs_scale_param()
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
        check_replay_settings(self)
        require(not (self.target_update and self.tau),
                "learner.target_update and learner.tau exclude each other",
                (self.target_update, self.tau))
        require(not self.double_dqn or self.target_update or self.tau,
                "learner.double_dqn needs a target network (target_update or tau)", self.double_dqn)
        require(self.v_min < self.v_max, f"learner.v_max must be above learner.v_min ({self.v_min})", self.v_max)
        require(all(hasattr(self.epsilon, k) for k in ("value", "step", "episode_end")),
                "learner.epsilon must be a schedule node (_target_: learners.schedules."
                "LinearEpsilon, MultiplicativeEpsilon or LogEpisodeEpsilon)", self.epsilon)
        self.device = str(resolve_device(self.device))  # auto -> cuda or cpu
        self.loss_function = LOSSES[self.loss]
        self.members = 0


    # -- one member's network ------------------------------------------------
    def arch(self) -> dict:
        """The network a saved state must match."""
        arch = {"n_obs": self.n_obs, "n_actions": self.n_actions, "hidden": self.hidden,
                "activation": self.activation}
        return arch | ({"obs_scale": dict(self.obs_scale)} if self.obs_scale else {}) | (
            {"dueling": True} if self.dueling else {}) | ({"noisy": True} if self.noisy else {}) | (
            {"distributional": {"atoms": self.atoms, "v_min": self.v_min, "v_max": self.v_max}}
            if self.distributional else {})

    def template(self, task) -> nn.Sequential:
        """One member's Q-network on the CPU (where each member's stream initialises it and
        its states are saved): TorchRL's ``MLP``, after a :class:`~learners.member.ObsScale` if asked, ending in
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
        return with_obs_scale(net, self.obs_scale, list(task.observation_names))

    def actor_of(self, template: nn.Sequential) -> nn.Module:
        """The network as ``model.pt`` holds it: TorchRL's Q-value actor."""
        from torchrl.data import Categorical

        spec = Categorical(self.n_actions, dtype=torch.int64)
        if not self.distributional:
            self.z = None
            return QValueActor(template, in_keys=["observation"], spec=spec)
        from learners.distributional import support  # C51 loads where it is used

        self.z = support(self.atoms, self.v_min, self.v_max).to(self.device)
        return DistributionalQValueActor(template, support=self.z.cpu(), in_keys=["observation"], spec=spec)

    # -- one member's acting and loss ----------------------------------------
    def draw(self, generator: torch.Generator, n: int) -> tuple[torch.Tensor, torch.Tensor]:
        """One step's exploration draws for ``n`` copies, as TorchRL's ``EGreedyModule`` draws:
        a uniform per copy, then a random action per copy."""
        return torch.rand(n, generator=generator), torch.randint(0, self.n_actions, (n,), generator=generator)

    def undrawn(self, n: int) -> tuple[torch.Tensor, torch.Tensor]:
        """The draws of a member that does not explore this step."""
        return torch.ones(n), torch.zeros(n, dtype=torch.int64)

    def choose(self, q: torch.Tensor, epsilon: torch.Tensor | None, drawn: list | None) -> torch.Tensor:
        """The Q-values' argmax (C51: of their means), or with probability ``epsilon`` (None:
        greedy) the random action drawn."""
        if self.distributional:
            from learners.distributional import expected

            q = expected(q, self.z)
        action = q.argmax(-1).cpu()
        if epsilon is None:
            return action
        uniform, random_action = drawn
        return torch.where(uniform < epsilon, random_action, action)

    def terms(self, q: QFunction, target_q: QFunction, batch: Transitions,
              gamma: float | torch.Tensor) -> tuple[torch.Tensor, ...]:
        """``(loss, q, target, error)`` of each transition of ``batch``: the TD loss (C51: the
        cross-entropy to the projected target), the taken actions' values, their targets, and
        the error prioritized replay keeps."""
        if self.distributional:
            from learners.distributional import c51_terms

            loss, value, target, m = c51_terms(q, target_q, batch, gamma, self.double_dqn, self.z)
            # the projected targets' mass on the support's two end atoms: near 1 when the returns
            # lie beyond [v_min, v_max] (they are clipped there)
            return loss, value, target, loss.detach(), {"support_edge": (m[..., :1] + m[..., -1:]).detach()}
        value, target = td_terms(q, target_q, batch, gamma, self.double_dqn)
        return _DISTANCES[self.loss_function](value, target, reduction="none"), value, target, target - value.detach()

    def advice(self, b: int) -> dict[str, str]:
        """C51 (``value_range``): a value range the task's returns lie beyond. Either the mean reward of the
        member's stored transitions, earned every step, makes a discounted return
        ``r / (1 - gamma)`` outside ``[v_min, v_max]`` (after 1,000 transitions), or most
        of the projected targets' mass sits on the support's end atoms."""
        buffer, own, numbers = self.buffers[b], self.settings[b], self.trackers[b].latest
        stored = buffer.stored()
        if not self.distributional or stored < 1000:
            return {}
        reward = float(unpack(buffer.rows[:stored]).reward.mean())
        steady = reward / (1 - own.gamma) if own.gamma < 1 else math.copysign(math.inf, reward)
        edge = numbers.get("support_edge", 0.0)
        if own.v_min <= steady <= own.v_max and edge < 0.5:
            return {}
        return {"value_range": f"learner.v_min/v_max [{own.v_min:g}, {own.v_max:g}] may not hold this task's returns: its mean "
                f"reward {reward:.3g} a step (after reward_scale) earned every step is a discounted return of "
                f"{steady:.3g} at gamma {own.gamma:g}, and {edge:.0%} of the C51 targets' mass sits on the "
                f"support's end atoms (the returns are clipped there); set them to the task's discounted returns "
                f"(bench/benchmark.yaml's dqn_c51 task_overrides list each shipped task's)"}

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


__all__ = ["DQN", "DuelingHead", "td_loss", "td_terms"]
