"""The README's generated tables: parameters, made from the declarations
(:mod:`params.declare`), and what there is to pick (:mod:`learners.discovery`).

    python -m learners.doc            # prints the tables
    python -m learners.doc --write    # rewrites them in README.md between their markers

One parameter table per class a config in ``conf/robot``, ``conf/task`` or
``conf/learner`` names (and the exploration schedules the learners use), so a
parameter's meaning, default and range are written once, in its class.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

from hydra.utils import get_object
from omegaconf import OmegaConf

from learners import discovery
from params.declare import specs, table
from tasks.factory import conf_dir

BEGIN, END = "<!-- parameter tables: python -m learners.doc --write -->", "<!-- end of parameter tables -->"
DISCOVERY_BEGIN = "<!-- discovery tables: python -m learners.doc --write -->"
DISCOVERY_END = "<!-- end of discovery tables -->"
GROUPS = (("robot", "robot"), ("task", "task"), ("learner", "learner"))


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
    found: dict[str, tuple[str, list[str]]] = {"learners.settings.RunSettings": ("", ["config.yaml"])}
    for folder, key in GROUPS:
        for path in sorted((conf_dir() / folder).glob("*.yaml")):
            node = OmegaConf.to_container(OmegaConf.load(path))
            node = node.get(key, node) if folder == "robot" else node
            for sub_key, target in _targets(node, key):
                found.setdefault(target, (sub_key, []))[1].append(f"{folder}/{path.name}")
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


def blocks() -> dict[tuple[str, str], str]:
    """(begin marker, end marker) -> what goes between them in the README."""
    return {(BEGIN, END): tables(), (DISCOVERY_BEGIN, DISCOVERY_END): discovery.tables()}


def rewrite(readme: Path) -> bool:
    """Puts each of :func:`blocks` between its markers in ``readme``; whether it changed."""
    text = new = readme.read_text()
    for (begin, end), body in blocks().items():
        head, sep, rest = new.partition(begin)
        _, sep2, tail = rest.partition(end)
        if not (sep and sep2):
            raise SystemExit(f"{readme} has no {begin} ... {end} block")
        new = f"{head}{begin}\n\n{body}\n{end}{tail}"
    readme.write_text(new)
    return new != text


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="rewrite the tables in README.md")
    parser.add_argument("--readme", type=Path, default=Path("README.md"))
    args = parser.parse_args(argv)
    if not args.write:
        sys.stdout.write("\n".join(blocks().values()))
        return
    print(f"{args.readme}: {'updated' if rewrite(args.readme) else 'already up to date'}")


if __name__ == "__main__":
    main()
