"""Composing configs: as Hydra alone, with each YAML text parsed once, and with each composition kept (run by hand).

    python bench/compose.py [--rounds 3] [--robots cartpole cube ...]

Composes every shipped robot with every learner (``tasks.catalog.compose``, as a sweep's
jobs, the benchmark's pairs and the suite's tables of inputs do) three ways, alternating for
``--rounds`` rounds in this one process: as Hydra alone would (every file read and parsed at
each composition), with ``params.private_api.configs_parsed_once``'s parses kept (each text
parsed once in the process), and with ``tasks.catalog``'s compositions kept too (each
composition made, then a second one timed: its copy); checks that all three give the same
configs. Prints the CPU seconds of each and their ratios to the first; last line
``COMPOSE compositions=<n> plain_s=<v> parsed_once_s=<v> ratio=<v> kept_s=<v>
kept_ratio=<v>`` (the medians over the rounds).
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
    from tasks import catalog
    from tasks.catalog import compose, names

    pairs = [(robot, learner) for robot in args.robots or names("robot") for learner in names("learner")]

    def compose_all(forget_parses: bool) -> tuple[float, list]:
        start, configs = time.process_time(), []
        for robot, learner in pairs:
            catalog._composed.cache_clear()  # this composition is made, not copied
            if forget_parses:
                private_api._PARSED.clear()  # as Hydra alone: this composition parses its files
            configs.append(compose(robot, learner=learner))
        return time.process_time() - start, configs

    def copy_all() -> tuple[float, list]:
        seconds, configs = 0.0, []
        for robot, learner in pairs:
            compose(robot, learner=learner)  # made (and kept), outside the timing
            start = time.process_time()
            configs.append(compose(robot, learner=learner))
            seconds += time.process_time() - start
        return seconds, configs

    compose_all(True)  # imports and Hydra's plugin scan, outside the timing
    plain, once, kept = [], [], []
    for k in range(args.rounds):
        seconds, expected = compose_all(True)
        plain.append(seconds)
        seconds, configs = compose_all(False)
        once.append(seconds)
        assert configs == expected, "a composition differs when its files are parsed once"
        seconds, configs = copy_all()
        kept.append(seconds)
        assert configs == expected, "a kept composition differs from one made anew"
        print(f"round {k + 1}: {len(pairs)} compositions, plain {plain[-1]:.1f} s, parsed once {once[-1]:.1f} s "
              f"(ratio {once[-1] / plain[-1]:.2f}), kept {kept[-1]:.2f} s (ratio {kept[-1] / plain[-1]:.3f})",
              flush=True)
    p, o, c = statistics.median(plain), statistics.median(once), statistics.median(kept)
    print(f"COMPOSE compositions={len(pairs)} plain_s={p:.2f} parsed_once_s={o:.2f} ratio={o / p:.2f} "
          f"kept_s={c:.2f} kept_ratio={c / p:.3f}")


if __name__ == "__main__":
    main()
