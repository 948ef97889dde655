"""Config validation before anything is built: one line naming key, value and what is allowed.

:func:`check_run_config` checks a composed run config:

- the top-level keys of ``conf/config.yaml``, declared in :class:`RunSettings`,
  and ``logger``;
- the ``robot``, ``task`` and ``learner`` nodes (and nested ``_target_`` nodes
  such as ``learner.epsilon``) against their class's declared parameters
  (:mod:`params.declare`): every key must be declared, and every value must
  have its type (a float a finite number, an int a whole number, a bool
  ``true``/``false``, a list a list, ...) and lie in its declared range. A
  class without declarations is checked against its signature's annotations.

Checks that relate two values (``min_pole_angle < max_pole_angle``, a task that
does not fit the robot, ``batch_size <= buffer_size``) are the constructors'
own, with :func:`params.require`; every message reads
``"<key> must be <allowed>; got <value>"``.

Why not Hydra structured configs (dataclasses in the ConfigStore)? Hydra
reports a type mismatch as a five-line composition error outside the run's
error handling, and it has no ranges: ``num_envs=-3`` and ``lr=nan`` pass.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import inspect
import typing
from typing import Any, Callable, Mapping

from omegaconf import DictConfig, ListConfig, OmegaConf, open_dict
from omegaconf.errors import OmegaConfBaseException

from params import ConfigError, did_you_mean, locate
from params.declare import check_values, declared, declared_robot, describe, mismatch, param, robot_name, specs

MODES = ("train", "eval")
# Keys of older configs and where each setting lives now: the training budget is the run's,
# and the task's time limit is the only one.
MOVED = {"learner.nepisodes": "max_episodes", "learner.nsteps": "task.max_episode_steps", "win": "task.win"}
_WHY = {"max_episodes": "the run's budget, beside max_env_steps",
        "task.max_episode_steps": "the task's time limit, the only one", "task.win": "the task's success rule"}
# Settings added since some run folders were written, each with the value that does what
# those runs did (an older folder's config.yaml lacks them).
ADDED = {"eval_every_steps": 0}
_ABSENT = object()
LOGGERS = ("csv", "tensorboard", "wandb", "mlflow", "none")
SEED_LIMIT = 2**63
ALLOWED_TARGET_PACKAGES = ("robots", "tasks", "learners")  # what a _target_ may build


def check_targets(cfg: Any, where: str = "") -> None:
    """Refuses (:class:`ConfigError`, one line) any ``_target_`` in ``cfg`` but a class defined
    in the project's own packages (``robots.``, ``tasks.``, ``learners.``).

    A run folder's config.yaml and a command line are data, and Hydra's ``instantiate``
    would call whatever a ``_target_`` names (``os.system``, ``subprocess.Popen``): checked as
    written, interpolations unresolved, and nothing outside those packages is imported to
    check it.
    """
    if isinstance(cfg, (DictConfig, ListConfig)):
        cfg = OmegaConf.to_container(cfg, resolve=False)
    if isinstance(cfg, dict):
        for key, value in cfg.items():
            name = f"{where}.{key}" if where else str(key)
            if key == "_target_":
                _check_target(value, name)
            else:
                check_targets(value, name)
    elif isinstance(cfg, list):
        for i, value in enumerate(cfg):
            check_targets(value, f"{where}[{i}]")


def _check_target(target: Any, key: str) -> None:
    allowed = ", ".join(f"{p}." for p in ALLOWED_TARGET_PACKAGES)
    refusal = ConfigError(f"{key}={target!r} is not allowed: a run builds only classes of the project's own "
                          f"packages ({allowed})")
    if not isinstance(target, str) or target.split(".", 1)[0] not in ALLOWED_TARGET_PACKAGES:
        raise refusal
    if declared(target):  # one of the project's declared classes, known without importing it
        return
    module_name, _, attr = target.rpartition(".")
    if not (module_name and all(part.isidentifier() for part in target.split("."))):
        raise refusal
    try:  # the module itself, not an attribute path through it (runs.checkpoint.os.system)
        module = importlib.import_module(module_name)
    except Exception:  # noqa: BLE001 - no such module in the project
        raise refusal from None
    obj = getattr(module, attr, None)
    if not (isinstance(obj, type)
            and str(obj.__module__).split(".", 1)[0] in ALLOWED_TARGET_PACKAGES):
        raise refusal


def check_hydra_key(override: str) -> None:
    """Refuses (one line) the override ``+hydra.<key>=<value>`` unless Hydra's own config has it: a key of its
    schema (``hydra.conf.HydraConf``), or one under a mapping open to any key (``job.env_set``,
    a launcher's or sweeper's settings, the logging configs)."""
    from hydra.conf import HydraConf

    kind, path = HydraConf, "hydra"
    for part in override.lstrip("+").split("=", 1)[0].split(".")[1:]:
        if not dataclasses.is_dataclass(kind):
            return  # a mapping or a plugin's node: its keys are its own
        fields = typing.get_type_hints(kind)
        if part not in fields:
            raise ConfigError(f"{path}.{part} is not a setting of Hydra; allowed under {path}: "
                              f"{', '.join(f.name for f in dataclasses.fields(kind))}; got {override}")
        kind, path = fields[part], f"{path}.{part}"


def check_run_config(cfg: DictConfig) -> None:
    """Raises :class:`ConfigError` (one line) for the first bad value in ``cfg``."""
    own = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"])  # Hydra's node is Hydra's business
    try:  # (present with return_hydra_config)
        conf = OmegaConf.to_container(own, resolve=True)
    except OmegaConfBaseException as err:
        raise ConfigError(f"config does not resolve: {_first_line(err)}") from None
    for old in MOVED:  # a key of an older config, in a config file or a run folder's
        value = OmegaConf.select(cfg, old, default=_ABSENT)
        if value is not _ABSENT:
            raise ConfigError(moved(old, value))
    check_targets(own)
    _check_top_level(conf)
    if conf.get("mode") == "train" and not conf.get("max_episodes") and not conf.get("max_env_steps"):
        raise ConfigError("max_episodes and max_env_steps are both 0 (no limit), so training would never "
                          "end; allowed: a budget in either or both, e.g. max_episodes=1000; got "
                          f"max_episodes={conf.get('max_episodes')!r}, max_env_steps={conf.get('max_env_steps')!r}")
    if conf.get("mode") == "eval" and conf.get("eval_episodes") == 0:
        raise ConfigError("mode=eval with eval_episodes=0 would evaluate nothing; allowed: eval_episodes >= 1 "
                          "(the greedy episodes to run)")
    for node in ("robot", "task", "learner"):
        if node not in conf or not isinstance(conf[node], dict):
            raise ConfigError(f"{node} must be a config group with a _target_; got {conf.get(node)!r}")
        check_params(conf[node], node, skip=("robot",) if node == "task" else ())


def check_fit(cfg: DictConfig, choices: Mapping[str, str | None]) -> None:
    """One line, before anything loads, when the task's class needs another of the project's
    robots than ``cfg``'s (its ``ROBOT``, read from params/declared.json), named as the
    command names them (``choices``: the robot and task picked). A robot class the
    declarations do not know (a user's own) is left to the task's own check when built."""
    task, robot = str(cfg.task.get("_target_", "")), str(cfg.robot.get("_target_", ""))
    need = declared_robot(task)
    if need is None or robot == need or declared(robot) is None:
        return
    picked = choices.get("task") or task.rsplit(".", 2)[-2]
    raise ConfigError(f"task={picked} needs robot={robot_name(need)}; got robot={choices.get('robot') or robot_name(robot)}")


def moved_to(key: str) -> str | None:
    """Where the setting of an old key (:data:`MOVED`, or a key under one) lives now; None
    for a key of today."""
    for old, new in MOVED.items():
        if key == old or key.startswith(old + "."):
            return new + key[len(old):]
    return None


def moved(key: str, value: Any) -> str:
    """The line for an old key: where its setting lives now."""
    new = moved_to(key)
    why = next(w for root, w in _WHY.items() if new == root or new.startswith(root + "."))
    return f"{key} is now {new} ({why}); got {key}={value}, give {new}={value}"


def check_no_empty_mappings(cfg: DictConfig, overrides: list[str]) -> None:
    """``key={}`` where ``key`` holds a non-empty mapping changes nothing (Hydra merges a
    mapping into the one there is): refused in one line rather than run as if obeyed."""
    for override in overrides:
        key, _, value = override.lstrip("+").partition("=")
        if value.strip() != "{}" or key.startswith("~"):
            continue
        node = OmegaConf.select(cfg, key)
        if isinstance(node, DictConfig) and len(node):
            raise ConfigError(f"{key}={{}} changes nothing: a mapping given on the command line merges into "
                              f"the one there is ({', '.join(map(str, node))}); allowed: an entry "
                              f"({key}.{next(iter(node))}=...), or '~tuned' to leave a tuned file's out")


def upgraded(saved: DictConfig) -> DictConfig:
    """An older run folder's ``config.yaml`` in today's keys (:data:`MOVED`): its episode budget
    the run's ``max_episodes``, its episode length cap folded into the task's time limit, as the
    run's env applied it, and the settings added since (:data:`ADDED`) at the values that do
    what it did. A copy; the file and its hash are untouched."""
    cfg = saved.copy()
    with open_dict(cfg):
        for key, value in ADDED.items():
            if key not in cfg:
                cfg[key] = value
    learner = cfg.get("learner")
    if not isinstance(learner, DictConfig):
        return cfg
    with open_dict(cfg):
        if "nepisodes" in learner:
            cfg.max_episodes = learner.pop("nepisodes")
        if "nsteps" in learner:
            steps = learner.pop("nsteps")
            if isinstance(cfg.get("task"), DictConfig):
                limit = cfg.task.get("max_episode_steps", _declared_default(cfg.task, "max_episode_steps"))
                cfg.task.max_episode_steps = int(steps) if limit is None else min(int(limit), int(steps))
    return cfg


def _declared_default(node: DictConfig, name: str) -> Any:
    """The default of ``node``'s target's declared parameter ``name`` (None if unknown)."""
    try:
        target = locate(str(node.get("_target_")))
    except Exception:  # noqa: BLE001 - an unimportable target is check_params' to report
        return None
    found = [s.default for s in specs(target) if s.name == name] if dataclasses.is_dataclass(target) else []
    return found[0] if found else None


# -- top level ---------------------------------------------------------------
@dataclasses.dataclass
class RunSettings:
    """The run's own settings: the top level of ``conf/config.yaml``."""

    seed: int = param(0, "seeds torch, numpy, the env and the evaluations", ge=0, lt=SEED_LIMIT)
    num_envs: int = param(1, "physics copies stepped per env call", ge=1, le=4096)
    mode: str = param("train", "train, or evaluate a saved model", choices=MODES)
    checkpoint: str | None = param(None, "a saved model.pt to start from (train) or to evaluate (eval)")
    checkpoint_every: int = param(50, "episodes between saves of the whole training state "
                                      "(checkpoint.pt)", ge=0, note="0 = only at the end")
    resume: str | None = param(None, "a run folder to continue from its checkpoint.pt "
                                     "(with its own config)")
    eval_episodes: int = param(20, "greedy episodes (batched copies) per evaluation", ge=0,
                               le=4096)
    eval_every: int = param(100, "training episodes between greedy evaluations", ge=0,
                            note="0 = only after training")
    eval_every_steps: int = param(0, "env steps (all copies counted) between greedy evaluations, "
                                     "whichever of it and eval_every comes first", ge=0,
                                  note="0 = eval_every alone decides")
    quiet: bool = param(False, "no progress bar and no summary lines (the banner and the verdict "
                               "only)")
    verbose: bool = param(False, "also one line per episode and per greedy evaluation")
    log_every: int = param(0, "episodes between summary lines", ge=0,
                           note="0 = about 20 lines per run")
    video: bool = param(False, "write policy.mp4 of the greedy policy at the end")
    video_steps: int = param(500, "env steps in that video", ge=0, le=100_000)
    torch_threads: int = param(1, "intra-op threads; small networks are fastest on one", ge=1,
                               le=256)
    max_episodes: int = param(1000, "stop training after this many episodes (all copies counted)",
                              ge=0, le=10**9, note="0 = no limit; then max_env_steps must be set")
    max_env_steps: int = param(0, "stop training after this many env steps (all copies counted)",
                               ge=0, note="0 = no limit")
    stop_when_solved: bool = param(True, "end training once the task counts as solved (false: spend "
                                         "the whole budget, as a tuning trial does)")
    trial: int | None = param(None, "the Optuna trial this run reports to (set by "
                                    "hydra/sweeper=optuna)", ge=0)


GROUPS = ("robot", "task", "learner", "logger")


def _check_top_level(conf: dict) -> None:
    declared = [s.name for s in specs(RunSettings)]
    unknown = sorted(set(conf) - set(declared) - set(GROUPS))
    if unknown:
        hint = did_you_mean(unknown[0], declared + list(GROUPS))
        raise ConfigError(f"{unknown[0]} is not a setting; {hint}allowed: {', '.join(declared)} and "
                          f"the groups {', '.join(GROUPS)}; got {unknown[0]}={conf[unknown[0]]!r}")
    missing = [k for k in declared if k not in conf]
    if missing:
        raise ConfigError(f"{missing[0]} is missing: every run needs it (conf/config.yaml sets it; "
                          f"do not remove it with ~{missing[0]})")
    check_values(RunSettings, {k: conf[k] for k in declared}, "")
    # Whether the file exists and fits is load_checkpoint's (it says so in one line).
    if not conf.get("checkpoint") and conf.get("mode") == "eval":
        raise ConfigError("mode=eval needs checkpoint=<path to a saved model.pt>")
    _check_logger(conf.get("logger"))


def _check_logger(logger: Any) -> None:
    if not isinstance(logger, dict):
        raise ConfigError(f"logger must be one of {', '.join(LOGGERS)}; got {logger!r}")
    kind = logger.get("kind")
    if kind not in LOGGERS:
        raise ConfigError(f"logger.kind must be one of {', '.join(LOGGERS)}; got {kind!r}")
    from runs.loggers import NEEDS, make_logger

    package = NEEDS.get(kind)
    if package is not None and importlib.util.find_spec(package) is None:
        raise ConfigError(
            f"logger={kind} needs the {package} package, which is not installed; "
            f"install it with: pip install -e '.[{kind}]'")
    options = {k: v for k, v in logger.items() if k != "kind"}
    _check_against(make_logger, options, "logger",
                   skip=("kind", "run_dir", "exp_name"), what="make_logger")


# -- robot, task, learner: the target's signature is the schema --------------
def check_params(node: dict, prefix: str, skip: tuple[str, ...] = ()) -> None:
    """Checks a plain-dict config ``node`` with a ``_target_`` against its target's signature."""
    target = node.get("_target_")
    if not isinstance(target, str) or not target:
        raise ConfigError(f"{prefix}._target_ must name a class to build; got {target!r}")
    params = {k: v for k, v in node.items() if not k.startswith("_") and k not in skip}
    known = declared(target)  # the project's classes: checked without importing them
    if known:
        check_values(target, params, prefix, nested=check_params, declared_specs=known)
        return
    try:
        obj = locate(target)
    except Exception as err:  # noqa: BLE001 - any import failure is the same config mistake
        raise ConfigError(f"{prefix}._target_ must name an importable class; got {target!r} "
                          f"({type(err).__name__}: {err})") from None
    if not inspect.isclass(obj):
        raise ConfigError(f"{prefix}._target_ must name a class to build; got {target!r} (a "
                          f"{type(obj).__name__})")
    params = {k: v for k, v in node.items() if not k.startswith("_") and k not in skip}
    if dataclasses.is_dataclass(obj) and specs(obj):  # declared: names, types and ranges
        check_values(obj, params, prefix, nested=check_params)
    else:
        _check_against(obj, params, prefix, skip=skip, what=target, check_str=False)


def _check_against(obj: Callable, params: dict, prefix: str, skip: tuple[str, ...], what: str,
                   check_str: bool = True) -> None:
    init = obj.__init__ if inspect.isclass(obj) else obj
    signature = inspect.signature(init)
    try:
        hints = typing.get_type_hints(init)
    except Exception:  # noqa: BLE001 - unresolvable annotations: check names only
        hints = {}
    accepted = [n for n, p in signature.parameters.items()
                if n not in ("self", *skip) and p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)]
    takes_any = any(p.kind is p.VAR_KEYWORD for p in signature.parameters.values())
    for key, value in params.items():
        if key in skip:
            continue
        if key not in accepted and not takes_any:
            raise ConfigError(f"{prefix}.{key} is not a parameter of {what}; allowed: "
                              f"{', '.join(accepted)}; got {prefix}.{key}={value!r}")
    for name in accepted:
        parameter = signature.parameters[name]
        if name not in params:
            if parameter.default is inspect.Parameter.empty:
                raise ConfigError(f"{prefix}.{name} is missing; {what} needs it")
            continue
        value = params[name]
        if isinstance(value, dict) and "_target_" in value:
            check_params(value, f"{prefix}.{name}")
            continue
        hint = hints.get(name, Any)
        if hint is str and not check_str:
            continue  # the constructor checks its choices and says which are allowed
        bad = mismatch(value, hint, f"{prefix}.{name}")
        if bad is not None:
            key, hint, got = bad
            raise ConfigError(f"{key} must be {describe(hint)}; got {got!r}")


def _first_line(err: BaseException) -> str:
    text = str(err).strip()
    return text.splitlines()[0] if text else type(err).__name__
