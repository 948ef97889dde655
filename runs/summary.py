"""summary.json: made at a run's end (:func:`run_summary`, with the verdict printed from it,
:func:`verdict_lines`), its names, and reading run folders back: what a comparison, a
tuning study or a benchmark needs.

Every number a run reports is named for what it is, the same in ``summary.json``, the
console verdict (its ``VERDICT`` line too), the loggers' ``run/*`` scalars, the
comparison and the Optuna objective. ``<measure>`` is the task's success measure
(``success.measure``: ``length``, ``distance_walked``, ``laps``, ...), ``<window>`` its
judging window (``success.window``); :func:`measure_keys` builds the names, and every
reader finds a number through it, never by spelling the name itself:

- ``train_return_mean``: the mean return over all training episodes;
- ``train_return_last100``: the mean return of the last 100 training episodes;
- ``train_<measure>_best_rolling<window>``: the best mean of ``window`` consecutive
  training episodes;
- ``train_<measure>_last<window>``: the mean of the last ``window`` training episodes;
- ``train_<measure>_best100_mean``: the mean of the 100 best training episodes, wherever
  they fell (the seeds' "best 100");
- ``greedy_<measure>``, ``greedy_return``: the final greedy evaluation's mean measure and
  mean return (a run a tuning study pruned: its last evaluation's, as it makes no final
  one; None without one);
- ``judged_<measure>``: the mean where the verdict was reached (the training window's,
  which a training verdict compares with the threshold, or the confirming greedy
  evaluation's, whose episodes' pass rate a greedy verdict compares); else the last greedy
  evaluation's, or the best training window's;
- ``start_level``, ``stuck_steps``, ``stuck``: the mean measure of the first 20 training
  episodes, the env steps the run spent at that level before it first rose above it
  (:class:`runs.run.StartWatch`), and whether that was a quarter of its budget or more (a
  stuck start);
- ``greedy_rate``: the share of the final greedy evaluation's episodes whose measure
  reached the threshold (``rate``: the share the task's rule asks; ``eval_episodes``: how
  many episodes it made).

:func:`summarize_run` returns, for any run folder (it never raises on a damaged one:
a missing, empty or corrupt file makes the run ``failed``, or ``interrupted`` when it
can still be resumed, with one line in ``error`` saying which file and what is wrong):

- always: ``run_dir``, ``status`` (one of ``STATUSES``), ``overrides`` (the job's
  command-line overrides, or None), and where known ``robot``, ``task``, ``learner``,
  ``seed``; ``error`` (why a run is not ``ok``), ``resume`` (the command that continues
  an interrupted run), ``warning`` (a finished run's damaged optional files);
- for a finished run (``status == "ok"``) also: the task's rule, ``measure``, ``unit``,
  ``window``, ``judge`` (``training`` or ``greedy``), ``threshold``, ``rate`` (None for a
  run from before rates); the outcome, ``greedy_rate`` (likewise),
  ``solved``, ``decided_by`` (the judge that solved it, else None), ``episodes``,
  ``episodes_to_solve``, ``steps_to_solve``, ``wall_to_solve`` (None unless solved),
  ``env_steps``, ``wall_s`` (the run's own clock), ``process_s`` (its process's seconds when it
  ended, imports included; None where unknown), ``pruned_at`` (the episode a tuning study stopped it at, or
  None); every number above under its name (``train_return_mean``, ...,
  ``greedy_<measure>``, ``judged_<measure>``); ``greedy``, the same number as
  ``greedy_<measure>`` under a name that does not depend on the task (None without a
  greedy evaluation); ``headline``, the name of the number a comparison and a tuning
  study rank a run by (:meth:`MeasureKeys.headline`: ``greedy_<measure>`` for a greedily
  judged task, ``train_<measure>_last<window>`` otherwise), and ``headline_value``, that
  number.

Run folders written before these names (summary.json with ``greedy``, ``best_rolling``,
``last_rolling``, ``mean_of_100_best_episodes``, ``value`` and ``score``) read the same:
the old keys are mapped to the new names (:meth:`MeasureKeys.legacy`), and the returns
come from metrics.csv.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np
from omegaconf import OmegaConf

from runs.layout import train_command
from runs.metrics_files import rolling_field

# A run's status: "ok" (finished: summary.json without "interrupted"), "interrupted"
# (Ctrl-C, or killed: partial metrics), "failed" (error.txt, or nothing usable),
# "never started" (no folder, or one without run.json and metrics.csv).
STATUSES = ("ok", "interrupted", "failed", "never started", "evaluation")

RETURN_WINDOW = 100  # train_return_last100's episodes
BEST_EPISODES = 100  # train_<measure>_best100_mean's episodes (the seeds' "best 100")


@dataclass(frozen=True)
class MeasureKeys:
    """The names of a run's numbers for the task measure ``measure`` judged over ``window``
    training episodes (see the module's docstring for what each means)."""

    measure: str
    window: int

    train_return_mean: ClassVar[str] = "train_return_mean"
    train_return_last100: ClassVar[str] = f"train_return_last{RETURN_WINDOW}"
    greedy_return: ClassVar[str] = "greedy_return"

    @property
    def train_best_rolling(self) -> str:
        """``train_<measure>_best_rolling<window>``."""
        return f"train_{self.measure}_best_rolling{self.window}"

    @property
    def train_last(self) -> str:
        """``train_<measure>_last<window>``."""
        return f"train_{self.measure}_last{self.window}"

    @property
    def train_best100_mean(self) -> str:
        """``train_<measure>_best100_mean``."""
        return f"train_{self.measure}_best{BEST_EPISODES}_mean"

    @property
    def greedy(self) -> str:
        """``greedy_<measure>``."""
        return f"greedy_{self.measure}"

    @property
    def judged(self) -> str:
        """``judged_<measure>``."""
        return f"judged_{self.measure}"

    def numbers(self) -> tuple[str, ...]:
        """Every number's name, in summary.json's order."""
        return (self.judged, self.train_return_mean, self.train_return_last100, self.train_best_rolling,
                self.train_last, self.train_best100_mean, self.greedy, self.greedy_return)

    def logged(self) -> tuple[str, ...]:
        """The numbers the loggers get as ``run/<name>`` (all but ``judged_<measure>``, which
        repeats one of them)."""
        return self.numbers()[1:]

    def headline(self, judge: str, has_greedy: bool = True) -> str:
        """The number a run is ranked by: the final greedy evaluation's measure for a greedily
        judged task (``greedy_<measure>``), else, or without a greedy evaluation, the mean of
        the last ``window`` training episodes (``train_<measure>_last<window>``)."""
        return self.greedy if judge == "greedy" and has_greedy else self.train_last

    def legacy(self) -> dict[str, str]:
        """Old summary.json keys -> these names (folders written before them read the same)."""
        return {"greedy": self.greedy, "best_rolling": self.train_best_rolling, "last_rolling": self.train_last,
                "mean_of_100_best_episodes": self.train_best100_mean, "value": self.judged}

    def meanings(self, unit: str = "", description: str | None = None) -> dict[str, str]:
        """Each name -> what it is, in words (``description``: the measure's, e.g. "steps balanced")."""
        what = description or self.measure
        unit = f" ({unit})" if unit else ""
        return {
            self.judged: f"the mean {what}{unit} where the verdict was reached (the training window's, which a "
                         "training verdict compares with the threshold, or the confirming greedy evaluation's, "
                         "whose episodes' pass rate a greedy verdict compares); else the last greedy "
                         "evaluation's, or the best training window's",
            self.train_return_mean: "the mean return over all training episodes",
            self.train_return_last100: f"the mean return of the last {RETURN_WINDOW} training episodes",
            self.train_best_rolling: f"the best mean {what}{unit} of {self.window} consecutive training episodes",
            self.train_last: f"the mean {what}{unit} of the last {self.window} training episodes",
            self.train_best100_mean: f"the mean {what}{unit} of the {BEST_EPISODES} best training episodes",
            self.greedy: f"the final greedy evaluation's mean {what}{unit}",
            self.greedy_return: "the final greedy evaluation's mean return",
        }


def measure_keys(measure: str, window: int) -> MeasureKeys:
    """The names of a run's numbers for the task measure ``measure`` and judging ``window``."""
    return MeasureKeys(str(measure), int(window))


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
    # run.json says an evaluation folder's mode; one written before it did, its command line does
    out["mode"] = "eval" if chosen_mode(run_dir) == "eval" or "mode=eval" in (out["overrides"] or []) else "train"
    return out


def chosen_mode(run_dir: Path) -> str | None:
    """run.json's ``mode`` (``train`` or ``eval``), None where it has none."""
    try:
        return read_json(run_dir / "run.json").get("mode")
    except (Unusable, AttributeError):
        return None


def summarize_run(run_dir: Path | str) -> dict:
    """What the run folder ``run_dir`` holds, as the module's docstring lists: its status,
    and for a finished run its rule, outcome and every number under its name.

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
    if out.pop("mode", "train") == "eval":
        return out | _evaluation(run_dir)
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


def _evaluation(run_dir: Path) -> dict:
    """A ``mode=eval`` folder: status ``evaluation`` with its checkpoint and the numbers of its
    eval.json (``failed`` where it has none: the evaluation did not end)."""
    try:
        result = read_json(run_dir / "eval.json")
    except Unusable as err:
        return {"status": "failed", "error": f"an evaluation folder (mode=eval): {err}"}
    measure = result.get("measure", "?")
    return {"status": "evaluation", "checkpoint": result.get("checkpoint"), "measure": measure,
            "greedy": result.get("value"), f"greedy_{measure}": result.get("value"),
            "greedy_rate": result.get("greedy_rate"), "passed": result.get("passed"),
            "episodes": result.get("episodes")}


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
        resume = f"{train_command()} resume={run_dir}"
        return {"status": "interrupted", "error": f"{why}; resume with: {resume}", "resume": resume}
    return {"status": "interrupted", "error": f"{why}; no checkpoint.pt to resume from: run it again"}


def _finished(run_dir: Path, summary: dict) -> dict:
    """The numbers of a run whose summary.json says it finished."""
    measure, window = _field(summary, "measure", str), _field(summary, "window", int)
    keys = measure_keys(measure, window)
    summary = _renamed(summary, keys)
    path = run_dir / "metrics.csv"
    rows = read_csv(path, ("reward", "length", "env_steps", rolling_field(measure, window)))
    at = _field(summary, "solved_at", int, optional=True)
    if at is not None and not 0 < at <= len(rows):
        raise Unusable(f"metrics.csv has {len(rows)} episodes, summary.json says solved at {at}")
    steps = numbers(rows, "env_steps", path)
    returns = numbers(rows, "reward", path)
    solved = bool(summary.get("solved"))
    out = dict(
        status="ok", measure=measure, unit=_field(summary, "unit", str), window=window,
        judge=_field(summary, "judge", str), threshold=_field(summary, "threshold"),
        episodes=_field(summary, "episodes", int), solved=solved,
        decided_by=summary.get("decided_by") if solved else None,
        episodes_to_solve=at, steps_to_solve=int(steps[at - 1]) if at else None,
        wall_s=_field(summary, "wall_s"), env_steps=_field(summary, "env_steps", int),
        pruned_at=_field(summary, "pruned_at", int, optional=True),
        rate=_field(summary, "rate", optional=True), greedy_rate=_field(summary, "greedy_rate", optional=True),
        stuck=summary.get("stuck"), stuck_steps=_field(summary, "stuck_steps", int, optional=True),
    )
    out[keys.train_best_rolling] = _field(summary, keys.train_best_rolling)
    out[keys.train_last] = _field(summary, keys.train_last)
    for name in (keys.judged, keys.train_best100_mean, keys.greedy, keys.greedy_return):
        out[name] = _field(summary, name, optional=True)
    # Folders from before the returns were summarized: metrics.csv holds them.
    for name, window_returns in ((keys.train_return_mean, returns),
                                 (keys.train_return_last100, returns[-RETURN_WINDOW:])):
        given = _field(summary, name, optional=True)
        out[name] = given if given is not None else (float(np.mean(window_returns)) if rows else None)
    out |= _optional_files(run_dir, at, keys, out)
    out["greedy"] = out[keys.greedy]
    out["headline"] = keys.headline(out["judge"], out[keys.greedy] is not None)
    out["headline_value"] = out[out["headline"]]
    return out


def final_measure(summary: dict) -> float | None:
    """The number a finished run's policy is judged by at its end: the final greedy
    evaluation's measure, or without one the headline (the last training window's)."""
    greedy = summary.get("greedy")
    return greedy if greedy is not None else summary.get("headline_value")


def succeeded(summary: dict) -> bool:
    """Whether a finished run's policy meets the task's rule at its end: the benchmark's
    success. Its final greedy evaluation's pass rate at least the task's ``rate``; a run
    from before rates (or without a greedy evaluation): :func:`final_measure` at least the
    threshold."""
    if summary.get("status") != "ok":
        return False
    rate, needed = summary.get("greedy_rate"), summary.get("rate")
    if rate is not None and needed is not None:
        return rate >= needed - 1e-12
    value = final_measure(summary)
    return value is not None and value >= summary["threshold"]


SUCCESS_AND_SPEED = "success_and_speed"


def success_and_speed(summary: dict, budget_steps: int) -> float | None:
    """One number that orders runs as the benchmark does, success first and then env steps
    to success: :func:`final_measure` over the threshold, capped at 1 (1 for a success),
    plus, for a success the verdict judged solved during training, the fraction of
    ``budget_steps`` left when it was. In [1, 2] for a success, below 1 otherwise (a
    threshold of 0 or less: 1 or 0 before the bonus). None for a run that did not finish."""
    value, threshold = final_measure(summary), summary.get("threshold")
    if summary.get("status") != "ok" or value is None or threshold is None:
        return None
    part = min(value / threshold, 1.0) if threshold > 0 else float(value >= threshold)
    steps = summary.get("steps_to_solve")
    if succeeded(summary) and summary.get("solved") and steps is not None:
        part += max(1.0 - steps / budget_steps, 0.0)
    return part


def _renamed(summary: dict, keys: MeasureKeys) -> dict:
    """``summary`` with an old folder's keys (``greedy``, ``best_rolling``, ...) under their
    new names (:meth:`MeasureKeys.legacy`); a new folder's keys win."""
    old = {new: summary[key] for key, new in keys.legacy().items() if key in summary and new not in summary}
    return summary | old


def _optional_files(run_dir: Path, at: int | None, keys: MeasureKeys, numbers_so_far: dict) -> dict:
    """Seconds to solve (timing.csv), and the final greedy evaluation (eval.json) where
    summary.json lacks it; a damaged file gives a ``warning`` instead."""
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
            greedy_return = float(result["mean_return"])
            if numbers_so_far.get(keys.greedy_return) is None:
                out[keys.greedy_return] = greedy_return
            if result.get("value") is not None and numbers_so_far.get(keys.greedy) is None:
                out[keys.greedy] = float(result["value"])
        except (Unusable, KeyError, TypeError, ValueError) as err:
            problems.append(str(err) if isinstance(err, Unusable) else f"eval.json is incomplete ({err!r})")
    return out | ({"warning": "; ".join(problems)} if problems else {})


# -- the end of a training run: summary.json's numbers and the verdict printed from them --
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
        "min_episodes": s.min_episodes, "rate": s.rate,
        keys.judged: judged,
        keys.train_return_mean: _mean(returns),
        keys.train_return_last100: _mean(returns[-RETURN_WINDOW:]),
        keys.train_best_rolling: float(rolling.max()),
        keys.train_last: float(rolling[-1]),
        keys.train_best100_mean: _mean(np.sort(values)[-BEST_EPISODES:]),
        keys.greedy: greedy,
        keys.greedy_return: final["return"] if final else None,
        "greedy_rate": final.get("rate") if final else None,  # the share of its episodes that passed
        "eval_episodes": final["episodes"] if final else None,
        "evaluations": len(run.evals),
        "env_steps": run.env_steps,
        "wall_s": run.wall_s,
        "process_s": getattr(run, "process_s", None),  # the process's seconds when the run ended
        "divergences": run.divergences,
        # the untrained level (the first 20 episodes' mean measure) and the env steps spent there
        "start_level": run.start_watch.level, "stuck_steps": run.start_watch.stuck_steps(run.env_steps),
        "stuck": run.start_watch.stuck(run.env_steps, run.max_env_steps),
        # imports, config and build: process start to the first env step (this process's)
        "first_step_s": run.first_step_s,
        **({"pruned_at": run.pruned_at} if run.pruned_at is not None else {}),
    }


def _greedy_line(s: dict, greedy: str, greedy_return: str) -> str:
    """The verdict's line on the greedy policy: its final evaluation's numbers; a run its
    tuning study pruned makes none, so its last evaluation's, if any."""
    if s.get("pruned_at") is None:
        n = s["evaluations"]
        return (f"  greedy policy, final evaluation ({n} evaluation{'' if n == 1 else 's'} in all): {greedy}, "
                f"{greedy_return}")
    if not s["evaluations"]:
        return "  greedy policy: not evaluated (pruned before its first evaluation; a pruned run makes no final one)"
    return (f"  greedy policy, its last evaluation before it was pruned ({s['evaluations']} in all; a pruned run "
            f"makes no final one): {greedy}, {greedy_return}")


def eval_verdict_lines(record: dict, run_dir: Path) -> list[str]:
    """A ``mode=eval`` folder's verdict from its eval.json ``record``: whether the checkpoint's
    greedy policy passed the task's rule in this one evaluation, and its ``VERDICT mode=eval
    ...`` line (an evaluation folder is not a training run: it has no summary.json, and
    ``compare.py`` lists it apart)."""
    measure, episodes, rate = record["measure"], record["episodes"], record["greedy_rate"]
    fields = {"mode": "eval", "passed": str(record["passed"]).lower(), "measure": measure,
              f"greedy_{measure}": _num(record["value"]), "greedy_rate": _num(rate), "rate": _num(record["rate"]),
              "threshold": f"{record['threshold']:g}", "episodes": episodes,
              "greedy_return": _num(record["mean_return"]), "checkpoint": record["checkpoint"], "run_dir": run_dir}
    return [f"{'passed' if record['passed'] else 'did not pass'}: {round(rate * episodes)} of {episodes} greedy "
            f"episodes reached {record['threshold']:g} (the rule asks {record['rate']:.0%}; one evaluation of "
            f"{record['checkpoint']}, not a training run)",
            f"results in {run_dir}",
            "VERDICT " + " ".join(f"{name}={value}" for name, value in fields.items())]


def _stuck_line(s: dict, unit: str) -> str:
    """The verdict's line on a stuck start (:class:`runs.run.StartWatch`)."""
    steps, made = s["stuck_steps"], s["env_steps"]
    if steps < made:
        when = f"for its first {steps:,} env steps ({steps / made:.0%} of {made:,})"
    else:  # left at its last step (the evaluation that solved it) or never
        when = "until the evaluation that solved it, its last" if s["solved"] else "and never left it"
    return (f"  a stuck start: it stayed at its untrained level (mean {s['description']} {_num(s['start_level'])}"
            f"{unit} over its first 20 episodes) {when}")


def _passed(s: dict) -> str:
    """``, greedy_rate 0.95 (19 of 20 episodes >= 250)``; nothing for a run from before rates."""
    rate = s.get("greedy_rate")
    if rate is None:
        return ""
    episodes = s.get("eval_episodes")
    count = f"{round(rate * episodes)} of {episodes} episodes" if episodes else "of its episodes"
    return f", greedy_rate {_num(rate)} ({count} >= {s['threshold']:g})"


def _num(v) -> str:
    return "-" if v is None or (isinstance(v, float) and np.isnan(v)) else f"{v:.4g}"


def _headline(s: dict, unit: str) -> str:
    """``solved after N episodes: <how> >= T`` (a greedy verdict: ``at least 90% of the greedy
    policy's episodes reached ...``) or ``not solved after N episodes: needs ...``."""
    n = s["solved_at"] if s["solved"] else s["episodes"]
    keys = measure_keys(s["measure"], s["window"])
    judged, greedy = s[keys.judged], s.get(keys.greedy)
    rated = s.get("greedy_rate") is not None and s.get("rate") is not None
    if rated and s["decided_by"] == "greedy":  # the rate decides, not the mean
        rule = f"{s['description']} >= {s['threshold']:g}{unit}"
        if s["solved"]:
            return (f"solved after {n} episodes: at least {s['rate']:.0%} of the greedy policy's episodes "
                    f"reached {rule}, in an evaluation at episode {n} and its confirmation from fresh "
                    f"starts (the confirmation's mean {_num(judged)}{unit})")
        return (f"not solved after {n} episodes: needs {rule} on at least {s['rate']:.0%} of a greedy "
                f"evaluation's episodes, confirmed from fresh starts (judged on the greedy policy, after "
                f"at least {s['min_episodes']} episodes); the final evaluation: {s['greedy_rate']:.0%} "
                f"passed, mean {_num(judged)}{unit}")
    if s["decided_by"] == "greedy":  # a run from before rates: the mean decided
        how = (f"the greedy policy's mean {s['description']}, "
               f"{_num(judged)}{unit} (greedy evaluation at episode {n})")
    else:
        how = (f"the mean {s['description']} of the last {s['window']} training episodes, "
               f"{_num(judged)}{unit}")
    if s["solved"]:
        confirmed = (f", and the greedy policy's {_num(greedy)}{unit}"
                     if s["decided_by"] == "training" and greedy is not None else "")
        if s.get("greedy_rate") is not None:
            confirmed += (f"; at least {s['rate']:.0%} of the greedy episodes passed, in an evaluation and "
                          "its confirmation from fresh starts")
        return f"solved after {n} episodes: {how} >= {s['threshold']:g}{unit}{confirmed}"
    if s["judge"] == "greedy":
        by = "judged on the greedy policy"
    else:
        by = "judged on training episodes, and the greedy policy's too"
    got = f"got {_num(judged)}{unit}"
    if s["judge"] == "training" and judged is not None and judged >= s["threshold"]:
        got += (f" (the training rule was met, the greedy policy never: {_num(greedy)}{unit} "
                "at the final evaluation)")
    elif s["judge"] == "training" and greedy is not None and greedy >= s["threshold"]:
        got += (f" (the greedy policy's {_num(greedy)}{unit} meets the threshold, but the rule asks it of the "
                f"mean of {s['window']} training episodes first; task.win.judge=greedy judges the greedy policy alone)")
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
              "greedy_rate": _num(s.get("greedy_rate")), "rate": _num(s.get("rate")),
              "wall_s": f"{s['wall_s']:.1f}", "process_s": "-" if s.get("process_s") is None else f"{s['process_s']:.1f}", "run_dir": run_dir}
    return [
        *([f"warning: the physics diverged {diverged} times; each time that copy's episode was "
           "truncated and reset (see the log)"] if diverged else []),
        _headline(s, unit),
        f"  training episodes' {s['description']}: {named(k.train_best_rolling, k.train_last, k.train_best100_mean)}"
        f" (the mean of the {BEST_EPISODES} best episodes: the seeds' \"best {BEST_EPISODES}\")",
        f"  training episodes' return: {named(k.train_return_mean, k.train_return_last100, with_unit=False)}",
        _greedy_line(s, named(k.greedy) + _passed(s), named(k.greedy_return, with_unit=False)),
        *([f"  stopped early by the tuning study (pruned) at episode {s['pruned_at']}"]
          if s.get("pruned_at") is not None else []),
        *([_stuck_line(s, unit)] if s.get("stuck") else []),
        f"  {s['env_steps']} env steps in {s['wall_s']:.1f}s "
        f"({s['env_steps'] / max(s['wall_s'], 1e-9):.0f} steps/s)"
        + (f"; the process so far: {s['process_s']:.1f}s (imports, building, files included)"
           if s.get("process_s") is not None else ""),
        f"results in {run_dir}",
        "VERDICT " + " ".join(f"{name}={value}" for name, value in fields.items()),
    ]
