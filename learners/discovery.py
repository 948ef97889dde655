"""What there is to pick, read from ``conf/``: robots, the tasks each fits, learners and the
tuned pairs; the README's "What there is" tables (``python -m learners.doc --write``).

A task fits a robot when it builds with it: each task's ``setup`` refuses a robot of
another class, so every robot is composed with every task (tuned files left out) and
what builds is kept. A description is the first sentence of the config file's header
comment.
"""

from __future__ import annotations

from pathlib import Path

from omegaconf import OmegaConf

from params import ConfigError
from tasks import factory
from tasks.base import Task
from tasks.gym_env import env_id


def names(group: str) -> list[str]:
    """The configs of ``conf/<group>/``, by name."""
    return sorted(p.stem for p in (factory.conf_dir() / group).glob("*.yaml"))


def summary(path: Path) -> str:
    """The first sentence of the header comment of a config file (``@package`` lines left out)."""
    words = []
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            break
        text = line.lstrip("#").strip()
        if not text.startswith("@"):
            words.append(text)
    header = " ".join(words)
    end = header.find(". ")
    return header if end < 0 else header[: end + 1]


def built(robot: str, task: str) -> Task | None:
    """``task`` built with ``robot`` (no tuned file), or ``None`` where it does not fit."""
    try:
        return factory.build_task(factory.compose(robot, task, overrides=["~tuned"]))
    except ConfigError:
        return None


def tuned_pairs() -> dict[str, tuple[str, str] | None]:
    """``conf/tuned/`` file name -> the ``(robot, learner)`` it tunes, ``None`` if it names
    no such pair (Hydra would never apply it)."""
    pairs = {f"{r}_{lr}": (r, lr) for r in factory.robot_names() for lr in names("learner")}
    return {stem: pairs.get(stem) for stem in names("tuned")}


def _row(*cells: str) -> str:
    return "| " + " | ".join(cells) + " |"


def _codes(items) -> str:
    return ", ".join(f"`{x}`" for x in items) or "none"


def _solved(task: Task) -> str:
    s = task.success
    judged = "greedy evaluation" if s.judge == "greedy" else f"last {s.window} training episodes"
    return f"{s.describe()} ({judged})"


def tables() -> str:
    """Markdown tables of the robots, the tasks and the learners."""
    fits = {(r, t): built(r, t) for r in factory.robot_names() for t in names("task")}
    tuned = [pair for pair in tuned_pairs().values() if pair]
    return "\n\n".join((_robots(fits, tuned), _tasks(fits), _learners(tuned))) + "\n"


def _table(intro: str, header: tuple[str, ...], rows: list[tuple[str, ...]]) -> str:
    return "\n".join([intro, "", _row(*header), _row(*["---"] * len(header)),
                      *(_row(*row) for row in rows)])


def _robots(fits: dict, tuned: list[tuple[str, str]]) -> str:
    rows = []
    for r in factory.robot_names():
        default = factory.default_task(r)
        rows.append((f"`{r}`", summary(factory.conf_dir() / "robot" / f"{r}.yaml"), f"`{default}`",
                     _codes(t for t in names("task") if fits[r, t]),
                     _codes(lr for rr, lr in tuned if rr == r), f"`{env_id(r, default)}`"))
    return _table("Robots (`robot=`); `robot=` alone picks its default task:",
                  ("robot", "what", "default task", "tasks that fit", "tuned learners",
                   "Gymnasium id"), rows)


def _tasks(fits: dict) -> str:
    rows = []
    for t in names("task"):
        fit = [r for r in factory.robot_names() if fits[r, t]]
        rows.append((f"`{t}`", summary(factory.conf_dir() / "task" / f"{t}.yaml"), _codes(fit),
                     _solved(fits[fit[0], t]) if fit else "-"))
    return _table("Tasks (`task=`):", ("task", "what", "robots it fits", "solved when"), rows)


def _learners(tuned: list[tuple[str, str]]) -> str:
    rows = []
    for lr in names("learner"):
        path = factory.conf_dir() / "learner" / f"{lr}.yaml"
        rows.append((f"`{lr}`", f"`{OmegaConf.load(path)._target_}`", summary(path),
                     _codes(r for r, ll in tuned if ll == lr)))
    return _table("Learners (`learner=`); a tuned pair's file is "
                  "`conf/tuned/<robot>_<learner>.yaml`:",
                  ("learner", "class", "what", "tuned for robots"), rows)
