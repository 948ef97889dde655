"""Our ``sac`` / ``ppo`` against Stable-Baselines3's SAC / PPO on a continuous task (run by hand).

    python bench/vs_sb3_continuous.py [--algo sac|ppo] [--robot pendulum] [--seeds 0]
                                      [--cap 150000] [--out bench/results/vs_sb3_<algo>_<robot>]

The same Gymnasium id on both sides (``MujocoRL/<Robot><Task>-v0`` with
``actions="continuous"``: the robot's default task, each motor one number in [-1, 1]), the
same budget of env steps (``--cap``) and the same verdict: every ``--eval-every`` env steps
20 greedy episodes from fresh starts, passed on the task's own measure and threshold; at
least the task's rate (90 %) passing, confirmed at once by 20 more from other starts,
is solved. SB3 trains with rl-baselines3-zoo's ``Pendulum-v1`` hyperparameters
(``hyperparams/sac.yml``: learning rate 1e-3, SB3's defaults otherwise; ``ppo.yml``: 4
envs, 1,024 steps each, 10 epochs, gamma 0.9, gSDE); ours runs ``train.py robot=<robot>
learner=<algo>`` with its tuned file where it has one, evaluated on the same period.

Each finished (side, seed) is a line of ``<out>/results.jsonl``: a run stopped part way
(or a study carried over several sessions) goes on with the seeds not yet there. The
table is every seed recorded so far: per side, seeds solved, the median env steps and
wall seconds to solved (of those that solved). Needs the ``bench`` extra
(stable-baselines3).

Last line: ``VS_SB3 <algo> <robot> solved=<ours>/<n> vs <sb3>/<n> median_steps=<ours>/<sb3>
steps_ratio=<ours/sb3> median_wall_s=<ours>/<sb3>`` (``nan`` where a side solved none).
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from stable_baselines3 import PPO, SAC  # noqa: E402
from stable_baselines3.common.callbacks import BaseCallback  # noqa: E402
from stable_baselines3.common.env_util import make_vec_env  # noqa: E402

import adapters.register_gym  # noqa: E402,F401  (the ids)
from adapters.gym_env import env_id  # noqa: E402
from sweep import run_to_solve  # noqa: E402
from tasks.base import Success  # noqa: E402
from tasks.catalog import compose, default_task  # noqa: E402
from tasks.factory import build_task  # noqa: E402

# rl-baselines3-zoo, hyperparams/<algo>.yml, Pendulum-v1 (the zoo's continuous swing-up).
ZOO = {
    "sac": {"n_envs": 1, "kwargs": dict(learning_rate=1e-3)},
    "ppo": {"n_envs": 4, "kwargs": dict(n_steps=1024, gae_lambda=0.95, gamma=0.9, n_epochs=10, ent_coef=0.0,
                                        learning_rate=1e-3, clip_range=0.2, use_sde=True, sde_sample_freq=4)},
}
EPISODES = 20  # greedy episodes an evaluation, as ours


def greedy_rate(model, make, success: Success, seed: int) -> float:
    """The share of ``EPISODES`` deterministic episodes of ``model`` (each on ``make()``'s env
    from its own start, seeded from ``seed``) whose measure reaches the task's threshold."""
    env = make()
    values = []
    for i in range(EPISODES):
        obs, _ = env.reset(seed=seed + i)
        done, steps, info = False, 0, {}
        while not done:
            action, _ = model.predict(obs, deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            steps += 1
            done = terminated or truncated
        values.append(steps if success.measure == "length" else info[success.measure])
    env.close()
    return success.pass_rate(values)


class GreedyWin(BaseCallback):
    """Every ``every`` env steps a greedy evaluation; a passing one confirmed at once by a
    second from other starts stops training, and is when SB3 solved."""

    def __init__(self, make, success: Success, every: int, seed: int) -> None:
        super().__init__()
        self.make, self.success, self.every, self.seed = make, success, every, seed
        self.next, self.evals, self.solved_at, self.rates = every, 0, None, []
        self.t0 = time.perf_counter()

    def _on_training_start(self) -> None:
        self.t0 = time.perf_counter()

    def _evaluate(self) -> float:
        self.evals += 1
        rate = greedy_rate(self.model, self.make, self.success, 10_000 * self.seed + 100 * self.evals)
        self.rates.append((self.num_timesteps, rate))
        return rate

    def _on_step(self) -> bool:
        if self.num_timesteps < self.next:
            return True
        self.next += self.every
        if self._evaluate() >= self.success.rate and self._evaluate() >= self.success.rate:
            self.solved_at = {"env_steps": self.num_timesteps, "wall_s": time.perf_counter() - self.t0}
            return False
        return True


def run_sb3(algo: str, robot: str, seed: int, cap: int, every: int, success: Success) -> dict:
    torch.set_num_threads(1)
    name = env_id(robot, default_task(robot))
    zoo = ZOO[algo]
    env = make_vec_env(name, n_envs=zoo["n_envs"], seed=seed, env_kwargs={"actions": "continuous"})
    model = (SAC if algo == "sac" else PPO)("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **zoo["kwargs"])
    win = GreedyWin(lambda: gym.make(name, actions="continuous"), success, every, seed)
    t0 = time.perf_counter()
    model.learn(total_timesteps=cap, callback=win)
    env.close()
    solved = win.solved_at is not None
    return {"side": f"sb3 {algo.upper()} (zoo)", "solved": solved,
            "env_steps": win.solved_at["env_steps"] if solved else model.num_timesteps,
            "wall_s": win.solved_at["wall_s"] if solved else time.perf_counter() - t0,
            "rates": win.rates}


def run_ours(algo: str, robot: str, seed: int, cap: int, every: int, out: Path, overrides: list[str]) -> dict:
    run_dir = out / "ours" / f"{algo}_{robot}_seed{seed}"
    s = run_to_solve([f"robot={robot}", f"learner={algo}", f"seed={seed}", f"max_env_steps={cap}", "max_episodes=0",
                      f"eval_every_steps={every}", "eval_every=1000000", *overrides], run_dir)
    where = run_dir.resolve()  # recorded from the project's root where it lies under it
    return {"side": f"ours {algo}", "solved": s["solved"], "env_steps": s["env_steps"], "wall_s": s["wall_s"],
            "run_dir": str(where.relative_to(ROOT) if where.is_relative_to(ROOT) else where)}


def recorded(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.is_file() else []


def median_of(rows: list[dict], key: str) -> float:
    won = [r[key] for r in rows if r["solved"]]
    return statistics.median(won) if won else math.nan


def report(rows: list[dict], algo: str, robot: str, cap: int, success: Success) -> None:
    """The table of every recorded seed and, last, the ``VS_SB3`` line."""
    print(f"\n{robot}/{default_task(robot)} with continuous actions, {algo}; solved: at least "
          f"{success.rate:.0%} of {EPISODES} greedy episodes reach {success.measure} >= {success.threshold:g}, "
          f"confirmed; cap {cap} env steps")
    print("| side | seed | solved | env steps | wall s |\n|---|---|---|---|---|")
    for r in sorted(rows, key=lambda r: (r["side"], r["seed"])):
        print(f"| {r['side']} | {r['seed']} | {str(r['solved']).lower()} | {r['env_steps']} | {r['wall_s']:.0f} |")
    ours = [r for r in rows if r["side"].startswith("ours")]
    sb3 = [r for r in rows if r["side"].startswith("sb3")]
    steps = median_of(ours, "env_steps"), median_of(sb3, "env_steps")
    wall = median_of(ours, "wall_s"), median_of(sb3, "wall_s")
    print(f"VS_SB3 {algo} {robot} solved={sum(r['solved'] for r in ours)}/{len(ours)} vs "
          f"{sum(r['solved'] for r in sb3)}/{len(sb3)} median_steps={steps[0]:.0f}/{steps[1]:.0f} "
          f"steps_ratio={steps[0] / steps[1]:.3f} median_wall_s={wall[0]:.0f}/{wall[1]:.0f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", choices=sorted(ZOO), default="sac")
    parser.add_argument("--robot", default="pendulum", help="a robot whose default task has continuous actions")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0])
    parser.add_argument("--cap", type=int, default=150_000, help="env steps at most, each side")
    parser.add_argument("--eval-every", type=int, default=10_000, help="env steps between greedy evaluations")
    parser.add_argument("--out", type=Path, help="results folder (default: bench/results/vs_sb3_<algo>_<robot>)")
    parser.add_argument("--overrides", nargs="+", default=[], metavar="KEY=VALUE",
                        help="set on our train.py run, e.g. max_episodes=3 (a quick check)")
    args = parser.parse_args()
    if args.cap < 1 or args.eval_every < 1:
        sys.exit("error: --cap and --eval-every must be positive numbers of env steps")
    out = args.out or ROOT / "bench" / "results" / f"vs_sb3_{args.algo}_{args.robot}"
    out.mkdir(parents=True, exist_ok=True)
    records = out / "results.jsonl"
    success = build_task(compose(args.robot, learner=args.algo)).success
    for seed in args.seeds:
        for side in ("ours", "sb3"):
            if any(r["seed"] == seed and r["side"].startswith(side) for r in recorded(records)):
                continue
            row = (run_ours(args.algo, args.robot, seed, args.cap, args.eval_every, out, args.overrides)
                   if side == "ours" else run_sb3(args.algo, args.robot, seed, args.cap, args.eval_every, success))
            with records.open("a") as f:
                f.write(json.dumps({"seed": seed, **row, "cap": args.cap, "date": time.strftime("%Y-%m-%d")}) + "\n")
            print(f"{row['side']} seed {seed}: solved={row['solved']} env_steps={row['env_steps']} "
                  f"wall_s={row['wall_s']:.0f}", flush=True)
    report(recorded(records), args.algo, args.robot, args.cap, success)


if __name__ == "__main__":
    main()
