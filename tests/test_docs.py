"""The docs stay true: every ``train.py`` command in README.md and docs/ composes and builds
(robot, task, learner) as written, so a renamed key or value fails here, not the reader; the
quick start's own command trains end to end in tests/test_success.py, and CI's last step
(tests/documented.py) runs every documented command on a small budget.

A command is taken from an indented code block (continued lines joined; its trailing
comment dropped). A sweep (``-m``) is checked at the first value of each swept key; keys of
Hydra's own node (``hydra/...``, ``hydra.*``: launchers, sweepers) are left to Hydra. Commands
with a placeholder (``<run>``), a folder of the reader's (``~/...``) or a run folder to
resume or evaluate are skipped.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest

from tests import documented
from tests.test_validation import build, compose_cfg

ROOT = Path(__file__).resolve().parents[1]
COMMAND = re.compile(r"^(?:\.venv/bin/)?python(?:3\.11)? (?:-m )?train(?:\.py)? (.*)$")
SKIP = ("<", "~/", "resume=", "checkpoint=", "--config-dir")


def commands() -> list[tuple[str, str]]:
    """``(where, arguments)`` of every documented train.py command (tests/documented.py finds
    them; a ``$`` command, shown with the refusal it gets, is left out)."""
    found = []
    for step in documented.steps():
        match = COMMAND.match(step.command) if not step.file and step.expect is None else None
        if match:
            found.append((step.where, match.group(1)))
    return found


def first_values(args: str) -> list[str] | None:
    """The overrides of one run of the command (None: skipped)."""
    if any(mark in args for mark in SKIP):
        return None
    overrides = []
    for arg in shlex.split(args):
        if arg == "-m" or arg.startswith(("hydra/", "hydra.")):
            continue
        key, sep, value = arg.partition("=")
        if sep and value.startswith("range("):
            value = re.match(r"range\((\d+)", value).group(1)
        elif sep and "," in value and not value.startswith(("[", "{")):
            value = value.split(",")[0]
        overrides.append(f"{key}{sep}{value}")
    return overrides


DOCUMENTED = [(where, first_values(args)) for where, args in commands() if first_values(args) is not None]


def test_the_docs_hold_the_commands_a_reader_needs():
    assert len(DOCUMENTED) >= 25
    assert sum(where.startswith("README.md") for where, _ in DOCUMENTED) >= 5


@pytest.mark.parametrize("where, overrides", DOCUMENTED, ids=[w for w, _ in DOCUMENTED])
def test_a_documented_command_builds(where, overrides):
    build(compose_cfg(*overrides))


def test_the_torchrl_tools_snippet_runs():
    """docs/gymnasium.md's block with TorchRL's Collector, StepCounter and RewardSum on the
    batched env runs as printed."""
    import os
    import subprocess
    import sys

    text = (ROOT / "docs" / "gymnasium.md").read_text()
    start = text.index("    from torchrl.collectors import Collector")
    lines = []
    for line in text[start:].splitlines():
        if line and not line.startswith("    "):
            break
        lines.append(line[4:])
    code = "\n".join(lines).strip() + "\n"
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")})
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.count("torch.Size([8, 100]) episodes ended:") == 2, proc.stdout


def test_every_documented_command_is_run_by_ci_or_says_why_not():
    """Each step tests/documented.py finds either runs (its placeholders are ones the runner
    fills, a benchmark gets small arguments) or is skipped with a reason; the tutorial's files
    are written before the commands that need them."""
    steps = documented.steps()
    reader = documented.Reader.__new__(documented.Reader)
    reader.runs, reader.sweep = [ROOT / "outputs" / "d" / "t_cartpole_dqn_1"], ROOT / "multirun" / "x"
    for step in steps:
        if step.file:
            assert step.command.strip(), f"{step.where}: no page shows {step.file}"
            continue
        if step.python:
            compile(shlex.split(step.command)[2], step.where, "exec")
            continue
        if any(mark in step.command for mark in documented.SKIP):
            continue
        command = documented.budgeted(reader.placed(step.command))
        assert "<" not in command.replace("<<", ""), f"{step.where}: a placeholder the runner cannot fill: {command}"
        assert not ("bench/" in command or "bench." in command) or any(
            mark in step.command for mark in documented.SMALL), f"{step.where}: a benchmark with no small arguments"
    wrote = [i for i, s in enumerate(steps) if s.file == "~/my_robots/robot/my_acrobot.yaml"]
    uses = [i for i, s in enumerate(steps) if "robot=my_acrobot" in s.command and not s.file]
    assert wrote and uses and wrote[0] < uses[0]
    installed = [s.command.split()[0] for s in steps if s.installed]  # run with a plain install, from HOME
    assert "mujoco-rl-train" in installed and "cp" in installed, installed
