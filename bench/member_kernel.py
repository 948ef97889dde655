"""The member layer's batched kernel against torch.vmap and TorchRL's DQNLoss (run by hand).

    python bench/member_kernel.py [1|default] [iters] [warmup] [repeats]

One DQN update (cart-pole's shapes: 4 -> 64 -> 64 -> 2 relu, 64 transitions, double DQN,
Huber, clip 10, Adam 1e-3, Polyak 0.01) of M = 1 and M = 10 members, timed side by side
in this run:

- A: :class:`learners.member.MemberNets` (each linear layer one ``baddbmm`` over the
  members), :func:`learners.dqn.td_terms`, :func:`learners.member.clip_norms` and
  :func:`learners.member.adam_step`: what the layer does;
- B: one member's module stacked with ``torch.func.stack_module_state`` (B'': tensordict's
  ``from_modules``), called through ``torch.vmap(functional_call)``, ``torch.optim.Adam``
  over the stacked leaves (B': ``fused=True``);
- C: TorchRL's ``DQNLoss`` (``SoftUpdate``, ``make_value_estimator``) per member, in a loop;
- D: A with its loss under ``torch.compile`` (compiled during the warm-up, not timed).

Prints microseconds per update (best and median of ``repeats``, the variants taking turns
within each) and each one's ratio to A.
Measured on 2026-12-02 (this project's 2-core machine, torch 2.13.0): B/A 3.4 at M=1 and
1.9-2.2 at M=10, C/A 4-5 at M=1 and 20-27 at M=10; every variant's member 0 is bit for bit
the same at M=1 and M=10; B differs from A by ~1e-8 after one update (Adam's last op).
D (2026-12-05, the variants taking turns, three training jobs beside): D/A 1.04 at M=1 and
0.96 at M=10, its parameters off A's in the last bits (~1e-6 after 840 updates).
"""
import copy, sys, time, statistics, warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
import torch
from torch import nn
from torch.func import functional_call, stack_module_state
from torchrl.modules import MLP, QValueActor
from learners.dqn import td_terms
from learners.member import MemberNets, adam_step, clip_norms
from learners.transitions import unpack

warnings.filterwarnings("ignore")
N_OBS, N_ACT, BATCH, GAMMA, LR, CLIP, TAU = 4, 2, 64, 0.99, 1e-3, 10.0, 0.01

def template():
    return MLP(in_features=N_OBS, out_features=N_ACT, num_cells=[64, 64], activation_class=nn.ReLU)

def member_vectors(M):
    """member j's initial parameter vector from seed j (same for any M)."""
    t = template()
    out = []
    for j in range(M):
        torch.manual_seed(1000 + j)
        for layer in t:
            if isinstance(layer, nn.Linear):
                layer.reset_parameters()
        out.append(nn.utils.parameters_to_vector(t.parameters()).detach().clone())
    return t, torch.stack(out)

def member_rows(M, n_updates):
    """[n_updates, M, BATCH, 11] fixed rows; member j's from its own seed."""
    rows = []
    for j in range(M):
        g = torch.Generator().manual_seed(5000 + j)
        obs = torch.randn(n_updates, BATCH, N_OBS, generator=g)
        nxt = torch.randn(n_updates, BATCH, N_OBS, generator=g)
        act = torch.randint(0, N_ACT, (n_updates, BATCH, 1), generator=g).float()
        rew = torch.randn(n_updates, BATCH, 1, generator=g)
        term = (torch.rand(n_updates, BATCH, 1, generator=g) < 0.05).float()
        rows.append(torch.cat([obs, nxt, act, rew, term], -1))
    return torch.stack(rows, 1)

# ---------------------------------------------------------------- A
class KernelA:
    def __init__(self, M):
        t, vec = member_vectors(M)
        self.net = MemberNets(t)
        self.params = vec.clone()
        self.target = vec.clone()
        self.grads = torch.zeros_like(vec)
        self.exp_avg = torch.zeros_like(vec)
        self.exp_avg_sq = torch.zeros_like(vec)
        self.valued = self.net.layers(self.target)
        self.steps = 0
        self.M = M

    def loss(self, online, rows):
        batch, net, valued = unpack(rows), self.net, self.valued
        q, tgt = td_terms(lambda x: net.q(online, x), lambda x: net.q(valued, x), batch, GAMMA, True)
        return nn.functional.smooth_l1_loss(q, tgt, reduction="none").mean((1, 2)).sum()

    def update(self, rows):
        self.grads.zero_()
        self.loss(self.net.layers(self.params, self.grads), rows).backward()
        with torch.no_grad():
            clip_norms(self.grads, CLIP)
            self.steps += 1
            adam_step(self.params, self.grads, self.exp_avg, self.exp_avg_sq, [self.steps] * self.M, [LR] * self.M)
            self.target.lerp_(self.params, TAU)

    def member_vector(self, j):
        return self.params[j].clone()

# ---------------------------------------------------------------- D
class CompiledD(KernelA):
    """A with its loss (forward, and backward through AOTAutograd) under ``torch.compile``
    (compiled in the warm-up); clipping, Adam and the target's step as A's. (Compiling that
    step too stops inductor here with ``KeyError: 'buf5'``, torch 2.13.0.)"""

    def __init__(self, M):
        super().__init__(M)
        self.loss = torch.compile(self.loss)

# ---------------------------------------------------------------- B
class FuncB:
    def __init__(self, M, fused=False, via="stack"):
        t, vec = member_vectors(M)
        copies = []
        for j in range(M):
            c = copy.deepcopy(t)
            nn.utils.vector_to_parameters(vec[j], c.parameters())
            copies.append(c)
        if via == "stack":
            params, _ = stack_module_state(copies)
            self.keys = list(params)
            self.params = params
            self.target = {k: v.detach().clone() for k, v in params.items()}
            base = copy.deepcopy(t).to("meta")
            def f(p, x):
                return functional_call(base, p, (x,))
            self.qf = torch.vmap(f)
            self.leaves = list(params.values())
            self.tleaves = list(self.target.values())
        else:  # tensordict from_modules
            from tensordict import TensorDict
            self.params = TensorDict.from_modules(*copies, as_module=True)
            self.target = self.params.data.clone()
            base = copy.deepcopy(t).to("meta")
            def f(p, x):
                with p.to_module(base):
                    return base(x)
            self.qf = torch.vmap(f, (0, 0))
            self.leaves = list(self.params.values(True, True))
            self.tleaves = list(self.target.values(True, True))
        kw = {"fused": True} if fused else {}
        self.opt = torch.optim.Adam(self.leaves, lr=LR, **kw)
        self.M = M
        self.shapes = [(-1,) + (1,) * (p.dim() - 1) for p in self.leaves]

    def update(self, rows):
        batch = unpack(rows)
        qf, params, target = self.qf, self.params, self.target
        q, tgt = td_terms(lambda x: qf(params, x), lambda x: qf(target, x), batch, GAMMA, True)
        loss = nn.functional.smooth_l1_loss(q, tgt, reduction="none").mean((1, 2))
        loss.sum().backward()
        with torch.no_grad():
            grads = [p.grad for p in self.leaves]
            per = torch.stack([torch.linalg.vector_norm(g.flatten(1), dim=1) for g in grads], 1)
            norms = torch.linalg.vector_norm(per, dim=1)
            factor = (CLIP / (norms + 1e-6)).clamp_(max=1.0)
            for g, s in zip(grads, self.shapes):
                g.mul_(factor.view(s))
            self.opt.step()
            self.opt.zero_grad()
            torch._foreach_lerp_(self.tleaves, [p.detach() for p in self.leaves], TAU)

    def member_vector(self, j):
        return torch.cat([p.detach()[j].reshape(-1) for p in self.leaves])

# ---------------------------------------------------------------- C
class TorchRLC:
    def __init__(self, M):
        from torchrl.objectives import DQNLoss, SoftUpdate
        from torchrl.data import Categorical
        from tensordict import TensorDict
        t, vec = member_vectors(M)
        self.members = []
        for j in range(M):
            c = copy.deepcopy(t)
            nn.utils.vector_to_parameters(vec[j], c.parameters())
            actor = QValueActor(c, in_keys=["observation"], spec=Categorical(N_ACT, dtype=torch.int64))
            loss = DQNLoss(actor, delay_value=True, double_dqn=True, loss_function="smooth_l1",
                           action_space="categorical")
            loss.make_value_estimator(gamma=GAMMA)
            upd = SoftUpdate(loss, tau=TAU)
            opt = torch.optim.Adam(list(loss.value_network_params.values(True, True)), lr=LR)
            self.members.append((loss, upd, opt, c))
        self.M = M
        self.TensorDict = TensorDict

    def make_td(self, rows):
        """rows [M, B, 11] -> list of M TensorDicts (built outside the timed loop)."""
        out = []
        for j in range(self.M):
            b = unpack(rows[j])
            out.append(self.TensorDict({
                "observation": b.observation, "action": b.action.squeeze(-1),
                "next": {"observation": b.next_observation, "reward": b.reward,
                         "terminated": b.terminated, "done": b.terminated,
                         "truncated": torch.zeros_like(b.terminated)}}, batch_size=[BATCH]))
        return out

    def update(self, tds):
        for (loss, upd, opt, c), td in zip(self.members, tds):
            out = loss(td)
            out["loss"].backward()
            params = [p for p in loss.value_network_params.values(True, True)]
            torch.nn.utils.clip_grad_norm_(params, CLIP)
            opt.step()
            opt.zero_grad()
            upd.step()

    def member_vector(self, j):
        loss = self.members[j][0]
        return torch.cat([p.detach().reshape(-1) for p in loss.value_network_params.values(True, True)])

# ---------------------------------------------------------------- timing
def timeit(makers, M, iters, warmup, repeats):
    """Microseconds an update of each of ``makers`` (name: (maker, is_c)) at ``M`` members,
    ``(best, median)`` over ``repeats``: the variants take turns within each repeat, so a
    change in the machine's load falls on all of them alike."""
    n = 16  # cycle through 16 fixed minibatches
    rows = member_rows(M, n)
    objs, data = {}, {}
    for name, (maker, is_c) in makers.items():
        objs[name] = obj = maker(M)
        data[name] = [obj.make_td(rows[i]) for i in range(n)] if is_c else [rows[i] for i in range(n)]
        for i in range(warmup):
            obj.update(data[name][i % n])
    results = {name: [] for name in makers}
    for r in range(repeats):
        for name, obj in objs.items():
            t0 = time.perf_counter()
            for i in range(iters):
                obj.update(data[name][i % n])
            results[name].append((time.perf_counter() - t0) / iters * 1e6)
    return {name: (min(v), statistics.median(v)) for name, v in results.items()}

def main():
    threads = sys.argv[1]
    iters = int(sys.argv[2]) if len(sys.argv) > 2 else 300
    warmup = int(sys.argv[3]) if len(sys.argv) > 3 else 50
    repeats = int(sys.argv[4]) if len(sys.argv) > 4 else 3
    if threads != "default":
        torch.set_num_threads(int(threads))
    print(f"torch {torch.__version__} threads={torch.get_num_threads()} iters={iters} warmup={warmup} repeats={repeats}")
    makers = {
        "A  MemberNets+adam_step": (KernelA, False),
        "B  vmap+Adam(foreach)": (lambda M: FuncB(M, False), False),
        "B' vmap+Adam(fused)": (lambda M: FuncB(M, True), False),
        "B\" TD.from_modules+foreach": (lambda M: FuncB(M, False, via="td"), False),
        "C  DQNLoss loop": (TorchRLC, True),
        "D  A under torch.compile": (CompiledD, False),
    }
    for M in (1, 10):
        times = timeit(makers, M, iters, warmup, repeats)
        base = next(iter(times.values()))[0]
        for name, (best, med) in times.items():
            print(f"M={M:2d} {name:30s} best {best:9.1f} us  median {med:9.1f} us  ratio/A {best / base:5.2f}", flush=True)

if __name__ == "__main__":
    main()
