"""What a training run prints: its banner before the first step (:func:`banner_lines`:
what was chosen, what a tuned file changed, when it is solved, where it goes), then while
it runs.

By default: a tqdm bar over the episode budget (on a terminal only) whose
postfix shows the task's measure, epsilon, the loss and steps/s, and a summary
line every ``log_every`` episodes (about 20 per run when 0). With ``verbose``
also one line per finished episode and per greedy evaluation; with ``quiet``
nothing. :func:`tee_console` copies the console into the run folder's log.
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
import time
from contextlib import contextmanager
from pathlib import Path
from typing import IO, TYPE_CHECKING, Callable, Iterator, Mapping, Sequence

from omegaconf import DictConfig, OmegaConf
from tqdm import tqdm

from params import dotted
from runs.metrics_files import Episode, rolling_field
from tasks.catalog import GROUPS, TASK_TUNED, TUNED_PICKS, compose, config_dirs

if TYPE_CHECKING:
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
    passed = f" passed={row['rate']:.0%}" if row.get("rate") is not None else ""
    return (f"greedy evaluation at episode {row['episode']}: {success.measure}={row['value']:.4g}{passed} "
            f"length={row['length']:.1f} return={row['return']:.1f}")


class Ticker:
    """A line every ``every`` seconds while a long piece of work runs (an evaluation alone, a
    video): ``<label>: <n>/<total> <unit>, <s> s``; nothing for work shorter than that. Call
    it with the count done so far."""

    def __init__(self, label: str, total: int, unit: str, every: float = 5.0) -> None:
        self.label, self.total, self.unit, self.every = label, int(total), unit, float(every)
        self.t0 = self.last = time.monotonic()

    def __call__(self, done: int) -> None:
        now = time.monotonic()
        if now - self.last >= self.every:
            self.last = now
            print(f"{self.label}: {done}/{self.total} {self.unit}, {now - self.t0:.0f} s", flush=True)


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
    parts = [f"episode {ep.episode}" + (f"/{total}" if total else ""),
             f"{success.description}: mean{success.window} {ep.rolling:.4g}{unit}, best {best:.4g}"]
    if last_eval is not None:
        passed = f" ({last_eval['rate']:.0%} passed)" if last_eval.get("rate") is not None else ""
        parts.append(f"greedy {last_eval['value']:.4g}{passed} at {last_eval['episode']}")
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
        # No episode budget (max_episodes=0, a budget of env steps): a line every 100 episodes.
        self.log_every = int(log_every) or (max(1, math.ceil(self.total / SUMMARY_LINES)) if self.total else 100)
        self.best = -math.inf
        # disable=None: no bar where the output is not a terminal (a log, a sweep worker)
        self._bar = tqdm(total=self.total or None, unit="ep", disable=True if quiet else None,
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
    """A text stream writing to ``terminal`` and, flushed line by line, to ``log``.

    It owns neither: closing it closes nothing, and once ``log`` is closed (its run over) it
    writes to ``terminal`` alone. A library that kept the stream it found at import (absl's
    log handler, imported inside a run) closes it when logging is configured again (Hydra's
    next job): that close reached the process's stderr, and a sweep's later signal handlers
    then failed on it (issue 63)."""

    def __init__(self, terminal: IO[str], log: IO[str]) -> None:
        self.terminal, self.log = terminal, log

    def write(self, text: str) -> int:
        if not self.log.closed:
            self.log.write(text)
            if "\n" in text:
                self.log.flush()
        return self.terminal.write(text)

    def flush(self) -> None:
        if not self.log.closed:
            self.log.flush()
        self.terminal.flush()

    def close(self) -> None:
        """Flushes what it can: the terminal and the log belong to whoever opened them (and
        may be closed already)."""
        try:
            self.flush()
        except (OSError, ValueError):
            pass

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


# -- the banner: the lines a run prints before its first step --
PICKS = (*GROUPS, "tuned", TASK_TUNED)  # the config groups' keys, not values
SHOWN_CHANGES = 5  # values a tuned file changed, named on its line (the rest counted)


def tuned_changes(cfg: DictConfig, choices: Mapping[str, str | None],
                  overrides: Sequence[str]) -> list[str] | None:
    """``key before -> after`` for each value the tuned files (the robot's and the task's)
    changed in ``cfg`` (the same command composed with ``~tuned``, which leaves out both);
    ``[]`` when no tuned file applies, ``None`` when the command does not compose without
    them (an override of a key only they add).

    An override that sets one value (``learner.lr=0.01``, ``seed=3``) sets it in both
    configs, so the composition without the tuned files leaves it out and is made once for
    all the jobs of a sweep that differ only in such values (the configs hold no
    interpolations outside ``hydra``)."""
    if not tuned_files(choices):
        return []
    kept = [o for o in overrides if o.split("=", 1)[0].lstrip("+~") not in PICKS]
    values = [o for o in kept if _sets_one_value(o, cfg)]
    before = _without_tuned(choices.get("robot"), choices.get("task"), choices.get("learner"),
                            tuple(o for o in kept if o not in values), _config_signature())
    set_keys = {o.split("=", 1)[0] for o in values}
    if before is None or not set_keys <= before.keys():
        return None
    after = dotted(OmegaConf.to_container(cfg, resolve=True))
    return [f"{key} {before.get(key)} -> {value}" for key, value in after.items()
            if key not in set_keys and before.get(key) != value]


def _sets_one_value(override: str, cfg: DictConfig) -> bool:
    """Whether ``override`` is ``key=value`` of a leaf ``cfg`` has (not a config group, an
    addition, a deletion or a ``hydra.`` setting)."""
    key = override.split("=", 1)[0]
    if "=" not in override or key[:1] in "+~" or "/" in key or "@" in key:
        return False
    node = OmegaConf.select(cfg, key, default=_ABSENT)
    return node is not _ABSENT and not isinstance(node, DictConfig)


_ABSENT = object()


def _config_signature() -> tuple:
    """Every config file's path, time and size: a cached composition holds while it is the same."""
    files = (p for folder in config_dirs() for p in sorted(folder.rglob("*.yaml")))
    return tuple((str(p), (st := p.stat()).st_mtime_ns, st.st_size) for p in files)


@functools.lru_cache(maxsize=32)
def _without_tuned(robot: str | None, task: str | None, learner: str | None, overrides: tuple[str, ...],
                   signature: tuple) -> dict | None:
    """The dotted resolved config of the command without its tuned files (None where it
    does not compose so); ``signature`` (:func:`_config_signature`) keys the cache only."""
    try:
        plain = compose(robot, task, learner, [*overrides, "~tuned"])
    except Exception:  # noqa: BLE001 - the banner still names the file
        return None
    return dotted(OmegaConf.to_container(plain, resolve=True))


def tuned_files(choices: Mapping[str, str | None]) -> list[str]:
    """The tuned files a run applied, ``conf/tuned/<name>.yaml``, the robot's first."""
    return [f"conf/tuned/{choices[key]}.yaml" for key in TUNED_PICKS if choices.get(key)]


def solved_when(success: Success) -> str:
    """``mean <description> of the last N training episodes >= T <unit> ..., then ...`` or
    the greedy form: the rule, the pass rate and the confirmation."""
    unit = f" {success.unit}" if success.unit else ""
    greedy = (f"{success.rate:.0%} of a greedy evaluation's episodes reach {success.threshold:g}{unit}, "
              "confirmed by a second evaluation from fresh starts")
    if success.judge == "greedy":
        minimum = f", after >= {success.min_episodes} episodes" if success.min_episodes else ""
        return f"{greedy} (evaluated every eval_every episodes or eval_every_steps env steps{minimum})"
    return (f"mean {success.description} of the last {success.window} training episodes "
            f">= {success.threshold:g}{unit} (after >= {success.min_episodes} episodes), then {greedy}")


def budget(cfg: DictConfig) -> str:
    """The training budget in words: "1000 episodes", "150000 env steps" or both."""
    parts = [f"{int(cfg.max_episodes)} episodes"] if cfg.get("max_episodes") else []
    if cfg.get("max_env_steps"):
        parts.append(f"{int(cfg.max_env_steps)} env steps")
    return " or ".join(parts)


def copies(n: int) -> str:
    """``n`` copies in words: "1 copy", "16 copies"."""
    return f"{n} cop{'y' if n == 1 else 'ies'}"


def banner_lines(cfg: DictConfig, choices: Mapping[str, str | None], changes: Sequence[str] | None,
                 success: Success, run_dir: Path) -> list[str]:
    """The start banner: robot / task / learner and the run's scale, the tuned file and what
    it changed (``changes``; ``None``: not worked out, e.g. a resumed run), what "solved" means
    here, the run folder."""
    what = "evaluate " if cfg.mode == "eval" else ""
    lines = [f"{what}{choices.get('robot')} / {choices.get('task')} / {choices.get('learner')}, "
             f"seed {cfg.seed}, {copies(int(cfg.num_envs))}"
             + (f", up to {budget(cfg)}" if cfg.mode == "train" else "")
             + (", training past 'solved'" if cfg.mode == "train" and not cfg.get("stop_when_solved", True) else "")
             + (f", Optuna trial {cfg.trial}" if cfg.get("trial") is not None else "")]
    files = tuned_files(choices)
    if files:
        if changes is None:
            what = "applied"
        else:
            more = f" and {len(changes) - SHOWN_CHANGES} more" if len(changes) > SHOWN_CHANGES else ""
            what = "changed " + (", ".join(changes[:SHOWN_CHANGES]) + more
                                 or "nothing (overridden on the command line)")
        lines.append(f"tuned: {' + '.join(files)} {what} ('~tuned' leaves {'them' if len(files) > 1 else 'it'} out)")
    lines.append(f"solved when: {solved_when(success)}")
    lines.append(f"run folder: {run_dir} (full log: train.log)")
    return lines
