"""A run's folder: making a new one, taking it (a lock), and reading an old one back.

A run folder holds ``config.yaml`` (resolved) and ``run.json`` (the choices, the seed,
the overrides and the run's identity) from its start; a resumed or evaluated run
reads them back here, with only the few overrides each accepts.
"""

from __future__ import annotations

import fcntl
import json
import os
import shutil
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator, Mapping

from omegaconf import DictConfig, OmegaConf

from params import ConfigError
from tasks.catalog import GROUPS
from params import CheckpointError
from runs.layout import is_run_folder, train_command
from runs.settings import upgraded

# Overrides a resumed run accepts; everything else comes from the run's own config.yaml.
RESUME_OVERRIDES = ("resume", "quiet", "verbose", "log_every", "torch_threads", "video", "video_steps",
                    "eval_episodes")
PICKS = GROUPS  # the config groups a run folder fixes


def check_output_folder(key: str, path: str) -> str:
    """``hydra.run.dir`` / ``hydra.sweep.dir`` (``key``) may be a new or empty folder, or one
    this project made (a run's: run.json, its .lock or Hydra's .hydra record; a sweep's: multirun.yaml):
    anything else (``/``, a home folder, a source tree) is refused before a file is written, and
    so is a folder inside a run's (symlinks and ``..`` resolved: no run is written into
    another), and a sweep's folder where a live run trains (one of its runs' locks held).
    Returns the path to make: ``path``, or its resolved form where it went through
    ``..`` (Hydra would make the folders before the ``..``)."""
    if "${" in path:  # resolved by Hydra later: a time-stamped name, a new folder
        return path
    resolved = Path(path).resolve()
    inside = next((p for p in resolved.parents if is_run_folder(p)), None)
    if inside is not None:
        raise ConfigError(f"{key}={path} is inside the run folder {inside}; allowed: a folder outside every "
                          "run's (a sweep's folder holds its runs side by side)")
    if ".." in Path(path).parts:
        path = str(resolved)
    folder = Path(path)
    if not folder.exists():
        return path
    if not folder.is_dir():
        raise ConfigError(f"{key}={path} is a file; allowed: a new or empty folder, or a run or sweep "
                          "folder of this project")
    try:
        names = sorted(p.name for p in folder.iterdir())
    except OSError as err:
        raise ConfigError(f"{key}={path} cannot be read ({err.strerror}); allowed: a new or empty "
                          "folder, or a run or sweep folder of this project") from None
    ours = ("run.json", ".lock") if key == "hydra.run.dir" else ("multirun.yaml",)  # never .hydra/ alone
    if names and not any(name in names for name in ours):
        shown = ", ".join(names[:4]) + (", ..." if len(names) > 4 else "")
        raise ConfigError(f"{key}={path} is a folder that holds other files ({shown}); allowed: a new or "
                          f"empty folder, or a {'run' if key == 'hydra.run.dir' else 'sweep'} folder of "
                          "this project")
    held = sweep_holders(folder) if key == "hydra.sweep.dir" else {}
    if held:  # a sweep refused before Hydra writes its multirun.yaml over another's
        name, pid = next(iter(held.items()))
        raise ConfigError(f"{key}={path} is in use by another run (pid {pid}, in {name}); "
                          "let it finish or pick another folder")
    return path


def sweep_holders(sweep: Path) -> dict[str, str]:
    """The live runs training in the sweep folder ``sweep`` now: each held run folder's name
    and its holder's pid (:func:`lock_holder`), in name order."""
    return {run.name: pid for run in sorted(sweep.iterdir()) if run.is_dir() and (pid := lock_holder(run)) is not None}


def held_elsewhere(run_dir: Path) -> bool:
    """Whether another live process holds ``run_dir``'s lock: nothing of this one's (a
    refusal's ``error.txt`` included) may be written there."""
    return lock_holder(run_dir) not in (None, str(os.getpid()))


def is_finished(run_dir: Path) -> bool:
    """Whether the run in ``run_dir`` ended (its summary.json, written last, does not say
    ``interrupted``); a missing or unreadable summary.json is a run still to finish."""
    try:
        summary = json.loads((run_dir / "summary.json").read_text())
    except (OSError, UnicodeDecodeError, ValueError):
        return False
    return isinstance(summary, dict) and not summary.get("interrupted")


def resumed_config(cfg: DictConfig, overrides: list[str]) -> tuple[DictConfig, Path]:
    """The config of the run folder ``cfg.resume``, with the few overrides a resume accepts."""
    run_dir = Path(cfg.resume)
    if not (run_dir / "config.yaml").is_file() or not (run_dir / "run.json").is_file():
        raise CheckpointError(f"resume={run_dir} is not a run folder (it needs config.yaml and run.json)")
    if not (run_dir / "checkpoint.pt").is_file():
        raise CheckpointError(f"resume={run_dir} has no checkpoint.pt to continue from "
                              "(it was run with checkpoint_every=0, or stopped before its first one)")
    others = [o for o in overrides if o.split("=", 1)[0].lstrip("+~") not in RESUME_OVERRIDES]
    if others:
        raise ConfigError(f"resume= continues a run with its own config; drop {' '.join(others)} "
                          f"(allowed with resume: {', '.join(RESUME_OVERRIDES[1:])})")
    if is_finished(run_dir):
        raise CheckpointError(f"resume={run_dir}: it is finished (its summary.json says so), so there is "
                              f"nothing to continue; allowed: a stopped or killed run (evaluate this one with "
                              f"mode=eval checkpoint={run_dir})")
    from runs.settings import check_targets
    from runs.training_state import check_checkpoint, load_run_config, read_run_json

    read_run_json(run_dir)  # a damaged run.json is refused now, not when model.pt is written
    saved = load_run_config(run_dir)
    for key in RESUME_OVERRIDES[1:]:
        if any(o.startswith(f"{key}=") for o in overrides):
            saved[key] = cfg[key]
    check_targets(saved)  # config.yaml is data: it may build only the project's own classes
    check_checkpoint(run_dir, saved)  # this run's, intact: refused before any file is touched
    return upgraded(saved), run_dir


def model_path(checkpoint: str | Path) -> Path:
    """``checkpoint=``'s model file: the path itself, or a run folder's model.pt."""
    path = Path(checkpoint)
    if path.is_dir():
        if not (path / "model.pt").is_file():
            raise CheckpointError(f"checkpoint={path} is a folder without model.pt (a run folder "
                                  "holds one once its run ends or stops)")
        return path / "model.pt"
    return path


def run_folder_of(checkpoint: str | Path | None) -> Path | None:
    """The run folder ``checkpoint=`` points into (the folder or a model.pt in it), if any."""
    if not checkpoint:
        return None
    path = Path(checkpoint)
    folder = path if path.is_dir() else path.parent
    return folder if (folder / "config.yaml").is_file() and (folder / "run.json").is_file() else None


def eval_config(cfg: DictConfig, overrides: list[str]) -> DictConfig:
    """``mode=eval checkpoint=<run folder or its model.pt>``: the robot, task and learner of
    the run's own config.yaml; the run settings (``eval_episodes``, ``seed``, ``video``, ...)
    and every override of this command (a task parameter for a robustness test) on top."""
    folder = run_folder_of(cfg.checkpoint)
    from runs.settings import check_targets
    from runs.training_state import load_run_config

    saved = upgraded(load_run_config(folder))
    check_targets(saved)  # config.yaml is data: it may build only the project's own classes
    evaluated = cfg.copy()
    for group in PICKS:
        if group in saved:
            evaluated[group] = saved[group]
    for override in overrides:  # robot./task./learner. values of this command, as composed
        key = override.split("=", 1)[0].lstrip("+")
        if "=" in override and not key.startswith("~") and key.split(".")[0] in PICKS and "." in key:
            OmegaConf.update(evaluated, key, OmegaConf.select(cfg, key), merge=False, force_add=True)
    evaluated.checkpoint = str(model_path(cfg.checkpoint))
    return evaluated


AGENT = "agent:"  # checkpoint=agent:<name>: a trained agent shipped with the package (conf/agents/)


def shipped_agent(arg: str) -> str:
    """``checkpoint=agent:<name>`` as the folder of that agent shipped in ``conf/agents/`` (a
    trimmed run folder: its config.yaml, run.json and model.pt); any other argument as it is.

    Raises:
        ConfigError: if no shipped agent has that name (the message lists them).
    """
    key, _, value = arg.partition("=")
    if key != "checkpoint" or not value.startswith(AGENT):
        return arg
    from tasks.catalog import conf_dir

    shipped = conf_dir() / "agents"
    name = value[len(AGENT):]
    known = sorted(p.name for p in shipped.iterdir() if (p / "model.pt").is_file()) if shipped.is_dir() else []
    if name not in known:
        raise ConfigError(f"checkpoint={value}: no agent of that name is shipped; the shipped ones: "
                          f"{', '.join(AGENT + k for k in known) or 'none'}")
    return f"checkpoint={shipped / name}"


def with_run_choices(args: list[str]) -> list[str]:
    """``mode=eval checkpoint=<run folder>``: the run's robot, task and learner (run.json's)
    put on the command line, so its other overrides compose as for that run; a different
    choice given with it is refused. ``checkpoint=agent:<name>``: a shipped agent's folder."""
    args = [shipped_agent(a) for a in args]
    given = dict(a.split("=", 1) for a in args if "=" in a and not a.startswith(("+", "~", "-")))
    folder = run_folder_of(given.get("checkpoint")) if given.get("mode") == "eval" else None
    if folder is None:
        return args
    from runs.training_state import read_run_json

    saved = read_run_json(folder)
    clash = [f"{k}={given[k]}" for k in PICKS if k in given and given[k] != saved.get(k)]
    if clash:
        raise ConfigError(f"checkpoint={folder} is a {'/'.join(str(saved.get(k)) for k in PICKS)} "
                          f"run, evaluated with its own robot, task and learner; drop {' '.join(clash)}")
    picks = [f"{k}={saved[k]}" for k in PICKS if k not in given and saved.get(k)]
    return [*_config_dirs_for(folder, saved, args), *picks, *args]


def _config_dirs_for(folder: Path, saved: Mapping, args: list[str]) -> list[str]:
    """``--config-dir`` options for a run's robot, task or learner that no config folder given
    holds: the folders the run was made with (its ``.hydra/hydra.yaml``), where they still hold
    them; else one line saying which to pass."""
    from tasks.catalog import config_file

    missing = [k for k in PICKS if saved.get(k) and config_file(k, str(saved[k])) is None]
    if not missing:
        return []
    recorded = []
    for record in (folder / ".hydra-resume" / "hydra.yaml", folder / ".hydra" / "hydra.yaml"):
        try:
            sources = OmegaConf.load(record).hydra.runtime.config_sources
        except Exception:  # noqa: BLE001 - a missing or unreadable record: nothing recorded
            continue
        recorded += [str(s.path) for s in sources if s.schema == "file" and s.provider == "command-line"]
    found = [d for d in dict.fromkeys(recorded)
             if all(Path(d, k, f"{saved[k]}.yaml").is_file() for k in missing)]
    if found:
        return ["--config-dir", found[0]]
    what = " ".join(f"{k}={saved[k]}" for k in missing)
    made = f" (it was made with --config-dir {recorded[0]}, which no longer holds it)" if recorded else ""
    raise ConfigError(f"checkpoint={folder} is a run of {what}, whose config no config folder given holds{made}; "
                      "pass the --config-dir that holds it")


WRITE_FAILED = 3  # exit status of a run that could not write its files (2: a refused command)


def cannot_write(err: OSError, run_dir: Path) -> str:
    """One line for a write into ``run_dir`` that failed (a full disk, a folder gone): what
    could not be written, why, and how to go on from the last checkpoint where there is one."""
    line = f"error: cannot write {err.filename or run_dir}: {err.strerror or err}"
    if (run_dir / "checkpoint.pt").is_file():
        line += (f"; the last checkpoint is intact: once there is room, resume with: "
                 f"{train_command()} resume={run_dir}")
    return line


class MadeFolders:
    """The folders that exist before Hydra makes a run's folder (``hydra.run.dir``, else the
    default ``outputs/<date>/<time>_...``), so that a refused command removes exactly the
    empty folders it made and none it did not."""

    def __init__(self, run_dir: str | None, root: Path) -> None:
        root = root.absolute()
        self.before = {root, *root.parents}
        if run_dir and "${" not in run_dir:
            target = Path(run_dir).absolute()
            self.before |= {p for p in (target, *target.parents) if p.exists()}
            self.scope = target
        else:
            outputs = root / "outputs"
            if outputs.is_dir():
                self.before |= {outputs, *(p for p in outputs.iterdir() if p.is_dir())}
            self.scope = outputs

    def remove(self, run_dir: Path) -> None:
        """Removes ``run_dir`` and its parents while each is empty and was made by this command."""
        run_dir = run_dir.absolute()
        if run_dir != self.scope and self.scope not in run_dir.parents:
            return
        for folder in (run_dir, *run_dir.parents):
            if folder in self.before or not folder.is_dir() or any(folder.iterdir()):
                return
            folder.rmdir()


@contextmanager
def taken(run_dir: Path, refusals: tuple[type[BaseException], ...]) -> Iterator[None]:
    """:func:`run_lock` on ``run_dir``; a ``refusals`` error raised inside before the run
    started (before its run.json) removes what was written into the folder while held. A
    resumed run refused (its run.json older) leaves its folder as it was: what was made is
    removed, ``train.log`` cut back to its length, ``.lock`` and Hydra's records of earlier
    commands given back their bytes."""
    before = set(os.listdir(run_dir))
    records = [run_dir / name for name in (".hydra", ".hydra-resume") if name in before]
    kept = {path: path.read_bytes() for path in [run_dir / ".lock", *(p for r in records for p in r.rglob("*"))]
            if path.is_file()}
    log = run_dir / "train.log"
    log_size = log.stat().st_size if "train.log" in before else None
    with run_lock(run_dir):
        try:
            yield
        except refusals:
            made = set(os.listdir(run_dir)) - before
            if "run.json" not in made:
                for name in made:
                    path = run_dir / name
                    shutil.rmtree(path) if path.is_dir() and not path.is_symlink() else path.unlink()
                if log_size is not None:
                    os.truncate(log, log_size)
                for record in records:
                    shutil.rmtree(record, ignore_errors=True)
                for path, data in kept.items():
                    path.parent.mkdir(parents=True, exist_ok=True)
                    path.write_bytes(data)
            raise


def write_hydra_record(run_dir: Path, name: str, cfg: DictConfig, hydra: DictConfig, overrides) -> None:
    """Hydra's record of the command in ``run_dir/name`` (config.yaml, hydra.yaml,
    overrides.yaml, as Hydra writes them with ``hydra.output_subdir``), once it is accepted."""
    folder = run_dir / name
    folder.mkdir(parents=True, exist_ok=True)
    OmegaConf.save(cfg, folder / "config.yaml")
    OmegaConf.save(OmegaConf.create({"hydra": hydra}), folder / "hydra.yaml")
    OmegaConf.save(OmegaConf.create(list(overrides)), folder / "overrides.yaml")


def check_new_run(run_dir: Path) -> None:
    """A new run's folder must not hold a run already."""
    if (run_dir / "config.yaml").exists() or (run_dir / "run.json").exists():
        raise ConfigError(f"hydra.run.dir={run_dir} already holds a run; continue it with "
                          f"resume={run_dir}, or pick another folder")


@contextmanager
def run_lock(run_dir: Path) -> Iterator[None]:
    """Holds ``run_dir/.lock`` exclusively while the run lives; another process asking for
    it gets a :class:`ConfigError`. The OS drops the lock when its holder dies, so a killed
    run's folder is taken over by the next run (or resume) without ceremony."""
    fd = os.open(run_dir / ".lock", os.O_RDWR | os.O_CREAT, 0o644)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = _pid_in(fd)
        os.close(fd)
        raise ConfigError(f"run folder {run_dir} is in use by another run (pid {holder}); let it "
                          "finish or pick another folder") from None
    try:
        os.ftruncate(fd, 0)
        os.write(fd, str(os.getpid()).encode())
        yield
    finally:
        os.close(fd)


def _pid_in(fd: int) -> str:
    """The pid a run wrote into its lock file (``?`` if it has not yet)."""
    return os.read(fd, 32).decode(errors="replace").strip() or "?"


def lock_holder(run_dir: Path) -> str | None:
    """The pid of the live run holding ``run_dir``'s lock (:func:`run_lock`), or None: no
    lock there, or its holder is gone."""
    try:
        fd = os.open(run_dir / ".lock", os.O_RDONLY)
    except FileNotFoundError:
        return None
    try:
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)  # refused while a run holds it exclusively
        return None
    except BlockingIOError:
        return _pid_in(fd)
    finally:
        os.close(fd)  # and with it the shared lock this took


def start_run(cfg: DictConfig, run_dir: Path, choices: Mapping[str, str | None],
              overrides: list[str]) -> None:
    """A new run's folder: refused if it already holds a run; then config.yaml and run.json."""
    from runs.training_state import new_run_identity

    check_new_run(run_dir)
    OmegaConf.save(cfg, run_dir / "config.yaml", resolve=True)
    (run_dir / "run.json").write_text(json.dumps(
        {group: choices.get(group) for group in ("robot", "task", "learner", "tuned", "tuned_task")}
        | {"seed": int(cfg.seed), "overrides": overrides, "mode": str(cfg.mode)}
        | ({"checkpoint": str(cfg.checkpoint)} if cfg.mode == "eval" else {}) | new_run_identity(), indent=1))
