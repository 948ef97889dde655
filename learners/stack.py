"""Seeds side by side: the learners of a seed batch called once for all of its seeds.

A seed batch (:mod:`runs.batch`) trains one learner config under several seeds in one
env of seed blocks: seed ``b``'s copies are rows ``b * n`` to ``(b + 1) * n`` of every
step. Called one seed at a time, each learner's per-step work (its action choice, its
update, their Python around a few small tensor calls) is paid once per seed. A stack does
that work once for all the seeds, each seed still learning exactly as alone:

    stacked = stack(learners, generators)   # None for a learner kind without a stack
    td = stacked.act(td, live)              # every live seed's actions, one call
    stacked.observe(td, live, guard)        # every live seed learns from its block
    ...                                     # each seed's episodes booked (end_episode)
    stacked.settle(live, guard)             # the updates its episodes owed (DQN)

``live`` lists the seed indices still training; the others' rows are left as they are
(their copies are held). ``guard(b, work)`` runs a seed's own part of a stacked call
(its generator's draws, its replay buffer, its schedule, its counters) so that a failure
there ends that seed alone; it returns False when ``work`` failed.

- :class:`QLearnStack`: the seeds' Q-tables and visited flags are one
  ``[seeds, states, actions]`` tensor, each seed's ``policy.table`` a view of its slice:
  one discretisation, one action choice and one table update for all seeds per step.
  Each seed's random numbers come from its own generator, one call per seed per step
  drawing what its separate calls draw alone (torch's CPU ``rand`` fills serially).
- :class:`DQNStack`: the seeds' Q-networks, target networks and Adam moments and steps
  are stacked ``[seeds, ...]`` tensors, each seed's parameters and optimizer state views
  of its slice: one forward gives every seed's action values; the minibatch updates of
  the seeds due at a step run as one stacked forward and backward (a batched matrix
  product per layer) and one fused Adam call. Each seed keeps its own replay buffer,
  epsilon schedule, update credit, counters, learning-rate schedule, statistics and
  random stream (its ``generators`` entry: the exploration draws and minibatch indices
  that torch's global generator gives it alone). With ``train_every=step`` the seeds
  update in lockstep; with ``train_every=episode`` they are due at different steps: an
  update round takes the seeds that still owe one and leaves the others' parameters and
  optimizer state untouched (a round of one seed runs that seed's own update).

Bit for bit: a seed's actions, updates, parameters, optimizer state and statistics are
those of its run alone (``tests/test_seed_stack.py``, ``tests/test_seed_batch.py``). The
arithmetic is the same per seed: a stacked matrix product is the BLAS product
``nn.Linear`` makes for each seed (products too small for it, which ATen's batched
product computes in a loop of its own, run seed by seed); the backward is written out
as the kernels autograd runs for the loss alone (the per-seed mean's ``1/n``, the loss's
and the gather's backward, each layer's ``g^T x``, ``g W`` and bias sum, the activation's
backward), which also spares autograd's graph (~170 us a round); norms, Adam and target
copies take each seed's tensors as separate tensors, as alone. ``bench/stack_update.py``
measures it against ``torch.func.vmap(grad(...))`` over ``functional_call`` and against
tensordict's ``from_modules``: on this CPU (torch 2.13) both gave the same gradients at
the tuned batch of 128 but took about 3 (ten seeds) to 7 (one seed) times as long.

The seeds' saved states stay their own: a module's or optimizer's ``state_dict`` of a
stacked seed holds copies of its slices (a hook), never the stacked tensors.
"""

from __future__ import annotations

from functools import partial
from typing import Callable, Sequence

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torch import nn
from torch.optim.adam import adam

from learners.dqn import DQN, _DISTANCES, ObsScale, Transitions, unpack
from learners.qlearn import QLearn

Guard = Callable[[int, Callable[[], None]], bool]

# ATen's batched matrix product computes a product of fewer multiply-adds per matrix than
# this in a loop of its own, not the BLAS call ``nn.Linear`` makes (its results differ in
# the last bits); at and above it, each matrix of the batch is the BLAS product alone.
BMM_BLAS_MIN = 400


def _unguarded(b: int, work: Callable[[], None]) -> bool:
    work()
    return True


def stack(learners: Sequence, generators: Sequence[torch.Generator]):
    """A stack of ``learners`` (built from one config, one per seed block, in block order),
    or None for a learner kind without one. ``generators``: each seed's stand-in for
    torch's global generator (what the DQN family draws from alone). The DQN family
    stacks on the CPU only, where its arithmetic is known to be each seed's alone (a
    GPU's batched products are other kernels, untested here)."""
    if len(learners) < 2:
        return None
    if all(type(learner) is QLearn for learner in learners):
        return QLearnStack(learners)
    if (all(type(learner) is DQN for learner in learners) and torch.device(learners[0].device).type == "cpu"
            and _stackable(list(learners[0].net))):
        return DQNStack(learners, generators)
    return None


def _stackable(layers: list[nn.Module]) -> bool:
    """Whether :class:`DQNStack` knows every layer: linear layers and the activations it has
    a backward for, after an optional :class:`~learners.dqn.ObsScale` (a fixed input factor,
    the same for every seed of one config: nothing to learn, nothing to backpropagate)."""
    if layers and type(layers[0]) is ObsScale:
        layers = layers[1:]
    return all(isinstance(layer, nn.Linear) or type(layer) in _ACTIVATION_BACKWARD for layer in layers)


def _with(td: TensorDictBase, **entries: torch.Tensor) -> TensorDictBase:
    """A new tensordict of ``td``'s entries and ``entries`` (``td`` unchanged: a seed that
    ended at this step keeps it as its last step's input). Made as the env makes its own,
    without TensorDict's checks (~2 us; ``copy()`` is ~30)."""
    return TensorDict._new_unsafe({**dict(td.items()), **entries}, batch_size=td.batch_size, device=td.device)


def _floats(values, dtype: torch.dtype) -> torch.Tensor:
    """A 1-D tensor of Python floats (through numpy: ``torch.tensor`` of a list is slower)."""
    return torch.from_numpy(np.array(values, dtype=np.float64)).to(dtype)


def _rows(live: Sequence[int], n: int, seeds: int) -> torch.Tensor | None:
    """The row indices of the ``live`` seeds' blocks (None: every seed is live)."""
    if len(live) == seeds:
        return None
    return (torch.as_tensor(list(live)).unsqueeze(1) * n + torch.arange(n)).reshape(-1)


class QLearnStack:
    """Tabular Q-learning of several seeds with one table tensor (see the module docstring)."""

    def __init__(self, learners: Sequence[QLearn]) -> None:
        self.learners = list(learners)
        self.policies = [learner.policy for learner in self.learners]
        first = self.policies[0]
        self.discretizer, self.n_actions = first.discretizer, first.n_actions
        self.n_states = first.discretizer.n_states
        self.seeds = len(self.learners)
        # Filled seed by seed, each seed's own table dropped as soon as it is copied.
        self.table = torch.empty((self.seeds, *first.table.shape), dtype=first.table.dtype)
        self.visited = torch.empty((self.seeds, *first.visited.shape), dtype=torch.bool)
        for b, policy in enumerate(self.policies):
            self.table[b].copy_(policy.table)
            self.visited[b].copy_(policy.visited)
            policy.table, policy.visited = self.table[b], self.visited[b]
        self._draws: torch.Tensor | None = None
        self._offsets: torch.Tensor | None = None  # each row's seed's first table row

    def _uniforms(self, n: int, live: Sequence[int], guard: Guard) -> torch.Tensor:
        """``[seeds, k]`` float64 uniforms: each live seed's draws of one step from its own
        generator, in the order its policy draws them alone (one call: the CPU generator
        fills serially, so one call of k is the separate calls one after another)."""
        a = self.n_actions
        k = n + 2 * n * a if self.learners[0].noise_exploration else 2 * n + n * a
        if self._draws is None or self._draws.shape[1] != k:
            self._draws = torch.zeros(self.seeds, k, dtype=torch.float64)
        draws = self._draws
        for b in live:
            generator = self.policies[b].generator
            guard(b, lambda g=generator, out=draws[b]: torch.rand(k, generator=g, dtype=torch.float64, out=out))
        return draws

    def act(self, td: TensorDictBase, live: Sequence[int], guard: Guard = _unguarded) -> TensorDictBase:
        """Every seed's epsilon-greedy actions (:class:`learners.qlearn.QTablePolicy`'s very
        arithmetic); the live seeds draw. Returns a shallow copy of ``td`` with them."""
        observation = td.get("observation")
        n = observation.shape[0] // self.seeds
        a = self.n_actions
        state = self.discretizer(observation)
        if self._offsets is None or len(self._offsets) != self.seeds * n:
            self._offsets = (torch.arange(self.seeds) * self.n_states).repeat_interleave(n)
        q = self.table.view(-1, a).index_select(0, state + self._offsets).view(self.seeds, n, a)
        draws = self._uniforms(n, live, guard)
        epsilon = _floats([p.epsilon for p in self.policies], torch.float64).unsqueeze(1)
        explore = draws[:, :n] < epsilon
        if self.learners[0].noise_exploration:
            magnitude = q.abs().amax(-1, keepdim=True)
            noise = (draws[:, n:n + n * a].view(self.seeds, n, a) * 2 - 1) * magnitude
            scored = torch.where(explore.unsqueeze(-1), q + noise, q)
            tie = draws[:, n + n * a:]
        else:
            scored, tie = q, draws[:, n:n + n * a]
        best = scored == scored.amax(-1, keepdim=True)
        action = torch.where(best, tie.view(self.seeds, n, a), -1.0).argmax(-1)
        if not self.learners[0].noise_exploration:
            random_action = (draws[:, n + n * a:] * a).long().clamp_max(a - 1)
            action = torch.where(explore, random_action, action)
        return _with(td, state_index=state, action_value=q.view(-1, a).to(torch.float32), action=action.view(-1))

    def observe(self, td: TensorDictBase, live: Sequence[int], guard: Guard = _unguarded) -> None:
        """One Q-update of every live seed's table from its block of ``td`` (holding
        ``next``): :meth:`learners.qlearn.QLearn.update`'s arithmetic, each seed's rows
        indexing its own slice of the table."""
        learner = self.learners[0]
        n = td.batch_size[0] // self.seeds
        rows = _rows(live, n, self.seeds)

        def pick(value: torch.Tensor) -> torch.Tensor:
            value = value.reshape(self.seeds * n, *value.shape[1:])
            return value if rows is None else value.index_select(0, rows)

        if self._offsets is None or len(self._offsets) != self.seeds * n:
            self._offsets = (torch.arange(self.seeds) * self.n_states).repeat_interleave(n)
        offset = pick(self._offsets)
        state = pick(td.get("state_index")).reshape(-1) + offset
        action = pick(td.get("action")).reshape(-1)
        reward = pick(td.get(("next", "reward"))).reshape(-1).to(torch.float64)
        terminated = pick(td.get(("next", "terminated"))).reshape(-1)
        next_state = self.discretizer(pick(td.get(("next", "observation")))).reshape(-1) + offset
        a = self.n_actions
        bootstrap = self.table.view(-1, a).index_select(0, next_state).amax(-1)
        if not learner.bootstrap_terminal:
            bootstrap.masked_fill_(terminated, 0.0)
        target = reward + learner.gamma * bootstrap
        pair = state * a + action
        table, visited = self.table.view(-1), self.visited.view(-1)
        old = table.index_select(0, pair)
        new = old + learner.alpha * (target - old)
        if learner.first_visit_reward:
            new = torch.where(visited.index_select(0, pair), new, reward)
        self._add_mean_increments(pair, new - old, n)

    def _add_mean_increments(self, pair: torch.Tensor, increment: torch.Tensor, n: int) -> None:
        """:meth:`learners.qlearn.QLearn._add_mean_increments` over the stacked table: the
        seeds' pairs never meet (each indexes its own slice), so a pair's increments are
        those of its seed's block, summed in its block's order."""
        table, visited = self.table.view(-1), self.visited.view(-1)
        if n > 1:
            pair, slot, count = torch.unique(pair, return_inverse=True, return_counts=True)
            total = torch.zeros(len(pair), dtype=torch.float64).index_add_(0, slot, increment)
            increment = total / count
        table.index_add_(0, pair, increment)
        visited.index_fill_(0, pair, True)

    def owes(self, b: int) -> bool:
        """Never: a Q-table learns in :meth:`observe`."""
        return False

    def settle(self, live: Sequence[int], guard: Guard = _unguarded) -> None:
        """Nothing: a Q-table learns in :meth:`observe`."""


def _blas_sized(m: int, k: int, n: int) -> bool:
    return m * k * n >= BMM_BLAS_MIN


def _linear(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """``nn.Linear`` of each seed: ``x`` ``[S, m, in]``, ``weight`` ``[S, out, in]``, ``bias``
    ``[S, out]``; per seed the very ``addmm`` a ``Linear`` makes."""
    if _blas_sized(x.shape[1], x.shape[2], weight.shape[1]):
        return torch.baddbmm(bias.unsqueeze(1), x, weight.transpose(1, 2))
    return torch.stack([torch.addmm(bias[b], x[b], weight[b].t()) for b in range(len(x))])


def _linear_backward(grad: torch.Tensor, x: torch.Tensor, weight: torch.Tensor, input_grad: bool):
    """The gradients autograd gives an ``nn.Linear`` (``addmm`` on a transposed weight), per
    seed: the weight's ``g^T x``, the bias's ``g`` summed over the batch and, if asked, the
    input's ``g W``; each product the BLAS call alone makes (seed by seed below its size)."""
    blas = _blas_sized(x.shape[1], x.shape[2], weight.shape[1])
    grad_t = grad.transpose(1, 2)
    grad_w = (torch.bmm(grad_t, x) if blas else torch.stack([grad_t[b].mm(x[b]) for b in range(len(x))]))
    grad_x = None
    if input_grad:
        grad_x = torch.bmm(grad, weight) if blas else torch.stack([grad[b].mm(weight[b]) for b in range(len(x))])
    return grad_w, grad.sum(1), grad_x


# Each activation's backward as autograd computes it, from its output.
_ACTIVATION_BACKWARD = {
    nn.ReLU: lambda grad, out: torch.ops.aten.threshold_backward(grad, out, 0),
    nn.Tanh: lambda grad, out: torch.ops.aten.tanh_backward(grad, out),
}
# Each loss's backward (reduction none: the per-seed mean's 1/n comes in as the gradient).
_LOSS_BACKWARD = {
    "l2": lambda grad, q, target: torch.ops.aten.mse_loss_backward(grad, q, target, 0),
    "smooth_l1": lambda grad, q, target: torch.ops.aten.smooth_l1_loss_backward(grad, q, target, 0, 1.0),
}


def _own_copies(module: nn.Module, state_dict: dict, prefix: str, local_metadata) -> None:
    """A stacked module's ``state_dict`` post-hook: its own tensors as copies (a view of a
    stacked tensor would save the whole stack)."""
    for name, _ in module.named_parameters(recurse=False):
        if prefix + name in state_dict:
            state_dict[prefix + name] = state_dict[prefix + name].clone()


def _own_optimizer_copies(optimizer, state_dict: dict) -> dict:
    """A stacked optimizer's ``state_dict`` post-hook: its state's tensors as copies (and
    new dicts: ``state_dict`` shares the optimizer's own)."""
    state_dict["state"] = {key: {name: value.clone() if isinstance(value, torch.Tensor) else value
                                 for name, value in entry.items()}
                           for key, entry in state_dict["state"].items()}
    return state_dict


class DQNStack:
    """The DQN family of several seeds on stacked parameters (see the module docstring)."""

    def __init__(self, learners: Sequence[DQN], generators: Sequence[torch.Generator]) -> None:
        self.learners, self.generators = list(learners), list(generators)
        self.seeds = len(self.learners)
        first = self.learners[0]
        self.layers = [None if isinstance(layer, nn.Linear) else layer for layer in first.net]
        self.weights = self._stack([learner._params for learner in self.learners])
        self.shared_target = first.target_net is first.net
        self.targets = self.weights if self.shared_target else self._stack(
            [learner._target_params for learner in self.learners])
        self.exp_avgs = [torch.zeros_like(w) for w in self.weights]
        self.exp_avg_sqs = [torch.zeros_like(w) for w in self.weights]
        self.steps = [torch.zeros(self.seeds, dtype=torch.float32, device=w.device) for w in self.weights]
        # grad_clip=0: train_stats measures each seed's latest gradients (its params' .grad).
        self.kept_grads = [torch.zeros_like(w) for w in self.weights] if first.grad_clip == 0 else None
        self.started = [False] * self.seeds  # the seed's optimizer holds its (stacked) state
        self.owed = [0] * self.seeds
        self._views = [self._seed_views(b) for b in range(self.seeds)]
        for b in range(self.seeds):
            self._take_optimizer_state(b)
        self._minibatch = torch.empty(self.seeds, first.batch_size, first.buffer._rows.shape[1],
                                      device=first.device)
        for b, learner in enumerate(self.learners):
            learner.updates_sink = partial(self._owe, b)
            for module in {id(m): m for m in (learner.net, learner.target_net)}.values():
                for layer in module:
                    layer.register_state_dict_post_hook(_own_copies)
            learner.optimizer.register_state_dict_post_hook(_own_optimizer_copies)

    @staticmethod
    def _stack(per_seed: list[list[nn.Parameter]]) -> list[torch.Tensor]:
        """One ``[seeds, ...]`` tensor per parameter; each seed's parameter becomes a view of
        its slice."""
        stacked = [torch.stack([params[k].detach() for params in per_seed]) for k in range(len(per_seed[0]))]
        for b, params in enumerate(per_seed):
            for k, p in enumerate(params):
                p.data = stacked[k][b]
        return stacked

    def _take_optimizer_state(self, b: int) -> None:
        """A seed whose optimizer has stepped already (a resumed run's): its Adam state and
        latest gradients move into its slices of the stacked ones, as it holds them alone."""
        learner, views = self.learners[b], self._views[b]
        state = [learner.optimizer.state.get(p) for p in learner._params]
        if not all(state):
            return
        for k, (p, own) in enumerate(zip(learner._params, state)):
            views["steps"][k].copy_(own["step"])
            views["exp_avgs"][k].copy_(own["exp_avg"])
            views["exp_avg_sqs"][k].copy_(own["exp_avg_sq"])
            if self.kept_grads is not None and p.grad is not None:
                self.kept_grads[k][b].copy_(p.grad)
        self._start(b)

    def _seed_views(self, b: int) -> dict[str, list[torch.Tensor]]:
        return {name: [t[b] for t in tensors] for name, tensors in (
            ("weights", self.weights), ("targets", self.targets), ("exp_avgs", self.exp_avgs),
            ("exp_avg_sqs", self.exp_avg_sqs), ("steps", self.steps))}

    # -- acting --------------------------------------------------------------
    def _forward(self, params: Sequence[torch.Tensor], x: torch.Tensor,
                 kept: list[torch.Tensor] | None = None) -> torch.Tensor:
        """Every seed's network on its ``x`` (``[S, m, n_obs]``) with stacked ``params``;
        ``kept`` collects each layer's input (for :meth:`_backward`)."""
        k = 0
        for layer in self.layers:
            if kept is not None:
                kept.append(x)
            if layer is None:
                x = _linear(x, params[k], params[k + 1])
                k += 2
            else:
                x = layer(x)
        return x

    def _backward(self, grad: torch.Tensor, params: Sequence[torch.Tensor], kept: list[torch.Tensor],
                  out: torch.Tensor) -> list[torch.Tensor]:
        """The gradients of ``params`` from ``grad`` at the network's output ``out``, layer by
        layer backwards (``kept``: the layers' inputs), as autograd computes them alone."""
        grads: list[torch.Tensor] = [None] * len(params)  # type: ignore[list-item]
        k = len(params)
        first = self.layers.index(None)  # the first linear layer: nothing before it learns
        for i in range(len(self.layers) - 1, first - 1, -1):
            layer, x = self.layers[i], kept[i]
            if layer is None:
                k -= 2
                grads[k], grads[k + 1], grad = _linear_backward(grad, x, params[k], input_grad=i > first)
            else:
                grad = _ACTIVATION_BACKWARD[type(layer)](grad, out)
            out = x
        return grads

    def act(self, td: TensorDictBase, live: Sequence[int], guard: Guard = _unguarded) -> TensorDictBase:
        """Every seed's greedy action, then each live seed's exploration as
        :class:`learners.dqn.QPolicy` draws it (a uniform per copy, then a random action per
        copy) from its own generator. Returns a shallow copy of ``td`` with the actions."""
        first = self.learners[0]
        observation = td.get("observation").to(first.device)
        n = observation.shape[0] // self.seeds
        with torch.no_grad():
            q = self._forward(self.weights, observation.view(self.seeds, n, -1))
        action = q.argmax(-1).cpu()
        uniform = torch.ones(self.seeds, n)
        random_action = torch.zeros(self.seeds, n, dtype=torch.int64)
        for b in live:
            def draw(g=self.generators[b], b=b) -> None:
                torch.rand(n, generator=g, out=uniform[b])
                torch.randint(0, first.n_actions, (n,), generator=g, out=random_action[b])
            guard(b, draw)
        epsilon = _floats([learner.explorer.epsilon for learner in self.learners], torch.float32)
        action = torch.where(uniform < epsilon.unsqueeze(1), random_action, action)
        return _with(td, action=action.view(-1))

    # -- learning ------------------------------------------------------------
    def observe(self, td: TensorDictBase, live: Sequence[int], guard: Guard = _unguarded) -> None:
        """Each live seed stores its block's transitions and counts them (schedule, update
        credit) as :meth:`learners.dqn.DQN.observe`; then the updates they owe run."""
        rows = self.learners[0].rows_of(td)
        n = len(rows) // self.seeds
        for b in live:
            guard(b, lambda b=b: self.learners[b].observe_rows(rows[b * n:(b + 1) * n]))
        self.settle(live, guard)

    def _owe(self, b: int, updates: int) -> None:
        self.owed[b] += updates

    def owes(self, b: int) -> bool:
        """Whether seed ``b`` owes updates that :meth:`settle` has yet to run."""
        return self.owed[b] > 0

    def settle(self, live: Sequence[int], guard: Guard = _unguarded) -> None:
        """Runs the updates the ``live`` seeds owe, in rounds: a round updates every seed
        that still owes one (a seed's updates in its order, as alone)."""
        owed = {b: self.owed[b] for b in live if self.owed[b] > 0}
        self.owed = [0] * self.seeds
        if not owed:
            return
        stored: dict[int, int] = {}  # each seed's buffer length (a seed that fails leaves)
        for b in sorted(owed):
            guard(b, lambda b=b: stored.__setitem__(b, len(self.learners[b].buffer)))
        done = 0
        while True:
            due = [b for b in stored if owed[b] > done]
            if not due:
                return
            self._round(due, stored, guard)
            done += 1

    def _sample(self, due: list[int], stored: dict[int, int], guard: Guard) -> list[int]:
        """Each due seed's minibatch into ``_minibatch[j]``, drawn as alone; the seeds whose
        draw worked."""
        first, drawn = self.learners[0], []
        for j, b in enumerate(due):
            def draw(b=b, j=j) -> None:
                index = torch.randint(0, stored[b], (first.batch_size,), generator=self.generators[b])
                rows = self.learners[b].buffer.rows
                torch.index_select(rows, 0, index.to(rows.device), out=self._minibatch[j])
            if guard(b, draw):
                drawn.append(b)
            else:
                del stored[b]
        return drawn

    def _round(self, due: list[int], stored: dict[int, int], guard: Guard) -> None:
        """One update of each seed of ``due``: :meth:`learners.dqn.DQN._update` per seed."""
        drawn = self._sample(due, stored, guard)
        if not drawn:
            return
        if len(drawn) != len(due):  # a seed failed its draw: the minibatches move up
            keep = torch.from_numpy(np.array([due.index(b) for b in drawn]))
            self._minibatch[:len(drawn)] = self._minibatch.index_select(0, keep)
        if len(drawn) == 1:
            if not guard(drawn[0], lambda: self._alone(drawn[0])):
                del stored[drawn[0]]
            return None
        batch = self._unpack(self._minibatch[:len(drawn)])
        everyone = len(drawn) == self.seeds
        index = None if everyone else torch.from_numpy(np.array(drawn)).to(self.weights[0].device)
        weights = self.weights if everyone else [w.index_select(0, index) for w in self.weights]
        targets = weights if self.shared_target else (
            self.targets if everyone else [t.index_select(0, index) for t in self.targets])
        with torch.no_grad():
            q, target, loss, grads = self._loss(weights, targets, batch)
            norms = self._clip(grads, len(drawn))
            self._adam(drawn, grads)
            self._after_step(drawn, grads, index)
        losses, qs, ts = loss.unbind(0), q.unbind(0), target.unbind(0)
        for j, b in enumerate(drawn):
            self.learners[b].tracker.add(losses[j], qs[j], ts[j], None if norms is None else norms[j])

    def _alone(self, b: int) -> None:
        """A round of one seed: its own :meth:`learners.dqn.DQN._update` of its minibatch (the
        path of its run alone, on its views of the stacked tensors: cheaper than the stacked
        path's for one seed)."""
        learner = self.learners[b]
        if not self.started[b]:
            self._start(b)
        learner._update(unpack(self._minibatch[0]))
        if self.kept_grads is not None:  # its new gradients, where train_stats reads them
            for kept, p in zip(self.kept_grads, learner._params):
                kept[b].copy_(p.grad)
                p.grad = kept[b]

    @staticmethod
    def _unpack(rows: torch.Tensor) -> Transitions:
        """:func:`learners.dqn.unpack` of ``[S, batch, width]`` rows."""
        n = (rows.shape[-1] - 3) // 2
        return Transitions(rows[..., :n], rows[..., 2 * n:2 * n + 1].long(), rows[..., 2 * n + 1:2 * n + 2],
                           rows[..., n:2 * n], rows[..., 2 * n + 2:] != 0)

    def _loss(self, weights, targets, batch):
        """:func:`learners.dqn.td_terms`, the loss and its gradients of every seed, stacked:
        ``q`` and ``target`` ``[S, batch, 1]``, the per-seed mean loss ``[S]`` and the
        gradients of ``weights``, by hand: the very kernels autograd runs for the loss alone
        (its mean's ``1/n``, the loss's backward, the gather's scatter, each layer's)."""
        first = self.learners[0]
        kept: list[torch.Tensor] = []
        out = self._forward(weights, batch.observation, kept)
        q = out.gather(-1, batch.action)
        next_q = self._forward(targets, batch.next_observation)
        if first.double_dqn:
            next_value = next_q.gather(-1, self._forward(weights, batch.next_observation).argmax(-1, keepdim=True))
        else:
            next_value = next_q.amax(-1, keepdim=True)
        target = batch.reward + first.gamma * next_value * ~batch.terminated
        loss = _DISTANCES[first.loss_function](q, target, reduction="none").mean((1, 2))
        grad = torch.ones(q.shape, device=q.device).div_(q.shape[1] * q.shape[2])
        grad = _LOSS_BACKWARD[first.loss_function](grad, q, target)
        grad = out.new_zeros(out.shape).scatter_add_(-1, batch.action, grad)
        return q, target, loss, self._backward(grad, weights, kept, out)

    def _clip(self, grads: list[torch.Tensor], seeds: int) -> torch.Tensor | None:
        """:meth:`learners.dqn.DQN._clip` of each seed (its tensors' norms one by one, as
        alone); the norms before clipping, ``[seeds]``, or None without clipping."""
        clip = self.learners[0].grad_clip
        if clip <= 0:
            return None
        per_param = [g.unbind(0) for g in grads]
        views = [seed_grads[j] for j in range(seeds) for seed_grads in per_param]
        norms = torch.linalg.vector_norm(torch.stack(torch._foreach_norm(views)).view(seeds, len(grads)), dim=1)
        coefficient = (clip / (norms + 1e-6)).clamp_(max=1.0)
        for g in grads:
            g.mul_(coefficient.view(seeds, *([1] * (g.dim() - 1))))
        return norms

    def _start(self, b: int) -> None:
        """Seed ``b``'s first update: its optimizer holds its slices of the stacked state, as
        ``Adam`` makes its state at its first step."""
        learner, views = self.learners[b], self._views[b]
        for k, p in enumerate(learner._params):
            learner.optimizer.state[p] = {"step": views["steps"][k], "exp_avg": views["exp_avgs"][k],
                                          "exp_avg_sq": views["exp_avg_sqs"][k]}
            if self.kept_grads is not None:
                p.grad = self.kept_grads[k][b]
        learner.optimizer._opt_called = True  # as Adam.step marks it (its lr scheduler checks)
        self.started[b] = True

    def _adam(self, drawn: list[int], grads: list[torch.Tensor]) -> None:
        """``Adam.step`` of each seed: one fused call per learning rate, each seed's tensors
        as separate tensors (the kernel's arithmetic on a tensor is the same as alone)."""
        group = self.learners[0].optimizer.param_groups[0]
        by_lr: dict[float, list[int]] = {}
        for j, b in enumerate(drawn):
            if not self.started[b]:
                self._start(b)
            by_lr.setdefault(self.learners[b].optimizer.param_groups[0]["lr"], []).append(j)
        per_param = [g.unbind(0) for g in grads]
        for lr, js in by_lr.items():
            views = [self._views[drawn[j]] for j in js]
            adam([w for v in views for w in v["weights"]], [seed_grads[j] for j in js for seed_grads in per_param],
                 [m for v in views for m in v["exp_avgs"]], [m for v in views for m in v["exp_avg_sqs"]], [],
                 [s for v in views for s in v["steps"]], foreach=group["foreach"], capturable=group["capturable"],
                 differentiable=group["differentiable"], fused=group["fused"], has_complex=False,
                 decoupled_weight_decay=group["decoupled_weight_decay"], amsgrad=group["amsgrad"],
                 beta1=group["betas"][0], beta2=group["betas"][1], lr=lr, weight_decay=group["weight_decay"],
                 eps=group["eps"], maximize=group["maximize"])

    def _after_step(self, drawn: list[int], grads: list[torch.Tensor], index: torch.Tensor | None) -> None:
        """Each updated seed's counters, learning rate and target network, as
        :meth:`learners.dqn.DQN._update` ends; its gradients kept where ``train_stats`` reads them."""
        first = self.learners[0]
        copies = []
        for b in drawn:
            learner = self.learners[b]
            learner.optimizer_steps += 1
            if learner.lr_decay:
                learner.lr_schedule.step()
            if first.target_update and learner.optimizer_steps % first.target_update == 0:
                copies.append(b)
        if first.tau and not self.shared_target:
            if index is None:
                torch._foreach_lerp_(self.targets, self.weights, first.tau)
            else:
                views = [self._views[b] for b in drawn]
                torch._foreach_lerp_([t for v in views for t in v["targets"]],
                                     [w for v in views for w in v["weights"]], first.tau)
        if copies and not self.shared_target:
            views = [self._views[b] for b in copies]
            torch._foreach_copy_([t for v in views for t in v["targets"]], [w for v in views for w in v["weights"]])
        if self.kept_grads is not None:
            if index is None:
                torch._foreach_copy_(self.kept_grads, grads)
            else:
                for kept, g in zip(self.kept_grads, grads):
                    kept.index_copy_(0, index, g)


__all__ = ["stack", "QLearnStack", "DQNStack"]
