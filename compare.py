"""Compare the learners of a Hydra sweep folder again (a sweep prints it when it ends).

    python compare.py multirun/2026-11-21/12-00-00
    python compare.py multirun/2026-11-21/12-00-00 --x wall_s   # the plot against wall time

Prints the table of :mod:`sweeps.comparison` (one row per robot/task, learner and
setting of the swept hyperparameters; the headline: the IQM over seeds of the task's own
measure as its judge sees it, ``greedy_<measure>`` or ``train_<measure>_last<window>``,
with its 95% bootstrap confidence interval) and one line per job that did not finish,
and writes ``comparison.csv``, ``comparison.md`` and ``comparison.png`` (learning curves
and greedy evaluations against env steps, or wall seconds with ``--x wall_s``) into the
sweep folder. A folder that is missing or holds no job, or an unknown ``--x``: one
``error:`` line, exit 2.
"""

from __future__ import annotations

import sys
from pathlib import Path

from runs.console import OneLineParser
from sweeps.comparison import NotASweep, report
from sweeps.comparison_plot import X_AXES


def main(argv: list[str] | None = None) -> int:
    parser = OneLineParser(prog="python compare.py", description=__doc__.splitlines()[0])
    parser.add_argument("sweep_dir", type=Path)
    parser.add_argument("--x", choices=X_AXES, default="env_steps",
                        help="comparison.png's x-axis: env steps (default) or wall seconds")
    args = parser.parse_args(argv)
    try:
        report(args.sweep_dir, x=args.x)
    except NotASweep as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
