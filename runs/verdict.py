"""The end of a training run: its summary numbers (``summary.json``) and the
verdict printed from them, whose last line is machine-readable (``VERDICT ...``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def training_means(values: list[float], window: int) -> np.ndarray:
    """The mean of every full ``window`` of episodes (the mean of all while fewer ran; NaN for none)."""
    values = np.asarray(values, dtype=float)
    if len(values) >= window:
        return np.convolve(values, np.ones(window) / window, mode="valid")
    return values.mean(keepdims=True) if len(values) else np.full(1, np.nan)


def run_summary(run) -> dict:
    """Solved or not and by which judge; the measure's headline numbers; the cost
    (``run``: a :class:`~runs.run.Run`)."""
    s = run.success
    values = np.asarray(run.values, dtype=float)
    rolling = training_means(values, s.window)  # the best of them is the headline
    greedy = run.evals[-1]["value"] if run.evals else None
    if run.solved_value is not None:
        value = run.solved_value
    else:  # what the judge saw: the last greedy evaluation, or the best training mean
        value = greedy if s.judge == "greedy" else float(rolling.max())
    return {
        "solved": run.solved_at is not None,
        "decided_by": run.decided_by or s.judge,
        "episodes": run.n_episodes,
        "solved_at": run.solved_at,
        "measure": s.measure, "unit": s.unit, "description": s.description,
        "threshold": s.threshold, "judge": s.judge, "window": s.window,
        "min_episodes": s.min_episodes,
        "value": value,
        "best_rolling": float(rolling.max()),
        "last_rolling": float(rolling[-1]),
        "mean_of_100_best_episodes": float(np.sort(values)[-100:].mean()) if len(values) else float("nan"),
        "greedy": greedy,
        "evaluations": len(run.evals),
        "score": float(np.mean(run.lengths)) if run.lengths else 0.0,
        "env_steps": run.env_steps,
        "wall_s": run.wall_s,
        "divergences": run.divergences,
        # imports, config and build: process start to the first env step (this process's)
        "first_step_s": run.first_step_s,
        **({"pruned_at": run.pruned_at} if run.pruned_at is not None else {}),
    }


def _num(v) -> str:
    return "-" if v is None or (isinstance(v, float) and np.isnan(v)) else f"{v:.4g}"


def _headline(s: dict, unit: str) -> str:
    """``solved after N episodes: <how> >= T`` or ``not solved after N episodes: needs ...``."""
    n = s["solved_at"] if s["solved"] else s["episodes"]
    if s["decided_by"] == "greedy":
        how = (f"the greedy policy's mean {s['description']}, "
               f"{_num(s['value'])}{unit} (greedy evaluation at episode {n})")
    else:
        how = (f"the mean {s['description']} of the last {s['window']} training episodes, "
               f"{_num(s['value'])}{unit}")
    if s["solved"]:
        return f"solved after {n} episodes: {how} >= {s['threshold']:g}{unit}"
    judged = f"judged on {'the greedy policy' if s['judge'] == 'greedy' else 'training episodes'}"
    return (f"not solved after {n} episodes: needs {s['description']} >= {s['threshold']:g}{unit} "
            f"({judged}, after at least {s['min_episodes']} episodes); got {_num(s['value'])}{unit}")


def verdict_lines(summary: dict, run_dir: Path) -> list[str]:
    """The human verdict, what each judge saw, and the final machine-readable ``VERDICT`` line."""
    s = summary
    unit = f" {s['unit']}" if s["unit"] else ""
    n = s["solved_at"] if s["solved"] else s["episodes"]
    diverged = s.get("divergences", 0)
    return [
        *([f"warning: the physics diverged {diverged} times; each time that copy's episode was "
           "truncated and reset (see the log)"] if diverged else []),
        _headline(s, unit),
        f"  training episodes: best rolling-{s['window']} mean {_num(s['best_rolling'])}{unit}, "
        f"last-{s['window']} mean {_num(s['last_rolling'])}{unit}, mean of the 100 best episodes "
        f"{_num(s['mean_of_100_best_episodes'])}{unit} (the seeds' \"best 100 score\")",
        f"  greedy policy: {_num(s['greedy'])}{unit} ({s['evaluations']} evaluations)",
        *([f"  stopped early by the tuning study (pruned) at episode {s['pruned_at']}"]
          if s.get("pruned_at") is not None else []),
        f"  {s['env_steps']} env steps in {s['wall_s']:.1f}s "
        f"({s['env_steps'] / max(s['wall_s'], 1e-9):.0f} steps/s)",
        f"results in {run_dir}",
        f"VERDICT solved={str(s['solved']).lower()} episodes={n} measure={s['measure']} "
        f"judge={s['decided_by']} value={_num(s['value'])} threshold={s['threshold']:g} "
        f"best_rolling{s['window']}={_num(s['best_rolling'])} greedy={_num(s['greedy'])} "
        f"wall_s={s['wall_s']:.1f} run_dir={run_dir}",
    ]
