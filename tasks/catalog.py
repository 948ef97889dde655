"""What there is to pick, read from ``conf/``: the config groups, robots, tasks, learners and
tuned files, and the run config Hydra composes from them.

    cfg = compose("cube", learner="dqn")                        # as train.py composes it
    env = make_env("turtlebot", "wall", ["task.min_range=0.4"])  # an env by names
    default_task("cube"), names("learner"), tuned_pairs(), tuned_layers("turtlebot", "wall", "dqn")

Tuned files come in two layers (``conf/config.yaml``'s defaults list): the robot's,
``conf/tuned/<robot>_<learner>.yaml``, then the task's on top of it,
``conf/tuned/<robot>_<task>_<learner>.yaml``; each applies where it exists. Hydra's ``~tuned``
removes one defaults entry: :func:`with_tuned_layers` makes it remove both, for the command
line (``train.py``) and for :func:`compose` alike.

The configs are found through the installed ``conf`` package, so this works from any
working directory and without an editable install. More config folders (a user's
``--config-dir ~/my_robots``, with ``robot/``, ``task/`` and models) join with
:func:`use_config_dirs`; ``conf/`` comes first, as in Hydra's search path. A robot's
relative ``model`` path is resolved against the folder its ``robot/<name>.yaml`` is
in (:func:`locate_model`), so a copied folder works anywhere. A task fits a robot when it
builds with it: each task's ``setup`` refuses a robot of another class (:func:`built`).
A description is the first sentence of the config file's header comment (:func:`summary`).
A composition is made once per process and handed out as copies until a config file
changes (:func:`_compose`; ``bench/compose.py`` prices it).
"""

from __future__ import annotations

import copy
import functools
import hashlib
import os
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING, Mapping, Sequence

from hydra import compose as hydra_compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import DictConfig, OmegaConf, open_dict

from params import ConfigError
from params.private_api import configs_parsed_once
from robots.folders import MODEL_FOLDERS

if TYPE_CHECKING:  # building a task imports MuJoCo and torch: only the functions that build do
    from tasks.base import Task
    from tasks.env import RobotTaskEnv

# The config groups a run picks by name (``robot=cube``); everything else is a value.
GROUPS = ("robot", "task", "learner")
# The defaults-list key of the per-task tuned layer (``optional tuned@_global_:
# ${robot}_${task}_${learner}`` in conf/config.yaml): the group ``tuned`` a second time,
# so a second key; run_choices calls its pick ``tuned_task``.
TASK_TUNED = "tuned@_global_"
TUNED_PICKS = ("tuned", "tuned_task")  # run_choices' names of the two layers, robot's first


_EXTRA_DIRS: list[Path] = []  # config folders after conf/ (use_config_dirs)


def conf_dir() -> Path:
    """The folder of the Hydra configs (``config.yaml``, ``robot/``, ``task/``, ...)."""
    return Path(str(resources.files("conf")))


def use_config_dirs(dirs: Sequence[str | Path]) -> None:
    """Config folders searched after ``conf/`` (Hydra's ``--config-dir``), from now on."""
    folders = [Path(d).expanduser().resolve() for d in dirs]
    for folder in folders:
        if not folder.is_dir():
            raise ConfigError(f"config folder {folder} does not exist")
    _EXTRA_DIRS[:] = [f for f in folders if f != conf_dir().resolve()]
    MODEL_FOLDERS[:] = config_dirs()
    _check_no_shadowing()


def _check_no_shadowing() -> None:
    """A config of a ``--config-dir`` folder named like one of an earlier folder (``conf/``'s
    first) would silently lose to it (Hydra takes the first it finds): refused in one line."""
    seen: dict[str, Path] = {}
    for folder in config_dirs():
        for path in sorted(folder.glob("*/*.yaml")):
            name = f"{path.parent.name}/{path.name}"
            if name in seen and path.parent.name != "hydra":
                raise ConfigError(f"{path} has the name of {seen[name]}, which Hydra would use instead; "
                                  f"allowed: another name for yours (e.g. {path.parent.name}/my_{path.name})")
            seen.setdefault(name, path)


def config_dirs() -> list[Path]:
    """Every config folder, in Hydra's search order: ``conf/`` first."""
    return [conf_dir(), *_EXTRA_DIRS]


def config_file(group: str, name: str) -> Path | None:
    """``<folder>/<group>/<name>.yaml`` of the first config folder that has it."""
    for folder in config_dirs():
        if (folder / group / f"{name}.yaml").is_file():
            return folder / group / f"{name}.yaml"
    return None


def unreadable_conf_file(folders: Sequence[Path] = ()) -> str | None:
    """The first YAML file under ``conf/`` (and ``folders``) that is not valid UTF-8, as
    ``"<path> is not valid UTF-8 (<reason>)"``; None if every one reads."""
    for folder in (conf_dir(), *folders):
        for path in sorted(Path(folder).rglob("*.yaml")):
            try:
                path.read_bytes().decode("utf-8")
            except UnicodeDecodeError as err:
                return f"{path} is not valid UTF-8 (byte {err.object[err.start]:#x} at position {err.start})"
            except OSError:
                continue
    return None


def read_conf_text(path: Path) -> str:
    """A file of ``conf/``, or :class:`ConfigError` naming it if it is not valid UTF-8."""
    try:
        return path.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise ConfigError(f"{path} is not valid UTF-8 (byte {err.object[err.start]:#x} at position "
                          f"{err.start}); allowed: a YAML file in UTF-8") from None


def names(group: str) -> list[str]:
    """The configs of ``<group>/`` in every config folder, by name."""
    return sorted({p.stem for d in config_dirs() for p in (d / group).glob("*.yaml")})


def locate_model(cfg: DictConfig, robot: str | None, sources: Sequence | None = None) -> DictConfig:
    """``cfg`` with a relative ``robot.model`` made absolute: relative to the config folder
    that holds ``robot/<robot>.yaml`` (the first of ``sources``, Hydra's config sources,
    or else of :func:`config_dirs`). Anything else is left as it is."""
    model = cfg.get("robot", {}).get("model") if isinstance(cfg.get("robot"), DictConfig) else None
    if not isinstance(model, str) or Path(model).expanduser().is_absolute() or not robot:
        return cfg
    folders = [Path(s["path"]) for s in sources or () if s.get("schema") == "file"] or config_dirs()
    for folder in folders:
        if (folder / "robot" / f"{robot}.yaml").is_file():
            with open_dict(cfg):
                cfg.robot.model = str((folder / model).resolve())
            break
    return cfg


def robot_names() -> list[str]:
    """Every robot with a config in ``conf/robot/``."""
    return names("robot")


def tuned_name(robot: str, learner: str, task: str | None = None) -> str:
    """The name of a tuned file: ``<robot>_<learner>``, or with ``task`` the per-task
    ``<robot>_<task>_<learner>``."""
    return f"{robot}_{task}_{learner}" if task else f"{robot}_{learner}"


def tuned_file(robot: str, learner: str, task: str | None = None) -> Path:
    """Where the tuned parameters of ``robot`` x ``learner`` live, with ``task`` those for
    that task only, applied on top (the file may not exist)."""
    name = tuned_name(robot, learner, task)
    return config_file("tuned", name) or conf_dir() / "tuned" / f"{name}.yaml"


def tuned_layers(robot: str, task: str, learner: str) -> list[str]:
    """The tuned files a plain run of ``robot`` / ``task`` / ``learner`` applies, by name,
    in the order Hydra applies them (the robot's, then the task's); ``[]`` for none."""
    layers = (tuned_name(robot, learner), tuned_name(robot, learner, task))
    return [name for name in layers if config_file("tuned", name) is not None]


def with_tuned_layers(overrides: Sequence[str]) -> list[str]:
    """``overrides`` with ``~tuned`` leaving out both tuned layers: ``~tuned@_global_``
    (:data:`TASK_TUNED`) added after it, unless given already."""
    out = list(overrides)
    if "~tuned" in out and f"~{TASK_TUNED}" not in out:
        out.insert(out.index("~tuned") + 1, f"~{TASK_TUNED}")
    return out


def run_choices(choices: Mapping[str, str | None]) -> dict[str, str | None]:
    """A run's picks of the config groups (robot, task, learner) and of the tuned files from
    Hydra's ``runtime.choices``: ``tuned`` (the robot's layer) and ``tuned_task`` (the task's,
    on top), each None where no file answers the pick (an ``optional`` default names its
    file whether or not there is one)."""
    picks = {k: choices.get(k) for k in (*GROUPS, "tuned")}
    picks["tuned_task"] = choices.get(TASK_TUNED)
    for key in TUNED_PICKS:
        if picks[key] and config_file("tuned", picks[key]) is None:
            picks[key] = None
    return picks


def compose(robot: str | None = None, task: str | None = None, learner: str | None = None,
            overrides: Sequence[str] = ()) -> DictConfig:
    """The resolved run config, as ``python train.py robot=.. task=.. learner=.. <overrides>``
    composes it (the robot's default task when ``task`` is None).

    Works inside a running Hydra app too: that app's global state is restored.
    """
    picks = [f"{k}={v}" for k, v in (("robot", robot), ("task", task), ("learner", learner)) if v]
    return _resolved(_compose([*picks, *with_tuned_layers(overrides)]))


def default_task(robot: str) -> str:
    """The task ``robot``'s config picks."""
    return robot_default(robot)[0]


def robot_default(robot: str) -> tuple[str, DictConfig]:
    """``(task name, resolved config)`` of ``robot`` with the task its config picks, from
    one composition (``default_task`` and ``compose(robot)`` together)."""
    cfg = _compose([f"robot={robot}"])
    return str(cfg.hydra.runtime.choices.task), _resolved(cfg)


def _resolved(cfg: DictConfig) -> DictConfig:
    runtime = cfg.hydra.runtime
    locate_model(cfg, runtime.choices.get("robot"), runtime.config_sources)
    with open_dict(cfg):
        del cfg["hydra"]
    OmegaConf.resolve(cfg)
    return cfg


def _config_texts() -> str:
    """A digest of every YAML file of the config folders, three levels deep (``config.yaml``,
    ``robot/x.yaml``, ``hydra/launcher/x.yaml``), by path and text: a kept composition is used
    only while no config file was added, removed or edited."""
    digest = hashlib.blake2b(digest_size=16)
    for folder in config_dirs():
        for path in sorted(p for depth in ("", "*/", "*/*/") for p in folder.glob(f"{depth}*.yaml")):
            digest.update(str(path).encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def _compose(overrides: list[str]) -> DictConfig:
    """Hydra's composition of ``config`` with ``overrides``, of its ``hydra`` node only
    ``runtime.choices`` and ``runtime.config_sources``: a copy of the one this process made for
    the same overrides, config folders, files and working directory (:func:`_composed`)."""
    dirs = tuple(str(d) for d in config_dirs())
    return copy.deepcopy(_composed(tuple(overrides), dirs, _config_texts(), os.getcwd()))


# A gym vector env's copies, a study's checks and the suite's tables compose the same config
# again and again (~0.4 s each on a 2-core machine; a kept one costs its copy): the last 64
# are kept (~0.2 MB each), never handed out themselves.
@functools.lru_cache(maxsize=64)
def _composed(overrides: tuple[str, ...], dirs: tuple[str, ...], texts: str, cwd: str) -> DictConfig:
    """The composition :func:`_compose` copies, made once per distinct arguments (``dirs``,
    ``texts`` and ``cwd`` only key it: they are the state Hydra reads)."""
    cfg = _hydra_compose(list(overrides))
    runtime = cfg.hydra.runtime
    with open_dict(cfg):
        cfg.hydra = {"runtime": {"choices": runtime.choices, "config_sources": runtime.config_sources}}
    return cfg


def _hydra_compose(overrides: list[str]) -> DictConfig:
    gh = GlobalHydra.instance()
    app = gh.hydra if gh.is_initialized() else None
    gh.clear()
    try:
        with configs_parsed_once(), initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
            extra = [f"hydra.searchpath=[{','.join(f'file://{d}' for d in _EXTRA_DIRS)}]"]
            return hydra_compose(config_name="config", overrides=[*extra[:len(_EXTRA_DIRS) > 0],
                                                                  *overrides],
                                 return_hydra_config=True)
    finally:
        if app is not None:
            GlobalHydra.instance().clear()
            GlobalHydra.instance().initialize(app)


def make_env(robot: str, task: str | None = None, overrides: Sequence[str] = (),
             num_envs: int = 1, seed: int = 0) -> RobotTaskEnv:
    """The env of ``robot`` (and ``task``, else the robot's default) with Hydra ``overrides``
    such as ``"task.pos_step=0.5"``."""
    from tasks import factory

    return factory.build_env(compose(robot, task, overrides=overrides), num_envs, seed)


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
        from tasks import factory

        return factory.build_task(compose(robot, task, overrides=["~tuned"]))
    except ConfigError:
        return None


def tuned_pairs() -> dict[str, tuple[str, str] | None]:
    """``conf/tuned/`` file name -> the ``(robot, learner)`` it tunes (a per-task file's
    too: :func:`tuned_targets` says which task), ``None`` if it names no such pair (Hydra
    would never apply it)."""
    return {stem: (target[0], target[2]) if target else None for stem, target in tuned_targets().items()}


def tuned_targets() -> dict[str, tuple[str, str | None, str] | None]:
    """``conf/tuned/`` file name -> the ``(robot, task, learner)`` it tunes (``task`` None for
    a robot's file, which applies to all its tasks), ``None`` if it names neither a
    ``<robot>_<learner>`` nor a ``<robot>_<task>_<learner>`` (Hydra would never apply it)."""
    robots, tasks, learners = robot_names(), names("task"), names("learner")
    targets: dict[str, tuple[str, str | None, str]] = {
        tuned_name(r, lr, t): (r, t, lr) for r in robots for t in tasks for lr in learners}
    targets |= {tuned_name(r, lr): (r, None, lr) for r in robots for lr in learners}
    return {stem: targets.get(stem) for stem in names("tuned")}
