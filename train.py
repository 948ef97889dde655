"""Train (or evaluate) a learner on a robot's task, all chosen by Hydra config.

    python train.py                                  # cartpole / stay_up / qlearn
    python train.py robot=cube learner=qlearn        # the robot's default task follows
    python train.py -m learner=qlearn seed=0,1,2     # a sweep
    python train.py mode=eval checkpoint=outputs/.../model.pt

The run folder (printed at the end) holds config.yaml (resolved), metrics.csv,
reward_curve.png, model.pt and, with ``video=true``, policy.mp4. The last line
printed is machine-readable:
``VERDICT solved=<true|false> episodes=<n> best100=<v> wall_s=<v> run_dir=<path>``.
"""

from __future__ import annotations

import json
import sys
import traceback
from pathlib import Path

import hydra
import torch
from hydra.core.hydra_config import HydraConfig
from hydra.errors import InstantiationException
from hydra.types import RunMode
from hydra.utils import instantiate
from omegaconf import DictConfig, OmegaConf

import robots  # noqa: F401  (sets a headless GL backend before dm_control loads)
from learners.checkpoint import CheckpointError
from learners.loggers import make_logger
from learners.run import Run, WinCriterion, evaluate, seed_everything, verdict_lines
from learners.video import record_video
from tasks.base import ConfigError
from tasks.env import RobotTaskEnv


def build_task(cfg: DictConfig):
    """A fresh task (with its robot) from the ``robot`` and ``task`` configs."""
    robot = instantiate(cfg.robot, _convert_="all")
    return instantiate(cfg.task, robot=robot, _convert_="all")


def build_env(cfg: DictConfig, num_envs: int, seed: int, max_episode_steps: int | None = None):
    task = build_task(cfg)
    if max_episode_steps is not None:
        task.max_episode_steps = min(task.max_episode_steps, int(max_episode_steps))
    return RobotTaskEnv(task, num_envs=num_envs, seed=seed)


def run(cfg: DictConfig, run_dir: Path) -> dict:
    """Trains or evaluates as ``cfg`` says; returns the summary (and prints the verdict)."""
    if cfg.mode not in ("train", "eval"):
        raise ConfigError(f"mode must be train or eval; got {cfg.mode!r}")
    torch.set_num_threads(int(cfg.torch_threads))
    generator = seed_everything(int(cfg.seed))
    learner = instantiate(cfg.learner, _convert_="all")
    env = build_env(cfg, int(cfg.num_envs), int(cfg.seed), learner.nsteps)
    learner.build(env.task, generator)
    if cfg.checkpoint:
        learner.load(Path(cfg.checkpoint))
    elif cfg.mode == "eval":
        raise CheckpointError("mode=eval needs checkpoint=<path to a saved model.pt>")
    summary: dict = {}
    if cfg.mode == "train":
        win = WinCriterion(float(cfg.win.n_win_ticks), int(cfg.win.min_episodes))
        logger = make_logger(cfg.logger.kind, run_dir, exp_name=run_dir.name,
                             **{k: v for k, v in cfg.logger.items() if k != "kind"})
        record = Run(run_dir, env.num_envs, learner.nepisodes, win,
                     extra_fields=tuple(learner.stats), quiet=bool(cfg.quiet), logger=logger)
        try:
            learner.train(env, record)
        finally:
            summary = record.close()
            learner.save(run_dir / "model.pt", meta={
                "choices": json.loads((run_dir / "run.json").read_text()),
                "config": OmegaConf.to_container(cfg, resolve=True),
            })
    env.close()
    n_eval = int(getattr(learner, "run_episodes", 0) or cfg.eval_episodes)
    if n_eval > 0:
        eval_env = build_env(cfg, n_eval, int(cfg.seed) + 10_000, learner.nsteps)
        with learner.greedy():
            result = evaluate(eval_env, learner.policy)
        eval_env.close()
        print(f"greedy evaluation over {result['episodes']} episodes: "
              f"length {result['mean_length']:.1f} +- {result['std_length']:.1f}, "
              f"return {result['mean_return']:.1f} +- {result['std_return']:.1f}"
              + "".join(f", {k} {v:.3f}" for k, v in result["info_mean"].items()))
        (run_dir / "eval.json").write_text(json.dumps(result, indent=1))
        summary["eval"] = result
    if cfg.video:  # the greedy policy on a fresh one-copy env
        video_env = build_env(cfg, 1, int(cfg.seed) + 20_000, learner.nsteps)
        with learner.greedy():
            record_video(video_env, learner.policy, run_dir / "policy.mp4", n_steps=int(cfg.video_steps))
        video_env.close()
        print(f"policy video in {run_dir / 'policy.mp4'}")
    if cfg.mode == "train":
        for line in verdict_lines(summary, run_dir):
            print(line)
    return summary


def _one_line(err: BaseException) -> str:
    """The innermost message of a config error, without Hydra's wrapping."""
    while isinstance(err, InstantiationException) and err.__cause__ is not None:
        err = err.__cause__
    return str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> None:
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    OmegaConf.save(cfg, run_dir / "config.yaml", resolve=True)
    choices = HydraConfig.get().runtime.choices
    (run_dir / "run.json").write_text(json.dumps(
        {group: choices.get(group) for group in ("robot", "task", "learner", "tuned")}
        | {"seed": int(cfg.seed), "overrides": list(HydraConfig.get().overrides.task)}, indent=1))
    in_sweep = HydraConfig.get().mode == RunMode.MULTIRUN
    try:
        run(cfg, run_dir)
    except (ConfigError, CheckpointError, InstantiationException) as err:
        message = f"error: {_one_line(err)}"
        print(message, file=sys.stderr)
        if not in_sweep:
            sys.exit(2)
        (run_dir / "error.txt").write_text(message + "\n")
    except Exception:
        if not in_sweep:
            raise
        # One broken job must not cost the sweep its other jobs: keep the trace, go on.
        trace = traceback.format_exc()
        print(trace, file=sys.stderr)
        (run_dir / "error.txt").write_text(trace)


if __name__ == "__main__":
    main()
