"""Composing configs with and without each YAML text parsed once per process (run by hand).

    python bench/compose.py [--rounds 3] [--robots cartpole cube ...]

Composes every shipped robot with every learner (``tasks.catalog.compose``, as a sweep's
jobs, the benchmark's pairs and the suite's tables of inputs do), once as Hydra alone would
(the parses forgotten before each composition: every file read and parsed at each) and once
with ``params.private_api.configs_parsed_once``'s parses kept (each text parsed once in the
process), alternating for ``--rounds`` rounds in this one process, and checks that both give
the same configs. Prints the CPU seconds of each and
their ratio; last line ``COMPOSE compositions=<n> plain_s=<v> parsed_once_s=<v> ratio=<v>``
(the medians over the rounds).
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--robots", nargs="+", help="the robots composed (default: every shipped one)")
    args = parser.parse_args()

    from params import private_api
    from tasks.catalog import compose, names

    pairs = [(robot, learner) for robot in args.robots or names("robot") for learner in names("learner")]

    def compose_all(forget: bool) -> tuple[float, list]:
        start, configs = time.process_time(), []
        for robot, learner in pairs:
            if forget:
                private_api._PARSED.clear()  # as Hydra alone: this composition parses its files
            configs.append(compose(robot, learner=learner))
        return time.process_time() - start, configs

    compose_all(True)  # imports and Hydra's plugin scan, outside the timing
    plain, once = [], []
    for k in range(args.rounds):
        seconds, expected = compose_all(True)
        plain.append(seconds)
        seconds, configs = compose_all(False)
        once.append(seconds)
        assert configs == expected, "a composition differs when its files are parsed once"
        print(f"round {k + 1}: {len(pairs)} compositions, plain {plain[-1]:.1f} s, "
              f"parsed once {once[-1]:.1f} s, ratio {once[-1] / plain[-1]:.2f}", flush=True)
    p, o = statistics.median(plain), statistics.median(once)
    print(f"COMPOSE compositions={len(pairs)} plain_s={p:.2f} parsed_once_s={o:.2f} ratio={o / p:.2f}")


if __name__ == "__main__":
    main()
