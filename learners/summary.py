"""Reading finished run folders back: what a comparison or a benchmark needs."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf


def summarize_run(run_dir: Path | str) -> dict:
    """Solved or not (and by which judge), episodes/steps/seconds to solve, the task's
    measure for the training episodes and the greedy policy, of one run folder.

    Reads ``run.json`` (robot, task, learner names, seed), ``config.yaml``,
    ``summary.json`` (the run's own verdict: what "solved" means is the task's,
    see ``success.json``), ``metrics.csv``, ``timing.csv`` and ``eval.json``.
    A folder without a verdict is ``failed`` (with ``error.txt``'s last line)
    or ``interrupted``.
    """
    run_dir = Path(run_dir)
    out: dict = {"run_dir": str(run_dir), "status": "failed"}
    cfg_path = run_dir / "config.yaml"
    if cfg_path.is_file():
        out["seed"] = int(OmegaConf.load(cfg_path).get("seed", 0))
    names = run_dir / "run.json"
    if names.is_file():
        chosen = json.loads(names.read_text())
        out.update({k: chosen.get(k) for k in ("robot", "task", "learner", "seed")})
    error = run_dir / "error.txt"
    if error.is_file():
        out["error"] = error.read_text().strip().splitlines()[-1]
        return out
    verdict, metrics = run_dir / "summary.json", run_dir / "metrics.csv"
    if not verdict.is_file() or not metrics.is_file():
        return out
    summary = json.loads(verdict.read_text())
    if summary.get("interrupted"):
        out["status"] = "interrupted"
        return out
    with open(metrics) as f:
        rows = list(csv.DictReader(f))
    timing = run_dir / "timing.csv"
    wall = [float("nan")] * len(rows)
    if timing.is_file():
        with open(timing) as f:
            wall = ([float(r["wall_s"]) for r in csv.DictReader(f)][: len(rows)]
                    + [float("nan")] * len(rows))[: len(rows)]
    at = summary["solved_at"]
    out.update(
        status="ok",
        measure=summary["measure"], unit=summary["unit"], judge=summary["judge"],
        window=summary["window"],
        threshold=summary["threshold"],
        episodes=summary["episodes"],
        solved=summary["solved"],
        decided_by=summary["decided_by"] if summary["solved"] else None,
        episodes_to_solve=at,
        steps_to_solve=int(rows[at - 1]["env_steps"]) if at else None,
        wall_to_solve=wall[at - 1] if at else None,
        best_rolling=summary["best_rolling"],
        last_rolling=summary["last_rolling"],
        greedy=summary["greedy"],
        final_mean_length=float(np.mean([float(r["length"]) for r in rows[-100:]])) if rows else None,
        final_mean_return=float(np.mean([float(r["reward"]) for r in rows[-100:]])) if rows else None,
        wall_s=summary["wall_s"],
        env_steps=summary["env_steps"],
    )
    eval_path = run_dir / "eval.json"
    if eval_path.is_file():
        result = json.loads(eval_path.read_text())
        out["greedy"] = result.get("value", out["greedy"])
        out["greedy_mean_length"] = result["mean_length"]
        out["greedy_mean_return"] = result["mean_return"]
    return out
