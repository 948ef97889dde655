"""Parameters are declared once (params/declare.py): the YAML files name only declared
parameters and agree with the declared defaults, the README's tables are made from
the declarations, and a declaration checks what it says."""

from __future__ import annotations

import dataclasses
import functools
import math
from pathlib import Path

import pytest
from hydra.utils import get_object
from omegaconf import OmegaConf

import readme_tables as doc
from params import ConfigError
from params.declare import check_values, param, specs, table
from tasks.catalog import conf_dir

ROOT = Path(__file__).resolve().parents[1]


def _base_configs():
    """(file, node) of every config that names a class itself (not a variant of another)."""
    for folder in ("robot", "task", "learner"):
        for path in sorted((conf_dir() / folder).glob("*.yaml")):
            node = OmegaConf.to_container(OmegaConf.load(path))
            node = node.get("robot", node) if folder == "robot" else node
            if "_target_" in node:
                yield f"{folder}/{path.name}", node


CONFIGS = list(_base_configs())


def test_top_level_keys_are_declared_with_the_yaml_values():
    from runs.settings import RunSettings

    top = OmegaConf.to_container(OmegaConf.load(conf_dir() / "config.yaml"))
    for spec in specs(RunSettings):
        assert spec.name in top and _same(top[spec.name], spec.default), spec.name


@pytest.mark.parametrize("name, node", CONFIGS, ids=[c[0] for c in CONFIGS])
def test_every_yaml_key_is_declared(name, node):
    cls = get_object(node["_target_"])
    declared = {s.name for s in specs(cls)}
    assert declared, f"{node['_target_']} declares no parameters"
    unknown = sorted(k for k in node if not k.startswith("_") and k not in declared and k != "defaults")
    assert not unknown, f"conf/{name} names undeclared parameters {unknown}"


def _same(a, b) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        return isinstance(a, (int, float)) and isinstance(b, (int, float)) and math.isclose(a, b, rel_tol=1e-8)
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return a == b


def _defining_configs():
    """The config that is each class's own (its defaults are the code's defaults)."""
    own = {}
    for name, node in CONFIGS:
        own.setdefault(node["_target_"], (name, node))
    preferred = {"learners.dqn.DQN": "learner/dqn.yaml"}
    for target, file in preferred.items():
        own[target] = next(c for c in CONFIGS if c[0] == file)
    return sorted(own.values())


@pytest.mark.parametrize("name, node", _defining_configs(), ids=[c[0] for c in _defining_configs()])
def test_yaml_values_are_the_declared_defaults(name, node):
    """The class's own config holds the declared defaults (a default of null is the
    code's "derive it"; the YAML may spell the value out)."""
    for spec in specs(get_object(node["_target_"])):
        if spec.name in node and spec.default is not None and not spec.required:
            assert _same(node[spec.name], spec.default), (
                f"conf/{name}: {spec.name} is {node[spec.name]!r}, its declaration says {spec.default!r}")


def test_every_parameter_says_what_it_means():
    for target, _ in doc.classes().items():
        cls = get_object(target)
        if dataclasses.is_dataclass(cls):
            for spec in specs(cls):
                assert len(spec.doc) > 8, f"{target}.{spec.name} has no meaning"


def test_readme_tables_are_current():
    text = doc.PAGES[doc.BEGIN].read_text()
    block = text.partition(doc.BEGIN)[2].partition(doc.END)[0]
    assert block.strip() == doc.tables().strip(), "docs tables are stale: python -m readme_tables --write"


@functools.cache
def discovery() -> str:
    """The discovery tables (every robot x task pair built), once per worker."""
    return doc.discovery_tables()


def test_readme_discovery_tables_are_current():
    text = doc.PAGES[doc.DISCOVERY_BEGIN].read_text()
    block = text.partition(doc.DISCOVERY_BEGIN)[2].partition(doc.DISCOVERY_END)[0]
    assert block.strip() == discovery().strip(), \
        "docs discovery tables are stale: python -m readme_tables --write"


def test_readme_names_table_is_current():
    text = doc.PAGES[doc.NAMES_BEGIN].read_text()
    block = text.partition(doc.NAMES_BEGIN)[2].partition(doc.NAMES_END)[0]
    assert block.strip() == doc.names_table().strip(), "docs names table is stale: python -m readme_tables --write"
    assert "| `train_<measure>_last<window>` | the mean `<measure>` of the last `<window>` training episodes |" in block


def test_the_declarations_file_is_current_and_reads_back_as_the_classes():
    """params/declared.json: what the classes declare, read back to the same checks."""
    import params.declare as declare

    assert declare.DECLARED.read_text() == doc.declarations(), \
        "params/declared.json is stale: python -m readme_tables --write"
    for target in doc.classes():
        cls = get_object(target)
        if not (dataclasses.is_dataclass(cls) and specs(cls)):
            continue
        read = declare.declared(target)
        assert read is not None, target
        for mine, theirs in zip(read, specs(cls), strict=True):
            assert (mine.name, mine.doc, mine.range, mine.note, mine.required) == \
                   (theirs.name, theirs.doc, theirs.range, theirs.note, theirs.required)
            assert mine.allowed() == theirs.allowed(), (target, mine.name)
            assert declare.hint_text(mine.hint) == declare.hint_text(theirs.hint)


def test_a_declaration_whose_source_changed_is_not_used(tmp_path, monkeypatch):
    """An entry read from a file that has changed since is ignored: the class is asked."""
    import json

    import params.declare as declare

    record = json.loads(declare.DECLARED.read_text())
    target = "learners.qlearn.QLearn"
    assert declare.declared(target) is not None
    source = next(iter(record[target]["sources"]))
    record[target]["sources"][source] = "0" * 40
    monkeypatch.setattr(declare, "_DECLARED", record)
    assert declare.declared(target) is None
    assert declare.declared("robots.nowhere.Robot") is None


def test_a_refused_value_and_help_answer_without_torch_or_mujoco():
    """train.py's checks come before its heavy imports (bench/answers.py times them)."""
    import subprocess
    import sys

    probe = ("import runpy, sys\nsys.argv = ['train.py', *sys.argv[1:]]\ntry:\n"
             "    runpy.run_path('train.py', run_name='__main__')\nexcept SystemExit:\n    pass\n"
             "print('HEAVY', sorted(m for m in ('torch', 'mujoco', 'torchrl', 'tensordict', 'dm_control') "
             "if m in sys.modules))")
    for args in (["learner=dqn", "learner.lr=-1"], ["robot=cube", "learner.alpha=2"], ["num_envs=0"],
                 ["robot=cube", "task=maze"], ["--help"]):
        proc = subprocess.run([sys.executable, "-c", probe, *args], cwd=ROOT, capture_output=True, text=True)
        assert "HEAVY []" in proc.stdout, (args, proc.stdout[-500:], proc.stderr[-500:])
        if args != ["--help"]:
            assert proc.stderr.strip().startswith("error: ") and len(proc.stderr.strip().splitlines()) == 1


def test_write_fills_every_block_and_says_when_nothing_changed(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text(f"a\n{doc.BEGIN}\nstale text\n{doc.END}\nb\n{doc.DISCOVERY_BEGIN}\n{doc.DISCOVERY_END}\n"
                      f"{doc.NAMES_BEGIN}\n{doc.NAMES_END}\nc\n")
    bodies = {(doc.BEGIN, doc.END): doc.tables(), (doc.DISCOVERY_BEGIN, doc.DISCOVERY_END): discovery(),
              (doc.NAMES_BEGIN, doc.NAMES_END): doc.names_table()}  # doc.blocks(), the pairs built once
    assert doc.rewrite(readme, bodies) and not doc.rewrite(readme, bodies)
    text = readme.read_text()
    assert "stale text" not in text and text.startswith("a\n") and text.endswith("c\n")
    assert "| `turtlebot` |" in text and "| `learner.gamma` |" not in text.partition(doc.END)[2]
    readme.write_text("no markers")
    with pytest.raises(SystemExit, match="has no <!-- parameter tables"):
        doc.rewrite(readme, bodies)


@dataclasses.dataclass
class Example:
    """An example."""

    rate: float = param(0.5, "a rate", gt=0, le=1)
    count: int = param(3, "a count", ge=1)
    kind: str = param("a", "a kind", choices=("a", "b"))
    limit: float = param(0.0, "a limit", ge=0, note="0 = none")


@pytest.mark.parametrize("values, message", [
    ({"rate": 0}, "x.rate must be a finite number in (0, 1]; got 0"),
    ({"rate": math.nan}, "x.rate must be a finite number in (0, 1]; got nan"),
    ({"count": 2.5}, "x.count must be an integer >= 1; got 2.5"),
    ({"count": True}, "x.count must be an integer >= 1; got True"),
    ({"kind": "c"}, "x.kind must be one of a, b; got 'c'"),
    ({"limit": -1}, "x.limit must be a finite number >= 0 (0 = none); got -1"),
    ({"rte": 1}, "x.rte is not a parameter of"),
])
def test_a_declaration_checks_what_it_says(values, message):
    with pytest.raises(ConfigError) as err:
        check_values(Example, values, "x")
    assert str(err.value).startswith(message), str(err.value)


def test_valid_values_pass_and_the_table_shows_the_declaration():
    check_values(Example, {"rate": 1, "count": 4.0, "kind": "b", "limit": 2}, "x")
    assert "| `limit` | 0 | a finite number >= 0 (0 = none) | a limit |" in table(Example)


# -- every setting the Parameters table lists is settable without '+' (issue 37) ------------
def _hydra_value(value) -> str:
    """``value`` in Hydra's override grammar."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return f"'{value}'"
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(map(_hydra_value, value)) + "]"
    return "{" + ",".join(f"{k}:{_hydra_value(v)}" for k, v in value.items()) + "}"


def _picks(group_file: str) -> dict:
    """robot / task / learner that compose the config file ``<group>/<name>.yaml``."""
    from tasks import catalog

    group, name = group_file.removesuffix(".yaml").split("/")
    if group == "robot":
        return {"robot": name}
    if group == "learner":
        return {"robot": "cartpole", "learner": name}
    robot = next(r for r in catalog.robot_names() if catalog.built(r, name) is not None)
    return {"robot": robot, "task": name}


def test_every_setting_of_the_parameters_table_is_settable_without_a_plus():
    from hydra.utils import get_object

    from tasks import catalog

    refused = []
    for target, (key, files) in doc.classes().items():
        cls = get_object(target)
        if not specs(cls):
            continue
        for group_file in files[:1] if key == "" else files:
            picks = {} if key == "" else _picks(group_file)
            overrides = [f"{key + '.' if key else ''}{spec.name}={_hydra_value(spec.default)}"
                         for spec in specs(cls)
                         if not isinstance(spec.default, dataclasses._MISSING_TYPE)]  # required: every file gives it
            try:  # all of the file's settings in one command; one at a time to name a refused one
                catalog.compose(**picks, overrides=["~tuned", *overrides])  # the file itself
                continue
            except Exception:  # noqa: BLE001 - Hydra's refusal of a key it lacks
                pass
            for override in overrides:
                try:
                    catalog.compose(**picks, overrides=["~tuned", override])
                except Exception as err:  # noqa: BLE001 - as above
                    refused.append(f"{group_file} {override}: {str(err).splitlines()[0][:80]}")
    assert not refused, "\n".join(refused)
