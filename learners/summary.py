"""Reading finished run folders back: what a comparison or a benchmark needs."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf


def summarize_run(run_dir: Path | str) -> dict:
    """Solved or not, episodes/steps/seconds to solve, final scores, of one run folder.

    Reads ``run.json`` (robot, task, learner names, seed), ``config.yaml`` (win
    criterion), ``metrics.csv``, ``timing.csv`` and, if present, ``eval.json``. A folder without metrics is reported as
    ``status: failed``.
    """
    run_dir = Path(run_dir)
    out: dict = {"run_dir": str(run_dir), "status": "failed"}
    cfg_path = run_dir / "config.yaml"
    if cfg_path.is_file():
        cfg = OmegaConf.load(cfg_path)
        out["seed"] = int(cfg.get("seed", 0))
        win = cfg.get("win", {"n_win_ticks": 250, "min_episodes": 100})
    else:
        win = {"n_win_ticks": 250, "min_episodes": 100}
    names = run_dir / "run.json"
    if names.is_file():
        chosen = json.loads(names.read_text())
        out.update({k: chosen.get(k) for k in ("robot", "task", "learner", "seed")})
    error = run_dir / "error.txt"
    if error.is_file():
        out["error"] = error.read_text().strip().splitlines()[-1]
        return out
    metrics = run_dir / "metrics.csv"
    if not metrics.is_file():
        return out
    with open(metrics) as f:
        rows = list(csv.DictReader(f))
    if not rows:
        return out
    timing = run_dir / "timing.csv"
    wall = [0.0] * len(rows)
    if timing.is_file():
        with open(timing) as f:
            wall = [float(r["wall_s"]) for r in csv.DictReader(f)][: len(rows)]
        wall += [float("nan")] * (len(rows) - len(wall))
    lengths = np.array([float(r["length"]) for r in rows])
    rewards = np.array([float(r["reward"]) for r in rows])
    mean100 = np.array([float(r["mean100"]) for r in rows])
    ok = (mean100 >= float(win["n_win_ticks"])) & (np.arange(1, len(rows) + 1) >= int(win["min_episodes"]))
    solved_at = int(np.argmax(ok)) if ok.any() else None
    out.update(
        status="ok",
        episodes=len(rows),
        solved=solved_at is not None,
        episodes_to_solve=solved_at + 1 if solved_at is not None else None,
        steps_to_solve=int(rows[solved_at]["env_steps"]) if solved_at is not None else None,
        wall_to_solve=wall[solved_at] if solved_at is not None else None,
        final_mean_length=float(lengths[-100:].mean()),
        final_mean_return=float(rewards[-100:].mean()),
        wall_s=wall[-1],
        env_steps=int(rows[-1]["env_steps"]),
    )
    eval_path = run_dir / "eval.json"
    if eval_path.is_file():
        result = json.loads(eval_path.read_text())
        out["greedy_mean_length"] = result["mean_length"]
        out["greedy_mean_return"] = result["mean_return"]
    return out
