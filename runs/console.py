"""What a training run prints while it runs.

By default: a tqdm bar over the episode budget (on a terminal only) whose
postfix shows the task's measure, epsilon, the loss and steps/s, and a summary
line every ``log_every`` episodes (about 20 per run when 0). With ``verbose``
also one line per finished episode and per greedy evaluation; with ``quiet``
nothing. :func:`tee_console` copies the console into the run folder's log.
"""

from __future__ import annotations

import argparse

import math
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Callable, Iterator, Mapping

from tqdm import tqdm

from runs.episode import Episode
from runs.metrics_files import rolling_field
from tasks.base import Success

SUMMARY_LINES = 20  # summary lines per run when log_every is 0


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


def _live(ep: Episode, live: Mapping[str, float] | None) -> list[str]:
    """``eps 0.05``, ``loss 0.012`` where the learner reports them."""
    values = {**ep.extra, **(live or {})}
    shown = [f"eps {values['epsilon']:.3g}"] if "epsilon" in values else []
    return shown + ([f"loss {values['loss']:.3g}"] if "loss" in values else [])


def summary_line(ep: Episode, total: int, success: Success, best: float,
                 last_eval: dict | None, live: Mapping[str, float] | None = None) -> str:
    """``episode 200/4000 | steps balanced: mean100 34.2, best 40.1 | greedy 25.3 at 200 | eps .. |
    12345 env steps, 2950 steps/s, 4.2s``."""
    unit = f" {success.unit}" if success.unit else ""
    parts = [f"episode {ep.episode}/{total}",
             f"{success.description}: mean{success.window} {ep.rolling:.4g}{unit}, best {best:.4g}"]
    if last_eval is not None:
        parts.append(f"greedy {last_eval['value']:.4g} at {last_eval['episode']}")
    parts += _live(ep, live)
    rate = ep.env_steps / max(ep.wall_s, 1e-9)
    parts.append(f"{ep.env_steps} env steps, {rate:.0f} steps/s, {ep.wall_s:.1f}s")
    return " | ".join(parts)


class Console:
    """The progress bar and the lines written above it."""

    def __init__(self, total_episodes: int, success: Success, quiet: bool = False,
                 verbose: bool = False, log_every: int = 0, bar_file: IO[str] | None = None) -> None:
        self.success, self.total = success, int(total_episodes)
        self.quiet, self.verbose = quiet, verbose and not quiet
        self.log_every = int(log_every) or max(1, math.ceil(self.total / SUMMARY_LINES))
        self.best = -math.inf
        # disable=None: no bar where the output is not a terminal (a log, a sweep worker)
        self._bar = tqdm(total=self.total, unit="ep", disable=True if quiet else None,
                         dynamic_ncols=True, file=bar_file or _terminal(sys.stderr), leave=False)

    def skip(self, episodes: int) -> None:
        """Moves the bar past the episodes a resumed run ran before."""
        self._bar.update(episodes)

    def episode(self, ep: Episode, last_eval: dict | None = None,
                live: Callable[[], Mapping[str, float]] | None = None) -> None:
        """Counts ``ep``; ``last_eval``: the newest evaluation row; ``live()``: the learner's
        current training numbers (``loss``, ``epsilon``, ...), asked only when shown."""
        self.best = max(self.best, ep.rolling)
        self._bar.update(1)
        if self.quiet:
            return
        if self.verbose:
            self.write(episode_line(ep, self.success))
        due = ep.episode % self.log_every == 0
        numbers = live() if live is not None and (due or not self._bar.disable) else None
        if not self._bar.disable:
            rate = ep.env_steps / max(ep.wall_s, 1e-9)
            self._bar.set_postfix_str(", ".join(
                [f"{self.success.measure} {ep.rolling:.3g}", *_live(ep, numbers), f"{rate:.0f} steps/s"]),
                refresh=False)
        if due:
            self.write(summary_line(ep, self.total, self.success, self.best, last_eval, numbers))

    def evaluation(self, row: dict) -> None:
        if self.verbose:
            self.write(evaluation_line(row, self.success))

    def write(self, line: str) -> None:
        """``line`` on stdout (and so in the log), on a line of its own above the bar: the
        bar (on the terminal's stderr) is cleared first and drawn again below it."""
        if not self._bar.disable:
            self._bar.clear()
        print(line, flush=True)
        if not self._bar.disable:
            self._bar.refresh()

    def close(self) -> None:
        """Removes the bar: the lines after it start on a clean line."""
        if not self._bar.disable:
            self._bar.clear()
        self._bar.close()


def _terminal(stream: IO[str]) -> IO[str]:
    """The stream under a :class:`Tee` (the bar is drawn, never logged)."""
    return stream.terminal if isinstance(stream, Tee) else stream


class Tee:
    """A text stream writing to ``terminal`` and, flushed line by line, to ``log``."""

    def __init__(self, terminal: IO[str], log: IO[str]) -> None:
        self.terminal, self.log = terminal, log

    def write(self, text: str) -> int:
        self.log.write(text)
        if "\n" in text:
            self.log.flush()
        return self.terminal.write(text)

    def flush(self) -> None:
        self.log.flush()
        self.terminal.flush()

    def isatty(self) -> bool:
        return self.terminal.isatty()

    def __getattr__(self, name: str):
        return getattr(self.terminal, name)


@contextmanager
def tee_console(path: Path) -> Iterator[None]:
    """Everything printed to stdout and stderr inside also goes to ``path`` (appended)."""
    with open(path, "a", encoding="utf-8") as log:
        out, err = sys.stdout, sys.stderr
        sys.stdout, sys.stderr = Tee(out, log), Tee(err, log)
        try:
            yield
        finally:
            sys.stdout, sys.stderr = out, err


class OneLineParser(argparse.ArgumentParser):
    """argparse whose mistakes are one ``error:`` line on stderr (no usage block) and exit 2."""

    def error(self, message: str):
        print(f"error: {message}; see {self.prog} --help", file=sys.stderr)
        sys.exit(2)
