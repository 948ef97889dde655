"""The train command's words: its arguments as Hydra should parse them, and what Hydra
refused as one line (``train.py`` is the entry; this is what it does with its arguments).
"""

from __future__ import annotations

import atexit
import logging
import os
import re
import signal
import sys
from pathlib import Path
from typing import Callable

from hydra.errors import InstantiationException
from omegaconf import DictConfig, ListConfig, OmegaConf

from params import did_you_mean
from tasks.catalog import compose, unreadable_conf_file


def one_line(err: BaseException) -> str:
    """The innermost message of a config error, without Hydra's wrapping."""
    while isinstance(err, InstantiationException) and err.__cause__ is not None:
        err = err.__cause__
    return str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__


_VALUED = ("--config-dir", "-cd", "--config-name", "-cn", "--config-path", "-cp", "--cfg", "-c", "--package",
           "-p", "--experimental-rerun")
_INFO = ("all", "config", "defaults", "defaults-tree", "plugins", "searchpath")


def physical(arg: str) -> str:
    """``resume=`` or ``checkpoint=`` a path that exists, resolved through its symlinks before
    its ``..`` (as the file system does, where text would not: ``link/../K``)."""
    key, eq, value = arg.partition("=")
    if eq and key.lstrip("+") in ("resume", "checkpoint") and value and "${" not in value and "," not in value:
        path = Path(value)
        if path.exists():
            return f"{key}={path.resolve()}"
    return arg


def flags_first(args: list[str]) -> list[str]:
    """Hydra's options (``--config-dir d``, ``-m``, ...) before the overrides, wherever they were
    typed: Hydra's parser takes the overrides as one run of words, so ``robot=x --config-dir d
    mode=eval`` would be "unrecognized arguments"."""
    flags, overrides, i = [], [], 0
    while i < len(args):
        arg = args[i]
        if not arg.startswith("-"):
            overrides.append(arg)
        elif arg in _VALUED and i + 1 < len(args):
            flags += [arg, args[i + 1]]
            i += 1
        elif arg in ("--info", "-i") and i + 1 < len(args) and args[i + 1] in _INFO:
            flags += [arg, args[i + 1]]
            i += 1
        else:
            flags.append(arg)
        i += 1
    return [*flags, *overrides]


def config_dir_args(args: list[str]) -> list[str]:
    """The folders of Hydra's ``--config-dir`` / ``-cd`` options in ``args``."""
    found = []
    for i, arg in enumerate(args):
        if arg in ("--config-dir", "-cd") and i + 1 < len(args):
            found.append(args[i + 1])
        elif arg.startswith("--config-dir="):
            found.append(arg.split("=", 1)[1])
    return found


def _unknown_key(err: Exception) -> str | None:
    """Hydra's "Could not override 'learner.gama'" as our line: the key, the closest one
    there is and the keys of its node (composed with the command line's robot, task, learner)."""
    found = re.search(r"Could not override '([^']+)'", str(err))
    if found is None:
        return None
    key = found.group(1)
    picks = [a for a in sys.argv[1:] if a.split("=", 1)[0] in ("robot", "task", "learner")]
    try:
        cfg = compose(overrides=picks)
    except Exception:  # noqa: BLE001 - the suggestion is a courtesy
        return None
    parent = key.rpartition(".")[0]
    node = OmegaConf.select(cfg, parent) if parent else cfg
    if parent and node is not None and not isinstance(node, (DictConfig, ListConfig)):
        return f"{key} is not a setting: {parent} is a value here ({parent}={node!r}), not a group of settings"
    names = [k for k in node if not str(k).startswith("_")] if isinstance(node, DictConfig) else []
    if not names:
        return None
    where = f"{parent}." if parent else ""
    hint = did_you_mean(key.rpartition(".")[2], names, where)
    return f"{key} is not a setting; {hint}allowed{' in ' + parent if parent else ''}: {', '.join(map(str, names))}"


def _plugin_or_type_error(text: str) -> str | None:
    """Hydra's "Could not find 'hydra/launcher/ray'" (a launcher or sweeper not installed) and
    "Error merging override k=v (Value 'v' of type 'str' could not be converted to Integer ...)"
    (a launcher setting of the wrong type) as our line, or None."""
    found = re.search(r"Could not find 'hydra/(launcher|sweeper)/([^']+)' Available options in "
                      r"'hydra/\1': ([\w ]+?)(?: Config search path|$)", text)
    if found:
        group, name, options = found.groups()
        return (f"hydra/{group}={name} is not installed; installed: {', '.join(options.split())} "
                f"(a Hydra {group} plugin is a pip package, e.g. hydra-{'submitit-launcher' if group == 'launcher' else 'ax-sweeper'})")
    found = re.search(r"Error merging override (\S+) \(Value '(.*?)' of type '\w+' could not be "
                      r"converted to (\w+)", text)
    if found:
        override, value, kind = found.groups()
        return f"{override.split('=', 1)[0]} must be {'an' if kind[0] in 'AEIOU' else 'a'} {kind.lower()}; got {value!r}"
    found = re.search(r"Error merging override (\S+?)=(.*?) \(Cannot convert '(\w+)' to (\w+)", text)
    if found:
        key, value, got, kind = found.groups()
        return f"{key} must be a {kind}; got a {got}: {value}"
    return None


def _caused_by(err: BaseException, kind: type) -> bool:
    """Whether ``err`` or an exception in its chain (cause or context) is a ``kind``."""
    seen = set()
    while err is not None and id(err) not in seen:
        if isinstance(err, kind):
            return True
        seen.add(id(err))
        err = err.__cause__ or err.__context__
    return False


def hydra_error(err: Exception) -> str:
    """One line of what Hydra (or the OS, creating the run folder) refused."""
    unknown = _unknown_key(err)
    if unknown is not None:
        return unknown
    if _caused_by(err, UnicodeDecodeError):  # Hydra does not say which file
        searched = [Path(a.split("=", 1)[1].strip("[]").removeprefix("file://"))
                    for a in sys.argv[1:] if a.startswith("hydra.searchpath=")]
        bad = unreadable_conf_file([p for p in searched if p.is_dir()])
        if bad is not None:
            return f"{bad}; allowed: a YAML file in UTF-8"
    text = " ".join(line.strip() for line in str(err).splitlines() if line.strip())
    text = text.split(" Config search path:")[0]
    if isinstance(err, OSError) and err.filename:
        text = f"cannot create the run folder {err.filename}: {err.strerror}"
    cause = err.__cause__ or err.__context__
    if cause is not None and str(cause).strip() and str(cause).strip() not in text:
        text += f" ({' '.join(str(cause).split())})"
    return _plugin_or_type_error(text) or text or type(err).__name__


def end_promptly(main: Callable[[], None]) -> None:
    """Runs ``main`` as the program, then ends the process as soon as Python's exit handlers
    have run (logs flushed, loggers finished), with its exit status: the interpreter's own
    teardown of torch's and TorchRL's modules, which writes nothing, took 1.0-1.3 s after
    the VERDICT line on this machine. A second Ctrl-C (which aborts) ends in one line, exit
    130; an unexpected exception ends the usual way, its trace printed."""
    status: list[int] = []

    def end_now() -> None:  # registered first, so it runs after every other exit handler
        if status:
            logging.shutdown()
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(status[0])

    atexit.register(end_now)
    try:
        main()
    except SystemExit as stop:
        code = stop.code  # (Python prints a message given as the code before the exit handlers)
        status.append(code if isinstance(code, int) else 0 if code is None else 1)
        raise
    except KeyboardInterrupt:  # a second Ctrl-C (the first asks the runs to stop and save)
        print("aborted by Ctrl-C: nothing saved since each run's last checkpoint", file=sys.stderr)
        status.append(128 + signal.SIGINT)
        raise SystemExit(128 + signal.SIGINT) from None
    status.append(0)
