"""The documentation's generated tables: parameters, made from the declarations
(:mod:`params.declare`; ``docs/reference/parameters.md``), what there is to pick
(:mod:`tasks.catalog`; ``docs/getting-started.md``), and the names of the numbers a run
reports (:mod:`runs.summary`; ``docs/solved.md``).

    python -m readme_tables            # prints the tables
    python -m readme_tables --write    # rewrites them in their pages between their markers,
                                       # and params/declared.json (the declarations as data)

One parameter table per class a config in ``conf/robot``, ``conf/task`` or
``conf/learner`` names (and the exploration schedules the learners use), so a
parameter's meaning, default and range are written once, in its class.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

from hydra.utils import get_object
from omegaconf import OmegaConf

from params.declare import DECLARED, declaration_record, specs, table
from tasks import catalog
from adapters.gym_env import env_id
from runs.summary import MeasureKeys
from tasks.base import Task

BEGIN, END = "<!-- parameter tables: python -m readme_tables --write -->", "<!-- end of parameter tables -->"
DISCOVERY_BEGIN = "<!-- discovery tables: python -m readme_tables --write -->"
DISCOVERY_END = "<!-- end of discovery tables -->"
NAMES_BEGIN = "<!-- names table: python -m readme_tables --write -->"
NAMES_END = "<!-- end of names table -->"


def _targets(node, key: str):
    """``(config key, class path)`` of a config node and of its nested ``_target_`` nodes."""
    if isinstance(node, dict):
        if isinstance(node.get("_target_"), str):
            yield key, node["_target_"]
        for k, v in node.items():
            if isinstance(v, dict):
                yield from _targets(v, f"{key}.{k}")


def classes() -> dict[str, tuple[str, list[str]]]:
    """Class path -> (config key, the config files naming it), in config order."""
    found: dict[str, tuple[str, list[str]]] = {"runs.settings.RunSettings": ("", ["config.yaml"])}
    for group in catalog.GROUPS:
        for path in sorted((catalog.conf_dir() / group).glob("*.yaml")):
            node = OmegaConf.to_container(OmegaConf.load(path))
            node = node.get(group, node) if group == "robot" else node
            for sub_key, target in _targets(node, group):
                found.setdefault(target, (sub_key, []))[1].append(f"{group}/{path.name}")
    return found


def tables() -> str:
    """Every declared class's table under a heading naming its config key and files."""
    parts = []
    for target, (key, files) in classes().items():
        cls = get_object(target)
        if not (dataclasses.is_dataclass(cls) and specs(cls)):
            continue
        doc = (cls.__doc__ or "").strip().splitlines()[0]
        where = f"`{key}`" if key else "top level"
        parts.append(f"#### {where}: `{target}` ({', '.join(f'`conf/{f}`' for f in files)})\n\n"
                     f"{doc}\n\n{table(cls)}\n")
    return "\n".join(parts)


def declarations() -> str:
    """``params/declared.json``: every declared class's parameters, read back without
    importing the class (:func:`params.declare.declared`)."""
    out = {}
    for target in classes():
        cls = get_object(target)
        if dataclasses.is_dataclass(cls) and specs(cls):
            out[target] = declaration_record(cls)
    return json.dumps(out, indent=1, sort_keys=True) + "\n"


def blocks() -> dict[tuple[str, str], str]:
    """(begin marker, end marker) -> what goes between them in the README."""
    return {(BEGIN, END): tables(), (DISCOVERY_BEGIN, DISCOVERY_END): discovery_tables(),
            (NAMES_BEGIN, NAMES_END): names_table()}


def _row(*cells: str) -> str:
    return "| " + " | ".join(cells) + " |"


def _codes(items) -> str:
    return ", ".join(f"`{x}`" for x in items) or "none"


def _solved(task: Task) -> str:
    s = task.success
    judged = "greedy evaluation" if s.judge == "greedy" else f"last {s.window} training episodes"
    return f"{s.describe()} ({judged})"


def discovery_tables() -> str:
    """Markdown tables of the robots, the tasks and the learners."""
    fits = {(r, t): catalog.built(r, t) for r in catalog.robot_names() for t in catalog.names("task")}
    # A pair with a robot's file and a task's file (conf/tuned/<robot>_<task>_<learner>) counts once.
    tuned = sorted(set(pair for pair in catalog.tuned_pairs().values() if pair))  # each list reads alphabetically
    return "\n\n".join((_robots(fits, tuned), _tasks(fits), _learners(tuned))) + "\n"


def names_table() -> str:
    """The numbers a run reports, by their summary.json names (:class:`runs.summary.MeasureKeys`,
    with ``<measure>`` and ``<window>`` for the task's), and what each is."""
    keys = MeasureKeys("<measure>", "<window>")  # type: ignore[arg-type]  # the patterns, not a task's
    rows = [(f"`{name}`", meaning.replace("<measure>", "`<measure>`").replace("<window>", "`<window>`"))
            for name, meaning in keys.meanings().items()]
    return _table("The numbers a run reports, by the names summary.json, the verdict, the loggers' `run/*` "
                  "scalars, the comparison and the tuning objective give them (`<measure>`: the task's "
                  "measure, `<window>`: its window; e.g. `greedy_distance_walked`, `train_length_last100`):",
                  ("name", "what"), rows) + "\n"


def _table(intro: str, header: tuple[str, ...], rows: list[tuple[str, ...]]) -> str:
    return "\n".join([intro, "", _row(*header), _row(*["---"] * len(header)),
                      *(_row(*row) for row in rows)])


def _robots(fits: dict, tuned: list[tuple[str, str]]) -> str:
    rows = []
    for r in catalog.robot_names():
        default = catalog.default_task(r)
        rows.append((f"`{r}`", catalog.summary(catalog.conf_dir() / "robot" / f"{r}.yaml"), f"`{default}`",
                     _codes(t for t in catalog.names("task") if fits[r, t]),
                     _codes(lr for rr, lr in tuned if rr == r), f"`{env_id(r, default)}`"))
    return _table("Robots (`robot=`); `robot=` alone picks its default task:",
                  ("robot", "what", "default task", "tasks that fit", "tuned learners",
                   "Gymnasium id"), rows)


def _tasks(fits: dict) -> str:
    rows = []
    for t in catalog.names("task"):
        fit = [r for r in catalog.robot_names() if fits[r, t]]
        rows.append((f"`{t}`", catalog.summary(catalog.conf_dir() / "task" / f"{t}.yaml"), _codes(fit),
                     _solved(fits[fit[0], t]) if fit else "-"))
    return _table("Tasks (`task=`):", ("task", "what", "robots it fits", "solved when"), rows)


def _learners(tuned: list[tuple[str, str]]) -> str:
    rows = []
    for lr in catalog.names("learner"):
        path = catalog.conf_dir() / "learner" / f"{lr}.yaml"
        rows.append((f"`{lr}`", f"`{OmegaConf.load(path)._target_}`", catalog.summary(path),
                     _codes(r for r, ll in tuned if ll == lr)))
    return _table("Learners (`learner=`); a tuned pair's file is "
                  "`conf/tuned/<robot>_<learner>.yaml`:",
                  ("learner", "class", "what", "tuned for robots"), rows)


ROOT = Path(__file__).resolve().parent
PAGES = {BEGIN: ROOT / "docs" / "reference" / "parameters.md", DISCOVERY_BEGIN: ROOT / "docs" / "getting-started.md",
         NAMES_BEGIN: ROOT / "docs" / "solved.md"}  # where each block lives


def rewrite(page: Path, bodies: dict[tuple[str, str], str] | None = None) -> bool:
    """Puts each of ``bodies`` (``(begin, end)`` markers -> text; default :func:`blocks`)
    between its markers in ``page``; whether it changed."""
    text = new = page.read_text()
    for (begin, end), body in (blocks() if bodies is None else bodies).items():
        head, sep, rest = new.partition(begin)
        _, sep2, tail = rest.partition(end)
        if not (sep and sep2):
            raise SystemExit(f"{page} has no {begin} ... {end} block")
        new = f"{head}{begin}\n\n{body}\n{end}{tail}"
    page.write_text(new)
    return new != text


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="rewrite the tables in their pages")
    args = parser.parse_args(argv)
    if not args.write:
        sys.stdout.write("\n".join(blocks().values()))
        return
    found = blocks()  # made once: the discovery tables build every robot's tasks
    for begin, page in PAGES.items():
        changed = rewrite(page, {markers: body for markers, body in found.items() if markers[0] == begin})
        print(f"{page.relative_to(ROOT)}: {'updated' if changed else 'already up to date'}")
    text = declarations()
    changed = not DECLARED.is_file() or DECLARED.read_text() != text
    DECLARED.write_text(text)
    print(f"{DECLARED.relative_to(ROOT)}: {'updated' if changed else 'already up to date'}")


if __name__ == "__main__":
    main()
