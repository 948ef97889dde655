"""Seeds in one process against one seed alone: wall time, CPU time and peak memory (run by hand).

    python bench/seed_batch.py [--seeds 10] [--learners qlearn dqn] [--num-envs tuned 1]
                               [--qlearn-steps 150000] [--dqn-steps 30000] [--repeats 1]
    python bench/seed_batch.py --robot pendulum --learners sac --num-envs tuned [--sac-steps 20000]

Per learner and number of copies a seed (``tuned``: the tuned file's, read from
``conf/tuned/cartpole_<learner>.yaml``; a number: ``num_envs=<n>``), side by side in this
run: one plain process ``train.py seed=0`` and one ``train.py -m seed='range(N)'`` (the
``seeds`` launcher: one batch of N seeds), each with the same per-seed budget of env steps
(``max_env_steps``; an episode budget would let the batch wait for its slowest seed),
training past "solved" so every seed spends the whole budget. Each default budget is of the
length a real run of the learner has: the cart-pole's dqn and qlearn solve at about 30,000 and
100,000-150,000 env steps; the pendulum's sac at 30,000 or later (its tuned file), so its
20,000 is still shorter than any run that solves (at 10,000 the process's fixed cost, about 8 s
of imports, building and ten reward curves that the floors do not pay, is a tenth of them). Timed from outside, start to
exit; the CPU time is the process's user + system seconds (its physics thread pool's
included: on a shared machine the wall time also counts the other jobs' turns); the peak
memory is the largest resident set of the process. The load average is printed at the start
and the end. The physics floor (``physics_floor_s``) is the batch's copy-steps (training and
greedy evaluations) priced at this machine's rollout cost a copy-step at the batch's widths,
on the states of the task's own episodes (:func:`per_copy_step`): no batch can go below it
here. A dqn or sac batch also has an update floor (``update_floor_s``): its gradient updates
(the rounds its members made, read from their ``model.pt``) done as plain stacked PyTorch
(the same network shapes, minibatch and members: each layer a batched product, the TD loss,
backward and one ``torch.optim.Adam`` step) with no sampling or bookkeeping, timed in the
same run (15 s of them, on both clocks at once); ``target_ratio`` is the batch's time over
both floors (issue 64's targets: dqn at most 1.3, qlearn at most 1.5 over its physics floor;
issue 66's: sac at most 1.3). Both floors are also read on this process's CPU clock
(``floors_cpu_s``) and ``target_cpu_ratio`` is the batch's CPU seconds over them: on a
machine other jobs share, each wall time counts their turns in its own share of the machine,
so the CPU ratio is the one to read there. This machine's speed also drifts by a third over
minutes (the same ten-seed batch took 132 s and, ten minutes later, 84 s): ``--repeats R``
runs the batch R times, its floors read after each, and judges each batch against the floors
read just before and just after it; the median of its ratios is the reading.

Its measurements (with their date and machine) are on the docs' performance page
(docs/performance.md, "Seeds in one process").

Last lines, per learner, copies and repeat: ``BATCH <learner> num_envs=<n> seeds=<N>
repeat=<r> one_s=<v> batch_s=<v> ratio=<batch/one> per_seed_ratio=<batch/(N*one)>
physics_floor_s=<v> floor_ratio=<floor/one> update_floor_s=<v> target_ratio=<v>
one_cpu_s=<v> batch_cpu_s=<v> cpu_ratio=<v> floors_cpu_s=<v> target_cpu_ratio=<v>
peak_rss_mb=<batch>``; then per learner and copies: ``TARGET <learner> num_envs=<n>
repeats=<R> target_ratio=<median> (<min>-<max>) target_cpu_ratio=<median> (<min>-<max>)``.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Callable

ROOT = Path(__file__).resolve().parents[1]


# Runs the command it is given and prints its peak RSS (kB) and CPU seconds (user + system):
# a fresh parent per measurement.
WRAP = ("import resource, subprocess, sys; code = subprocess.call(sys.argv[1:], stdout=subprocess.DEVNULL); "
        "r = resource.getrusage(resource.RUSAGE_CHILDREN); "
        "print(r.ru_maxrss, r.ru_utime + r.ru_stime, file=sys.stderr); sys.exit(code)")


ROBOT = "cartpole"  # --robot: the robot every run trains (its default task)
Clock = Callable[[], float]  # time.perf_counter (wall seconds) or time.process_time (this process's CPU seconds)


def tuned_copies(learner: str) -> int:
    """``num_envs`` of the robot's tuned file for ``learner`` (conf/tuned/<robot>_<learner>.yaml)."""
    sys.path.insert(0, str(ROOT))
    from tasks.catalog import compose

    return int(compose(robot=ROBOT, learner=learner).num_envs)


def timed(cmd: list[str], cwd: Path = ROOT) -> tuple[float, float, float]:
    """Runs ``cmd`` in the project folder (or ``cwd``: another checkout); (seconds start to
    exit, its CPU seconds, its peak RSS in MB)."""
    print("running:" if cwd == ROOT else f"running in {cwd}:", " ".join(cmd), flush=True)
    t0 = time.perf_counter()
    proc = subprocess.run([sys.executable, "-c", WRAP, *cmd], cwd=cwd, stderr=subprocess.PIPE, text=True)
    seconds = time.perf_counter() - t0
    if proc.returncode:
        sys.exit(f"error: {' '.join(cmd)} exited {proc.returncode}: {proc.stderr[-500:]}")
    rss, cpu = proc.stderr.split()[-2:]
    return seconds, float(cpu), int(rss) / 1024


def budget(learner: str, args) -> list[str]:
    """The same env-step budget for every seed (so no seed waits for a slower one)."""
    steps = {"qlearn": args.qlearn_steps, "sac": args.sac_steps}.get(learner, args.dqn_steps)
    return [f"robot={ROBOT}", f"max_env_steps={steps}", "max_episodes=0", "stop_when_solved=false"]


def copies(value: str) -> str:
    """``--num-envs`` entries: ``tuned`` or a positive number."""
    if value != "tuned" and not (value.isdigit() and int(value) >= 1):
        raise argparse.ArgumentTypeError(f"must be 'tuned' or a number >= 1; got {value!r}")
    return value


def copy_steps(folder: Path) -> tuple[int, int, int]:
    """The training copy-steps (env steps), the greedy evaluations' copy-steps (episodes x
    mean length, per evaluation) and the evaluations' copies (the largest) of the job
    folders under ``folder``."""
    train = evals = width = 0
    for summary in folder.rglob("summary.json"):
        train += int(json.loads(summary.read_text())["env_steps"])
        with open(summary.parent / "evals.csv", newline="") as f:
            for row in csv.DictReader(f):
                evals += round(int(row["episodes"]) * float(row["length"]))
                width = max(width, int(row["episodes"]))
    return train, evals, width


def physics_floor(learner: str, n: str, seeds: int, folder: Path, clock: Clock = time.perf_counter) -> float:
    """Seconds the batch under ``folder`` needs for its physics alone (:func:`floor_of` at
    ``seeds`` x the copies a seed)."""
    copies_a_seed = tuned_copies(learner) if n == "tuned" else int(n)
    return floor_of(ROBOT, folder, seeds * copies_a_seed, clock)


def floor_of(robot: str, folder: Path, copies: int, clock: Clock = time.perf_counter) -> float:
    """Seconds the job folders under ``folder`` need for their physics alone: their
    copy-steps, each priced at this machine's cost per copy-step of a ``mujoco.rollout``
    call as wide as its steps are (training: ``copies``; evaluations: their copies;
    :func:`per_copy_step`). Below this no batch can go here."""
    train, evals, width = copy_steps(folder)
    return train * per_copy_step(robot, copies, clock=clock) + evals * per_copy_step(robot, max(width, 1), clock=clock)


def per_copy_step(robot: str, copies: int, seconds: float = 2.0, clock: Clock = time.perf_counter,
                  at_rest: bool = False) -> float:
    """Seconds a copy-step of ``robot``'s physics takes here, ``copies`` side by side (one
    ``mujoco.rollout`` call a step, as a batch steps them; the rollout pool's threads as
    the env uses them), timed over ``seconds`` of wall time; read on ``clock`` (the wall's,
    or ``time.process_time``: the CPU seconds of every thread of this process).

    The copies step from the states and with the controls of the robot's default task's
    own episodes under random actions (:func:`episode_steps`): a copy held still at its
    model's rest pose costs less (the cart-pole's upright pole at rest: 8-16 % less, its
    constraint solver done at once). ``at_rest``: from that rest pose, with no control
    (the machine yardstick ``bench.tune_grid.physics_speed`` keeps reading, for its
    earlier rows)."""
    sys.path.insert(0, str(ROOT))
    from robots.physics import BatchedPhysics
    from tasks import catalog

    env = catalog.make_env(robot, num_envs=copies)
    steps = [] if at_rest else episode_steps(env)
    physics, substeps = BatchedPhysics(env.physics.model, copies), env.task.n_substeps
    env.close()
    physics.step(substeps)
    calls, spent, start = 0, 0.0, time.perf_counter()
    while time.perf_counter() - start < seconds:
        for state, ctrl in steps or [(physics.state, physics.ctrl)]:  # at rest: each step from the last
            physics.state[:], physics.ctrl[:] = state, ctrl
            read = clock()
            physics.step(substeps)
            spent += clock() - read
            calls += 1
    return spent / (calls * copies)


def episode_steps(env, steps: int = 100) -> list[tuple]:
    """``steps`` env steps of ``env``'s episodes under uniformly random actions (a copy
    whose episode ends starts its next one): each physics step's starting state and
    control, one row a copy."""
    import torch

    seen, step = [], env.physics.step

    def keep(nsubsteps: int) -> None:
        seen.append((env.physics.state.copy(), env.physics.ctrl.copy()))
        step(nsubsteps)

    env.physics.step = keep
    torch.manual_seed(0)
    try:
        env.rollout(steps, break_when_any_done=False)
    finally:
        env.physics.step = step
    return seen


def update_floor(folder: Path, seeds: int, seconds: float = 15.0) -> tuple[float, float]:
    """Seconds the batch under ``folder`` needs for its gradient updates alone: the update
    rounds its members made (the most optimizer steps of a member, from the ``model.pt``
    files), each priced at one plain stacked PyTorch update of ``seeds`` members (the
    members' network shapes and minibatch, from a job's ``config.yaml``; each linear layer
    one ``baddbmm``, ``backward`` and ``torch.optim.Adam``; no sampling, clipping or
    bookkeeping): dqn's double-DQN Huber TD loss, or sac's three losses (twin critics with
    target copies, a tanh-Gaussian actor, the temperature), on as many threads as the runs had
    (their ``torch_threads``). ``(wall s, CPU s)``, both clocks read around the same updates,
    as many as take ``seconds`` (a few seconds' price moved by 10% between readings on this
    shared machine)."""
    import torch
    from omegaconf import OmegaConf

    models = list(folder.rglob("model.pt"))
    if not models:
        return 0.0, 0.0
    saved = [torch.load(m, weights_only=False) for m in models]
    steps = max(int(m["optimizer_steps"]) for m in saved)
    cfg = OmegaConf.load(models[0].parent / "config.yaml")
    shapes = [tuple(v.shape) for k, v in saved[0]["actor"].items() if k.endswith("weight")]  # [out, in] a layer
    activation = torch.relu if cfg.learner.activation == "relu" else torch.tanh
    step = plain_update(saved[0]["kind"], seeds, shapes, int(cfg.learner.batch_size), activation)

    threads = torch.get_num_threads()
    torch.set_num_threads(int(cfg.get("torch_threads", threads)))  # as many threads as the batch's updates had
    try:
        for _ in range(20):
            step()
        rounds, wall, cpu = 0, time.perf_counter(), time.process_time()
        while time.perf_counter() - wall < seconds:
            step()
            rounds += 1
        wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    finally:
        torch.set_num_threads(threads)
    return wall / rounds * steps, cpu / rounds * steps


def plain_update(kind: str, seeds: int, shapes: list[tuple[int, int]], batch: int,
                 activation: Callable) -> Callable[[], None]:
    """One plain stacked PyTorch update of ``seeds`` members, as a function to call: the
    actor's layer ``shapes`` (``[out, in]`` each) of a learner of ``kind`` (``sac``: its
    three losses; else dqn's double-DQN Huber TD loss) with ``activation`` between layers, on
    random minibatches of ``batch`` transitions, each linear layer one ``baddbmm``, then
    ``backward`` and one ``torch.optim.Adam`` step."""
    import torch

    gen = torch.Generator().manual_seed(0)

    def net(sizes: list[tuple[int, int]]) -> list[tuple[torch.Tensor, torch.Tensor]]:
        return [(torch.randn(seeds, o, i, generator=gen).mul_(0.1).requires_grad_(),
                 torch.zeros(seeds, 1, o).requires_grad_()) for o, i in sizes]

    def q(params, x):
        for j, (w, b) in enumerate(params):
            x = torch.baddbmm(b, x, w.transpose(1, 2))
            x = activation(x) if j < len(params) - 1 else x
        return x

    n_obs = shapes[0][1]
    obs, nxt = torch.randn(seeds, batch, n_obs, generator=gen), torch.randn(seeds, batch, n_obs, generator=gen)
    reward = torch.randn(seeds, batch, 1, generator=gen)
    if kind == "sac":
        update, leaves = sac_update(net, q, shapes, obs, nxt, reward, gen)
    else:
        layers = net(shapes)
        target = [(w.detach().clone(), b.detach().clone()) for w, b in layers]
        action = torch.randint(0, shapes[-1][0], (seeds, batch, 1), generator=gen)
        leaves = [p for layer in layers for p in layer]

        def update() -> torch.Tensor:
            value = q(layers, obs).gather(-1, action)
            with torch.no_grad():
                best = q(layers, nxt).argmax(-1, keepdim=True)
                goal = reward + 0.99 * q(target, nxt).gather(-1, best)
            return torch.nn.functional.smooth_l1_loss(value, goal)
    optimizer = torch.optim.Adam(leaves, lr=1e-3)

    def step() -> None:
        update().backward()
        optimizer.step()
        optimizer.zero_grad()

    return step


def sac_update(net, q, shapes, obs, nxt, reward, gen):
    """One plain stacked SAC update for :func:`update_floor`: ``(loss function, leaves)``."""
    import torch

    n_act = shapes[-1][0] // 2
    hidden = [o for o, _ in shapes[:-1]]
    critic = list(zip([*hidden, 1], [shapes[0][1] + n_act, *hidden]))
    actor, q1, q2 = net(shapes), net(critic), net(critic)
    t1, t2 = ([(w.detach().clone(), b.detach().clone()) for w, b in c] for c in (q1, q2))
    log_alpha = torch.zeros(obs.shape[0], 1, 1, requires_grad=True)
    action = torch.rand(*obs.shape[:2], n_act, generator=gen) * 2 - 1
    noise = torch.randn(2, *obs.shape[:2], n_act, generator=gen)

    def pi(x, eps):
        loc, scale = q(actor, x).chunk(2, -1)
        scale = torch.nn.functional.softplus(scale) + 1e-4
        u = loc + scale * eps
        a = torch.tanh(u)
        log_prob = (-0.5 * eps ** 2 - scale.log() - 0.5 * math.log(2 * math.pi)
                    - 2 * (math.log(2) - u - torch.nn.functional.softplus(-2 * u))).sum(-1, keepdim=True)
        return a, log_prob

    def update() -> torch.Tensor:
        alpha = log_alpha.detach().exp()
        with torch.no_grad():
            a2, lp2 = pi(nxt, noise[0])
            after = torch.cat((nxt, a2), -1)
            goal = reward + 0.99 * (torch.minimum(q(t1, after), q(t2, after)) - alpha * lp2)
        taken = torch.cat((obs, action), -1)
        critic_loss = (q(q1, taken) - goal).pow(2).mean() + (q(q2, taken) - goal).pow(2).mean()
        a, lp = pi(obs, noise[1])
        chosen = torch.cat((obs, a), -1)
        frozen = [[(w.detach(), b.detach()) for w, b in c] for c in (q1, q2)]
        actor_loss = (alpha * lp - torch.minimum(q(frozen[0], chosen), q(frozen[1], chosen))).mean()
        alpha_loss = -(log_alpha * (lp.detach() - n_act)).mean()
        with torch.no_grad():  # the targets follow (Polyak)
            for target, online in ((t1, q1), (t2, q2)):
                for (tw, tb), (w, b) in zip(target, online):
                    tw.lerp_(w, 0.005)
                    tb.lerp_(b, 0.005)
        return critic_loss + actor_loss + alpha_loss

    leaves = [p for n in (actor, q1, q2) for layer in n for p in layer] + [log_alpha]
    return update, leaves


def floors_of(learner: str, n: str, seeds: int, folder: Path) -> tuple[tuple[float, float], tuple[float, float]]:
    """The floors of the batch under ``folder``, read now: ``((physics, updates) wall s,
    (physics, updates) CPU s)`` (qlearn: no update floor)."""
    updates = update_floor(folder, seeds) if learner != "qlearn" else (0.0, 0.0)
    wall = physics_floor(learner, n, seeds, folder, time.perf_counter), updates[0]
    return wall, (physics_floor(learner, n, seeds, folder, time.process_time), updates[1])


def load() -> str:
    return "/".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> None:
    sys.path.insert(0, str(ROOT))
    from tasks.catalog import robot_names

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--learners", nargs="+", default=["qlearn", "dqn"])
    parser.add_argument("--num-envs", nargs="+", type=copies, default=["tuned", "1"],
                        help="copies a seed: 'tuned' (the tuned file's) and/or numbers")
    parser.add_argument("--qlearn-steps", type=int, default=150000)
    parser.add_argument("--dqn-steps", type=int, default=30000)
    parser.add_argument("--sac-steps", type=int, default=20000)
    parser.add_argument("--robot", default="cartpole", choices=robot_names(),
                        help="the robot every run trains (its default task)")
    parser.add_argument("--repeats", type=int, default=1,
                        help="batches per learner and copies, each followed by a reading of its floors")
    args = parser.parse_args()
    global ROBOT
    ROBOT = args.robot
    if args.seeds < 1 or args.repeats < 1:
        sys.exit("error: --seeds and --repeats must be >= 1")
    out = ROOT / "multirun" / f"bench_seed_batch_{time.strftime('%Y%m%d-%H%M%S')}"
    print(f"load average (1/5/15 min) at the start: {load()} on {os.cpu_count()} cores", flush=True)
    rows = []
    for learner in args.learners:
        for n in args.num_envs:
            label = str(tuned_copies(learner)) if n == "tuned" else n
            common = [f"learner={learner}", "quiet=true", *budget(learner, args),
                      *([] if n == "tuned" else [f"num_envs={n}"])]
            where = out / learner / f"n{label}"
            one = timed([sys.executable, "train.py", *common, "seed=0", f"hydra.run.dir={where / 'one'}"])
            read = []  # the floors read after each batch: ((wall physics, wall updates), (CPU ...))
            for r in range(args.repeats):
                batch = timed([sys.executable, "train.py", "-m", *common, f"seed=range({args.seeds})",
                               f"hydra.sweep.dir={where / f'batch{r}'}"])
                read.append(floors_of(learner, n, args.seeds, where / f"batch{r}"))
                beside = read[-2:]  # the floors read just before this batch and just after it
                floors = [tuple(sum(f[c][i] for f in beside) / len(beside) for i in (0, 1)) for c in (0, 1)]
                rows.append((learner, label, r, one, batch, *floors))
    print(f"load average (1/5/15 min) at the end: {load()}")
    ratios: dict[tuple[str, str], list[tuple[float, float]]] = {}
    for learner, label, r, (one_s, one_cpu, one_mb), (batch_s, batch_cpu, batch_mb), (floor_s, updates_s), cpu in rows:
        print(f"BATCH {learner} num_envs={label} seeds={args.seeds} repeat={r} one_s={one_s:.1f} batch_s={batch_s:.1f} "
              f"ratio={batch_s / one_s:.2f} per_seed_ratio={batch_s / (args.seeds * one_s):.3f} "
              f"physics_floor_s={floor_s:.1f} floor_ratio={floor_s / one_s:.2f} update_floor_s={updates_s:.1f} "
              f"target_ratio={batch_s / (floor_s + updates_s):.2f} "
              f"one_cpu_s={one_cpu:.1f} batch_cpu_s={batch_cpu:.1f} cpu_ratio={batch_cpu / one_cpu:.2f} "
              f"floors_cpu_s={sum(cpu):.1f} target_cpu_ratio={batch_cpu / sum(cpu):.2f} "
              f"peak_rss_mb={batch_mb:.0f} (one seed: {one_mb:.0f})")
        ratios.setdefault((learner, label), []).append((batch_s / (floor_s + updates_s), batch_cpu / sum(cpu)))
    for (learner, label), found in ratios.items():
        wall, cpu = ([x[i] for x in found] for i in (0, 1))
        print(f"TARGET {learner} num_envs={label} repeats={len(found)} target_ratio={statistics.median(wall):.2f} "
              f"({min(wall):.2f}-{max(wall):.2f}) target_cpu_ratio={statistics.median(cpu):.2f} "
              f"({min(cpu):.2f}-{max(cpu):.2f})")


if __name__ == "__main__":
    main()
