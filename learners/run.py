"""What every training run shares: episode bookkeeping, the win criterion,
per-episode console lines and metrics, the reward-curve plot and the verdict.

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

METRIC_FIELDS = ("episode", "env_index", "reward", "length", "terminated", "env_steps", "mean100")
TIMING_FIELDS = ("episode", "wall_s")


@dataclass(frozen=True)
class WinCriterion:
    """Solved when the mean length of the last ``window`` episodes reaches
    ``n_win_ticks`` and at least ``min_episodes`` episodes have run."""

    n_win_ticks: float = 250.0
    min_episodes: int = 100
    window: int = 100

    def __post_init__(self) -> None:
        if self.min_episodes < 0 or self.window < 1:
            raise ValueError(
                f"win.min_episodes must be >= 0 and win.window >= 1; got "
                f"{self.min_episodes}, {self.window}"
            )

    def solved(self, lengths: list[int]) -> bool:
        if len(lengths) < max(self.min_episodes, 1):
            return False
        return float(np.mean(lengths[-self.window :])) >= self.n_win_ticks


@dataclass
class Episode:
    episode: int
    env_index: int
    reward: float
    length: int
    terminated: bool
    env_steps: int
    wall_s: float
    mean100: float
    extra: dict = field(default_factory=dict)


class Run:
    """Records finished episodes of a batched env, prints and stores them."""

    def __init__(
        self,
        run_dir: Path | str,
        num_envs: int,
        max_episodes: int,
        win: WinCriterion,
        extra_fields: tuple[str, ...] = (),
        quiet: bool = False,
        logger=None,
        checkpoint_every: int = 0,
        resume: bool = False,
    ) -> None:
        self.run_dir = Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        self.num_envs = num_envs
        self.max_episodes = int(max_episodes)
        self.win = win
        self.extra_fields = tuple(extra_fields)
        self.quiet = quiet
        self.logger = logger
        self.checkpoint_every = int(checkpoint_every)
        self.checkpoint = None  # checkpoint(td): saves the whole run; set by the trainer
        self.resume_td: TensorDictBase | None = None  # where a resumed run's first step starts
        self.last_td: TensorDictBase | None = None  # where the next step would start
        self.n_episodes = 0
        self.lengths: list[int] = []
        self.env_steps = 0
        self.solved_at: int | None = None
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
        for name, header in (("metrics.csv", METRIC_FIELDS + self.extra_fields),
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

    @property
    def finished(self) -> bool:
        """True once the episode budget is spent or the win criterion is met."""
        return self.solved_at is not None or self.n_episodes >= self.max_episodes

    @property
    def done(self) -> bool:
        """True when the run is finished or a stop was asked."""
        return self.finished or self.stop_requested

    def request_stop(self) -> None:
        """Ends the run after the current step (the trainer then saves a checkpoint)."""
        self.stop_requested = True

    def after_step(self, td: TensorDictBase) -> None:
        """Saves a checkpoint when ``checkpoint_every`` more episodes have finished."""
        due = self.checkpoint_every and self.n_episodes - self._last_checkpoint >= self.checkpoint_every
        if due and self.checkpoint is not None and not self.done:
            self.checkpoint(td)
            self._last_checkpoint = self.n_episodes

    def state_dict(self) -> dict:
        return {"n_episodes": self.n_episodes, "lengths": list(self.lengths), "env_steps": self.env_steps,
                "solved_at": self.solved_at, "wall_s": self.wall_s,
                "ret": torch.from_numpy(self._ret.copy()), "len": torch.from_numpy(self._len.copy())}

    def load_state_dict(self, state: Mapping) -> None:
        """Continues from ``state``; metrics files are cut back to its episodes."""
        if len(state["ret"]) != self.num_envs:
            raise ValueError(f"the checkpoint has {len(state['ret'])} copies, this run {self.num_envs}")
        self.n_episodes = self._last_checkpoint = int(state["n_episodes"])
        self.lengths = [int(v) for v in state["lengths"]]
        self.env_steps = int(state["env_steps"])
        self.solved_at = state["solved_at"]
        self._ret[:] = state["ret"].numpy()
        self._len[:] = state["len"].numpy()
        self._t0 = time.perf_counter() - float(state["wall_s"])
        self._bar.update(self.n_episodes)
        self._open_files(self.n_episodes)

    @property
    def wall_s(self) -> float:
        return time.perf_counter() - self._t0

    def record(self, next_td: TensorDictBase, stats: Mapping[str, float] | None = None) -> list[Episode]:
        """Accounts one batched step; returns the episodes it finished."""
        reward = next_td.get("reward").reshape(self.num_envs).numpy()
        done = next_td.get("done").reshape(self.num_envs).numpy()
        terminated = next_td.get("terminated").reshape(self.num_envs).numpy()
        self._ret += reward
        self._len += 1
        self.env_steps += self.num_envs
        finished = []
        for i in np.flatnonzero(done):
            if self.finished:
                break
            length = int(self._len[i])
            self.lengths.append(length)
            self.n_episodes += 1
            ep = Episode(
                episode=self.n_episodes, env_index=int(i), reward=float(self._ret[i]),
                length=length, terminated=bool(terminated[i]), env_steps=self.env_steps,
                wall_s=round(self.wall_s, 3), mean100=float(np.mean(self.lengths[-self.win.window :])),
                extra=dict(stats or {}),
            )
            finished.append(ep)
            self._write(ep)
            if self.win.solved(self.lengths):
                self.solved_at = ep.episode
        self._ret[done] = 0.0
        self._len[done] = 0
        return finished

    def _write(self, ep: Episode) -> None:
        row = [ep.episode, ep.env_index, ep.reward, ep.length, int(ep.terminated), ep.env_steps,
               round(ep.mean100, 3)]
        row += [ep.extra.get(k, "") for k in self.extra_fields]
        self._csv.writerow(row)
        self._timing.writerow([ep.episode, ep.wall_s])
        self._bar.update(1)
        if self.logger is not None:
            scalars = {"reward": ep.reward, "length": ep.length, "mean100": ep.mean100,
                       "env_steps": ep.env_steps, **ep.extra}
            for key, value in scalars.items():
                self.logger.log_scalar(f"episode/{key}", float(value), step=ep.episode)
        if not self.quiet:
            stats = " ".join(f"{k}={v:.4g}" for k, v in ep.extra.items())
            self._bar.write(
                f"episode {ep.episode:5d} {stats} reward={ep.reward:.1f} length={ep.length} "
                f"mean100={ep.mean100:.1f} time={ep.wall_s:.1f}s"
            )

    def summary(self) -> dict:
        lengths = np.asarray(self.lengths, dtype=float)
        best = np.sort(lengths)[-100:] if len(lengths) else np.zeros(1)
        return {
            "solved": self.solved_at is not None,
            "episodes": self.n_episodes,
            "solved_at": self.solved_at,
            "score": float(lengths.mean()) if len(lengths) else 0.0,
            "best100": float(best.mean()),
            "env_steps": self.env_steps,
            "wall_s": self.wall_s,
            "divergences": self.divergences,
        }

    def close(self) -> dict:
        """Flushes metrics, draws the reward curve and returns the summary."""
        self._bar.close()
        for f in getattr(self, "_files", ()):
            f.close()
        if self.logger is not None:
            summary = self.summary()
            for key in ("score", "best100", "env_steps", "wall_s", "divergences"):
                self.logger.log_scalar(f"run/{key}", float(summary[key]), step=self.n_episodes)
            self.logger.close()
        plot_reward_curve(self.run_dir / "metrics.csv", self.run_dir / "reward_curve.png",
                          self.win.n_win_ticks)
        return self.summary()


def plot_reward_curve(metrics_csv: Path, out_png: Path, win_line: float | None = None) -> None:
    """Episode length and its 100-episode mean (and return if it differs) per episode."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    with open(metrics_csv) as f:
        rows = list(csv.DictReader(f))
    ep = np.array([int(r["episode"]) for r in rows])
    length = np.array([float(r["length"]) for r in rows])
    mean100 = np.array([float(r["mean100"]) for r in rows])
    reward = np.array([float(r["reward"]) for r in rows])
    fig, axes = plt.subplots(2 if not np.allclose(reward, length) else 1, 1, figsize=(8, 5),
                             squeeze=False, sharex=True)
    ax = axes[0, 0]
    ax.plot(ep, length, lw=0.6, alpha=0.5, label="episode length")
    ax.plot(ep, mean100, lw=2, label="mean of last 100")
    if win_line is not None:
        ax.axhline(win_line, color="k", ls="--", lw=1, label=f"win ({win_line:g})")
    ax.set_ylabel("steps")
    ax.legend(loc="upper left")
    if axes.shape[0] > 1:
        axes[1, 0].plot(ep, reward, lw=0.6)
        axes[1, 0].set_ylabel("episode return")
    axes[-1, 0].set_xlabel("episode")
    fig.suptitle(Path(out_png).parent.name)
    fig.tight_layout()
    fig.savefig(out_png, dpi=100)
    plt.close(fig)


def verdict_lines(summary: dict, run_dir: Path) -> list[str]:
    """The human verdict and the final machine-readable ``VERDICT`` line."""
    n = summary["solved_at"] if summary["solved"] else summary["episodes"]
    word = "solved" if summary["solved"] else "not solved"
    diverged = summary.get("divergences", 0)
    return [
        *([f"warning: the physics diverged {diverged} times; each time that copy's episode was "
           "truncated and reset (see the log)"] if diverged else []),
        f"{word} after {n} episodes "
        f"(overall score {summary['score']:.1f}, best-100 score {summary['best100']:.1f}, "
        f"{summary['env_steps']} env steps in {summary['wall_s']:.1f}s, "
        f"{summary['env_steps'] / max(summary['wall_s'], 1e-9):.0f} steps/s)",
        f"results in {run_dir}",
        f"VERDICT solved={str(summary['solved']).lower()} episodes={n} "
        f"best100={summary['best100']:.1f} wall_s={summary['wall_s']:.1f} run_dir={run_dir}",
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
        for episode in run.record(td.get("next"), stats()):
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
