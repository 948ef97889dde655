"""Reading run folders back: what a comparison or a benchmark needs.

:func:`summarize_run` never raises on a damaged folder: a missing, empty or
corrupt file makes the run ``failed`` (or ``interrupted``, when it can still be
resumed) with one line in ``error`` saying which file and what is wrong.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
from omegaconf import OmegaConf

from runs.metrics_files import rolling_field

# A run's status: "ok" (finished: summary.json without "interrupted"), "interrupted"
# (Ctrl-C, or killed: partial metrics), "failed" (error.txt, or nothing usable),
# "never started" (no folder, or one without run.json and metrics.csv).
STATUSES = ("ok", "interrupted", "failed", "never started")


class Unusable(Exception):
    """A file of a run folder that is missing, empty or unreadable; the message says which."""


def read_json(path: Path) -> dict:
    """The JSON object in ``path``; :class:`Unusable` if it is missing, empty or not one."""
    if not path.exists():
        raise Unusable(f"no {path.name}")
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise Unusable(f"{path.name} is unreadable ({type(err).__name__})") from None
    if not text.strip():
        raise Unusable(f"{path.name} is empty")
    try:
        data = json.loads(text)
    except ValueError:
        raise Unusable(f"{path.name} is not valid JSON") from None
    if not isinstance(data, dict):
        raise Unusable(f"{path.name} holds no JSON object")
    return data


def read_csv(path: Path, columns: tuple[str, ...]) -> list[dict]:
    """The rows of ``path``, which must have ``columns``; :class:`Unusable` otherwise."""
    if not path.exists():
        raise Unusable(f"no {path.name}")
    try:
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            rows = list(reader)
            fields = reader.fieldnames or []
    except (OSError, UnicodeDecodeError, csv.Error) as err:
        raise Unusable(f"{path.name} is unreadable ({type(err).__name__})") from None
    if not fields:
        raise Unusable(f"{path.name} is empty")
    missing = [c for c in columns if c not in fields]
    if missing:
        raise Unusable(f"{path.name} has no column {', '.join(missing)}")
    return rows


def numbers(rows: list[dict], column: str, path: Path) -> list[float]:
    """``column`` of ``rows`` as floats; :class:`Unusable` for a cell that is not a number."""
    try:
        return [float(r[column]) for r in rows]
    except (TypeError, ValueError):
        raise Unusable(f"{path.name}: a {column} cell is not a number") from None


def _field(summary: dict, key: str, kind=float, optional: bool = False):
    """``summary[key]`` as ``kind`` (None stays None where ``optional``)."""
    value = summary.get(key)
    if value is None:
        if optional:
            return None
        raise Unusable(f"summary.json: {key} is missing")
    try:
        return kind(value)
    except (TypeError, ValueError):
        raise Unusable(f"summary.json: {key} is {value!r}, not a {kind.__name__}") from None


def _names(run_dir: Path) -> dict:
    """robot, task, learner, seed and the job's overrides, from run.json (else config.yaml's seed
    and .hydra/overrides.yaml); a damaged run.json gives a ``warning``."""
    out: dict = {}
    try:
        chosen = read_json(run_dir / "run.json")
        out.update({k: chosen.get(k) for k in ("robot", "task", "learner", "seed", "overrides")})
    except Unusable as err:
        if (run_dir / "run.json").exists():
            out["warning"] = str(err)
    for key, path in (("seed", "config.yaml"), ("overrides", ".hydra/overrides.yaml")):
        if out.get(key) is None and (run_dir / path).is_file():
            try:  # any YAML or type error: the value stays unknown
                loaded = OmegaConf.load(run_dir / path)
                out[key] = int(loaded.get("seed")) if key == "seed" else [str(o) for o in loaded]
            except Exception:
                pass
    overrides = out.get("overrides")
    out["overrides"] = [str(o) for o in overrides] if isinstance(overrides, list) else None
    return out


def summarize_run(run_dir: Path | str) -> dict:
    """Status (see ``STATUSES``), and for a finished run: solved or not (and by which judge),
    episodes/steps/seconds to solve, the task's measure for the training episodes and
    the greedy policy.

    Reads ``run.json`` (robot, task, learner names, seed, overrides), ``summary.json``
    (the run's own verdict: what "solved" means is the task's, see ``success.json``),
    ``metrics.csv``, ``timing.csv`` and ``eval.json``; ``error`` says why a run is not
    ``ok`` (``error.txt``'s last line for a failed job), ``resume`` how to continue an
    interrupted one, ``warning`` what is wrong with a finished run's optional files.
    """
    run_dir = Path(run_dir)
    out: dict = {"run_dir": str(run_dir), "status": "never started", "overrides": None}
    if not run_dir.is_dir():
        return out | {"error": "no run folder"}
    out.update(_names(run_dir))
    try:
        state = _state(run_dir)
    except Unusable as err:
        state = {"status": "failed", "error": str(err)}
    warnings = [w for w in (out.pop("warning", None), state.pop("warning", None)) if w]
    return out | state | ({"warning": "; ".join(warnings)} if warnings else {})


def _state(run_dir: Path) -> dict:
    """Which status the folder's files say, and the finished run's numbers."""
    error = run_dir / "error.txt"
    if error.exists():
        try:
            lines = [line for line in error.read_text(errors="replace").splitlines() if line.strip()]
        except OSError as err:
            lines = [f"error.txt is unreadable ({type(err).__name__})"]
        return {"status": "failed", "error": lines[-1].strip() if lines else "error.txt is empty"}
    try:
        summary = read_json(run_dir / "summary.json")
    except Unusable as err:
        return _unfinished(run_dir, str(err))
    if summary.get("interrupted"):
        return _interrupted(run_dir, f"stopped after episode {summary.get('episodes', '?')} (Ctrl-C)")
    return _finished(run_dir, summary)


def _unfinished(run_dir: Path, why: str) -> dict:
    """A folder without a usable summary.json: killed (or still running), stopped before
    training began, or never started."""
    if (run_dir / "checkpoint.pt").exists() or (run_dir / "metrics.csv").exists():
        return _interrupted(run_dir, f"{why}: killed before it finished, or still running")
    if (run_dir / "run.json").exists() or (run_dir / "config.yaml").exists():
        return {"status": "failed", "error": f"{why}, no metrics.csv, no error.txt: "
                                              "stopped before its first episode"}
    return {"status": "never started", "error": "no run.json and no metrics.csv"}


def _interrupted(run_dir: Path, why: str) -> dict:
    """An interrupted run, with the command that resumes it where checkpoint.pt allows."""
    if (run_dir / "checkpoint.pt").is_file():
        resume = f"python train.py resume={run_dir}"
        return {"status": "interrupted", "error": f"{why}; resume with: {resume}", "resume": resume}
    return {"status": "interrupted", "error": f"{why}; no checkpoint.pt to resume from: run it again"}


def _finished(run_dir: Path, summary: dict) -> dict:
    """The numbers of a run whose summary.json says it finished."""
    measure, window = _field(summary, "measure", str), _field(summary, "window", int)
    path = run_dir / "metrics.csv"
    rows = read_csv(path, ("reward", "length", "env_steps", rolling_field(measure, window)))
    at = _field(summary, "solved_at", int, optional=True)
    if at is not None and not 0 < at <= len(rows):
        raise Unusable(f"metrics.csv has {len(rows)} episodes, summary.json says solved at {at}")
    steps = numbers(rows, "env_steps", path)
    rewards, lengths = numbers(rows[-100:], "reward", path), numbers(rows[-100:], "length", path)
    solved = bool(summary.get("solved"))
    out = dict(
        status="ok", measure=measure, unit=_field(summary, "unit", str), window=window,
        judge=_field(summary, "judge", str), threshold=_field(summary, "threshold"),
        episodes=_field(summary, "episodes", int), solved=solved,
        decided_by=summary.get("decided_by") if solved else None,
        episodes_to_solve=at, steps_to_solve=int(steps[at - 1]) if at else None,
        best_rolling=_field(summary, "best_rolling"), last_rolling=_field(summary, "last_rolling"),
        greedy=_field(summary, "greedy", optional=True),
        final_mean_length=float(np.mean(lengths)) if rows else None,
        final_mean_return=float(np.mean(rewards)) if rows else None,
        wall_s=_field(summary, "wall_s"), env_steps=_field(summary, "env_steps", int),
        pruned_at=_field(summary, "pruned_at", int, optional=True),
    )
    return out | _optional_files(run_dir, at)


def _optional_files(run_dir: Path, at: int | None) -> dict:
    """Seconds to solve (timing.csv) and the final greedy evaluation (eval.json), where
    present; a damaged one gives a ``warning`` instead."""
    out: dict = {"wall_to_solve": None}
    problems = []
    timing = run_dir / "timing.csv"
    if at and timing.exists():
        try:
            wall = numbers(read_csv(timing, ("wall_s",)), "wall_s", timing)
            out["wall_to_solve"] = wall[at - 1] if at <= len(wall) else None
        except Unusable as err:
            problems.append(str(err))
    if (run_dir / "eval.json").exists():
        try:
            result = read_json(run_dir / "eval.json")
            out.update(greedy_mean_length=float(result["mean_length"]),
                       greedy_mean_return=float(result["mean_return"]))
            if result.get("value") is not None:
                out["greedy"] = float(result["value"])
        except (Unusable, KeyError, TypeError, ValueError) as err:
            problems.append(str(err) if isinstance(err, Unusable) else f"eval.json is incomplete ({err!r})")
    return out | ({"warning": "; ".join(problems)} if problems else {})
