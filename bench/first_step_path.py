"""The project files a run passes through from ``train.py`` to its first env step (run by hand).

    python bench/first_step_path.py [train.py arguments, e.g. robot=cube learner=dqn]

Runs ``train.cli`` in this process under ``sys.setprofile`` and stops it at the first call
of the env's step (``tasks/env.py``'s ``_step_and_maybe_reset``); every function called in
between (module code run by a lazy import too) counts its file, and every call from one
project file into another counts as a call across files. Hydra's plugin discovery imports
``hydra_plugins/`` at start-up, so those count too. The run folder goes to a temporary
folder.

Last lines: the files in the order first entered, then ``FIRST_STEP_PATH files=<n>
calls_across_files=<n>``.
"""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


class _Reached(BaseException):
    """The first env step: the trace stops here."""


def trace(args: list[str]) -> tuple[list[str], set[tuple[str, str, str]]]:
    """(files in the order first entered, the calls across files as (caller, callee, name))."""
    root, order, calls = str(ROOT), [], set()

    def project(filename: str) -> str | None:
        if filename.startswith(root) and "/.venv/" not in filename:
            return os.path.relpath(filename, root)
        return None

    def profile(frame, event, _arg):
        if event != "call":
            return
        here = project(frame.f_code.co_filename)
        if here is None:
            return
        if here not in order:
            order.append(here)
        caller = frame.f_back and project(frame.f_back.f_code.co_filename)
        if caller is not None and caller != here:
            calls.add((caller, here, frame.f_code.co_name))
        if here == "tasks/env.py" and frame.f_code.co_name == "_step_and_maybe_reset":
            raise _Reached

    with tempfile.TemporaryDirectory() as folder:
        sys.argv = ["train.py", *args, f"hydra.run.dir={folder}/run"]
        import train

        sys.setprofile(profile)
        try:
            train.cli()
        except (_Reached, SystemExit):
            pass
        finally:
            sys.setprofile(None)
    return order, calls


def main() -> None:
    order, calls = trace(sys.argv[1:])
    print("\n".join(order))
    print(f"FIRST_STEP_PATH files={len(order)} calls_across_files={len(calls)}")


if __name__ == "__main__":
    main()
