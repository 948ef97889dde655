"""Our ``dqn`` learner vs Stable-Baselines3 DQN on cartpole/stay_up (run by hand).

    python bench/vs_sb3.py [--seed 0] [--cap 150000] [--overrides max_env_steps=400 ...]

SB3 trains with rl-baselines3-zoo's CartPole-v1 hyperparameters
(``hyperparams/dqn.yml``) on ``MujocoRL/CartPoleStayUp-v0`` through the
Gymnasium registration; ours runs ``train.py learner=dqn``. Both stop at the
task's success rule (stay_up: the seeds' mean length of the last 100 training
episodes >= ``task.win.threshold`` after ``task.win.min_episodes`` episodes);
SB3 at ``--cap`` env steps at most.
Needs the ``bench`` extra (stable-baselines3).

Last line: ``VS_SB3 wall_ratio=<ours/sb3> steps_ratio=<ours/sb3>`` (``nan`` when
either did not solve).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import torch  # noqa: E402
from stable_baselines3 import DQN  # noqa: E402
from stable_baselines3.common.callbacks import BaseCallback  # noqa: E402
from stable_baselines3.common.monitor import Monitor  # noqa: E402

from tasks.base import Success  # noqa: E402
from runs.summary import measure_keys  # noqa: E402
from sweep import run_to_solve  # noqa: E402
from tasks.factory import build_task  # noqa: E402
from tasks.catalog import compose  # noqa: E402

ENV_ID = "adapters.register_gym:MujocoRL/CartPoleStayUp-v0"
# rl-baselines3-zoo hyperparams/dqn.yml, CartPole-v1 ("Almost Tuned").
ZOO_N_TIMESTEPS = 50_000
ZOO = dict(learning_rate=2.3e-3, batch_size=64, buffer_size=100_000, learning_starts=1000,
           gamma=0.99, target_update_interval=10, train_freq=256, gradient_steps=128,
           exploration_fraction=0.16, exploration_final_eps=0.04,
           policy_kwargs=dict(net_arch=[256, 256]))


class StopAtWin(BaseCallback):
    """Stops training once the win criterion holds over Monitor's episode lengths."""

    def __init__(self, win: Success) -> None:
        super().__init__()
        self.win = win
        self.lengths: list[int] = []
        self.solved_at: dict | None = None
        self.t0 = time.perf_counter()

    def _on_training_start(self) -> None:
        self.t0 = time.perf_counter()

    def _on_step(self) -> bool:
        for info in self.locals["infos"]:
            if "episode" in info:
                self.lengths.append(int(info["episode"]["l"]))
                if self.win.met(float(np.mean(self.lengths[-self.win.window:])), len(self.lengths)):
                    self.solved_at = {"episodes": len(self.lengths), "steps": self.num_timesteps,
                                      "wall_s": time.perf_counter() - self.t0}
                    return False
        return True

    def best100(self) -> float:
        x = np.asarray(self.lengths, dtype=float)
        if len(x) == 0:
            return 0.0
        window = np.convolve(x, np.ones(100) / 100, mode="valid") if len(x) >= 100 else [x.mean()]
        return float(np.max(window))


def run_sb3(seed: int, cap: int, win: Success) -> dict:
    torch.set_num_threads(1)
    env = Monitor(gym.make(ENV_ID))
    # The zoo's epsilon decays over 0.16 x its 50k steps; keep that span under our cap.
    params = {**ZOO, "exploration_fraction": ZOO["exploration_fraction"] * ZOO_N_TIMESTEPS / cap}
    model = DQN("MlpPolicy", env, seed=seed, device="cpu", verbose=0, **params)
    stop = StopAtWin(win)
    t0 = time.perf_counter()
    model.learn(total_timesteps=cap, callback=stop)
    wall = time.perf_counter() - t0
    env.close()
    out = {"learner": "sb3 DQN (zoo)", "solved": stop.solved_at is not None,
           "episodes": len(stop.lengths), "env_steps": model.num_timesteps, "wall_s": wall,
           "best100": stop.best100()}
    if stop.solved_at:
        out.update(episodes=stop.solved_at["episodes"], env_steps=stop.solved_at["steps"],
                   wall_s=stop.solved_at["wall_s"])
    return out


def run_ours(seed: int, overrides: list[str]) -> dict:
    run_dir = ROOT / "outputs" / f"vs_sb3_{time.strftime('%Y%m%d-%H%M%S')}_dqn_seed{seed}"
    s = run_to_solve(["robot=cartpole", "learner=dqn", f"seed={seed}", "eval_episodes=0", *overrides], run_dir)
    return {"learner": "ours dqn", "solved": s["solved"], "episodes": s["episodes"], "env_steps": s["env_steps"],
            "wall_s": s["wall_s"], "best100": float(s[measure_keys(s["measure"], s["window"]).train_best_rolling]),
            "run_dir": str(run_dir)}


def report(ours: dict, sb3: dict, seed: int, cap: int, win: Success) -> None:
    """Prints the table and, last, the ``VS_SB3`` line."""
    print(f"\ncartpole/stay_up, seed {seed}, win: mean length of last 100 >= "
          f"{win.threshold:g} after >= {win.min_episodes} episodes (SB3 cap {cap} steps)")
    print(f"| {'learner':15s} | solved | episodes | env steps | wall s | steps/s |")
    print("|" + "|".join("-" * w for w in (17, 8, 10, 11, 8, 9)) + "|")
    for r in (ours, sb3):
        print(f"| {r['learner']:15s} | {str(r['solved']).lower():6s} | {r['episodes']:8d} | "
              f"{r['env_steps']:9d} | {r['wall_s']:6.1f} | {r['env_steps'] / r['wall_s']:7.0f} |")
    wall = ours["wall_s"] / sb3["wall_s"]
    steps = ours["env_steps"] / sb3["env_steps"]
    if not ours["solved"]:
        print(f"ours did not reach the criterion; best 100-episode mean length {ours['best100']:.1f}")
    if not sb3["solved"]:
        print(f"SB3 did not reach the criterion within {cap} steps; "
              f"its best 100-episode mean length was {sb3['best100']:.1f}")
        if ours["solved"]:
            print(f"so ours/sb3 is at most: wall {wall:.3f}, steps {steps:.3f}")
    if not (ours["solved"] and sb3["solved"]):
        wall = steps = math.nan
    print(f"VS_SB3 wall_ratio={wall:.3f} steps_ratio={steps:.3f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--cap", type=int, default=150_000, help="SB3 env steps at most")
    parser.add_argument("--overrides", nargs="+", default=[], metavar="KEY=VALUE",
                        help="set on our train.py run, e.g. max_env_steps=400 (a quick check)")
    args = parser.parse_args()
    win = build_task(compose("cartpole", learner="dqn")).success
    ours = run_ours(args.seed, args.overrides)
    sb3 = run_sb3(args.seed, args.cap, win)
    report(ours, sb3, args.seed, args.cap, win)


if __name__ == "__main__":
    main()
