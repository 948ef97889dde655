"""What every training run shares: episode bookkeeping, the task's success
measure and who judges it, greedy evaluations during training, per-episode
console lines and metrics, the reward-curve plot and the verdict.

Episodes in a batch end at different times; :class:`Run` turns the batch's
per-step ``next`` tensordicts into one record per finished episode, in the
order they finish (ties by copy index), so the metrics read the same for any
``num_envs``.

``metrics.csv`` holds only what the seed determines (bit-identical for the
same config and seed); wall-clock seconds per episode go to ``timing.csv``.
A run can be stopped at a step boundary (``request_stop``, e.g. on Ctrl-C)
and saves its whole state every ``checkpoint_every`` episodes through the
``checkpoint`` hook :func:`drive` calls (see :mod:`learners.resume`).
"""

from __future__ import annotations

import csv
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping

import numpy as np
import torch
from tensordict import TensorDictBase
from tqdm import tqdm

from tasks.base import Success

BASE_FIELDS = ("episode", "env_index", "reward", "length", "terminated", "env_steps")
TIMING_FIELDS = ("episode", "wall_s")
EVAL_FIELDS = ("episode", "env_steps", "episodes", "length", "return")


def metric_fields(success: Success, extra_fields: tuple[str, ...] = ()) -> tuple[str, ...]:
    """metrics.csv's columns: the episode, the task's measure and its rolling mean, the learner's."""
    measure = () if success.measure in BASE_FIELDS else (success.measure,)
    return BASE_FIELDS + measure + (f"{success.measure}_mean{success.window}",) + tuple(extra_fields)


@dataclass
class Episode:
    episode: int
    env_index: int
    reward: float
    length: int
    terminated: bool
    env_steps: int
    wall_s: float
    value: float  # the task's success measure for this episode
    rolling: float  # its mean over the last ``success.window`` episodes
    extra: dict = field(default_factory=dict)


class Run:
    """Records finished episodes of a batched env, judges them, prints and stores them.

    "Solved" follows the task's :class:`~tasks.base.Success`: with
    ``judge="training"`` the mean measure of the last ``window`` training
    episodes, with ``judge="greedy"`` the mean measure of a greedy evaluation
    (``greedy_eval``, run every ``eval_every`` episodes); either way the run
    stops once it is met. Every evaluation is kept (``evals``, evals.csv),
    whichever judge decides.
    """

    def __init__(
        self,
        run_dir: Path | str,
        num_envs: int,
        max_episodes: int,
        success: Success,
        extra_fields: tuple[str, ...] = (),
        quiet: bool = False,
        logger=None,
        checkpoint_every: int = 0,
        eval_every: int = 0,
        resume: bool = False,
    ) -> None:
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.num_envs = num_envs
        self.max_episodes = int(max_episodes)
        self.success = success
        self.extra_fields = tuple(extra_fields)
        self.quiet = quiet
        self.logger = logger
        self.checkpoint_every = int(checkpoint_every)
        self.eval_every = int(eval_every)
        self.checkpoint = None  # checkpoint(td): saves the whole run; set by the trainer
        self.greedy_eval = None  # greedy_eval() -> evaluate()'s result; set by the trainer
        self.resume_td: TensorDictBase | None = None  # where a resumed run's first step starts
        self.last_td: TensorDictBase | None = None  # where the next step would start
        self.n_episodes = 0
        self.lengths: list[int] = []
        self.values: list[float] = []  # the task's measure, per episode
        self.evals: list[dict] = []  # one row per greedy evaluation (EVAL_FIELDS + "value")
        self.last_eval: dict | None = None  # the newest evaluation's full result
        self.env_steps = 0
        self.solved_at: int | None = None
        self.decided_by: str | None = None  # "training" or "greedy", once solved
        self.solved_value: float | None = None  # the judged mean that solved it
        self.stop_requested = False
        self.divergences = 0  # the env's count of physics divergences (truncated episodes)
        self._last_checkpoint = 0
        self._ret = np.zeros(num_envs)
        self._len = np.zeros(num_envs, dtype=np.int64)
        self._t0 = time.perf_counter()
        self._bar = tqdm(total=self.max_episodes, unit="ep", disable=quiet, dynamic_ncols=True)
        if not resume:  # a resumed run opens its files in ``load_state_dict``
            self._open_files(0)

    def _open_files(self, keep_rows: int) -> None:
        """Opens metrics.csv and timing.csv for appending after their first ``keep_rows`` rows.

        Rows past ``keep_rows`` (episodes after the last checkpoint of a killed
        run) are dropped, so a resumed run neither repeats nor skips an episode.
        """
        self._files = []
        for name, header in (("metrics.csv", metric_fields(self.success, self.extra_fields)),
                             ("timing.csv", TIMING_FIELDS)):
            path = self.run_dir / name
            rows = []
            if keep_rows and path.is_file():
                with open(path, newline="") as f:
                    rows = list(csv.reader(f))[1 : keep_rows + 1]
            if len(rows) != keep_rows:
                raise ValueError(f"{path} has {len(rows)} episode rows, the checkpoint needs {keep_rows}")
            tmp = path.with_suffix(".csv.tmp")
            with open(tmp, "w", newline="") as f:
                csv.writer(f).writerows([header, *rows])
            tmp.replace(path)
            # Line-buffered: every finished episode is on disk, even if the run is killed.
            self._files.append(open(path, "a", newline="", buffering=1))
        self._csv, self._timing = (csv.writer(f) for f in self._files)
        self._write_evals()

    @property
    def finished(self) -> bool:
        """True once the episode budget is spent or the task counts as solved."""
        return self.solved_at is not None or self.n_episodes >= self.max_episodes

    @property
    def done(self) -> bool:
        """True when the run is finished or a stop was asked."""
        return self.finished or self.stop_requested

    def request_stop(self) -> None:
        """Ends the run after the current step (the trainer then saves a checkpoint)."""
        self.stop_requested = True

    def after_step(self, td: TensorDictBase) -> None:
        """At a step boundary: a greedy evaluation every ``eval_every`` episodes, then a
        checkpoint every ``checkpoint_every`` (so the checkpoint holds the evaluation)."""
        last_eval = self.evals[-1]["episode"] if self.evals else 0
        if (self.eval_every and self.greedy_eval is not None and not self.done
                and self.n_episodes - last_eval >= self.eval_every):
            self.evaluate_greedy()
        due = self.checkpoint_every and self.n_episodes - self._last_checkpoint >= self.checkpoint_every
        if due and self.checkpoint is not None and not self.done:  # the trainer saves the end
            self.checkpoint(td)
            self._last_checkpoint = self.n_episodes

    def evaluate_greedy(self, evaluation=None) -> dict:
        """Runs ``evaluation`` (default ``greedy_eval``) now, records it and, if the greedy
        policy judges, may solve."""
        result = (evaluation or self.greedy_eval)()
        value = measure_of(result, self.success.measure)
        row = {"episode": self.n_episodes, "env_steps": self.env_steps, "episodes": result["episodes"],
               "length": result["mean_length"], "return": result["mean_return"], "value": value}
        self.evals.append(row)
        self.last_eval = result
        self._write_evals()
        if (self.solved_at is None and self.success.judge == "greedy"
                and self.success.met(value, self.n_episodes)):
            self._solve("greedy", value)
        if self.logger is not None:
            for key, v in ((self.success.measure, value), ("length", row["length"]),
                           ("return", row["return"])):
                self.logger.log_scalar(f"eval/{key}", float(v), step=self.n_episodes)
        if not self.quiet:
            self._bar.write(f"greedy evaluation at episode {self.n_episodes}: "
                            f"{self.success.measure}={value:.4g} length={row['length']:.1f} "
                            f"return={row['return']:.1f}")
        return result

    def _solve(self, judge: str, value: float) -> None:
        self.solved_at, self.decided_by, self.solved_value = self.n_episodes, judge, value

    def _write_evals(self) -> None:
        """evals.csv: one row per greedy evaluation so far (rewritten whole: a few rows)."""
        path = self.run_dir / "evals.csv"
        tmp = path.with_suffix(".csv.tmp")
        with open(tmp, "w", newline="") as f:
            writer = csv.writer(f)
            own = self.success.measure not in EVAL_FIELDS  # the length is a column anyway
            writer.writerow(EVAL_FIELDS[:2] + (self.success.measure,) * own + EVAL_FIELDS[2:])
            for r in self.evals:
                writer.writerow([r["episode"], r["env_steps"], *[round(r["value"], 6)] * own,
                                 r["episodes"], round(r["length"], 3), round(r["return"], 3)])
        tmp.replace(path)

    def state_dict(self) -> dict:
        return {"n_episodes": self.n_episodes, "lengths": list(self.lengths),
                "values": list(self.values), "evals": [dict(r) for r in self.evals],
                "env_steps": self.env_steps, "solved_at": self.solved_at,
                "decided_by": self.decided_by, "solved_value": self.solved_value,
                "wall_s": self.wall_s,
                "ret": torch.from_numpy(self._ret.copy()), "len": torch.from_numpy(self._len.copy())}

    def load_state_dict(self, state: Mapping) -> None:
        """Continues from ``state``; metrics files are cut back to its episodes."""
        if len(state["ret"]) != self.num_envs:
            raise ValueError(f"the checkpoint has {len(state['ret'])} copies, this run {self.num_envs}")
        self.n_episodes = self._last_checkpoint = int(state["n_episodes"])
        self.lengths = [int(v) for v in state["lengths"]]
        self.values = [float(v) for v in state["values"]]
        self.evals = [dict(r) for r in state["evals"]]
        self.env_steps = int(state["env_steps"])
        self.solved_at = state["solved_at"]
        self.decided_by = state["decided_by"]
        self.solved_value = state["solved_value"]
        self._ret[:] = state["ret"].numpy()
        self._len[:] = state["len"].numpy()
        self._t0 = time.perf_counter() - float(state["wall_s"])
        self._bar.update(self.n_episodes)
        self._open_files(self.n_episodes)

    @property
    def wall_s(self) -> float:
        return time.perf_counter() - self._t0

    def rolling(self) -> float:
        """Mean measure of the last ``success.window`` episodes (of all, while fewer ran)."""
        return float(np.mean(self.values[-self.success.window :])) if self.values else float("nan")

    def record(self, next_td: TensorDictBase, stats: Mapping[str, float] | None = None,
               ended_info: Mapping[str, np.ndarray] | None = None) -> list[Episode]:
        """Accounts one batched step; returns the episodes it finished.

        ``ended_info``: the env's ``ended_info`` after this step (the task's
        ``episode_info`` of each copy whose episode just ended), where the
        task's measure is read unless it is the episode length.
        """
        reward = next_td.get("reward").reshape(self.num_envs).numpy()
        done = next_td.get("done").reshape(self.num_envs).numpy()
        terminated = next_td.get("terminated").reshape(self.num_envs).numpy()
        self._ret += reward
        self._len += 1
        self.env_steps += self.num_envs
        measure = self.success.measure
        finished = []
        for i in np.flatnonzero(done):
            if self.finished:
                break
            length = int(self._len[i])
            value = float(length) if measure == "length" else float(ended_info[measure][i])
            self.lengths.append(length)
            self.values.append(value)
            self.n_episodes += 1
            ep = Episode(
                episode=self.n_episodes, env_index=int(i), reward=float(self._ret[i]),
                length=length, terminated=bool(terminated[i]), env_steps=self.env_steps,
                wall_s=round(self.wall_s, 3), value=value, rolling=self.rolling(),
                extra=dict(stats or {}),
            )
            finished.append(ep)
            self._write(ep)
            if self.success.judge == "training" and self.success.met(ep.rolling, self.n_episodes):
                self._solve("training", ep.rolling)
        self._ret[done] = 0.0
        self._len[done] = 0
        return finished

    def _write(self, ep: Episode) -> None:
        measure = self.success.measure
        row = [ep.episode, ep.env_index, ep.reward, ep.length, int(ep.terminated), ep.env_steps]
        if measure not in BASE_FIELDS:
            row.append(round(ep.value, 6))
        row.append(round(ep.rolling, 6))
        row += [ep.extra.get(k, "") for k in self.extra_fields]
        self._csv.writerow(row)
        self._timing.writerow([ep.episode, ep.wall_s])
        self._bar.update(1)
        if self.logger is not None:
            scalars = {"reward": ep.reward, "length": ep.length, measure: ep.value,
                       f"{measure}_mean{self.success.window}": ep.rolling,
                       "env_steps": ep.env_steps, **ep.extra}
            for key, value in scalars.items():
                self.logger.log_scalar(f"episode/{key}", float(value), step=ep.episode)
        if not self.quiet:
            stats = " ".join(f"{k}={v:.4g}" for k, v in ep.extra.items())
            shown = "" if measure == "length" else f"{measure}={ep.value:.3g} "
            self._bar.write(
                f"episode {ep.episode:5d} {stats} reward={ep.reward:.1f} length={ep.length} "
                f"{shown}{measure}_mean{self.success.window}={ep.rolling:.3g} time={ep.wall_s:.1f}s"
            )

    def summary(self) -> dict:
        """Solved or not and by which judge; the measure's headline numbers; the cost."""
        s = self.success
        values = np.asarray(self.values, dtype=float)
        if len(values) >= s.window:  # every full window's mean, the best of them the headline
            rolling = np.convolve(values, np.ones(s.window) / s.window, mode="valid")
        else:
            rolling = values.mean(keepdims=True) if len(values) else np.full(1, np.nan)
        greedy = self.evals[-1]["value"] if self.evals else None
        if self.solved_value is not None:
            value = self.solved_value
        else:  # what the judge saw: the last greedy evaluation, or the best training mean
            value = greedy if s.judge == "greedy" else float(rolling.max())
        return {
            "solved": self.solved_at is not None,
            "decided_by": self.decided_by or s.judge,
            "episodes": self.n_episodes,
            "solved_at": self.solved_at,
            "measure": s.measure, "unit": s.unit, "description": s.description,
            "threshold": s.threshold, "judge": s.judge, "window": s.window,
            "min_episodes": s.min_episodes,
            "value": value,
            "best_rolling": float(rolling.max()),
            "last_rolling": float(rolling[-1]),
            "mean_of_100_best_episodes": float(np.sort(values)[-100:].mean()) if len(values) else float("nan"),
            "greedy": greedy,
            "evaluations": len(self.evals),
            "score": float(np.mean(self.lengths)) if self.lengths else 0.0,
            "env_steps": self.env_steps,
            "wall_s": self.wall_s,
            "divergences": self.divergences,
        }

    def close(self) -> dict:
        """Flushes metrics, draws the reward curve and returns the summary."""
        self._bar.close()
        for f in getattr(self, "_files", ()):
            f.close()
        summary = self.summary()
        if self.logger is not None:
            for key in ("best_rolling", "mean_of_100_best_episodes", "score", "env_steps", "wall_s",
                        "divergences"):
                self.logger.log_scalar(f"run/{key}", float(summary[key]), step=self.n_episodes)
            self.logger.log_scalar("run/solved", float(summary["solved"]), step=self.n_episodes)
            self.logger.close()
        plot_reward_curve(self.run_dir / "metrics.csv", self.run_dir / "reward_curve.png",
                          self.success, self.run_dir / "evals.csv")
        return summary


def measure_of(result: Mapping, measure: str) -> float:
    """The mean of ``measure`` over the episodes of an :func:`evaluate` result."""
    return float(result["mean_length"] if measure == "length" else result["info_mean"][measure])


def plot_reward_curve(metrics_csv: Path, out_png: Path, success: Success,
                      evals_csv: Path | None = None) -> None:
    """The task's measure per episode, its rolling mean, the threshold and the greedy
    evaluations; the episode length (if it is not the measure) and return (if it is
    not the length) below."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(metrics_csv) as f:
        rows = list(csv.DictReader(f))
    evals = []
    if evals_csv is not None and Path(evals_csv).is_file():
        with open(evals_csv) as f:
            evals = list(csv.DictReader(f))
    m, rolling = success.measure, f"{success.measure}_mean{success.window}"
    col = lambda rs, key: np.array([float(r[key]) for r in rs])  # noqa: E731
    ep = col(rows, "episode")
    panels = [(m, f"{success.description} ({success.unit})")]
    if m != "length":
        panels.append(("length", "episode length (steps)"))
    if not rows or not np.array_equal(col(rows, "reward"), col(rows, "length")):  # +1 a step: same curve
        panels.append(("reward", "episode return"))
    fig, axes = plt.subplots(len(panels), 1, figsize=(8, 2.6 * len(panels) + 0.6), squeeze=False,
                             sharex=True)
    for ax, (key, label) in zip(axes[:, 0], panels):
        if rows:
            ax.plot(ep, col(rows, key), lw=0.6, alpha=0.5, label="training episode")
        ax.set_ylabel(label)
    ax = axes[0, 0]
    if rows:
        ax.plot(ep, col(rows, rolling), lw=2, label=f"mean of last {success.window}")
    if evals:
        ax.plot(col(evals, "episode"), col(evals, m), "o-", ms=4, lw=1, color="C3",
                label="greedy evaluation")
    if np.isfinite(success.threshold):
        ax.axhline(success.threshold, color="k", ls="--", lw=1,
                   label=f"solved: {success.judge} >= {success.threshold:g}")
    if ax.get_legend_handles_labels()[0]:  # an empty run with no threshold has nothing to label
        ax.legend(loc="upper left", fontsize=8)
    axes[-1, 0].set_xlabel("episode")
    fig.suptitle(f"{Path(out_png).parent.name}\nsolved when {success.describe()} "
                 f"({'greedy policy' if success.judge == 'greedy' else 'training episodes'})",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(out_png, dpi=100)
    plt.close(fig)


def verdict_lines(summary: dict, run_dir: Path) -> list[str]:
    """The human verdict, what each judge saw, and the final machine-readable ``VERDICT`` line."""
    s = summary
    unit = f" {s['unit']}" if s["unit"] else ""
    num = lambda v: "-" if v is None or (isinstance(v, float) and np.isnan(v)) else f"{v:.4g}"  # noqa: E731
    n = s["solved_at"] if s["solved"] else s["episodes"]
    rule = f"{s['description']} >= {s['threshold']:g}{unit}"
    if s["decided_by"] == "greedy":
        how = (f"the greedy policy's mean {s['description']}, "
               f"{num(s['value'])}{unit} (greedy evaluation at episode {n})")
    else:
        how = f"the mean {s['description']} of the last {s['window']} training episodes, {num(s['value'])}{unit}"
    judged = f"judged on {'the greedy policy' if s['judge'] == 'greedy' else 'training episodes'}"
    if s["solved"]:
        head = f"solved after {n} episodes: {how} >= {s['threshold']:g}{unit}"
    else:
        head = (f"not solved after {n} episodes: needs {rule} ({judged}, after at least "
                f"{s['min_episodes']} episodes); got {num(s['value'])}{unit}")
    diverged = s.get("divergences", 0)
    return [
        *([f"warning: the physics diverged {diverged} times; each time that copy's episode was "
           "truncated and reset (see the log)"] if diverged else []),
        head,
        f"  training episodes: best rolling-{s['window']} mean {num(s['best_rolling'])}{unit}, "
        f"last-{s['window']} mean {num(s['last_rolling'])}{unit}, mean of the 100 best episodes "
        f"{num(s['mean_of_100_best_episodes'])}{unit} (the seeds' \"best 100 score\")",
        f"  greedy policy: {num(s['greedy'])}{unit} ({s['evaluations']} evaluations)",
        f"  {s['env_steps']} env steps in {s['wall_s']:.1f}s "
        f"({s['env_steps'] / max(s['wall_s'], 1e-9):.0f} steps/s)",
        f"results in {run_dir}",
        f"VERDICT solved={str(s['solved']).lower()} episodes={n} measure={s['measure']} "
        f"judge={s['decided_by']} value={num(s['value'])} threshold={s['threshold']:g} "
        f"best_rolling{s['window']}={num(s['best_rolling'])} greedy={num(s['greedy'])} "
        f"wall_s={s['wall_s']:.1f} run_dir={run_dir}",
    ]


def seed_everything(seed: int) -> torch.Generator:
    """Seeds torch and numpy globals; returns a dedicated torch generator."""
    torch.manual_seed(seed)
    np.random.seed(seed % (2**32))
    gen = torch.Generator()
    gen.manual_seed(seed)
    return gen


def drive(env, policy, run: Run, on_step, on_episode, stats) -> None:
    """Steps ``env`` with ``policy`` until ``run`` is done.

    ``on_step(td)`` sees each batched transition (``td`` holds ``next``);
    ``on_episode(episode)`` each finished episode; ``stats()`` gives the
    learner's numbers for the episode's console line and metrics row.
    Starts from ``run.resume_td`` if set (a resumed run), else a reset; leaves
    the input of the step it did not take in ``run.last_td``.
    """
    td = run.resume_td if run.resume_td is not None else env.reset()
    while not run.done:
        td = policy(td)
        td, td_next = env.step_and_maybe_reset(td)
        run.divergences = getattr(env, "divergences", 0)
        on_step(td)
        for episode in run.record(td.get("next"), stats(), getattr(env, "ended_info", None)):
            on_episode(episode)
        td = td_next
        run.after_step(td)
    run.last_td = td


def evaluate(env, policy, max_steps: int | None = None) -> dict:
    """Runs one episode in each copy of ``env`` with ``policy``; length and return stats.

    If the task has ``episode_info(physics) -> dict[str, ndarray]`` (one value
    per copy), each copy's values at its episode end are reported too, with
    their mean under ``info_mean``.
    """
    n = env.num_envs
    ret = np.zeros(n)
    length = np.zeros(n, dtype=np.int64)
    alive = np.ones(n, dtype=bool)
    info_fn = getattr(env.task, "episode_info", None)
    info: dict[str, np.ndarray] = {}
    td = env.reset()
    steps = 0
    with torch.no_grad():
        while alive.any() and (max_steps is None or steps < max_steps):
            td = env.step(policy(td))
            nxt = td.get("next")
            ret += nxt.get("reward").reshape(n).numpy() * alive
            length += alive
            ended = alive & nxt.get("done").reshape(n).numpy()
            if info_fn is not None and ended.any():
                for key, value in info_fn(env.physics).items():
                    info.setdefault(key, np.zeros(n))[ended] = np.asarray(value)[ended]
            alive &= ~ended
            td = nxt.exclude("reward", "done", "terminated", "truncated")
            steps += 1
    if info_fn is not None and alive.any():  # cut off by max_steps
        for key, value in info_fn(env.physics).items():
            info.setdefault(key, np.zeros(n))[alive] = np.asarray(value)[alive]
    return {
        "episodes": n,
        "mean_length": float(length.mean()), "std_length": float(length.std()),
        "mean_return": float(ret.mean()), "std_return": float(ret.std()),
        "lengths": length.tolist(), "returns": ret.tolist(),
        "info": {k: v.tolist() for k, v in info.items()},
        "info_mean": {k: float(v.mean()) for k, v in info.items()},
    }
