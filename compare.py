"""Compare the learners of a Hydra sweep folder again (a sweep prints it when it ends).

    python compare.py multirun/2026-11-21/12-00-00

Prints the table of :mod:`sweeps.comparison` (one row per robot/task, learner and
setting of the swept hyperparameters; the headline: the IQM of the task's own measure
over seeds with its 95% bootstrap confidence interval) and one line per job that did
not finish, and writes ``comparison.csv``, ``comparison.md`` and ``comparison.png``
into the sweep folder. A folder that is missing or holds no job: one ``error:`` line,
exit 2.
"""

from __future__ import annotations

import sys
from pathlib import Path

from runs.console import OneLineParser
from sweeps.comparison import NotASweep, report


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python compare.py", description=__doc__.splitlines()[0])
    parser.add_argument("sweep_dir", type=Path)
    args = parser.parse_args(argv)
    try:
        report(args.sweep_dir)
    except NotASweep as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
