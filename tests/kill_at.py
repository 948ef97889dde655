"""``python tests/kill_at.py <point> <train.py arguments>``: ``train.py``, killed by SIGKILL
where ``<point>`` says (a test's way to land a kill exactly there; a real kill gives no
warning, so nothing after the point runs: no ``finally``, no flush).

Points: ``second_checkpoint`` (just after the second periodic checkpoint.pt is saved;
``checkpoint:N`` after the N-th, counting every run of a batch),
``final_evaluation`` (training done, before the final greedy evaluation),
``final_checkpoint`` (just after the final checkpoint.pt, before the files of the end),
``model`` (just after model.pt, before eval.json and summary.json).
"""

from __future__ import annotations

import os
import runpy
import signal
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runs import lifecycle as session  # noqa: E402


def die(*_args, **_kwargs) -> None:
    sys.stdout.flush()
    os.kill(os.getpid(), signal.SIGKILL)


def after(function, calls: int = 1):
    """``function``, then a kill once it has been called ``calls`` times."""
    count = [0]

    def wrapped(*args, **kwargs):
        out = function(*args, **kwargs)
        count[0] += 1
        if count[0] >= calls:
            die()
        return out

    return wrapped


def arm(point: str) -> None:
    if point == "second_checkpoint":
        session.save_training_state = after(session.save_training_state, calls=2)
    elif point.startswith("checkpoint:"):
        session.save_training_state = after(session.save_training_state, calls=int(point.split(":")[1]))
    elif point == "final_evaluation":
        session.final_evaluation = die
    elif point == "final_checkpoint":
        session.save_model = die  # the session saves model.pt right after its final checkpoint
    elif point == "model":
        session.save_model = after(session.save_model)
    else:
        raise SystemExit(f"unknown kill point {point}")


if __name__ == "__main__":
    arm(sys.argv.pop(1))
    sys.argv[0] = str(ROOT / "train.py")
    runpy.run_path(sys.argv[0], run_name="__main__")  # as `python train.py`: Hydra's record the same
