"""What a training run prints while it runs: a tqdm bar over the episode budget,
one line per finished episode and one per greedy evaluation (only the bar's
count when ``quiet``, and that hidden)."""

from __future__ import annotations

from tqdm import tqdm

from learners.episode import Episode
from learners.metrics_files import rolling_field
from tasks.base import Success


def episode_line(ep: Episode, success: Success) -> str:
    """``episode    12 alpha=0.1 ... reward=.. length=.. [measure=..] <measure>_mean100=.. time=..s``."""
    measure = success.measure
    stats = " ".join(f"{k}={v:.4g}" for k, v in ep.extra.items())
    shown = "" if measure == "length" else f"{measure}={ep.value:.3g} "
    return (f"episode {ep.episode:5d} {stats} reward={ep.reward:.1f} length={ep.length} "
            f"{shown}{rolling_field(measure, success.window)}={ep.rolling:.3g} time={ep.wall_s:.1f}s")


def evaluation_line(row: dict, success: Success) -> str:
    """``greedy evaluation at episode N: <measure>=.. length=.. return=..`` (``row`` as ``Run.evals``)."""
    return (f"greedy evaluation at episode {row['episode']}: {success.measure}={row['value']:.4g} "
            f"length={row['length']:.1f} return={row['return']:.1f}")


class Console:
    """The progress bar and the lines written above it."""

    def __init__(self, total_episodes: int, success: Success, quiet: bool = False) -> None:
        self.success = success
        self.quiet = quiet
        self._bar = tqdm(total=total_episodes, unit="ep", disable=quiet, dynamic_ncols=True)

    def skip(self, episodes: int) -> None:
        """Moves the bar past the episodes a resumed run ran before."""
        self._bar.update(episodes)

    def episode(self, ep: Episode) -> None:
        self._bar.update(1)
        if not self.quiet:
            self._bar.write(episode_line(ep, self.success))

    def evaluation(self, row: dict) -> None:
        if not self.quiet:
            self._bar.write(evaluation_line(row, self.success))

    def close(self) -> None:
        self._bar.close()
