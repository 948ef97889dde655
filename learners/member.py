"""The member axis: one layer under every learner, so that a learner reads as its algorithm.

A member is one independent learning run: a seed of a seed batch, a tuning trial's seed,
or the one seed of a single run (a batch of one). A learner (:mod:`learners.qlearn`,
:mod:`learners.dqn`) writes its algorithm for one member: its settings, its table or
network, its acting rule, its loss. This module holds what it has once per member, laid out
so that every member's arithmetic is one call:

- :class:`MemberLearner`: the members' random streams and settings (a member-wise setting
  reaches the algorithm as a number where every member has the same, else a
  ``[members, 1]`` tensor: :meth:`MemberLearner.own`), and the contract's member-wise calls
  (:class:`learners.base.Learner`: acting with the live members' streams, a member seen alone);
- :class:`MemberTables`: every member's table, the rows of one tensor (tabular learners);
- :class:`MemberNets`: every member's network, its parameters one ``[members, P]`` tensor,
  each linear layer one batched product;
- :class:`MemberAdam`: Adam's moments and step counts per member, one step for all;
- :class:`RowReplayBuffer`: one member's replay storage, TorchRL's buffer over one tensor;
- :class:`ReplayLearner`: a replay-buffer learner's members: their buffers (and n-step
  queues, priorities), update credit, rounds of updates, gradient clip, optimizer and target
  network steps, statistics, and saving, loading and renewing one member. Its algorithm
  gives the network (``template``), the loss (``terms``) and the acting rule (``choose``).

Each member's arithmetic is the same kernels whatever the number of members (a batched
product computes each matrix alone, a reduction each row alone), and every random draw is
made from the member's own generator outside the batched call, so a member of a batch
learns bit for bit as alone (``tests/test_members.py``). The batched products replace
``torch.vmap`` of one member's module (tensordict's stacked modules) because they measure
faster: ``bench/member_kernel.py`` times one DQN update 1.9-3.4x faster than vmap with
``torch.optim.Adam``, and 20x faster than TorchRL's ``DQNLoss`` looped over 10 members.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
import warnings
from typing import Any, Callable, Hashable, Mapping, NamedTuple, Sequence

import torch
from tensordict import TensorDictBase
from torch import nn
from torchrl.data import RandomSampler, ReplayBuffer, TensorStorage
from torchrl.modules import NoisyLinear

from learners.base import Member, StateMismatch, check_state, everyone, member_settings, per_member, single
from learners.transitions import Transitions, pack, unpack
from params import require
from params.declare import param
from params.private_api import writer_cursor, with_entries

# The layers' gradients are views of one tensor (MemberNets.layers), strided as their
# parameters are; autograd adds into them in place and notes that this is not its layout.
warnings.filterwarnings("ignore", message="grad and param do not obey the gradient layout contract")
ADAM_BETAS, ADAM_EPS = (0.9, 0.999), 1e-8  # torch.optim.Adam's defaults


class MemberLearner:
    """The members of a learner: their random streams (``generators``), their settings
    (``settings``: the learner itself, or each member's own variant) and the calls of the
    contract every learner answers alike."""

    members = 0
    MEMBER_WISE = ()  # settings members of one batch may differ in (the learner says)
    schedules: Sequence = ()  # each member's exploration schedule, where the algorithm has one

    def _members(self, generators: torch.Generator | Sequence[torch.Generator] | None,
                 variants: Sequence[Any] | None) -> None:
        """One member per generator, with its variant's settings (None: this learner's)."""
        self.generators = single(generators)
        self.members = len(self.generators)
        self.settings = member_settings(self, variants, self.members)

    def own(self, name: str, members: Sequence[int] | None = None, dtype: torch.dtype = torch.float32,
            device: Any = "cpu") -> float | torch.Tensor:
        """Setting ``name`` of ``members`` (None: all), as the algorithm's arithmetic takes it:
        a number where they agree, else a ``[members, 1]`` tensor (:func:`per_member`)."""
        return per_member([getattr(self.settings[b], name) for b in everyone(self, members)], dtype, device)

    def variant(self, variant: Any | None) -> Any:
        """A renewed member's settings: ``variant``, checked as :meth:`build` checks one
        (:func:`member_settings`), or None: this learner's."""
        return self if variant is None else member_settings(self, [variant], 1)[0]

    def rows(self, live: Sequence[int] | None, n: int) -> Callable[[torch.Tensor], torch.Tensor]:
        """A function that picks the ``live`` members' rows (None: all) of a value with a row per
        env copy, ``n`` copies a member, flattened."""
        index = None if live is None or len(live) == self.members else (
            torch.as_tensor(list(live)).unsqueeze(1) * n + torch.arange(n)).reshape(-1)

        def pick(value: torch.Tensor) -> torch.Tensor:
            value = value.reshape(self.members * n)
            return value if index is None else value.index_select(0, index)

        return pick

    def member(self, b: int) -> Member:
        return Member(self, b)

    def begin(self) -> None:
        """Before the first step of a training session (a fresh run or a resumed one)."""

    def phase(self, b: int) -> tuple[Hashable, Hashable] | None:
        """Where member ``b`` is in its cycle of updates (:meth:`learners.base.Learner.phase`);
        None: its updates do not follow its steps."""
        return None

    def advice(self, b: int) -> dict[str, str]:
        """What member ``b``'s numbers so far say about its settings: a line per subject (a run
        prints each subject once, the first time it is given); none by default."""
        return {}

    def end_episodes(self, ended: Mapping[int, int]) -> None:
        """After each finished episode of a member: its exploration schedule's episode step
        (``schedules``: one per member, :mod:`learners.schedules`)."""
        for b, count in ended.items():
            for _ in range(count * bool(self.schedules)):
                self.schedules[b].episode_end()

    def act(self, td: TensorDictBase, live: Sequence[int] | None = None) -> TensorDictBase:
        """Every member's exploring actions on its block; only ``live`` members draw."""
        if live is None or len(live) == self.members:
            return self.act_members(td, None, False, self.generators)
        live = set(live)
        return self.act_members(td, None, False, [g if b in live else None for b, g in enumerate(self.generators)])

    def act_members(self, td: TensorDictBase, members: Sequence[int] | None, greedy: bool,
                    generators: Sequence[torch.Generator | None]) -> TensorDictBase:
        raise NotImplementedError


LANES = 64  # a multiple of every CPU's vector loop (2 x 16 floats with AVX-512)


def lanes(f: Callable[[torch.Tensor], torch.Tensor], x: torch.Tensor) -> torch.Tensor:
    """``f(x)`` for an elementwise ``f`` (tanh, softplus, log, exp), each member's numbers as
    alone: each member's row of ``x`` (its first dimension) is padded to a multiple of
    :data:`LANES` numbers, so that every number takes the vectorised loop, whatever the
    number of members. (PyTorch computes a tensor's tail past its last full vector by scalar
    code, whose transcendental functions differ in the last bit from the vectorised ones:
    without it a member's softplus would depend on how many members precede it.)"""
    k = x.shape[0] if x.dim() else 1
    flat = x.reshape(k, -1)
    m = flat.shape[1]
    wide = -(-m // LANES) * LANES
    if wide != m:
        flat = torch.cat((flat, flat.new_ones(k, wide - m)), 1)
    return f(flat.contiguous())[:, :m].reshape(x.shape)


def draws(generators: Sequence[torch.Generator | None], size: int, draw: Callable[..., None],
          dtype: torch.dtype = torch.float32, fill: float = 0.0) -> torch.Tensor:
    """``[k, size]``: row ``j`` filled by ``draw(generator, out=row)`` from ``generators[j]``
    (one member's draw, outside any batched call), ``fill`` for a row without a generator."""
    found = torch.full((len(generators), size), fill, dtype=dtype)
    for j, generator in enumerate(generators):
        if generator is not None:
            draw(generator, out=found[j])
    return found


class MemberTables:
    """Every member's ``[states, actions]`` table as rows of one tensor, member ``b``'s
    ``sizes[b]`` rows from its start; ``visited`` flags alike."""

    def __init__(self, sizes: Sequence[int], actions: int, fills: Sequence[float]) -> None:
        self.starts = [sum(sizes[:b]) for b in range(len(sizes))]
        self.values = torch.empty((sum(sizes), actions), dtype=torch.float64)
        self.seen = torch.zeros((sum(sizes), actions), dtype=torch.bool)
        self.table = [self.values[start:start + size] for start, size in zip(self.starts, sizes)]
        self.visited = [self.seen[start:start + size] for start, size in zip(self.starts, sizes)]
        for part, fill in zip(self.table, fills):
            part.fill_(float(fill))
        self._offsets: torch.Tensor | None = None

    def offset(self, members: Sequence[int] | None, n: int) -> torch.Tensor | int:
        """Each row's member's first row in the table, ``n`` rows a member of ``members``
        (None: all, kept between steps; one member: one number)."""
        if members is None:
            if self._offsets is None or len(self._offsets) != len(self.starts) * n:
                self._offsets = torch.as_tensor(self.starts).repeat_interleave(n)
            return self._offsets
        if len(members) == 1:
            return self.starts[members[0]]
        return torch.as_tensor([self.starts[b] for b in members]).repeat_interleave(n)


class ObsScale(nn.Module):
    """Multiplies each observation entry by a fixed factor before a network's layers
    (inputs of one size: a wheel speed of 100 beside an angle of 0.1 drowns the angle)."""

    def __init__(self, scale: torch.Tensor) -> None:
        super().__init__()
        self.register_buffer("scale", scale)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x * self.scale


def obs_scale_param() -> Any:
    """Declares a learner's ``obs_scale`` (None, or a factor per observation name)."""
    return param(None, "per observation name, a factor its value is multiplied by before the networks "
                       "(others 1)", note="null = none")


def with_obs_scale(net: nn.Sequential, obs_scale: Mapping[str, float] | None,
                   names: Sequence[str]) -> nn.Sequential:
    """``net`` after an :class:`ObsScale` of ``obs_scale``'s factors on its first inputs, the
    observation's ``names`` in order (its later inputs, such as a critic's action, by 1);
    ``net`` itself when ``obs_scale`` is empty. A name that is no observation is refused."""
    if not obs_scale:
        return net
    unknown = sorted(set(obs_scale) - set(names))
    require(not unknown, f"learner.obs_scale names no observation of this task; its observations: "
                         f"{', '.join(names)}", unknown)
    inputs = next(layer for layer in net if isinstance(layer, nn.Linear)).in_features
    scale = torch.ones(inputs)
    scale[:len(names)] = torch.tensor([float(obs_scale.get(n, 1.0)) for n in names])
    return nn.Sequential(ObsScale(scale), *net)


_FUNCTIONS = {nn.Tanh: lambda x: lanes(torch.tanh, x), nn.ReLU: torch.relu}


def affine(x: torch.Tensor, weight: torch.Tensor, bias: torch.Tensor) -> torch.Tensor:
    """Each member's linear layer, ``x @ weight^T + bias`` (``[k, n, in]``, ``[k, out, in]``,
    ``[k, 1, out]``), one batched product. A layer of one output (a critic's last) is each
    row's products summed, a layer of one input a broadcast product: a batched product one
    column wide or deep takes another kernel when ``k`` is 1 than when it is more
    (matrix-vector rather than batched matrix products) and differs from it in the last bit,
    where a sum along a row (and its gradients) does not (``tests/test_members.py``); it also
    costs about a third of the product padded to two columns, forward and backward."""
    if weight.shape[1] == 1:
        return (x * weight).sum(-1, keepdim=True) + bias
    if weight.shape[2] == 1:
        return x * weight.transpose(1, 2) + bias
    return torch.baddbmm(bias, x, weight.transpose(1, 2))


class MemberNets:
    """The networks of every member, all their parameters one ``[members, P]`` tensor laid out
    as ``torch.nn.utils.parameters_to_vector`` lays out one member's ``template`` (its linear
    layers' weight and bias in order, after an optional :class:`ObsScale`).

    ``q(params, x)``: each member's network on its ``x`` (``[k, n, inputs]`` with ``params``
    ``[k, P]``): every linear layer one ``baddbmm``, each member's product computed alone
    whatever ``k``. Other layers of the template: an activation, a module whose ``forward``
    maps the last dimension (such as a dueling head), or an ``nn.Unflatten`` (skipped: the
    saved model's shape, not the stacked one's).

    A TorchRL ``NoisyLinear`` (Fortunato et al. 2018) holds its mean and standard deviation
    weights (``weight_mu``, ``weight_sigma``, ``bias_mu``, ``bias_sigma``, its parameters'
    order); ``q`` uses the mean weights unless given factorised noise (:meth:`noise`):
    ``w = mu_w + sigma_w * f(e_out) f(e_in)^T``, ``b = mu_b + sigma_b * f(e_out)``,
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
                slots = []
                for shape in shapes:
                    slots.append((offset, offset + math.prod(shape), shape))
                    offset += math.prod(shape)
                self.plan.append(tuple(slots))
                if noisy:
                    self.noisy_sizes.append((inp, out))
            elif type(layer) in _FUNCTIONS:  # (a tanh by lanes: each member's numbers as alone)
                self.plan.append(_FUNCTIONS[type(layer)])
            elif not isinstance(layer, nn.Unflatten):
                self.plan.append(layer.forward)
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
                shape = shape if len(shape) == 2 else (1, *shape)  # a bias: [k, 1, out]
                view = params[:, start:end].view(k, *shape)
                if grads is not None:  # (a leaf itself: a view of it would lose its way back
                    view.requires_grad_(True)  # to the leaf once Adam changes params in place)
                    view.grad = grads[:, start:end].view(k, *shape)
                views.append(view)
            found.append(tuple(views))
        return found

    def noise(self, generators: Sequence[torch.Generator | None], device: torch.device | str) -> list:
        """Factorised noise of each noisy layer for ``k`` members, ``(f(e_in) [k, in],
        f(e_out) [k, out])``, member ``j``'s drawn from ``generators[j]`` (None: zero noise,
        the mean weights)."""
        total = sum(inp + out for inp, out in self.noisy_sizes)
        drawn = draws(generators, total, lambda g, out: torch.randn(total, generator=g, out=out))
        drawn = drawn.sign().mul_(drawn.abs().sqrt_()).to(device)
        found, offset = [], 0
        for inp, out in self.noisy_sizes:
            found.append((drawn[:, offset:offset + inp], drawn[:, offset + inp:offset + inp + out]))
            offset += inp + out
        return found

    def q(self, params: torch.Tensor | list, x: torch.Tensor, noise: list | None = None) -> torch.Tensor:
        """Each member's network on its ``x`` (``[k, n, inputs]``); ``params``: ``[k, P]`` or
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
            x = affine(x, weight, bias)
        return x

    def with_noise(self, layers: list, noise: list | None) -> list:
        """:meth:`layers` with each noisy layer's ``(weight, bias)`` for ``noise`` (None: its
        mean weights); a network evaluated twice with one noise makes them once."""
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

    def initial(self, generator: torch.Generator) -> torch.Tensor:
        """Fresh parameters of the template's layers drawn from ``generator`` (their own
        ``reset_parameters``, as on torch's global stream)."""
        with torch.random.fork_rng(devices=[]):
            torch.set_rng_state(generator.get_state())
            for layer in self.template:
                if isinstance(layer, nn.Linear):
                    layer.reset_parameters()
            generator.set_state(torch.get_rng_state())
        return self.vector()

    def state(self, vector: torch.Tensor) -> dict:
        """The template's ``state_dict`` holding ``vector``, copied."""
        return {k: v.clone() for k, v in self.load(vector).state_dict().items()}

    def vector_of(self, state: Mapping, device: torch.device | str) -> torch.Tensor:
        """The ``[P]`` vector of a template's ``state_dict``."""
        self.template.load_state_dict(state)
        return self.vector().to(device)


class MemberAdam:
    """Adam (``torch.optim.Adam``'s arithmetic, default betas and eps) of every member's
    ``[P]`` row of parameters: the moments ``[members, P]``, each member's step count."""

    def __init__(self, params: torch.Tensor) -> None:
        self.exp_avg = torch.zeros_like(params)
        self.exp_avg_sq = torch.zeros_like(params)
        self.steps = [0] * len(params)

    def step(self, rows: torch.Tensor | None, params: torch.Tensor, grads: torch.Tensor,
             members: Sequence[int], lrs: Sequence[float]) -> None:
        """One step of ``members`` (``rows``: their rows, None for all, whose tensors
        ``params`` and ``grads`` then are), ``lrs`` their learning rates; in place."""
        for b in members:
            self.steps[b] += 1
        exp_avg = self.exp_avg if rows is None else self.exp_avg.index_select(0, rows)
        exp_avg_sq = self.exp_avg_sq if rows is None else self.exp_avg_sq.index_select(0, rows)
        adam_step(params, grads, exp_avg, exp_avg_sq, [self.steps[b] for b in members], lrs)
        if rows is not None:
            self.exp_avg.index_copy_(0, rows, exp_avg)
            self.exp_avg_sq.index_copy_(0, rows, exp_avg_sq)

    def reset(self, b: int) -> None:
        """Member ``b`` before its first step."""
        self.exp_avg[b].zero_()
        self.exp_avg_sq[b].zero_()
        self.steps[b] = 0

    def state_dict(self, b: int, shapes: Sequence[torch.Size], lr: float, initial_lr: float) -> dict:
        """Member ``b``'s state in ``torch.optim.Adam``'s ``state_dict`` layout (one tensor
        per parameter of ``shapes``)."""
        state, offset = {}, 0
        for i, shape in enumerate(shapes):
            size = math.prod(shape)
            if self.steps[b]:
                state[i] = {"step": torch.tensor(float(self.steps[b])),
                            "exp_avg": self.exp_avg[b, offset:offset + size].reshape(shape).clone(),
                            "exp_avg_sq": self.exp_avg_sq[b, offset:offset + size].reshape(shape).clone()}
            offset += size
        group = {"lr": lr, "betas": ADAM_BETAS, "eps": ADAM_EPS, "weight_decay": 0,
                 "amsgrad": False, "maximize": False, "foreach": None, "capturable": False,
                 "differentiable": False, "fused": True, "decoupled_weight_decay": False,
                 "initial_lr": initial_lr, "params": list(range(len(shapes)))}
        return {"state": state, "param_groups": [group]}

    @torch.no_grad()
    def load_state_dict(self, b: int, state: Mapping, steps: int) -> None:
        """Member ``b``'s moments from an Adam ``state_dict`` (none before a first step)."""
        moments = state.get("state", {})
        self.exp_avg[b].zero_()
        self.exp_avg_sq[b].zero_()
        if moments:
            self.exp_avg[b] = torch.cat([moments[i]["exp_avg"].reshape(-1) for i in sorted(moments)])
            self.exp_avg_sq[b] = torch.cat([moments[i]["exp_avg_sq"].reshape(-1) for i in sorted(moments)])
        self.steps[b] = int(steps)


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


def clip_norms(grads: torch.Tensor, clip: float | torch.Tensor) -> torch.Tensor:
    """Each row of ``grads`` (``[k, P]``) scaled to a norm of at most ``clip`` (a number, or
    ``[k, 1]`` per member; 0: no clip), in place; the norms before."""
    norms = torch.linalg.vector_norm(grads, dim=1)
    scale_to(grads, norms, clip)
    return norms


def scale_to(grads: torch.Tensor | Sequence[torch.Tensor], norms: torch.Tensor, clip: float | torch.Tensor) -> None:
    """Each member's rows of ``grads`` (one ``[k, P]`` tensor, or several scaled together),
    whose norms are ``norms`` (``[k]``), scaled in place to a norm of at most ``clip`` (a
    number, or ``[k, 1]`` per member; 0: no clip)."""
    if isinstance(clip, torch.Tensor):  # members' own clips; 0 (none) scales by 1
        clip = clip.squeeze(1)
        factor = torch.where(clip > 0, (clip / (norms + 1e-6)).clamp_(max=1.0), 1.0)
    elif clip > 0:
        factor = (clip / (norms + 1e-6)).clamp_(max=1.0)
    else:
        return
    for g in [grads] if isinstance(grads, torch.Tensor) else grads:
        g.mul_(factor.unsqueeze(1))


class RowReplayBuffer(ReplayBuffer):
    """One member's replay storage: TorchRL's ``ReplayBuffer`` over a ``TensorStorage`` of one
    pre-allocated float tensor, ``rows``, a row per transition (:func:`pack`).

    ``extend``, ``sample``, indexing and ``state_dict`` are TorchRL's. An update draws the
    indices itself (:meth:`sample_rows`), the very draw of TorchRL's ``RandomSampler``
    (``torch.randint``), from the member's generator, and indexes ``rows``
    (``bench/update_rate.py`` times it against ``sample()``).

    :meth:`put` writes rows into ``rows`` at once, where ``extend`` would, and books them
    with TorchRL later: TorchRL's ``extend`` costs ~80 us a call whatever its size, and a
    learner adds a few rows per env step. The rows put since the last booking are handed to
    one ``extend`` (the same values to the same places: the storage, cursor and counts
    become what an ``extend`` per put makes) as soon as anything of TorchRL's touches the
    storage (every path of ``ReplayBuffer`` goes through ``_storage``: length, ``sample``,
    ``state_dict``), and before they would be more than the buffer holds. The learner's own
    paths (:meth:`stored`, :meth:`sample_rows`) read ``rows`` and need no booking, so a run
    books at its checkpoints (``extend`` was ~12% of a cart-pole dqn run, then ~8% when
    booked at each update).
    """

    def __init__(self, capacity: int, width: int, batch_size: int,
                 device: torch.device | str = "cpu") -> None:
        self._unbooked = self._next = 0  # rows put since the last booking; the row the next put writes
        self._filled = 0  # rows stored, booked or not (len(self) reads TorchRL's storage: ~5 us a call)
        self.priorities = None  # prioritized replay (learners.priority.Priorities): each written row gets one
        self._capacity = int(capacity)
        rows = torch.zeros(capacity, width, device=device)
        super().__init__(storage=TensorStorage(rows, device=device), sampler=RandomSampler(),
                         batch_size=batch_size)
        self.empty()  # a TensorStorage made from a tensor counts it full
        self._rows = rows

    def empty(self, *args, **kwargs) -> None:
        super().empty(*args, **kwargs)
        self._unbooked, self._next = 0, writer_cursor(self)  # the row the next put writes
        self._filled = 0

    def load_state_dict(self, state_dict: dict) -> None:
        super().load_state_dict(state_dict)
        self._unbooked, self._next = 0, writer_cursor(self)
        self._filled = len(self)

    @property
    def _storage(self):
        if self._unbooked:
            self.book()
        return self.__dict__.get("_storage_")

    @_storage.setter
    def _storage(self, storage) -> None:
        self.__dict__["_storage_"] = storage

    @property
    def rows(self) -> torch.Tensor:
        """The storage tensor (every row put is in it)."""
        return self._rows

    def put(self, rows: torch.Tensor) -> None:
        """Writes ``rows`` (``[n, width]``) after those stored, as ``extend`` would (booked with
        TorchRL when it next reads the buffer); with priorities, each row gets the largest."""
        if self._unbooked + len(rows) > self._capacity:
            self.book()  # one extend never wraps onto its own rows
        cursor, n = self._next, len(rows)
        if cursor + n <= self._capacity:
            self._rows[cursor:cursor + n] = rows
        else:
            self._rows[(torch.arange(cursor, cursor + n) % self._capacity).to(self._rows.device)] = rows
        self._next = (cursor + n) % self._capacity
        self._unbooked += n
        self._filled = min(self._filled + n, self._capacity)
        if self.priorities is not None:
            self.priorities.added(torch.arange(cursor, cursor + n) % self._capacity)

    def stored(self) -> int:
        """``len(self)`` without booking the rows put."""
        return self._filled

    def book(self) -> None:
        """The rows put since the last booking handed to TorchRL (one ``extend`` of their own
        values, at their own places)."""
        n, self._unbooked = self._unbooked, 0
        if n:
            index = torch.arange(self._next - n, self._next) % self._capacity
            self.extend(self._rows[index.to(self._rows.device)])

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


class Round(NamedTuple):
    """One update round's numbers for the statistics, a row per member it updated: the loss
    ``[k]``, the values ``q`` and their ``target`` (``[k, ...]``), the gradient norms ``[k]``
    (None: not kept) and the algorithm's own numbers per transition (``[k, ...]`` each)."""

    loss: torch.Tensor
    q: torch.Tensor
    target: torch.Tensor
    norms: torch.Tensor | None
    extras: Mapping[str, torch.Tensor]


def track(trackers: Sequence[UpdateStats], due: Sequence[int], loss: torch.Tensor, q: torch.Tensor,
          target: torch.Tensor, norms: torch.Tensor | None, clipped: Sequence[bool],
          extras: Mapping[str, torch.Tensor] | None = None) -> None:
    """One update round into the trackers of ``due`` (member ``due[j]``: row ``j``), its
    gradient norm kept where ``clipped[j]``: the round's tensors detached once, each tracker
    keeping its row's place (a round of ten members: ~0.25 ms less than picking each row here)."""
    record = Round(loss.detach(), q.detach(), target.detach(), None if norms is None else norms.detach(),
                   {name: value.detach() for name, value in (extras or {}).items()})
    for j, b in enumerate(due):
        trackers[b].add(record, j, clipped[j])


def picked(values: Sequence[torch.Tensor], rows: Sequence[int]) -> torch.Tensor:
    """``values[i][rows[i]]`` for every ``i``, joined along the first dimension (as
    ``torch.cat`` joins them: the same numbers in the same order)."""
    if len({value.shape for value in values}) == 1:
        found = torch.stack(list(values))[torch.arange(len(values)), torch.as_tensor(list(rows))]
    else:  # rounds of different widths (members renewed or owing different updates)
        found = torch.stack([value[row] for value, row in zip(values, rows)])
    return found.reshape(-1, *found.shape[2:]) if found.dim() > 1 else found


class UpdateStats:
    """One member's losses, Q of the taken actions, TD targets and gradient norms since the
    last :meth:`read`. Per update it only keeps its place in the round (no host sync, no
    arithmetic); they are picked and reduced to sums every ``FOLD`` updates and when read."""

    FOLD = 256

    def __init__(self) -> None:
        self.latest: dict[str, float] = {}
        self.restart(0)

    def restart(self, updates: int) -> None:
        """A new interval, starting now after ``updates`` optimizer steps."""
        self.pending: list[tuple[Round, int, bool]] = []  # (round, this member's row, its norm kept)
        self.extra_sums: dict[str, float] = {}
        self.extra_counts: dict[str, int] = {}  # numbers of each (an extra some updates lack)
        self.loss_sum = self.q_sum = self.td_sum = self.norm_sum = 0.0
        self.count = self.values = self.n_norms = 0
        self.since, self.t0 = updates, time.perf_counter()

    def add(self, record: Round, row: int = 0, norm: bool = True) -> None:
        """One update: row ``row`` of ``record`` (:func:`track`), its gradient norm counted if
        ``norm`` and the round kept one."""
        self.count += 1
        self.pending.append((record, row, norm and record.norms is not None))
        if len(self.pending) >= self.FOLD:
            self._fold()

    def _fold(self) -> None:
        if not self.pending:
            return
        records, rows, norms = zip(*self.pending)
        q, target = picked([r.q for r in records], rows), picked([r.target for r in records], rows)
        sums = torch.stack((picked([r.loss for r in records], rows).sum(), q.sum(), (target - q).abs_().sum()))
        loss_sum, q_sum, td_sum = sums.tolist()
        self.loss_sum, self.q_sum, self.td_sum = self.loss_sum + loss_sum, self.q_sum + q_sum, self.td_sum + td_sum
        self.values += q.numel()
        kept = [(r.norms, j) for r, j, norm in self.pending if norm]
        if kept:
            self.norm_sum += float(picked(*zip(*kept)).sum())
            self.n_norms += len(kept)
        for name in {name for r in records for name in r.extras}:
            joined = picked(*zip(*[(r.extras[name], j) for r, j in zip(records, rows) if name in r.extras]))
            self.extra_sums[name] = self.extra_sums.get(name, 0.0) + float(joined.sum())
            self.extra_counts[name] = self.extra_counts.get(name, 0) + joined.numel()
        self.pending.clear()

    def read(self, updates: int, reset: bool = True) -> dict[str, float]:
        """The interval's means (``loss``, ``q_mean``, ``td_error``, ``grad_norm``), the
        ``updates`` so far and ``updates_per_s``; ``reset``: start a new interval."""
        self._fold()
        if self.count:
            self.latest = {"loss": self.loss_sum / self.count, "q_mean": self.q_sum / self.values,
                           "td_error": self.td_sum / self.values}
        if self.n_norms:
            self.latest["grad_norm"] = self.norm_sum / self.n_norms
        if self.count:
            self.latest.update({name: total / self.extra_counts[name] for name, total in self.extra_sums.items()})
        rate = (updates - self.since) / max(time.perf_counter() - self.t0, 1e-9)
        stats = {**self.latest, "updates": float(updates), "updates_per_s": rate}
        if reset:
            self.restart(updates)
        return stats


# The replay training state's layout. 2: the replay buffer holds one float row per
# transition (``pack``) and there is no ``last_loss``; 1 (unmarked): a TensorDict storage.
FORMAT = 2


class ReplayMembers(MemberLearner):
    """The replay bookkeeping of every member of a replay-buffer learner, whatever its
    networks: each member's buffer (and n-step queues, priorities), its update credit, and
    the rounds in which the updates owed run (:meth:`settle` calls the learner's
    ``_update(due, stored, minibatch)`` for the members of one minibatch size).

    Its settings read here: ``updates``, ``train_every``, ``learning_starts``,
    ``buffer_size``, ``batch_size``, ``n_step``, ``prioritized`` (``priority_*``),
    ``device``. When it trains (``train_every``): ``episode``: ``updates`` minibatches after
    each finished episode; ``step``: ``updates`` minibatches per collected transition
    (fractions carried over), once the buffer holds ``learning_starts``. The updates owed
    run in rounds: a round updates every member that still owes one, the others'
    parameters and optimizer state untouched.
    """

    action_width = 1  # numbers of an action in a replay row (a continuous learner: its dims)

    def _row_width(self) -> int:
        """A replay row's numbers (:func:`pack`); n-step rows carry their steps."""
        return 2 * self.n_obs + self.action_width + 2 + (self.n_step > 1)

    def _buffer(self, own: Any) -> RowReplayBuffer:
        """An empty replay buffer of a member with settings ``own`` (its priorities too)."""
        buffer = RowReplayBuffer(own.buffer_size, self._row_width(), own.batch_size, self.device)
        if self.prioritized:  # Rainbow's parts load where they are used
            from learners.priority import Priorities

            buffer.priorities = Priorities(own.buffer_size, own.priority_alpha, own.priority_eps, self.device)
        return buffer

    def _minibatches(self) -> dict[int, torch.Tensor]:
        """A round's minibatches, per minibatch size among the members: as many as members of it."""
        sizes = [v.batch_size for v in self.settings]
        return {size: torch.empty(sizes.count(size), size, self._row_width(), device=self.device) for size in sizes}

    def store(self, td: TensorDictBase, live: Sequence[int] | None = None) -> int:
        """Each live member adds its block's transitions to its replay buffer (with
        ``n_step`` > 1, the n-step rows that leave its queues); the block size."""
        n = td.numel() // self.members
        alike = all(v is self.settings[0] for v in self.settings)  # seeds of the learner's settings, not trials
        flat = td.reshape(-1) if self.n_step > 1 or not alike else None
        if self.n_step > 1:
            self._queues(n)
            done = flat.get(("next", "done")).reshape(-1)
            for b in everyone(self, live):
                block = slice(b * n, (b + 1) * n)
                rows = self.nsteps[b].push(self.transitions_of(flat[block], self.settings[b]), done[block])
                if rows is not None:
                    self.buffers[b].put(pack(rows).to(self.device))
            return n
        blocks = pack(self.transitions_of(td, self)).to(self.device).split(n) if alike else None
        for b in everyone(self, live):
            self.buffers[b].put(blocks[b] if blocks is not None else pack(
                self.transitions_of(flat[b * n:(b + 1) * n], self.settings[b])).to(self.device))
        return n

    def _queues(self, copies: int) -> None:
        """Each member's n-step queues for ``copies`` copies (made at the first step or the
        first loaded state, when the copies are known)."""
        if not self.nsteps:
            from learners.nstep import NStep

            self.nsteps = [NStep(self.n_step, copies, self.n_obs, own.gamma) for own in self.settings]

    def observe(self, td: TensorDictBase, live: Sequence[int] | None = None) -> None:
        """Each live member stores its block's transitions and counts them (schedule, update
        credit with ``train_every=step``); then the updates owed run."""
        n = self.store(td, live)
        for b in everyone(self, live):
            if self.schedules:
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
        super().end_episodes(ended)
        if self.train_every == "episode":
            for b, count in ended.items():
                for _ in range(count):
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

    def phase(self, b: int) -> tuple[Hashable, Hashable] | None:
        """Member ``b``'s update credit with ``train_every=step`` once it learns (its
        ``updates`` a step with it): members of one phase owe their updates at the same steps."""
        if self.train_every != "step" or self.buffers[b].stored() < max(self.settings[b].learning_starts, 1):
            return None
        return self.settings[b].updates, self.credit[b]

    def settle(self) -> None:
        """Runs the updates the members owe, in rounds: a round updates every member that still
        owes one (each member's updates in its order, as alone), those of one minibatch size
        together."""
        owed, self.owed = self.owed, [0] * self.members
        stored = {b: self.buffers[b].stored() for b in range(self.members) if owed[b]}
        for done in range(max(owed)):
            due = [b for b in stored if owed[b] > done]
            for size in sorted({self.settings[b].batch_size for b in due}):
                self._update([b for b in due if self.settings[b].batch_size == size], stored, self._minibatch[size])

    def _sample(self, due: list[int], stored: Mapping[int, int], minibatch: torch.Tensor) -> tuple[list, list]:
        """Each due member's minibatch into ``minibatch``'s rows, drawn from its own stream;
        with prioritized replay, their rows' indices and importance weights."""
        drawn, weights = [], []
        if self.prioritized:
            from learners.priority import annealed_beta
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
        return drawn, weights

    def begin(self) -> None:
        for b, tracker in enumerate(self.trackers):
            tracker.restart(self.steps[b])


class ReplayLearner(ReplayMembers):
    """The members of a replay-buffer learner with one network (and its target network).

    The algorithm (a subclass, a dataclass of its settings) gives:

    - ``template(task)``: one member's network on the CPU (an ``nn.Sequential`` of
      :class:`MemberNets`'s layers), and ``actor(template)``: it as ``model.pt`` holds it;
    - ``arch()``: what a saved state must match (shapes), and ``kind``;
    - ``terms(q, target_q, batch, gamma)``: the loss of a minibatch, one row per transition
      ``(loss, q, target, error)``, ``error`` what prioritized replay keeps (``q`` and
      ``target_q``: the networks as functions of observations);
    - ``choose(q, explore, draws)``: actions from the network's outputs, and ``draw(generator,
      copies, out)``: one member's random numbers for one step (``explore`` says how many);
    - ``transitions_of(td, own)``: the transitions a member with settings ``own`` stores.

    Its settings read here: ``lr``, ``lr_decay``, ``gamma``, ``tau``, ``target_update``,
    ``grad_clip``, ``updates``, ``train_every``, ``learning_starts``, ``buffer_size``,
    ``batch_size``, ``n_step``, ``prioritized`` (``priority_*``), ``noisy``, ``epsilon`` (a
    schedule), ``device``.

    When it trains (``train_every``): ``episode``: ``updates`` minibatches after each finished
    episode; ``step``: ``updates`` minibatches per collected transition (fractions carried
    over), once the buffer holds ``learning_starts``. The updates owed run in rounds: a round
    updates every member that still owes one, the others' parameters and optimizer state
    untouched.
    """

    # -- building ------------------------------------------------------------
    def build(self, task, generators: torch.Generator | Sequence[torch.Generator] | None = None,
              variants: Sequence[Any] | None = None) -> None:
        """The networks, optimizer state and replay buffers of one member per generator: its
        stream initialises its network (as ``nn.Linear`` does from torch's global stream) and
        then draws its exploration and minibatches; ``variants``: each member's own settings."""
        self._members(generators, variants)
        self._one_target_kind(self.settings)
        self.n_obs, self.n_actions = len(task.observation_names), int(task.n_actions)
        with torch.random.fork_rng(devices=[]):  # its own init is replaced by each member's
            template = self.template(task)
        self.actor = self.actor_of(template)
        self.has_target = bool(self.target_update or self.tau)
        starts = MemberNets(template)  # draws each member's start into the template
        self.group = MemberGroup(template, [starts.initial(g) for g in self.generators], self.device, self.has_target)
        self.net = self.group.net
        self.credit = [0.0] * self.members  # updates owed, fractions carried over
        self.owed = [0] * self.members  # whole updates owed, run by settle
        self.schedules = [v.epsilon if b == 0 else copy.deepcopy(v.epsilon) for b, v in enumerate(self.settings)]
        self.trackers = [UpdateStats() for _ in range(self.members)]
        self.buffers = [self._buffer(v) for v in self.settings]
        self._minibatch = self._minibatches()
        self.nsteps: list = []  # each member's n-step queues (learners.nstep), made at its first step

    @staticmethod
    def _one_target_kind(settings: Sequence[Any]) -> None:
        """One line unless the members of ``settings`` all have a target network or none."""
        require(len({bool(v.target_update or v.tau) for v in settings}) == 1,
                "learner.tau and learner.target_update: members of one batch must all have a target network or none",
                [(v.tau, v.target_update) for v in settings])

    @property
    def params(self) -> torch.Tensor:
        """Every member's parameters, ``[members, P]`` (:class:`MemberGroup`)."""
        return self.group.params

    @property
    def target(self) -> torch.Tensor:
        """Every member's target network's parameters (without one: :attr:`params`)."""
        return self.group.target if self.has_target else self.group.params

    @property
    def grads(self) -> torch.Tensor:
        """Every member's latest gradients."""
        return self.group.grads

    @property
    def adam(self) -> MemberAdam:
        return self.group.adam

    @property
    def steps(self) -> list[int]:
        """Each member's optimizer steps."""
        return self.adam.steps

    @property
    def exp_avg(self) -> torch.Tensor:
        return self.adam.exp_avg

    @property
    def exp_avg_sq(self) -> torch.Tensor:
        return self.adam.exp_avg_sq

    @torch.no_grad()
    def renew(self, b: int, generator: torch.Generator, variant: Any | None = None) -> None:
        """Member ``b`` made anew from ``generator`` and ``variant`` (None: this learner's
        settings), as :meth:`build` makes a member: a batch's freed member given another trial
        x seed. The other members are left as they are."""
        own = self.variant(variant)
        self._one_target_kind([self.settings[0], own])
        self.generators[b], self.settings[b] = generator, own
        self.group.renew(b, self.net.initial(generator).to(self.device))
        self.credit[b], self.owed[b] = 0.0, 0
        self.schedules[b] = dataclasses.replace(own.epsilon)  # at its start, whatever own's has done
        self.trackers[b] = UpdateStats()
        self.buffers[b] = self._buffer(own)
        self._minibatch = self._minibatches()
        if self.nsteps:
            from learners.nstep import NStep

            self.nsteps[b] = NStep(self.n_step, len(self.nsteps[b].count), self.n_obs, own.gamma)

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
        ``epsilon`` (none with ``noisy``: the noisy layers explore, epsilon is not used),
        ``lr``, ``updates`` (optimizer steps so far) and ``updates_per_s`` (per wall-clock
        second since the last reset). ``reset=False`` reads without starting a new interval
        (for a progress bar shown between the logger's reads)."""
        stats = self.trackers[b].read(self.steps[b], reset)
        if self.settings[b].grad_clip == 0 and self.steps[b]:
            stats["grad_norm"] = float(torch.linalg.vector_norm(self.grads[b]))
        explores = {} if self.noisy else {"epsilon": float(self.schedules[b].value)}
        return {**stats, **explores, "lr": self.lr_of(b)}

    # -- acting --------------------------------------------------------------
    def act_members(self, td: TensorDictBase, members: Sequence[int] | None, greedy: bool,
                    generators: Sequence[torch.Generator | None]) -> TensorDictBase:
        """The actions of ``members`` (None: all) on their blocks of ``td`` (block ``j`` is
        member ``members[j]``'s), ``generators[j]`` drawing its noise and exploration
        (:meth:`choose`); greedy: the mean weights and no exploration. Returns a new
        tensordict of ``td``'s entries and ``action``."""
        params = self.group.layers if members is None else self.params[list(members)]
        members = range(self.members) if members is None else list(members)
        k = len(members)
        noise = self.net.noise(generators, self.device) if self.noisy and not greedy else None
        with torch.no_grad():
            q = self.net.q(params, td.get("observation").reshape(k, -1, self.n_obs).to(self.device), noise)
        n = q.shape[1]
        explore = None if greedy or self.noisy else torch.tensor([[float(self.schedules[b].value)] for b in members])
        drawn = None if explore is None else self.draw_all(generators, n)
        action = self.choose(q, explore, drawn)
        return with_entries(td, action=action.reshape(td.batch_size))

    def draw_all(self, generators: Sequence[torch.Generator | None], n: int) -> list[torch.Tensor]:
        """Each block's :meth:`draw` for ``n`` copies, stacked (a block without a generator:
        the algorithm's ``undrawn``)."""
        found = [self.draw(g, n) if g is not None else self.undrawn(n) for g in generators]
        return [torch.stack(parts) for parts in zip(*found)]

    # -- learning ------------------------------------------------------------
    def _update(self, due: list[int], stored: Mapping[int, int], minibatch: torch.Tensor) -> None:
        """One update of each member of ``due`` (all of one minibatch size): its minibatch,
        the algorithm's loss (:meth:`terms`), gradients by autograd, its clipped norm, its
        Adam step and its target network's."""
        k = len(due)
        drawn, weights = self._sample(due, stored, minibatch)
        batch = unpack(minibatch[:k])
        step = self.group.open(None if k == self.members else torch.tensor(due, device=self.device))
        online, valued = step.leaves, step.target_layers if self.has_target else step.layers
        if self.noisy:  # fresh noise for each update: the online network's, then the target's
            streams = [self.generators[b] for b in due]
            noise = self.net.noise(streams, self.device)
            target_noise = self.net.noise(streams, self.device) if self.has_target else noise
            online, valued = self.net.with_noise(online, noise), self.net.with_noise(valued, target_noise)
        gamma = self.own("gamma", due, torch.float32, self.device)
        gamma = gamma.unsqueeze(-1) if isinstance(gamma, torch.Tensor) else gamma
        loss, q, td_target, errors, *extra = self.terms(lambda x: self.net.q(online, x),
                                                        lambda x: self.net.q(valued, x), batch, gamma)
        extras = extra[0] if extra else {}  # the algorithm's own numbers of each transition
        if self.prioritized:  # importance-weighted; the rows take their new errors
            loss = loss * torch.stack(weights).to(loss.device).unsqueeze(-1)
            for j, b in enumerate(due):
                self.buffers[b].priorities.update(drawn[j], errors[j])
        loss = loss.mean((1, 2))
        loss.sum().backward()
        # Adam, then the target networks: Polyak averaging by tau (a member with tau 0 moves by
        # 0: exactly not), a hard copy every target_update steps.
        norms = step.step(due, [self.lr_of(b) for b in due],
                          self.own("grad_clip", due, torch.float32, self.device),
                          self.own("tau", due, torch.float32, self.device))
        with torch.no_grad():
            for b in due:
                every = self.settings[b].target_update
                if every and self.steps[b] % every == 0:
                    self.target[b] = self.params[b]
        track(self.trackers, due, loss, q, td_target, norms, [self.settings[b].grad_clip > 0 for b in due], extras)

    # -- persistence ---------------------------------------------------------
    def _optimizer_state(self, b: int) -> dict:
        shapes = [p.shape for p in self.net.template.parameters()]
        return self.adam.state_dict(b, shapes, self.lr_of(b), self.settings[b].lr)

    def _check_arch(self, arch: dict, where: str) -> None:
        if arch != self.arch():
            raise StateMismatch(f"checkpoint {where} does not fit this run: it has network {arch}, "
                                f"this run builds {self.arch()}")

    def training_state(self, b: int) -> dict:
        """Everything member ``b``'s next update depends on, replay buffer and random stream
        included (for resuming)."""
        return {
            "format": FORMAT, "arch": self.arch(), "net": self.net.state(self.params[b]),
            "target_net": self.net.state(self.target[b]), "optimizer": self._optimizer_state(b),
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
                f"the training checkpoint holds a {self.kind.upper()} state of format {state.get('format', 1)}, "
                f"this code reads format {FORMAT} (its replay buffer changed); resume it with "
                "the version that wrote it, or start the run afresh")
        own = {k: v for k, v in self.training_state(b).items() if k not in ("generator", "lr_schedule")}
        check_state(state, own, "the training checkpoint")
        self._check_arch(state["arch"], "the training checkpoint")
        check_state(state, own, "the training checkpoint", deep=("net", "target_net"))
        self.params[b] = self.net.vector_of(state["net"], self.device)
        if self.has_target:
            self.target[b] = self.net.vector_of(state["target_net"], self.device)
        self.adam.load_state_dict(b, state["optimizer"], state["optimizer_steps"])
        self.schedules[b].load_state_dict(state["schedule"])
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

    def model_state(self, b: int) -> dict:
        """Member ``b``'s trained network, its optimiser and schedule (``model.pt``)."""
        self.net.load(self.params[b])
        return {
            "kind": self.kind, "arch": self.arch(),
            "actor": {k: v.clone() for k, v in self.actor.state_dict().items()},
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
        self.adam.load_state_dict(b, ckpt["optimizer"], ckpt["optimizer_steps"])
        self.schedules[b].load_state_dict(ckpt["schedule"])
        if self.has_target:
            self.target[b] = self.params[b]


def check_replay_settings(learner: Any) -> None:
    """One line unless a replay learner's ``hidden``, ``batch_size``, ``buffer_size`` and
    ``learning_starts`` fit together (its own ranges are its declared parameters')."""
    require(1 <= len(learner.hidden) <= 16 and all(1 <= h <= 65_536 for h in learner.hidden),
            "learner.hidden must list 1 to 16 layer widths in [1, 65536]", learner.hidden)
    require(learner.batch_size <= learner.buffer_size, "learner.batch_size must be in [1, buffer_size]",
            (learner.batch_size, learner.buffer_size))
    require(learner.learning_starts <= learner.buffer_size,
            f"learner.learning_starts must be <= learner.buffer_size ({learner.buffer_size}), "
            "else it never trains", learner.learning_starts)
    learner.hidden = [int(h) for h in learner.hidden]


class MemberGroup:
    """One network of every member with its Adam, and its target network where asked: the
    parameters ``[members, P]`` as :class:`MemberNets` lays out one member's ``template`` (or,
    without a template, ``P`` plain numbers such as SAC's log-alpha), their latest gradients
    and Adam's moments. An actor-critic has several (:class:`ActorCriticLearner`)."""

    def __init__(self, template: nn.Sequential | None, initial: Sequence[torch.Tensor],
                 device: torch.device | str, target: bool = False) -> None:
        self.net = None if template is None else MemberNets(template, device)
        self.params = torch.stack(list(initial)).to(device)
        self.target = self.params.clone() if target else None
        self.adam = MemberAdam(self.params)
        self.grads = torch.zeros_like(self.params)
        # Every member's layers, made once for an update of every member and for acting: as
        # autograd leaves (gradients into ``grads``), plain, and the target's.
        if self.net is not None:
            self.leaves = self.net.layers(self.params, self.grads)
            self.layers = self.net.layers(self.params)
            self.target_layers = None if self.target is None else self.net.layers(self.target)

    def renew(self, b: int, initial: torch.Tensor) -> None:
        """Member ``b`` from ``initial`` (``[P]``), its target a copy and its Adam at its start."""
        self.params[b] = initial
        if self.target is not None:
            self.target[b] = self.params[b]
        self.adam.reset(b)
        self.grads[b].zero_()

    def open(self, rows: torch.Tensor | None) -> GroupStep:
        """The :class:`GroupStep` of one update of the members at ``rows`` (None: all)."""
        return GroupStep(self, rows)

    def state(self, b: int) -> dict:
        """Member ``b``'s parameters (a template's ``state_dict``, or its numbers), target and Adam."""
        def of(vector: torch.Tensor) -> Any:
            return vector.clone() if self.net is None else self.net.state(vector)

        found = {"net": of(self.params[b]), "exp_avg": self.adam.exp_avg[b].clone(),
                 "exp_avg_sq": self.adam.exp_avg_sq[b].clone(), "steps": self.adam.steps[b]}
        return found | ({} if self.target is None else {"target_net": of(self.target[b])})

    @torch.no_grad()
    def load(self, b: int, state: Mapping, optimizer: bool = True) -> None:
        """Member ``b`` from a :meth:`state` (``optimizer``: its Adam and target too)."""
        def vector(saved: Any) -> torch.Tensor:
            return saved.to(self.params.device) if self.net is None else self.net.vector_of(saved, self.params.device)

        self.params[b] = vector(state["net"])
        if self.target is not None:
            self.target[b] = vector(state["target_net"]) if optimizer and "target_net" in state else self.params[b]
        if optimizer:
            self.adam.exp_avg[b] = state["exp_avg"].to(self.params.device)
            self.adam.exp_avg_sq[b] = state["exp_avg_sq"].to(self.params.device)
            self.adam.steps[b] = int(state["steps"])


class GroupStep:
    """One update of some members' :class:`MemberGroup`: their parameters as autograd leaves
    (``__call__``: the network on inputs ``[k, n, in]``), the same weights without gradient
    (:meth:`frozen`), the target network (:meth:`target`) or the plain numbers (``value``),
    then :meth:`step` (clip, Adam, Polyak averaging) and the write-back."""

    def __init__(self, group: MemberGroup, rows: torch.Tensor | None) -> None:
        self.group, self.rows = group, rows
        if rows is None:  # every member: its own tensors, in place
            self.params, self.grads, self.targets = group.params, group.grads, group.target
            self.grads.zero_()
            if group.net is not None:
                self.leaves, self.layers, self.target_layers = group.leaves, group.layers, group.target_layers
        else:  # the due members' rows, written back after the step
            self.params = group.params.index_select(0, rows)
            self.grads = torch.zeros_like(self.params)
            self.targets = None if group.target is None else group.target.index_select(0, rows)
            if group.net is not None:
                self.leaves, self.layers = group.net.layers(self.params, self.grads), group.net.layers(self.params)
                self.target_layers = None if self.targets is None else group.net.layers(self.targets)
        if group.net is None:
            self.value = self.params.detach().requires_grad_(True)
            self.value.grad = self.grads

    def __call__(self, x: torch.Tensor) -> Any:
        return self.group.net.q(self.leaves, x)

    def frozen(self, x: torch.Tensor) -> Any:
        """The network on ``x`` without gradient to its weights (to the input, still)."""
        return self.group.net.q(self.layers, x)

    def target(self, x: torch.Tensor) -> Any:
        """The target network on ``x``."""
        return self.group.net.q(self.target_layers, x)

    @torch.no_grad()
    def step(self, due: Sequence[int], lrs: Sequence[float], clip: float | torch.Tensor = 0.0,
             tau: float | torch.Tensor = 0.0) -> torch.Tensor:
        """The members' gradient norms (before clipping them to ``clip``), after their Adam step
        (learning rates ``lrs``) and their target's Polyak averaging by ``tau``."""
        norms = clip_norms(self.grads, clip)
        self.group.adam.step(self.rows, self.params, self.grads, due, lrs)
        if self.targets is not None and (isinstance(tau, torch.Tensor) or tau):
            self.targets.lerp_(self.params, tau)
        if self.rows is not None:
            self.group.params.index_copy_(0, self.rows, self.params)
            self.group.grads.index_copy_(0, self.rows, self.grads)
            if self.targets is not None:
                self.group.target.index_copy_(0, self.rows, self.targets)
        return norms


class Losses(NamedTuple):
    """An actor-critic's update of some members (:meth:`ActorCriticLearner.losses`): each
    member's summed loss ``[k]`` (autograd reaching each group it trains), the groups it steps,
    the groups whose targets then follow by Polyak averaging, and for the statistics the
    critics' loss ``[k]`` (``train/loss``), the first critic's values ``q`` and their
    ``target``, and the algorithm's own numbers per transition."""

    loss: torch.Tensor
    stepped: tuple[str, ...]
    followed: tuple[str, ...]
    critic_loss: torch.Tensor
    q: torch.Tensor
    target: torch.Tensor
    extras: dict[str, torch.Tensor]


class PolicyMembers(MemberLearner):
    """Every member's networks of a learner on continuous actions (SAC, TD3, PPO), each a
    :class:`MemberGroup` with its own Adam (and target, where the algorithm has one), and
    acting: each member's noise from its own stream, then the actor on every block at once.

    The algorithm (a subclass, a dataclass of its settings) gives ``networks(task)``:
    ``{name: (template, target)}``, one member's networks on the CPU (``actor`` among them,
    and the group ``critic`` names, which every update steps; a template ``nn.Sequential`` of
    :class:`MemberNets`'s layers, or None for plain numbers whose start ``initial(name, own)``
    gives); ``policy(template)``: the actor as ``model.pt`` holds it; ``kind``; its settings
    ``hidden`` and ``activation`` (what a saved state must match, with the shapes: :meth:`arch`);
    ``draw_act(generator, n)``: one member's standard normal step noise; and
    ``act_with(actor, observation, noise)``: the entries acting writes (``action``, and what
    else the algorithm keeps), ``noise`` None for the greedy action.
    """

    ACTIONS = "continuous"
    critic = "critic"  # the group every update steps: its steps count the updates, its norms are shown

    def _build_groups(self, task, generators: torch.Generator | Sequence[torch.Generator] | None,
                      variants: Sequence[Any] | None) -> None:
        """Every network of one member per generator, drawn from its stream in the order of
        ``networks`` (as ``nn.Linear`` draws from torch's global stream)."""
        from tasks.base import check_action_form

        check_action_form(task, "continuous", self.kind)
        self._members(generators, variants)
        self.n_obs, self.n_actions = len(task.observation_names), task.action_range.dims
        names = list(task.observation_names)
        with torch.random.fork_rng(devices=[]):  # its own init is replaced by each member's
            plan = {name: (None if template is None else with_obs_scale(template, self.obs_scale, names), target)
                    for name, (template, target) in self.networks(task).items()}
        self.templates = {name: template for name, (template, _) in plan.items()}
        starts = [self._initial(g, own) for g, own in zip(self.generators, self.settings)]
        self.groups = {name: MemberGroup(template, [start[name] for start in starts], self.device, target)
                       for name, (template, target) in plan.items()}
        self.policy_module = self.policy(self.templates["actor"])
        self.trackers = [UpdateStats() for _ in range(self.members)]

    def _initial(self, generator: torch.Generator, own: Any) -> dict[str, torch.Tensor]:
        """One member's starting parameters of every group, drawn from ``generator`` in order."""
        return {name: self.initial(name, own) if template is None else MemberNets(template).initial(generator)
                for name, template in self.templates.items()}

    @torch.no_grad()
    def _renew_groups(self, b: int, generator: torch.Generator, variant: Any | None) -> Any:
        """Member ``b``'s networks made anew from ``generator`` with ``variant``'s settings (None:
        this learner's), as :meth:`_build_groups` makes them; its settings."""
        own = self.variant(variant)
        self.generators[b], self.settings[b] = generator, own
        for name, start in self._initial(generator, own).items():
            self.groups[name].renew(b, start.to(self.device))
        self.trackers[b] = UpdateStats()
        return own

    @property
    def steps(self) -> list[int]:
        """Each member's updates (its ``critic`` group's Adam steps: every update steps it)."""
        return self.groups[self.critic].adam.steps

    def lr_of(self, b: int, group: str = "actor") -> float:
        """Member ``b``'s learning rate of ``group``: its ``<group>_lr`` setting, else ``lr``."""
        own = self.settings[b]
        return float(getattr(own, f"{group}_lr", own.lr))

    def _warming(self, b: int) -> bool:
        """Whether member ``b`` still acts uniformly at random (none does, unless the layer says)."""
        return False

    def act_members(self, td: TensorDictBase, members: Sequence[int] | None, greedy: bool,
                    generators: Sequence[torch.Generator | None]) -> TensorDictBase:
        """The actions of ``members`` (None: all) on their blocks of ``td``, ``generators[j]``
        drawing block ``j``'s noise (None: none); greedy: the actor's deterministic action. A
        member still warming up (:meth:`_warming`) acts uniformly at random. Returns a new
        tensordict of ``td``'s entries and the algorithm's (``action``, ...)."""
        members = list(range(self.members)) if members is None else list(members)
        k = len(members)
        observation = td.get("observation").reshape(k, -1, self.n_obs).to(self.device)
        n = observation.shape[1]
        noise, warm = None, []
        if not greedy:
            rows = []
            for j, (b, g) in enumerate(zip(members, generators)):
                if g is None:
                    rows.append(torch.zeros(n, self.n_actions))
                elif self._warming(b):
                    rows.append(torch.rand(n, self.n_actions, generator=g) * 2 - 1)
                    warm.append(j)
                else:
                    rows.append(self.draw_act(g, n))
            noise = torch.stack(rows)
        params = self.groups["actor"].layers if k == self.members else self.groups["actor"].params[members]
        with torch.no_grad():
            found = self.act_with(lambda x: self.groups["actor"].net.q(params, x), observation,
                                  None if noise is None else noise.to(self.device))
        if warm:
            found["action"][warm] = noise[warm].to(found["action"].device)
        return with_entries(td, **{name: value.reshape(*td.batch_size, *value.shape[2:]).cpu()
                                   for name, value in found.items()})

    def stats(self, b: int) -> dict[str, float]:
        return {"alpha": self.lr_of(b), "gamma": self.settings[b].gamma}

    def train_stats(self, b: int, reset: bool = True) -> dict[str, float]:
        """``train/*`` of member ``b``: ``loss`` (the critics'), ``q_mean`` (their values),
        ``td_error`` (to their targets) and the algorithm's own means (``loss_actor``,
        ``entropy``, ...) over the updates since the last reset; ``lr``, ``updates`` and
        ``updates_per_s``."""
        return {**self.trackers[b].read(self.steps[b], reset), "lr": self.lr_of(b)}

    def begin(self) -> None:
        for b, tracker in enumerate(self.trackers):
            tracker.restart(self.steps[b])

    def arch(self) -> dict:
        """The networks a saved state must match (the algorithm's ``hidden``, ``activation``
        and ``obs_scale``)."""
        return {"n_obs": self.n_obs, "n_actions": self.n_actions, "hidden": self.hidden,
                "activation": self.activation} | ({"obs_scale": dict(self.obs_scale)} if self.obs_scale else {})

    def _check_arch(self, arch: dict, where: str) -> None:
        if arch != self.arch():
            raise StateMismatch(f"checkpoint {where} does not fit this run: it has networks {arch}, "
                                f"this run builds {self.arch()}")

    def _load_groups(self, b: int, state: Mapping, where: str, key: str, optimizer: bool) -> None:
        """Member ``b``'s groups from ``state[key]``, checked against this learner's own first."""
        own = self.training_state(b) if optimizer else self.model_state(b)
        own = {k: v for k, v in own.items() if k not in ("generator", "rollout")}
        check_state(state, own, where)
        self._check_arch(state["arch"], where)
        check_state(state, own, where, deep=(key,))
        for name, group in self.groups.items():
            group.load(b, state[key][name], optimizer=optimizer)

    def model_state(self, b: int) -> dict:
        """Member ``b``'s trained networks (``model.pt``): the policy as TorchRL's actor
        (``actor``: loads into :meth:`policy`'s module), and every group's parameters."""
        self.groups["actor"].net.load(self.groups["actor"].params[b])
        return {"kind": self.kind, "arch": self.arch(),
                "actor": {k: v.clone() for k, v in self.policy_module.state_dict().items()},
                "groups": {n: {"net": g.state(b)["net"]} for n, g in self.groups.items()},
                "optimizer_steps": self.steps[b]}

    @torch.no_grad()
    def load_model_state(self, b: int, ckpt: Mapping, where: str) -> None:
        """Loads saved networks into member ``b`` (its optimizers start afresh)."""
        self._load_groups(b, ckpt, where, "groups", optimizer=False)


class ActorCriticLearner(PolicyMembers, ReplayMembers):
    """The members of a replay-buffer actor-critic on continuous actions (SAC, TD3): the
    networks of :class:`PolicyMembers` and the replay bookkeeping of :class:`ReplayMembers`.

    The algorithm gives, besides what :class:`PolicyMembers` asks: ``draw_update(generator,
    batch_size)``: one member's random numbers for one update; ``losses(nets, batch, noise,
    gamma, own, kind)``: the members' :class:`Losses` (autograd reaching each group through
    ``nets``), and ``update_kind(b)`` where updates differ in what they step (TD3's delayed
    actor). Settings read here, besides :class:`ReplayMembers`'s: ``lr`` (and ``<group>_lr``
    where the algorithm has one, as ``alpha_lr``), ``tau``, ``grad_clip``, ``reward_scale``,
    ``learning_starts`` (until its buffer holds that many, a member acts uniformly at random).
    """

    n_step, prioritized, train_every = 1, False, "step"

    def build(self, task, generators: torch.Generator | Sequence[torch.Generator] | None = None,
              variants: Sequence[Any] | None = None) -> None:
        """Every member's networks (:meth:`_build_groups`), then its replay buffer."""
        self._build_groups(task, generators, variants)
        self.action_width = self.n_actions
        self.credit = [0.0] * self.members
        self.owed = [0] * self.members
        self.buffers = [self._buffer(v) for v in self.settings]
        self._minibatch = self._minibatches()
        self.nsteps: list = []

    def renew(self, b: int, generator: torch.Generator, variant: Any | None = None) -> None:
        """Member ``b`` made anew from ``generator`` and ``variant`` (None: this learner's
        settings), as :meth:`build` makes a member; the others are left as they are."""
        own = self._renew_groups(b, generator, variant)
        self.credit[b], self.owed[b] = 0.0, 0
        self.buffers[b] = self._buffer(own)
        self._minibatch = self._minibatches()

    def _warming(self, b: int) -> bool:
        """Whether member ``b`` still acts at random (its buffer below ``learning_starts``)."""
        return self.buffers[b].stored() < self.settings[b].learning_starts

    # -- learning ------------------------------------------------------------
    def update_kind(self, b: int) -> Hashable:
        """Which networks member ``b``'s next update steps (members of one kind update together;
        TD3's delayed actor): by default every update is alike."""
        return None

    def _update(self, due: list[int], stored: Mapping[int, int], minibatch: torch.Tensor) -> None:
        """One update of each member of ``due`` (all of one minibatch size): its minibatch and
        its update's random numbers from its own stream, the algorithm's losses, gradients by
        autograd, and each stepped group's clipped Adam step and Polyak averaging; the members
        whose updates are of one kind (:meth:`update_kind`) together."""
        kinds: dict[Hashable, list[int]] = {}
        for b in due:
            kinds.setdefault(self.update_kind(b), []).append(b)
        for kind, some in kinds.items():
            self._update_some(some, kind, stored, minibatch)

    def _update_some(self, due: list[int], kind: Hashable, stored: Mapping[int, int], minibatch: torch.Tensor) -> None:
        k = len(due)
        self._sample(due, stored, minibatch)
        batch = unpack(minibatch[:k], continuous=self.n_actions)
        noise = torch.stack([self.draw_update(self.generators[b], minibatch.shape[1]) for b in due]).to(self.device)
        rows = None if k == self.members else torch.tensor(due, device=self.device)
        nets = {name: group.open(rows) for name, group in self.groups.items()}
        gamma = self.own("gamma", due, torch.float32, self.device)
        gamma = gamma.unsqueeze(-1) if isinstance(gamma, torch.Tensor) else gamma
        found = self.losses(nets, batch, noise, gamma, [self.settings[b] for b in due], kind)
        found.loss.sum().backward()
        clip = self.own("grad_clip", due, torch.float32, self.device)
        tau = self.own("tau", due, torch.float32, self.device)
        norms = {name: nets[name].step(due, [self.lr_of(b, name) for b in due], clip,
                                       tau if name in found.followed else 0.0) for name in found.stepped}
        track(self.trackers, due, found.critic_loss, found.q, found.target, norms.get(self.critic),
              [self.settings[b].grad_clip > 0 for b in due], found.extras)

    def transitions_of(self, tensordict: TensorDictBase, own: Any | None = None) -> Transitions:
        """The transitions of ``tensordict``, rewards scaled by ``reward_scale`` (``own``'s: a
        member's settings; default the learner's)."""
        own = self if own is None else own
        batch = Transitions.of(tensordict)
        if own.reward_scale != 1.0:
            batch = batch._replace(reward=batch.reward * float(own.reward_scale))
        return batch

    # -- persistence ---------------------------------------------------------
    def training_state(self, b: int) -> dict:
        """Everything member ``b``'s next update depends on: every group, its replay buffer,
        update credit and random stream (for resuming)."""
        return {"format": 1, "arch": self.arch(), "groups": {n: g.state(b) for n, g in self.groups.items()},
                "credit": self.credit[b], "buffer": self.buffers[b].state_dict(),
                "generator": self.generators[b].get_state()}

    @torch.no_grad()
    def load_training_state(self, b: int, state: Mapping) -> None:
        self._load_groups(b, state, "the training checkpoint", "groups", optimizer=True)
        self.credit[b] = float(state["credit"])
        self.buffers[b].load_state_dict(state["buffer"])
        self.generators[b].set_state(state["generator"])


class RolloutLearner(PolicyMembers):
    """The members of an on-policy actor-critic (PPO): the ``actor`` and ``critic`` of
    :class:`PolicyMembers`, and each member's rollout of ``rollout_steps`` env steps of its
    copies. When a member's rollout is full it learns from it: the critic's values, the
    advantages by TorchRL's ``generalized_advantage_estimate`` (each member's ``gamma`` and
    ``gae_lambda``), then ``epochs`` passes over the rollout in ``minibatches`` minibatches
    drawn by a permutation from its own stream; the members whose rollouts fill at one step
    learn together.

    The algorithm gives, besides what :class:`PolicyMembers` asks (its ``act_with`` writing
    ``action_preimage`` and ``action_log_prob`` too): ``losses(actor, critic, minibatch,
    own)``: the members' :class:`Losses` of a minibatch (a dict of ``observation``,
    ``preimage``, ``log_prob``, ``advantage``, ``returns``, each ``[k, S, ...]``).
    """

    out_keys = ("action", "action_preimage", "action_log_prob")

    def build(self, task, generators: torch.Generator | Sequence[torch.Generator] | None = None,
              variants: Sequence[Any] | None = None) -> None:
        """Every member's networks (:meth:`_build_groups`) and its empty rollout (sized at its
        first step, when its copies are known)."""
        self._build_groups(task, generators, variants)
        self.rollouts: dict[str, torch.Tensor] = {}
        self.filled = [0] * self.members  # each member's steps in its rollout

    def renew(self, b: int, generator: torch.Generator, variant: Any | None = None) -> None:
        """Member ``b`` made anew from ``generator`` and ``variant``; the others as they are."""
        self._renew_groups(b, generator, variant)
        self.filled[b] = 0

    # -- learning ------------------------------------------------------------
    def _rollout(self, copies: int) -> None:
        """Every member's rollout storage for ``copies`` copies a member."""
        if self.rollouts:
            return
        size = (self.members, max(own.rollout_steps for own in self.settings), copies)
        self.rollouts = {"observation": torch.zeros(*size, self.n_obs), "next_observation": torch.zeros(*size, self.n_obs),
                         "preimage": torch.zeros(*size, self.n_actions), "log_prob": torch.zeros(size),
                         "reward": torch.zeros(size), "terminated": torch.zeros(size, dtype=torch.bool),
                         "done": torch.zeros(size, dtype=torch.bool)}

    def observe(self, td: TensorDictBase, live: Sequence[int] | None = None) -> None:
        """Each live member writes its block's step into its rollout; the members whose
        rollouts are full then learn from them, together."""
        n = td.numel() // self.members
        self._rollout(n)
        flat, nxt = td.reshape(self.members, n), td.get("next").reshape(self.members, n)
        step = {"observation": flat.get("observation"), "next_observation": nxt.get("observation"),
                "preimage": flat.get("action_preimage"), "log_prob": flat.get("action_log_prob"),
                "reward": nxt.get("reward").reshape(self.members, n),
                "terminated": nxt.get("terminated").reshape(self.members, n),
                "done": nxt.get("done").reshape(self.members, n)}
        full = []
        for b in everyone(self, live):
            own = self.settings[b]
            for name, value in step.items():
                value = value[b] * float(own.reward_scale) if name == "reward" else value[b]
                self.rollouts[name][b, self.filled[b]] = value.reshape(self.rollouts[name][b, 0].shape)
            self.filled[b] += 1
            if self.filled[b] == own.rollout_steps:
                full.append(b)
        by_size: dict[tuple, list[int]] = {}
        for b in full:
            own = self.settings[b]
            by_size.setdefault((own.rollout_steps, own.epochs, own.minibatches), []).append(b)
        for (steps, epochs, minibatches), due in by_size.items():
            self._learn(due, steps, epochs, minibatches)
            for b in due:
                self.filled[b] = 0

    @torch.no_grad()
    def _advantages(self, due: list[int], steps: int) -> dict[str, torch.Tensor]:
        """The due members' rollouts flattened ``[k, steps * copies, ...]``, with their
        advantages and value targets (GAE over each copy's steps)."""
        from torchrl.objectives.value.functional import generalized_advantage_estimate

        index = torch.tensor(due)
        part = {name: value.index_select(0, index)[:, :steps] for name, value in self.rollouts.items()}
        k, copies = len(due), part["reward"].shape[2]
        params = self.groups["critic"].params.index_select(0, index.to(self.device))
        value = self.groups["critic"].net.q(params, part["observation"].reshape(k, -1, self.n_obs).to(self.device))
        after = self.groups["critic"].net.q(params, part["next_observation"].reshape(k, -1, self.n_obs).to(self.device))

        def per_copy(x: torch.Tensor) -> torch.Tensor:  # [k, steps, copies] -> [k, copies, steps, 1]
            return x.reshape(k, steps, copies).transpose(1, 2).unsqueeze(-1)

        gamma = self.own("gamma", due, torch.float32, self.device)
        lmbda = self.own("gae_lambda", due, torch.float32, self.device)
        gamma, lmbda = (x.view(k, 1, 1, 1) if isinstance(x, torch.Tensor) else x for x in (gamma, lmbda))
        advantage, returns = generalized_advantage_estimate(
            gamma, lmbda, per_copy(value), per_copy(after), per_copy(part["reward"].to(self.device)),
            per_copy(part["done"].to(self.device)), per_copy(part["terminated"].to(self.device)))

        def back(x: torch.Tensor) -> torch.Tensor:  # [k, copies, steps, 1] -> [k, steps * copies]
            return x.squeeze(-1).transpose(1, 2).reshape(k, -1)

        return {"observation": part["observation"].reshape(k, -1, self.n_obs).to(self.device),
                "preimage": part["preimage"].reshape(k, -1, self.n_actions).to(self.device),
                "log_prob": part["log_prob"].reshape(k, -1).to(self.device),
                "advantage": back(advantage), "returns": back(returns)}

    def _learn(self, due: list[int], steps: int, epochs: int, minibatches: int) -> None:
        """``epochs`` passes of the due members over their rollouts, ``minibatches`` a pass."""
        data = self._advantages(due, steps)
        k, total = len(due), data["returns"].shape[1]
        size = total // minibatches
        rows = None if k == self.members else torch.tensor(due, device=self.device)
        members = torch.arange(k).unsqueeze(1)
        clip = self.own("grad_clip", due, torch.float32, self.device)
        for _ in range(epochs):
            order = torch.stack([torch.randperm(total, generator=self.generators[b]) for b in due])
            for m in range(minibatches):
                pick = order[:, m * size:(m + 1) * size].to(self.device)
                minibatch = {name: value[members, pick] for name, value in data.items()}
                nets = {name: group.open(rows) for name, group in self.groups.items()}
                found = self.losses(nets["actor"], nets["critic"], minibatch, [self.settings[b] for b in due])
                found.loss.sum().backward()
                norm = clip_together([nets[name].grads for name in found.stepped], clip)
                for name in found.stepped:
                    nets[name].step(due, [self.lr_of(b) for b in due])
                track(self.trackers, due, found.critic_loss, found.q, found.target, norm,
                      [self.settings[b].grad_clip > 0 for b in due], found.extras)

    # -- persistence ---------------------------------------------------------
    def training_state(self, b: int) -> dict:
        """Everything member ``b``'s next update depends on: its networks and Adam, its
        rollout so far and its random stream (for resuming)."""
        rollout = {name: value[b].clone() for name, value in self.rollouts.items()}
        return {"format": 1, "arch": self.arch(), "groups": {n: g.state(b) for n, g in self.groups.items()},
                "filled": self.filled[b], "rollout": rollout, "generator": self.generators[b].get_state()}

    @torch.no_grad()
    def load_training_state(self, b: int, state: Mapping) -> None:
        self._load_groups(b, state, "the training checkpoint", "groups", optimizer=True)
        if state["rollout"]:
            self._rollout(state["rollout"]["reward"].shape[1])
            for name, value in state["rollout"].items():
                self.rollouts[name][b] = value
        self.filled[b] = int(state["filled"])
        self.generators[b].set_state(state["generator"])



def clip_together(grads: Sequence[torch.Tensor], clip: float | torch.Tensor) -> torch.Tensor:
    """Each member's gradients of several networks (``[k, P_i]`` each) scaled together to a
    norm of at most ``clip`` (``torch.nn.utils.clip_grad_norm_`` over all of them), in place;
    the norms before."""
    # each network's norm, then theirs together elementwise (a reduction across the stacked
    # norms would take another kernel for one member than for several)
    norms = sum(torch.linalg.vector_norm(g, dim=1) ** 2 for g in grads).sqrt()
    scale_to(grads, norms, clip)
    return norms


__all__ = ["PolicyMembers", "RolloutLearner", "clip_together", "ActorCriticLearner", "GroupStep", "Losses", "MemberGroup", "ReplayMembers", "FORMAT", "MemberLearner", "ObsScale", "ReplayLearner", "RowReplayBuffer", "MemberAdam",
           "MemberNets", "MemberTables", "Round", "UpdateStats", "adam_step", "clip_norms", "draws", "scale_to",
           "track"]
