"""The docs stay true: every ``train.py`` command in README.md and docs/ composes and builds
(robot, task, learner) as written, so a renamed key or value fails here, not the reader; the
quick start's own command trains end to end in tests/test_success.py.

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

from tests.test_validation import build, compose_cfg

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
COMMAND = re.compile(r"^ {4,}(?:\.venv/bin/)?python(?:3\.11)? (?:-m )?train(?:\.py)? (.*)$")
SKIP = ("<", "~/", "resume=", "checkpoint=", "--config-dir")


def commands() -> list[tuple[str, str]]:
    """``(where, arguments)`` of every documented train.py command."""
    found = []
    for page in PAGES:
        lines = page.read_text().splitlines()
        i = 0
        while i < len(lines):
            line = lines[i]
            while line.rstrip().endswith("\\") and i + 1 < len(lines):
                i += 1
                line = line.rstrip()[:-1] + " " + lines[i].strip()
            match = COMMAND.match(line.split(" # ")[0].split("  #")[0].rstrip())
            if match and not line.lstrip().startswith("$"):
                found.append((f"{page.relative_to(ROOT)}:{i + 1}", match.group(1)))
            i += 1
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
