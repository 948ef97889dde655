"""The end of a training run: its summary numbers (``summary.json``) and the
verdict printed from them, whose last line is machine-readable (``VERDICT ...``).

Every number is named for what it is (:func:`runs.summary.measure_keys`: e.g.
``train_length_last100``, ``greedy_distance_walked``, ``train_return_mean``), the same
in summary.json, the verdict's lines and its ``VERDICT`` line."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from runs.summary import BEST_EPISODES, RETURN_WINDOW, measure_keys


def training_means(values, window: int) -> np.ndarray:
    """The mean of every full ``window`` of episodes (the mean of all while fewer ran; NaN for none)."""
    values = np.asarray(values, dtype=float)
    if len(values) >= window:
        return np.convolve(values, np.ones(window) / window, mode="valid")
    return values.mean(keepdims=True) if len(values) else np.full(1, np.nan)


def _mean(values) -> float:
    values = np.asarray(values, dtype=float)
    return float(values.mean()) if len(values) else float("nan")


def run_summary(run) -> dict:
    """Solved or not and by which judge; the task's rule; every number under its name
    (:class:`runs.summary.MeasureKeys`); the cost (``run``: a :class:`~runs.run.Run`)."""
    s = run.success
    keys = measure_keys(s.measure, s.window)
    values = np.asarray(run.values, dtype=float)
    returns = np.asarray(run.returns, dtype=float)
    rolling = training_means(values, s.window)
    final = run.evals[-1] if run.evals else None
    greedy = final["value"] if final else None
    if run.solved_value is not None:
        judged = run.solved_value
    else:  # what the judge saw: the last greedy evaluation, or the best training mean
        judged = greedy if s.judge == "greedy" else float(rolling.max())
    return {
        "solved": run.solved_at is not None,
        "decided_by": run.decided_by or s.judge,
        "episodes": run.n_episodes,
        "solved_at": run.solved_at,
        "measure": s.measure, "unit": s.unit, "description": s.description,
        "threshold": s.threshold, "judge": s.judge, "window": s.window,
        "min_episodes": s.min_episodes,
        keys.judged: judged,
        keys.train_return_mean: _mean(returns),
        keys.train_return_last100: _mean(returns[-RETURN_WINDOW:]),
        keys.train_best_rolling: float(rolling.max()),
        keys.train_last: float(rolling[-1]),
        keys.train_best100_mean: _mean(np.sort(values)[-BEST_EPISODES:]),
        keys.greedy: greedy,
        keys.greedy_return: final["return"] if final else None,
        "evaluations": len(run.evals),
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
    keys = measure_keys(s["measure"], s["window"])
    judged, greedy = s[keys.judged], s.get(keys.greedy)
    if s["decided_by"] == "greedy":
        how = (f"the greedy policy's mean {s['description']}, "
               f"{_num(judged)}{unit} (greedy evaluation at episode {n})")
    else:
        how = (f"the mean {s['description']} of the last {s['window']} training episodes, "
               f"{_num(judged)}{unit}")
    if s["solved"]:
        confirmed = (f", and the greedy policy's {_num(greedy)}{unit}"
                     if s["decided_by"] == "training" and greedy is not None else "")
        return f"solved after {n} episodes: {how} >= {s['threshold']:g}{unit}{confirmed}"
    if s["judge"] == "greedy":
        by = "judged on the greedy policy"
    else:
        by = "judged on training episodes, and the greedy policy's too"
    got = f"got {_num(judged)}{unit}"
    if s["judge"] == "training" and judged is not None and judged >= s["threshold"]:
        got += (f" (the training rule was met, the greedy policy never: {_num(greedy)}{unit} "
                "at the final evaluation)")
    return (f"not solved after {n} episodes: needs {s['description']} >= {s['threshold']:g}{unit} "
            f"({by}, after at least {s['min_episodes']} episodes); {got}")


def verdict_lines(summary: dict, run_dir: Path) -> list[str]:
    """The human verdict, every number under its summary.json name, and the final
    machine-readable ``VERDICT`` line (``name=value`` fields, the same names)."""
    s = summary
    k = measure_keys(s["measure"], s["window"])
    unit = f" {s['unit']}" if s["unit"] else ""
    diverged = s.get("divergences", 0)

    def named(*names: str, with_unit: bool = True) -> str:
        return ", ".join(f"{name} {_num(s[name])}{unit if with_unit else ''}" for name in names)

    fields = {"solved": str(s["solved"]).lower(), "episodes": s["episodes"],
              "solved_at": "-" if s["solved_at"] is None else s["solved_at"], "measure": s["measure"],
              "judge": s["decided_by"], k.judged: _num(s[k.judged]), "threshold": f"{s['threshold']:g}",
              **{name: _num(s[name]) for name in (k.train_best_rolling, k.train_last, k.greedy,
                                                   k.train_return_mean, k.greedy_return)},
              "wall_s": f"{s['wall_s']:.1f}", "run_dir": run_dir}
    return [
        *([f"warning: the physics diverged {diverged} times; each time that copy's episode was "
           "truncated and reset (see the log)"] if diverged else []),
        _headline(s, unit),
        f"  training episodes' {s['description']}: {named(k.train_best_rolling, k.train_last, k.train_best100_mean)}"
        f" (the mean of the {BEST_EPISODES} best episodes: the seeds' \"best {BEST_EPISODES}\")",
        f"  training episodes' return: {named(k.train_return_mean, k.train_return_last100, with_unit=False)}",
        f"  greedy policy, final evaluation ({s['evaluations']} evaluations in all): "
        f"{named(k.greedy)}, {named(k.greedy_return, with_unit=False)}",
        *([f"  stopped early by the tuning study (pruned) at episode {s['pruned_at']}"]
          if s.get("pruned_at") is not None else []),
        f"  {s['env_steps']} env steps in {s['wall_s']:.1f}s "
        f"({s['env_steps'] / max(s['wall_s'], 1e-9):.0f} steps/s)",
        f"results in {run_dir}",
        "VERDICT " + " ".join(f"{name}={value}" for name, value in fields.items()),
    ]
