"""Import layering of the project, read statically with ``ast`` (nothing is imported).

Layers, bottom to top: ``params`` <- ``robots`` <- ``tasks`` <- ``learners`` <- ``runs`` <-
``adapters`` and ``sweeps`` (one floor, neither importing the other) <- the entry points (``train.py``, ``compare.py``, ``bench/*.py``, the Hydra plugins
``hydra_plugins/``). A module imports from its own
layer or lower ones only; project modules form no import cycle; the packages neither
import an entry point nor edit ``sys.path``. Every import counts, also one inside a
function (it runs the first time that function does).
"""

from __future__ import annotations

import ast
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("params", "robots", "tasks", "learners", "runs", "adapters", "sweeps")
ENTRY_POINTS = ("train", "compare", "bench", "hydra_plugins")
LAYER = {"params": 0, "robots": 1, "tasks": 2, "learners": 3, "runs": 4, "adapters": 5, "sweeps": 5, "train": 6,
         "compare": 6, "bench": 6, "hydra_plugins": 6}
LIST_EDITS = {"insert", "append", "extend", "remove", "pop", "clear", "reverse", "sort"}


@dataclass(frozen=True)
class Import:
    """One import statement's target: ``name`` as written (made absolute), ``target`` the
    project module it loads (``None`` for a module outside the project)."""

    module: str
    path: str
    line: int
    name: str
    target: str | None


def project_modules(root: Path) -> dict[str, Path]:
    """Dotted module name -> file, for every ``.py`` of the packages and the entry points."""
    modules = {}
    for package in (*PACKAGES, "hydra_plugins"):
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    for name in ("train", "compare"):
        if (root / f"{name}.py").is_file():
            modules[name] = root / f"{name}.py"
    for path in sorted((root / "bench").glob("*.py")):
        modules[f"bench.{path.stem}"] = path
    return modules


def _resolve(name: str, modules: dict[str, Path]) -> str | None:
    """The longest prefix of ``name`` that is a project module, else ``None``."""
    parts = name.split(".")
    for n in range(len(parts), 0, -1):
        if ".".join(parts[:n]) in modules:
            return ".".join(parts[:n])
    return None


def _absolute(module: str, is_package: bool, node: ast.ImportFrom) -> str:
    """The absolute dotted name a ``from`` import (relative or not) names."""
    if not node.level:
        return node.module or ""
    base = module.split(".") if is_package else module.split(".")[:-1]
    base = base[: len(base) - (node.level - 1)]
    return ".".join(base + ([node.module] if node.module else []))


def _sibling_script(module: str, name: str, modules: dict[str, Path]) -> str:
    """``bench/*.py`` run as scripts import each other by bare name (``from sweep import``)."""
    top = name.split(".")[0]
    if module.startswith("bench.") and top not in LAYER and f"bench.{top}" in modules:
        return f"bench.{name}"
    return name


def imports(root: Path) -> list[Import]:
    """Every import (at any depth) of every project module, project targets resolved."""
    modules = project_modules(root)
    found = []
    for module, path in modules.items():
        rel = path.relative_to(root).as_posix()
        is_package = path.name == "__init__.py"
        tree = ast.parse(path.read_text(), filename=str(path))
        for node in sorted((n for n in ast.walk(tree) if isinstance(n, (ast.Import, ast.ImportFrom))),
                           key=lambda n: (n.lineno, n.col_offset)):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = _absolute(module, is_package, node)
                # ``from a import b`` loads the submodule ``a.b`` when there is one.
                names = [f"{base}.{a.name}" if f"{base}.{a.name}" in modules else base for a in node.names]
            for name in dict.fromkeys(_sibling_script(module, n, modules) for n in names):
                found.append(Import(module, rel, node.lineno, name, _resolve(name, modules)))
    return found


def _layer(module: str) -> int:
    return LAYER[module.split(".")[0]]


def upward_imports(root: Path) -> list[str]:
    """``"<file> imports <module> (<layer> is above <layer>)"`` for each import of a higher layer."""
    return list(dict.fromkeys(
        f"{i.path} imports {i.target} ({i.target.split('.')[0]} is above {i.module.split('.')[0]})"
        for i in imports(root) if i.target and _layer(i.target) > _layer(i.module)))


def import_graph(root: Path) -> dict[str, set[str]]:
    """Project module -> the project modules it imports (self-imports left out)."""
    graph = {module: set() for module in project_modules(root)}
    for i in imports(root):
        if i.target and i.target != i.module:
            graph[i.module].add(i.target)
    return graph


def import_cycles(root: Path) -> list[str]:
    """One cycle path (``"a -> b -> a"``) per group of mutually importing modules (each
    strongly connected component of the import graph with two or more modules)."""
    graph = import_graph(root)
    index, low, stack, on_stack, components = {}, {}, [], set(), []

    def connect(v: str) -> None:  # Tarjan's algorithm
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                connect(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = set()
            while v not in component:
                component.add(stack.pop())
            on_stack.difference_update(component)
            components.append(component)

    for v in sorted(graph):
        if v not in index:
            connect(v)
    return [" -> ".join(_cycle_through(graph, sorted(c)[0], c)) for c in components if len(c) > 1]


def _cycle_through(graph: dict[str, set[str]], start: str, component: set[str]) -> list[str]:
    """The shortest path ``start -> ... -> start`` inside ``component`` (breadth first)."""
    paths, seen = [[start]], {start}
    while paths:
        path = paths.pop(0)
        for w in sorted(graph[path[-1]] & component):
            if w == start:
                return path + [start]
            if w not in seen:
                seen.add(w)
                paths.append(path + [w])
    raise AssertionError(f"no cycle through {start}")


def entry_point_imports(root: Path) -> list[str]:
    """``"<file>:<line> imports <name>"`` for each package module importing an entry point."""
    return [f"{i.path}:{i.line} imports {i.name}" for i in imports(root)
            if i.module.split(".")[0] in PACKAGES and i.name.split(".")[0] in ENTRY_POINTS]


def _is_sys_path(node: ast.AST) -> bool:
    return (isinstance(node, ast.Attribute) and node.attr == "path"
            and isinstance(node.value, ast.Name) and node.value.id == "sys")


def sys_path_edits(root: Path) -> list[str]:
    """``"<file>:<line> edits sys.path"`` for each package module that changes ``sys.path``:
    a list method (``insert``, ``append``, ...), an assignment (also augmented or to an item)."""
    found = []
    for module, path in project_modules(root).items():
        if module.split(".")[0] not in PACKAGES:
            continue
        for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
            called = (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
                      and node.func.attr in LIST_EDITS and _is_sys_path(node.func.value))
            targets = (node.targets if isinstance(node, ast.Assign)
                       else [node.target] if isinstance(node, (ast.AugAssign, ast.AnnAssign)) else [])
            assigned = any(_is_sys_path(t.value if isinstance(t, ast.Subscript) else t) for t in targets)
            if called or assigned:
                found.append(f"{path.relative_to(root).as_posix()}:{node.lineno} edits sys.path")
    return found


def _listing(problems: list[str]) -> str:
    return "\n  " + "\n  ".join(problems)


def test_no_upward_imports():
    problems = upward_imports(ROOT)
    assert not problems, ("imports of a higher layer (params <- robots <- tasks <- learners <- runs <- sweeps <- "
                          "entry points):"
                          + _listing(problems))


def test_no_import_cycles():
    problems = import_cycles(ROOT)
    assert not problems, f"import cycles between project modules:{_listing(problems)}"


def test_packages_import_no_entry_point():
    problems = entry_point_imports(ROOT)
    assert not problems, f"package modules importing train, compare or bench:{_listing(problems)}"


def test_packages_leave_sys_path_alone():
    problems = sys_path_edits(ROOT)
    assert not problems, f"package modules editing sys.path:{_listing(problems)}"


def test_checks_catch_what_they_guard(tmp_path):
    """A small synthetic project with one of each violation; a clean one with none."""
    files = {
        "params/__init__.py": "import math\n",
        "robots/__init__.py": "",
        "robots/cube.py": "import sys\nfrom tasks.base import Task\nsys.path.insert(0, '.')\n",
        "tasks/__init__.py": "import robots\n",
        "tasks/base.py": "from params import finite\nfrom robots import cube\nclass Task: ...\n",
        "tasks/a.py": "from .b import f\n",
        "tasks/b.py": "def f():\n    from . import a\n",
        "learners/__init__.py": "",
        "learners/video.py": "import sys\n\ndef g():\n    sys.path = ['.']\n    import train\n",
        "runs/__init__.py": "",
        "runs/run.py": "from sweeps.tuning import TrialLink\n",
        "sweeps/__init__.py": "",
        "sweeps/tuning.py": "from runs import run\n",
        "train.py": "from learners import video\n",
        "bench/sweep.py": "import sys\nsys.path.append('..')\nfrom learners.video import g\n",
        "bench/x.py": "from sweep import run\n",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    assert upward_imports(tmp_path) == [
        "robots/cube.py imports tasks.base (tasks is above robots)",
        "learners/video.py imports train (train is above learners)",
        "runs/run.py imports sweeps.tuning (sweeps is above runs)",
    ]
    assert sorted(import_cycles(tmp_path)) == [
        "learners.video -> train -> learners.video",
        "robots.cube -> tasks.base -> robots.cube",
        "runs.run -> sweeps.tuning -> runs.run",
        "tasks.a -> tasks.b -> tasks.a",
    ]
    assert entry_point_imports(tmp_path) == ["learners/video.py:5 imports train"]
    assert sys_path_edits(tmp_path) == ["robots/cube.py:3 edits sys.path", "learners/video.py:4 edits sys.path"]
    assert import_graph(tmp_path)["bench.x"] == {"bench.sweep"}

    for name in ("robots/cube.py", "tasks/b.py", "learners/video.py", "runs/run.py"):
        (tmp_path / name).write_text("import params\n")
    assert (upward_imports(tmp_path), import_cycles(tmp_path), entry_point_imports(tmp_path),
            sys_path_edits(tmp_path)) == ([], [], [], [])


def test_a_run_loads_only_what_it_uses_and_the_docs_quote_the_count():
    """``bench/first_step_path.py robot=cube learner=dqn`` (a fresh interpreter): a plain dqn
    run reaches its first env step without the sweeps' modules, the plot and video modules
    or Rainbow's parts, and docs/concepts.md quotes the tool's own count of files and calls."""
    import os
    import re
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "bench/first_step_path.py", "robot=cube", "learner=dqn"], cwd=ROOT,
                          capture_output=True, text=True, timeout=600, env={**os.environ, "MUJOCO_GL": "egl"})
    found = re.search(r"FIRST_STEP_PATH files=(\d+) calls_across_files=(\d+)", proc.stdout)
    assert found, proc.stdout[-2000:] + proc.stderr[-2000:]
    files = set(proc.stdout.split())
    unused = {"sweeps/tuning.py", "sweeps/seed_batch.py", "sweeps/optuna_sweep.py", "sweeps/state.py",
              "runs/plot.py", "runs/video.py", "learners/nstep.py", "learners/priority.py",
              "learners/distributional.py", "learners/qlearn.py"}
    assert not unused & files, sorted(unused & files)
    docs = " ".join((ROOT / "docs" / "concepts.md").read_text().split())
    assert f"passes through {found[1]} project files and {found[2]} calls" in docs, found.group(0)
