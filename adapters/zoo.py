"""rl-baselines3-zoo on the MujocoRL ids: ``python -m adapters.zoo <script> [the zoo's arguments]``
registers the ids in this process, then runs the zoo's ``rl_zoo3.<script>`` as
``python -m rl_zoo3.<script>`` would (its ``record_video`` has no ``--gym-packages``)::

    python -m adapters.zoo train --algo dqn --env MujocoRL/CartPoleStayUp-v0 --conf-file conf/zoo/dqn.yml -f logs/zoo
    python -m adapters.zoo enjoy --algo dqn --env MujocoRL/CartPoleStayUp-v0 -f logs/zoo --load-best
    python -m adapters.zoo record_video --algo dqn --env MujocoRL/CartPoleStayUp-v0 -f logs/zoo -n 1000

``train`` and ``enjoy`` also work as the zoo's own modules with ``--gym-packages
adapters.register_gym``. The zoo is not a dependency: ``pip install rl_zoo3``.
"""

from __future__ import annotations

import importlib.util
import runpy
import sys

import adapters.register_gym  # noqa: F401  (registers the MujocoRL ids)

SCRIPTS = ("train", "enjoy", "record_video", "record_training")


def main(argv: list[str] | None = None) -> None:
    """Runs ``rl_zoo3.<argv[0]>`` with the rest of ``argv`` as its command line."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv or argv[0] not in SCRIPTS:
        print(f"usage: python -m adapters.zoo {{{','.join(SCRIPTS)}}} [rl_zoo3's arguments]", file=sys.stderr)
        raise SystemExit(2)
    if importlib.util.find_spec("rl_zoo3") is None:
        print("error: adapters.zoo needs rl-baselines3-zoo: pip install rl_zoo3", file=sys.stderr)
        raise SystemExit(2)
    sys.argv = [f"rl_zoo3.{argv[0]}", *argv[1:]]
    runpy.run_module(f"rl_zoo3.{argv[0]}", run_name="__main__", alter_sys=True)


if __name__ == "__main__":
    main()
