"""The run folder's CSV files, appended as the run goes.

- ``metrics.csv``: one row per finished training episode, only what the seed
  determines (bit-identical for the same config and seed);
- ``timing.csv``: the wall-clock seconds of each of those episodes;
- ``evals.csv``: one row per greedy evaluation.

:func:`metric_fields` and :func:`eval_fields` are the one place that names
the columns, and every row is built from them; :func:`rolling_field` names
the measure's rolling mean (``length_mean100``) wherever it appears. A
resumed run cuts metrics.csv and timing.csv back to its checkpoint's episodes
(:meth:`MetricsFiles.open`), so it neither repeats nor skips one.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tasks.base import Success



@dataclass
class Episode:
    """One finished training episode, as the run's outputs report it (the metrics files, the
    console and the logger each read what they show from it)."""

    episode: int  # 1-based, in the order episodes finished (ties by copy index)
    env_index: int  # which copy of the batched env ran it
    reward: float  # its return
    length: int  # its steps
    terminated: bool  # ended by the task (not by a time limit or a physics divergence)
    env_steps: int  # env steps of all copies so far
    wall_s: float  # seconds since the run started, to the millisecond
    value: float  # the task's success measure for this episode
    rolling: float  # its mean over the last ``success.window`` episodes
    extra: dict = field(default_factory=dict)  # the learner's numbers (alpha, gamma, epsilon)

BASE_FIELDS = ("episode", "env_index", "reward", "length", "terminated", "env_steps")
TIMING_FIELDS = ("episode", "wall_s")
EVAL_FIELDS = ("episode", "env_steps", "episodes", "length", "return", "rate")


def rolling_field(measure: str, window: int) -> str:
    """The name of the measure's rolling mean over ``window`` episodes: ``<measure>_mean<window>``."""
    return f"{measure}_mean{window}"


def metric_fields(success: Success, extra_fields: tuple[str, ...] = ()) -> tuple[str, ...]:
    """metrics.csv's columns: the episode, the task's measure (unless it is one of those)
    and its rolling mean, the learner's numbers."""
    measure = () if success.measure in BASE_FIELDS else (success.measure,)
    return BASE_FIELDS + measure + (rolling_field(success.measure, success.window),) + tuple(extra_fields)


def eval_fields(success: Success) -> tuple[str, ...]:
    """evals.csv's columns: when, the task's measure (unless it is the length), how many
    episodes, their mean length and return, and the share of them that passed the task's
    threshold (``rate``)."""
    measure = () if success.measure in EVAL_FIELDS else (success.measure,)
    return EVAL_FIELDS[:2] + measure + EVAL_FIELDS[2:]


def episode_cells(ep: Episode, success: Success) -> dict:
    """An episode's metrics.csv values by column, the learner's numbers aside."""
    cells = {"episode": ep.episode, "env_index": ep.env_index, "reward": ep.reward,
             "length": ep.length, "terminated": int(ep.terminated), "env_steps": ep.env_steps}
    cells.setdefault(success.measure, round(ep.value, 6))
    cells[rolling_field(success.measure, success.window)] = round(ep.rolling, 6)
    return cells


def eval_cells(row: dict, success: Success) -> dict:
    """A greedy evaluation's evals.csv values by column (``row`` as ``Run.evals`` keeps it)."""
    cells = {"episode": row["episode"], "env_steps": row["env_steps"], "episodes": row["episodes"],
             "length": round(row["length"], 3), "return": round(row["return"], 3),
             "rate": round(row["rate"], 4) if row.get("rate") is not None else ""}  # (none: a run from before rates)
    cells.setdefault(success.measure, round(row["value"], 6))
    return cells


def _rewrite(path: Path, rows: list) -> None:
    """Replaces ``path`` with ``rows`` at once (a kill leaves the old file or the new one)."""
    tmp = path.with_suffix(".csv.tmp")
    with open(tmp, "w", newline="") as f:
        csv.writer(f).writerows(rows)
    tmp.replace(path)


class MetricsFiles:
    """metrics.csv, timing.csv and evals.csv of one run folder."""

    def __init__(self, run_dir: Path | str, success: Success, extra_fields: tuple[str, ...] = ()) -> None:
        self.run_dir = Path(run_dir)
        self.success = success
        self.fields = metric_fields(success, extra_fields)
        self._files = []

    def open(self, keep_rows: int, evals: list[dict]) -> None:
        """Opens metrics.csv and timing.csv for appending after their first ``keep_rows``
        rows (0: afresh) and writes evals.csv from ``evals``.

        Rows past ``keep_rows`` (episodes after the last checkpoint of a killed
        run) are dropped. Both files are read and checked before either is
        rewritten, so a refusal leaves them as they were.
        """
        kept = {}
        for name in ("metrics.csv", "timing.csv"):
            path = self.run_dir / name
            rows = []
            if keep_rows and path.is_file():
                with open(path, newline="") as f:
                    rows = list(csv.reader(f))[1 : keep_rows + 1]
            if len(rows) != keep_rows:
                raise ValueError(f"{path} has {len(rows)} episode rows, the checkpoint needs {keep_rows}")
            kept[name] = rows
        for name, header in (("metrics.csv", self.fields), ("timing.csv", TIMING_FIELDS)):
            path = self.run_dir / name
            _rewrite(path, [header, *kept[name]])
            # Line-buffered: every finished episode is on disk, even if the run is killed.
            self._files.append(open(path, "a", newline="", buffering=1))
        self._metrics, self._timing = (csv.writer(f) for f in self._files)
        self.write_evals(evals)

    def write_episode(self, ep: Episode) -> None:
        """Appends ``ep``'s row to metrics.csv and its seconds to timing.csv."""
        cells = episode_cells(ep, self.success)
        self._metrics.writerow([cells[k] if k in cells else ep.extra.get(k, "") for k in self.fields])
        self._timing.writerow([ep.episode, ep.wall_s])

    def write_evals(self, evals: list[dict]) -> None:
        """Rewrites evals.csv whole with one row per greedy evaluation (a few rows)."""
        fields = eval_fields(self.success)
        rows = [[cells[k] for k in fields] for cells in (eval_cells(r, self.success) for r in evals)]
        _rewrite(self.run_dir / "evals.csv", [fields, *rows])

    def close(self) -> None:
        for f in self._files:
            f.close()
