"""Shape of the code, read statically (``ast`` and ``tokenize``; nothing is imported).

- Every function of ``robots/`` and ``tasks/`` (methods and nested functions too) is
  under ``MAX_FUNCTION_LINES`` lines, from its ``def`` line to its last line
  (decorators left out, docstring and nested functions counted).
- No two constructors (``__init__``/``__post_init__`` bodies) of the packages share
  ``MIN_SHARED_LINES`` or more consecutive lines of the same shape: each line with its
  identifiers, strings and numbers replaced by placeholders (keywords and punctuation
  kept), blank and comment lines left out. Copy-pasted set-up belongs in one helper.
"""

from __future__ import annotations

import ast
import io
import keyword
import tokenize
from collections import defaultdict
from itertools import combinations
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_FUNCTION_LINES = 40
MIN_SHARED_LINES = 6
CONSTRUCTORS = ("__init__", "__post_init__")


def functions(path: Path) -> list[tuple[str, ast.FunctionDef | ast.AsyncFunctionDef]]:
    """``(qualified name, node)`` for every function defined in ``path``, at any depth."""
    found = []

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
                name = f"{prefix}{child.name}"
                if not isinstance(child, ast.ClassDef):
                    found.append((name, child))
                visit(child, f"{name}.")
            else:
                visit(child, prefix)

    visit(ast.parse(path.read_text(), filename=str(path)), "")
    return found


def long_functions(root: Path, folders=("robots", "tasks"), limit=MAX_FUNCTION_LINES) -> list[str]:
    """``"<file>:<line> <name> (<n> lines)"`` for each function of ``limit`` lines or more,
    longest first."""
    found = []
    for folder in folders:
        for path in sorted((root / folder).rglob("*.py")):
            for name, node in functions(path):
                length = node.end_lineno - node.lineno + 1
                if length >= limit:
                    where = f"{path.relative_to(root).as_posix()}:{node.lineno}"
                    found.append((-length, f"{where} {name} ({length} lines)"))
    return [text for _, text in sorted(found)]


def line_shapes(source: str) -> dict[int, str]:
    """Line number -> the shape of the code starting on it: identifiers become ``N``,
    strings ``S``, numbers ``0``; keywords and punctuation stay. Lines with no code
    (blank, comment only, inside a multi-line string) have no entry."""
    shapes = defaultdict(list)
    for tok in tokenize.generate_tokens(io.StringIO(source).readline):
        if tok.type == tokenize.NAME:
            text = tok.string if keyword.iskeyword(tok.string) else "N"
        elif tok.type == tokenize.STRING:
            text = "S"
        elif tok.type == tokenize.NUMBER:
            text = "0"
        elif tok.type == tokenize.OP:
            text = tok.string
        else:
            continue
        shapes[tok.start[0]].append(text)
    return {line: " ".join(texts) for line, texts in shapes.items()}


def constructors(root: Path, folders=("robots", "tasks", "learners", "params")) -> list[tuple[str, list]]:
    """``("<file>:<line> <name>", [(line, shape), ...])`` for the body of every constructor."""
    found = []
    for folder in folders:
        for path in sorted((root / folder).rglob("*.py")):
            shapes = line_shapes(path.read_text())
            for name, node in functions(path):
                if node.name in CONSTRUCTORS:
                    body = range(node.body[0].lineno, node.end_lineno + 1)
                    found.append((f"{path.relative_to(root).as_posix()}:{node.lineno} {name}",
                                  [(line, shapes[line]) for line in body if line in shapes]))
    return found


def shared_runs(ctors: list[tuple[str, list[tuple[int, str]]]], least=MIN_SHARED_LINES) -> list[str]:
    """For each two constructors (or two places in one) sharing ``least`` or more consecutive
    lines of the same shape, their longest shared run:
    ``"<ctor> (line <a>) and <ctor> (line <b>) share <n> lines"``."""
    starts = defaultdict(list)  # the shapes of ``least`` lines -> (constructor, index) starting them
    for c, (_, lines) in enumerate(ctors):
        shapes = [shape for _, shape in lines]
        for i in range(len(shapes) - least + 1):
            starts[tuple(shapes[i:i + least])].append((c, i))
    best = {}
    for places in starts.values():
        for (a, i), (b, j) in combinations(places, 2):
            if a == b and j - i < least:
                continue  # a run overlapping itself
            run_a, run_b = ctors[a][1], ctors[b][1]
            n = least
            while (i + n < len(run_a) and j + n < len(run_b) and run_a[i + n][1] == run_b[j + n][1]
                   and (a != b or i + n < j)):
                n += 1
            if n > best.get((a, b), (0,))[0]:
                best[(a, b)] = (n, run_a[i][0], run_b[j][0])
    return [f"{ctors[a][0]} (line {la}) and {ctors[b][0]} (line {lb}) share {n} lines"
            for (a, b), (n, la, lb) in sorted(best.items())]


def test_functions_of_robots_and_tasks_are_short():
    problems = long_functions(ROOT)
    assert not problems, (f"functions of {MAX_FUNCTION_LINES} lines or more in robots/ and tasks/:\n  "
                          + "\n  ".join(problems))


def test_constructors_share_no_copied_block():
    problems = shared_runs(constructors(ROOT))
    assert not problems, (f"constructors sharing {MIN_SHARED_LINES}+ consecutive lines of the same shape:\n  "
                          + "\n  ".join(problems))


def test_checks_catch_what_they_guard(tmp_path):
    """Synthetic sources: a 42-line method (decorated, with a docstring and a nested
    function) and a short one; two constructors sharing a 6-line block of the same shape
    under other names and numbers; one constructor repeating a 6-line block of its own."""
    block = "self.{0} = float({0})\nif self.{0} < {1}:\n    raise ValueError('{0}')\n"
    (tmp_path / "robots").mkdir()
    (tmp_path / "robots" / "a.py").write_text(
        "class A:\n"
        "    @property\n"
        "    def long(self):\n"  # line 3
        "        '''Doc.'''\n"
        + "        x = 1\n" * 30 + "\n        # comment\n"
        "        def inner():\n" + "            y = 2\n" * 6 + "        return x\n"  # line 44
        "\n"
        "    def __init__(self, mass, size):\n"  # line 46
        "        # set up\n"
        + indent(block.format("mass", 0) + "\n" + block.format("size", 2), 8)  # lines 48-54
        + "def short():\n    return 1\n")
    (tmp_path / "tasks").mkdir()
    (tmp_path / "tasks" / "b.py").write_text(
        "from dataclasses import dataclass\n"
        "@dataclass\n"
        "class B:\n"
        "    def __post_init__(self):\n"  # line 4
        + indent('"""Checks."""\n' + block.format("gain", 1.5) + block.format("step", 3), 8)  # lines 5-11
        + "class C:\n"
        "    def __init__(self, items):\n"  # line 13
        + indent("items.append(1)\n" * 6 + "self.items = items\n" + "items.append(2)\n" * 6, 8))

    assert long_functions(tmp_path) == ["robots/a.py:3 A.long (42 lines)"]
    assert long_functions(tmp_path, limit=43) == []
    assert shared_runs(constructors(tmp_path)) == [
        "robots/a.py:46 A.__init__ (line 48) and tasks/b.py:4 B.__post_init__ (line 6) share 6 lines",
        "tasks/b.py:13 C.__init__ (line 14) and tasks/b.py:13 C.__init__ (line 21) share 6 lines",
    ]
    assert shared_runs(constructors(tmp_path), least=7) == []


def indent(text: str, spaces: int) -> str:
    """``text`` with each non-blank line indented by ``spaces``."""
    return "".join(" " * spaces + line if line.strip() else line for line in text.splitlines(True))
