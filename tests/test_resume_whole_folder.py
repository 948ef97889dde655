"""Killed anywhere and resumed, a run's folder ends file for file as an uninterrupted run's.

Every file of both folders is compared. What may differ, and why (nothing else may):

- wall-clock: ``timing.csv`` (seconds per episode), ``train.log`` (the console of each
  process, progress and times; the killed one's lines stay in it), the CSV logger's
  ``run/wall_s.csv``, ``summary.json``'s ``wall_s``, ``process_s`` and ``first_step_s``, checkpoint.pt's
  ``run.wall_s``, ``.lock`` (the process id of the run's last holder);
- identity: ``run_id`` (random per run: run.json's, in model.pt's ``meta.choices`` and
  checkpoint.pt's ``identity``), and the checksums that cover it;
- the folder's own path, in Hydra's record ``.hydra/hydra.yaml`` (compared with each
  run's path replaced by the same placeholder);
- the resume's own record: ``.hydra-resume/`` (Hydra's copy of the resume command), which
  only a resumed run has.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from inprocess import run_train
import torch

ROOT = Path(__file__).resolve().parents[1]
RUN = ["learner=qlearn", "num_envs=2", "max_episodes=60", "checkpoint_every=15", "eval_every=20",
       "eval_episodes=2", "seed=5", "quiet=true"]
WALL_CLOCK_FILES = {"timing.csv", "train.log", ".lock", "logs/run/scalars/run/wall_s.csv"}
WALL_CLOCK_FIELDS = {"summary.json": ("wall_s", "process_s", "first_step_s")}
RESUME_RECORD = ".hydra-resume"


def train(*args: str, kill_at: str | None = None, process: bool = False) -> subprocess.CompletedProcess:
    """``train.py <args>``: in this process unless it is killed or ``process`` (a folder made
    by a process of its own, Hydra's logging record as a user's holds it)."""
    if not kill_at and not process:  # in this process (tests/inprocess.py); a kill needs a process of its own
        return run_train(*args)
    script = ["tests/kill_at.py", kill_at] if kill_at else ["train.py"]
    return subprocess.run([sys.executable, *script, *args], cwd=ROOT, capture_output=True, text=True,
                          timeout=600)


@pytest.fixture(scope="module")
def whole(tmp_path_factory) -> Path:
    run_dir = tmp_path_factory.mktemp("whole") / "run"
    done = train(*RUN, f"hydra.run.dir={run_dir}", process=True)  # as the killed runs' first part
    assert done.returncode == 0, done.stderr[-1500:]
    return run_dir


def files(run_dir: Path) -> set[str]:
    return {p.relative_to(run_dir).as_posix() for p in run_dir.rglob("*") if p.is_file()}


def without(tree, drop: dict):
    """``tree`` (nested dicts) without the keys ``drop`` names (nested the same way)."""
    out = dict(tree)
    for key, inner in drop.items():
        if isinstance(inner, dict) and isinstance(out.get(key), dict):
            out[key] = without(out[key], inner)
        else:
            out.pop(key, None)
    return out


def same_checkpoint(a: Path, b: Path) -> bool:
    drop = {"checksum": 1, "identity": {"run_id": 1}, "run": {"wall_s": 1}, "meta": {"choices": {"run_id": 1}}}
    ta, tb = (without(torch.load(p, weights_only=True), drop) for p in (a, b))
    return _equal(ta, tb)


def _equal(x, y) -> bool:
    if isinstance(x, torch.Tensor):
        return isinstance(y, torch.Tensor) and x.dtype == y.dtype and torch.equal(x, y)
    if isinstance(x, dict):
        return isinstance(y, dict) and x.keys() == y.keys() and all(_equal(x[k], y[k]) for k in x)
    if isinstance(x, (list, tuple)):
        return type(x) is type(y) and len(x) == len(y) and all(_equal(i, j) for i, j in zip(x, y))
    return x == y


def assert_same_folder(resumed: Path, whole: Path) -> None:
    mine = files(resumed)
    assert {f for f in mine if not f.startswith(RESUME_RECORD + "/")} == files(whole)
    for name in sorted(files(whole) - WALL_CLOCK_FILES):
        a, b = resumed / name, whole / name
        if name.endswith(".pt"):
            assert same_checkpoint(a, b), name
        elif name == "run.json":
            assert without(json.loads(a.read_text()), {"run_id": 1}) == without(json.loads(b.read_text()),
                                                                                   {"run_id": 1})
        elif name.startswith(".hydra/"):
            assert (a.read_text().replace(str(resumed), "<run_dir>")
                    == b.read_text().replace(str(whole), "<run_dir>")), name
        elif name in WALL_CLOCK_FIELDS:
            drop = dict.fromkeys(WALL_CLOCK_FIELDS[name], 1)
            assert without(json.loads(a.read_text()), drop) == without(json.loads(b.read_text()), drop), name
        else:
            assert a.read_bytes() == b.read_bytes(), name


@pytest.mark.parametrize("point", ["second_checkpoint", "final_evaluation", "final_checkpoint", "model"])
def test_a_kill_anywhere_then_resume_ends_with_the_same_folder(tmp_path, whole, point):
    run_dir = tmp_path / "run"
    killed = train(*RUN, f"hydra.run.dir={run_dir}", kill_at=point)
    assert killed.returncode == -9, killed.stderr[-1500:]
    assert not (run_dir / "summary.json").exists()
    resumed = train(f"resume={run_dir}")
    assert resumed.returncode == 0, resumed.stderr[-1500:]
    assert_same_folder(run_dir, whole)


def test_the_comparison_sees_a_repeated_evaluation_row(tmp_path, whole):
    """The check above catches the old fault: the final evaluation's row written twice."""
    import shutil

    copy = tmp_path / "run"
    shutil.copytree(whole, copy)
    for record in (copy / ".hydra").iterdir():  # as if it had been run in its own folder
        record.write_text(record.read_text().replace(str(whole), str(copy)))
    assert_same_folder(copy, whole)
    rows = (copy / "evals.csv").read_text().splitlines()
    (copy / "evals.csv").write_text("\n".join([*rows, rows[-1]]) + "\n")
    with pytest.raises(AssertionError, match="evals.csv"):
        assert_same_folder(copy, whole)


def test_resuming_a_finished_run_is_refused_and_touches_nothing(tmp_path, whole):
    import shutil

    finished = tmp_path / "run"
    shutil.copytree(whole, finished)
    before = {name: (finished / name).read_bytes() for name in files(finished) - {"train.log"}}
    done = train(f"resume={finished}")
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and f"resume={finished}: it is finished" in lines[0], done.stderr
    assert all((finished / name).read_bytes() == data for name, data in before.items())
