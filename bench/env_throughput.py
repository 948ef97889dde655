"""Environment throughput against the raw-MuJoCo limit, side by side (run by hand).

    python bench/env_throughput.py [--seconds 2] [--rounds 10] [--robots cartpole cube ...]
                                   [--sizes 1 16 64 256 1024]

For each robot with its default task, in one run:
  (b) our ``RobotTaskEnv`` at num_envs = N (1, 16, 64, 256, 1024) with uniform random
      actions (drawn beforehand: the policy is not timed), through TorchRL's
      ``step_and_maybe_reset`` (auto-resets included);
  (a) the physics limit: the very control steps (b) simulated, replayed from
      recorded states and controls with raw ``mujoco.mj_step`` in a Python loop
      over N ``MjData`` copies of the same compiled model and the task's
      substeps per control step (one thread) -- the cost of a MuJoCo step
      depends on the state (contacts, limits), so the limit uses the same ones;
  (a') the same replay through ``mujoco.rollout``'s thread pool (what our env uses);
  (c) transitions/s of each and the ratio of (b) to the physics limit, the
      faster of (a) and (a'): a one-thread ``mj_step`` loop is no limit for an
      env that steps its copies on every core, so the ratio is not flattered.
The three are measured in ``--rounds`` interleaved rounds (a, a', b, a, a', b, ...)
of ``seconds / rounds`` each, every one warm (its env, pool or copies built once per
size); each rate is the median of its rounds and each ratio the median of the rounds'
own ratios (a round's three windows run back to back): on a machine shared with other
work, a load change then hits all three alike instead of whichever ran during it.
Rates are transitions per second. Memory, per size, in a fresh process that only
builds our env and steps it 50 times: ``peak RSS MiB``, its resident-set high-water
mark (interpreter, torch and MuJoCo included), and ``env MiB``, how far that peak is
above the resident set just before the env was built (Linux: ``/proc/self/status``,
the mark reset through ``/proc/self/clear_refs``; elsewhere the process's peak from
``getrusage`` and no growth). Torch is pinned to one thread. The last lines are
machine-readable: ``RATIO <robot>/<task> num_envs=64 <ours/limit>``.

    python bench/env_throughput.py --pool [--gap-ms 2] [--robots ...] [--sizes 1 2 4 10 20 40]

prices ``robots.physics.BatchedPhysics``'s choice between rollout's thread pool and the calling
thread (``POOL_FROM_S``): a step of N copies (the robot's default task's substeps, zero
controls), each followed by ``--gap-ms`` of Python work as a learner's between steps, on the
pool, on the calling thread and as the physics chooses, in interleaved rounds; microseconds of
wall and of CPU (every thread of this process) a step, the gap not counted, medians over rounds.
"""

from __future__ import annotations

import argparse
import os
import re
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from mujoco import rollout  # noqa: E402

from tasks import factory  # noqa: E402
from tasks import catalog
from robots.physics import default_threads  # noqa: E402

SIZES = (1, 16, 64, 256, 1024)
_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS


def timed(fn, seconds: float) -> float:
    """Calls ``fn`` repeatedly for about ``seconds``; returns calls per second."""
    fn()  # warm-up
    calls, start = 0, time.perf_counter()
    while (elapsed := time.perf_counter() - start) < seconds:
        fn()
        calls += 1
    return calls / elapsed


def record(cfg, n: int, steps: int = 100) -> list[tuple[np.ndarray, np.ndarray]]:
    """The (state, control) of every copy at the start of ``steps`` control steps of
    our env under random actions (resets included): what (b) makes MuJoCo simulate."""
    env = factory.build_env(cfg, n, seed=0)
    physics, snaps = env.physics, []
    step = physics.step

    def recording_step(nsubsteps: int) -> None:
        snaps.append((physics.state.copy(), physics.ctrl.copy()))
        step(nsubsteps)
    physics.step = recording_step
    gen = torch.Generator().manual_seed(0)
    td = env.reset()
    for _ in range(steps):
        td["action"] = torch.randint(0, env.task.n_actions, (n,), generator=gen)
        _, td = env.step_and_maybe_reset(td)
    env.close()
    return snaps


def raw_loop(model: mujoco.MjModel, snaps, substeps: int):
    """(a): one control step of the recorded states per call, ``mj_step`` in a Python loop."""
    n = snaps[0][0].shape[0]
    datas = [mujoco.MjData(model) for _ in range(n)]
    k = [0]

    def control_step():
        state, ctrl = snaps[k[0] % len(snaps)]
        k[0] += 1
        for i, d in enumerate(datas):
            mujoco.mj_setState(model, d, state[i], _FULL)
            d.ctrl[:] = ctrl[i]
            for _ in range(substeps):
                mujoco.mj_step(model, d)
    return control_step, lambda: None


def raw_rollout(model: mujoco.MjModel, snaps, substeps: int):
    """(a'): the same through ``mujoco.rollout``'s thread pool."""
    n = snaps[0][0].shape[0]
    nthread = min(default_threads(), n)
    datas = [mujoco.MjData(model) for _ in range(nthread)]
    controls = [np.repeat(ctrl[:, None, :], substeps, axis=1) for _, ctrl in snaps]
    warmstart = np.zeros((n, model.nv))
    k = [0]
    pool = rollout.Rollout(nthread=nthread if nthread > 1 else 0)

    def control_step():
        i = k[0] % len(snaps)
        k[0] += 1
        pool.rollout([model] * n, datas, snaps[i][0], controls[i], nstep=substeps,
                     initial_warmstart=warmstart)
    return control_step, pool.close


def ours(cfg, n: int, steps: int = 100):
    """(b): our env, ``step_and_maybe_reset`` with random actions drawn beforehand (the
    ``steps`` of ``record``, cycled), as (a) and (a') replay recorded controls: the
    policy's cost is no part of either."""
    env = factory.build_env(cfg, n, seed=0)
    gen = torch.Generator().manual_seed(0)
    actions = [torch.randint(0, env.task.n_actions, (n,), generator=gen) for _ in range(steps)]
    holder = {"td": env.reset(), "k": 0}

    def control_step():
        td, k = holder["td"], holder["k"]
        holder["k"] = k + 1
        td.set("action", actions[k % steps])
        _, holder["td"] = env.step_and_maybe_reset(td)
    return control_step, env.close


def _status_mib(field: str) -> float:
    with open("/proc/self/status") as f:
        return int(re.search(rf"{field}:\s+(\d+)", f.read()).group(1)) / 1024


def memory_probe(robot: str, n: int) -> None:
    """In a fresh process (``--memory-of``): builds our env of ``n`` copies, steps it 50
    times (restarts, buffers, TorchRL's caches) and prints its peak resident set and the
    resident set just before building it (imports done), in MiB."""
    cfg = catalog.compose(robot)
    try:
        base = _status_mib("VmRSS")
        with open("/proc/self/clear_refs", "w") as f:  # the high-water mark := now (Linux)
            f.write("5")
    except OSError:  # the peak since the process started instead
        base = float("nan")
    control_step, close = ours(cfg, n)
    for _ in range(50):
        control_step()
    try:
        peak = _status_mib("VmHWM")
    except OSError:
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    close()
    print(f"{peak:.1f} {base:.1f}")


def env_memory(robot: str, n: int) -> tuple[float, float]:
    """(peak RSS, its growth over the RSS before the env was built) of ``memory_probe``,
    in MiB: a fresh process each, as freed memory stays with a process and would make a
    later size's reading the earlier ones'."""
    out = subprocess.run([sys.executable, __file__, "--memory-of", robot, str(n)],
                         capture_output=True, text=True, check=True)
    peak, base = map(float, out.stdout.split()[-2:])
    return peak, peak - base


def measure(cfg, model, substeps: int, n: int, seconds: float, rounds: int):
    """(a, a', b) in transitions per second, one list each over interleaved rounds."""
    snaps = record(cfg, n)
    runners = [raw_loop(model, snaps, substeps), raw_rollout(model, snaps, substeps), ours(cfg, n)]
    rates = [[] for _ in runners]
    for _ in range(rounds):
        for (fn, _), column in zip(runners, rates):
            column.append(timed(fn, seconds / rounds) * n)
    for _, close in runners:
        close()
    return rates


def pool_choice(robots: list[str], sizes: list[int], gap: float, seconds: float, rounds: int) -> None:
    """The ``--pool`` table (see the module docstring)."""
    from robots import physics

    print(f"rollout threads: {default_threads()}; POOL_FROM_S={physics.POOL_FROM_S}; gap {gap * 1e3:.1f} ms; "
          f"load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    print(f"{'robot':>10s} {'copies':>6s} {'pool wall/CPU us':>17s} {'alone wall/CPU us':>18s} "
          f"{'chosen wall/CPU us':>19s} {'chosen':>6s}")
    for robot in robots:
        probe = factory.build_env(catalog.compose(robot), 1, seed=0)
        model, substeps = probe.model, probe.task.n_substeps
        probe.close()
        for n in sizes:
            ways = {"pool": lambda copies, steps: True, "alone": lambda copies, steps: False, "chosen": None}
            built = {}
            for name, rule in ways.items():
                built[name] = physics.BatchedPhysics(model, n)
                if rule is not None:
                    built[name]._pooled_step = rule
                for _ in range(20):
                    built[name].step(substeps)
            times = {name: [] for name in ways}
            for _ in range(rounds):
                for name, batch in built.items():
                    steps, wall, cpu = 0, time.perf_counter(), time.process_time()
                    while time.perf_counter() - wall < seconds / rounds:
                        batch.step(substeps)
                        steps += 1
                        until = time.perf_counter() + gap
                        while time.perf_counter() < until:
                            pass
                    times[name].append(((time.perf_counter() - wall) / steps - gap,
                                        (time.process_time() - cpu) / steps - gap))
            chosen = built["chosen"]._pooled_step(n, substeps)
            cells = [f"{statistics.median(w for w, _ in t) * 1e6:8.0f}/{statistics.median(c for _, c in t) * 1e6:<8.0f}"
                     for t in times.values()]
            print(f"{robot:>10s} {n:6d} {cells[0]:>17s} {cells[1]:>18s} {cells[2]:>19s} "
                  f"{'pool' if chosen else 'alone':>6s}", flush=True)
            for batch in built.values():
                batch.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=2.0, help="per measurement (all rounds)")
    parser.add_argument("--rounds", type=int, default=10, help="interleaved rounds per measurement")
    parser.add_argument("--robots", nargs="+", default=catalog.robot_names())
    parser.add_argument("--sizes", nargs="+", type=int, default=list(SIZES))
    parser.add_argument("--pool", action="store_true", help="price the physics' choice of thread pool")
    parser.add_argument("--gap-ms", type=float, default=2.0, help="with --pool: Python work between steps")
    parser.add_argument("--memory-of", nargs=2, metavar=("ROBOT", "NUM_ENVS"),
                        help=argparse.SUPPRESS)  # the child of env_memory
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.memory_of:
        memory_probe(args.memory_of[0], int(args.memory_of[1]))
        return
    if args.pool:
        sizes = args.sizes if args.sizes != list(SIZES) else [1, 2, 4, 10, 20, 40]
        pool_choice(args.robots, sizes, args.gap_ms / 1e3, args.seconds, args.rounds)
        return
    print(f"torch threads: {torch.get_num_threads()}; rollout threads: {default_threads()}; "
          f"cores: {os.cpu_count()}; {args.seconds:.1f} s per measurement in {args.rounds} "
          f"interleaved rounds; load average {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    ratios = []
    for robot in args.robots:
        cfg, task_name = catalog.compose(robot), catalog.default_task(robot)
        probe = factory.build_env(cfg, 1, seed=0)
        model, substeps = probe.model, probe.task.n_substeps
        probe.close()
        print(f"\n{robot}/{task_name}: {substeps} substeps of {model.opt.timestep * 1e3:.1f} ms "
              f"per control step")
        print(f"{'num_envs':>8s} {'raw mj_step/s':>14s} {'raw rollout/s':>14s} {'ours/s':>10s} "
              f"{'ours/mj_step':>12s} {'ours/limit':>10s} {'peak RSS MiB':>12s} {'env MiB':>8s}")
        for n in args.sizes:
            rates = measure(cfg, model, substeps, n, args.seconds, args.rounds)
            peak, grown = env_memory(robot, n)
            a, a2, b = (statistics.median(column) for column in rates)
            # Ratios: medians of each round's own ratio (its three windows ran back to back).
            vs_loop = statistics.median(y / x for x, _, y in zip(*rates))
            vs_limit = statistics.median(y / max(x, x2) for x, x2, y in zip(*rates))
            print(f"{n:8d} {a:14.0f} {a2:14.0f} {b:10.0f} {vs_loop:12.2f} {vs_limit:10.2f} "
                  f"{peak:12.0f} {grown:8.1f}", flush=True)
            if n == 64:
                ratios.append((robot, task_name, vs_limit))
    print(f"\nload average at the end {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    for robot, task_name, ratio in ratios:
        print(f"RATIO {robot}/{task_name} num_envs=64 {ratio:.2f}")


if __name__ == "__main__":
    main()
