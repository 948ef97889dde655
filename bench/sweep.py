"""Run a Hydra multirun of train.py and read back each job's summary (for the benchmarks)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from runs.summary import summarize_run  # noqa: E402
from sweeps import child  # noqa: E402


def run_to_solve(overrides: list[str], run_dir: Path) -> dict:
    """One ``train.py <overrides> quiet=true`` into ``run_dir``: its summary, with ``solved``
    and, at solving (or at the end when it did not), ``episodes``, ``env_steps`` and ``wall_s``
    (the run's own clock). A run stopped part way there (Ctrl-C, a benchmark stopped or
    killed) is continued from its checkpoint (``resume=``)."""
    if "resume" in summarize_run(run_dir):
        cmd = [sys.executable, "train.py", f"resume={run_dir}"]
    else:
        cmd = [sys.executable, "train.py", *overrides, "quiet=true", f"hydra.run.dir={run_dir}"]
    print("running:", " ".join(cmd), flush=True)
    stopped = f"stopped; {run_dir} keeps its checkpoint: the same command continues it"
    try:  # a Ctrl-C or SIGTERM of this process goes on to train.py, which saves and ends
        code = child.call(cmd, ROOT)
    except child.Stopped:
        raise SystemExit(stopped) from None
    if code in child.STOPPED:
        raise SystemExit(stopped)
    s = summarize_run(run_dir)
    if s.get("status") != "ok":
        raise SystemExit(f"our run failed; see {run_dir}")
    solved = bool(s["solved"])
    return {**s, "solved": solved, "episodes": s["episodes_to_solve"] if solved else s["episodes"],
            "env_steps": s["steps_to_solve"] if solved else s["env_steps"],
            "wall_s": s["wall_to_solve"] if solved else s["wall_s"]}


def run_sweep(name: str, overrides: list[str]) -> tuple[Path, list[dict]]:
    """``train.py -m <overrides>`` into ``multirun/<name>_<time>``; one summary per job."""
    sweep_dir = ROOT / "multirun" / f"{name}_{time.strftime('%Y%m%d-%H%M%S')}"
    cmd = [sys.executable, "train.py", "-m", "quiet=true", f"hydra.sweep.dir={sweep_dir}", *overrides]
    print("running:", " ".join(cmd), flush=True)
    proc = subprocess.run(cmd, cwd=ROOT, check=False)
    if not sweep_dir.is_dir():
        sys.exit(f"error: the sweep did not start (train.py exit code {proc.returncode})")
    return sweep_dir, job_summaries(sweep_dir)


def job_summaries(sweep_dir: Path) -> list[dict]:
    """One summary per job folder of a sweep, in job order."""
    jobs = sorted((p for p in Path(sweep_dir).iterdir() if p.is_dir() and p.name.split("_")[0].isdigit()),
                  key=lambda p: int(p.name.split("_")[0]))
    return [summarize_run(d) for d in jobs]


def fmt(value, spec: str = ".0f") -> str:
    return "-" if value is None else format(value, spec)
