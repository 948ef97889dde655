"""Every command in README.md and docs/ run as a reader would, on a small budget: CI's last step.

``python -m tests.documented`` copies the checkout's files to a scratch folder (HOME there
too, so ``~/my_robots`` is the reader's own), runs the quick start's setup there as written
(``python3.11 -m venv .venv && .venv/bin/pip install -e .``), then every documented
command in page order (README first, then docs/ by name), each through bash with that
venv's ``bin`` first on PATH, and stops at the first that fails: its page and line, the
command and the end of its output. A block that shows a file the reader writes
(``~/my_robots/robot/my_acrobot.yaml``) is written, a block of Python that starts with its
imports is run as a script; ``<run>``, ``<run folder>`` and the
sweep placeholders become the folders the earlier commands made (``<cartpole run>``:
the latest of that robot); a ``$`` command is one
whose documented output (the lines under it) must appear; an installed user's command
(``mujoco-rl-train``, one marked ``# installed``, the block under "a plain `pip install .`")
runs from HOME with the project installed plainly in a venv of its own; a ``resume=`` command continues a
run (or sweep) the runner starts and stops with Ctrl-C just before. Training gets a budget of a few
episodes (:data:`BUDGET`); the benchmarks, their small arguments (:data:`SMALL`). What cannot
run here is listed with why (:data:`SKIP`): a Slurm cluster, a browser, the test command
CI runs itself.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
STARTS = (".venv/bin/", "python", "mujoco-rl-", "mkdir ", "cp ", "$ ")
#: key=value set on every training command (a value the command gives is replaced).
BUDGET = {"max_episodes": "3", "max_env_steps": "400", "eval_episodes": "2", "video_steps": "20",
          "hydra.sweeper.n_trials": "2", "hydra.sweeper.budget_steps": "1000",
          "hydra.sweeper.report_every": "500"}
#: What a tuning sweep sets for each job itself (its budget: the hydra.sweeper keys).
SWEEPER_SETS = ("max_episodes", "max_env_steps", "eval_episodes")
#: A benchmark script -> the arguments that make it small (its own are kept where not named).
SMALL = {
    "bench/learners.py": "max_env_steps=300 --robots cartpole --learners qlearn --seeds 0",
    "bench/env_throughput.py": "--seconds 0.2 --rounds 1 --robots cartpole --sizes 1 8",
    "bench/update_rate.py": "--seconds 0.05 --rounds 1",
    "bench/seed_batch.py": "--seeds 2 --learners qlearn --num-envs 1 --qlearn-steps 400",
    "bench/async_bound.py": "--steps 100 --rounds 1",
    "bench/soak.py": "--episodes 40 --every 20",
    "bench/tune_batch.py": "--trials 2 --budget 1000 --per-batch 2",
    "bench/width.py": "--members 4 --steps 20 --repeats 1",
    "bench/answers.py": "--rounds 1",
    "bench.benchmark --tune": "--dry-run",
    "bench/time_to_solve.py": "--seeds 0 --overrides max_episodes=3 max_env_steps=400",
    "bench/vs_sb3.py": "--cap 500 --overrides max_episodes=3 max_env_steps=400",
    "bench/vs_sb3_continuous.py": "--cap 2000 --eval-every 1000 --out vs_sb3_check",
    "bench/first_step_path.py": "",
    "bench/compose.py": "--rounds 1 --robots cartpole",
    "rl_zoo3.train": "-n 2000 --eval-freq 1000 --eval-episodes 2",  # a best model for --load-best
    "rl_zoo3.enjoy": "-n 200",
    "adapters.zoo record_video": "-n 50",  # small as it is: one build and one step
}
#: A mark in the command -> why it is not run here.
SKIP = {
    "-m pytest": "the test command: .ci/run runs it itself",
    "slurm": "needs a Slurm cluster",
    "site_check.py": "needs Playwright's Chromium (bench/site_check.py: pip install playwright)",
    "tensorboard --logdir": "a server: the suite's tests/test_loggers.py reads what it serves",
    "before_after.py": "needs the checkout's git history (it builds an earlier commit's worktree)",
}


@dataclass
class Step:
    """One documented command (or a file the reader writes), where it is."""

    where: str
    command: str
    expect: list[str] | None = None  # a $ command's documented output (a line may end "...")
    file: str | None = None          # a file block: its path (command is its text)
    python: bool = False             # a Python snippet (command: python -c '<its code>')
    installed: bool = False          # an installed user's command: a plain install, from HOME


def blocks(page: Path) -> list[tuple[int, list[str], str]]:
    """``(line, lines, paragraph)`` of each indented code block of ``page``: its first line's
    number, its lines without the indent, and the prose just above it."""
    lines = page.read_text().splitlines()
    found, i, prose, blank = [], 0, [], True
    while i < len(lines):
        match = re.match(r"^( {4,})\S", lines[i])
        if match and (i == 0 or not lines[i - 1].strip()):
            indent, start, body = len(match.group(1)), i, []
            while i < len(lines) and (lines[i].startswith(" " * indent) or not lines[i].strip()):
                body.append(lines[i][indent:])
                i += 1
            while body and not body[-1].strip():
                body.pop()
            found.append((start + 1, body, " ".join(prose)))
            prose, blank = [], True
            continue
        if lines[i].strip():
            prose = (prose if not blank else []) + [lines[i].strip()]
        blank = not lines[i].strip()
        i += 1
    return found


def steps(pages: list[Path] = PAGES) -> list[Step]:
    """Every documented command and reader's file, in page order."""
    found, files = [], {}
    for page in pages:
        name = page.relative_to(ROOT)
        for line, body, prose in blocks(page):
            target = re.findall(r"`(~/[^`]+\.(?:yaml|xml))`", prose)
            if len(target) == 1 and not body[0].startswith(STARTS):
                files[target[0]] = "\n".join(body) + "\n"
                found.append(Step(f"{name}:{line}", files[target[0]], file=target[0]))
                continue
            if body[0].startswith(("import ", "from ")):  # a Python snippet: run as a script
                code = "\n".join(body) + "\n"
                found.append(Step(f"{name}:{line}", f"python -c {shlex.quote(code)}", python=True))
                continue
            j = 0
            while j < len(body):
                text, where = body[j], f"{name}:{line + j}"
                while text.rstrip().endswith("\\") and j + 1 < len(body):
                    j += 1
                    text = text.rstrip()[:-1] + " " + body[j].strip()
                j += 1
                if text.startswith("# write "):  # a page's pointer to the files another page shows
                    found += [Step(where, "", file=path) for path in re.findall(r"~/\S+\.yaml", text)]
                if not text.startswith(STARTS):
                    continue
                if text.startswith("$ "):
                    expect = []
                    while j < len(body) and not body[j].startswith("$ ") and body[j].strip():
                        expect.append(body[j].strip())
                        j += 1
                    found.append(Step(where, text[2:], expect=expect))
                else:
                    installed = (text.startswith("mujoco-rl-") or "# installed" in text
                                 or "plain `pip install .`" in prose)
                    found.append(Step(where, strip_comment(text), installed=installed))
    for step in found:
        if step.file and not step.command:
            step.command = files.get(step.file, "")
    return found


def strip_comment(text: str) -> str:
    """``text`` without its trailing comment (`` # ...`` or ``  #...``)."""
    return text.split(" # ")[0].split("  #")[0].rstrip()


def budgeted(command: str) -> str:
    """``command`` with :data:`BUDGET` on its training part and :data:`SMALL` on a benchmark."""
    for mark, extra in SMALL.items():
        if mark in command:
            command = re.sub(r"\s+\[[^\]]*\]", "", command)
            return f"{command} {extra}".rstrip()
    head, sep, train = command.rpartition("&& ")
    words = train.split()
    if not any(w.endswith(("train.py", "mujoco-rl-train")) or w == "train" for w in words):
        return command
    for key, value in BUDGET.items():
        tuning = "hydra/sweeper=optuna" in train
        if (key.startswith("hydra.sweeper") and not tuning) or (key in SWEEPER_SETS and tuning):
            continue
        if key == "video_steps" and "video=true" not in train:
            continue
        given = [w for w in words if w.startswith(f"{key}=")]
        words = [f"{key}={value}" if w in given else w for w in words]
        if not given and not (("mode=eval" in train or "resume=" in train) and key.startswith("max_")):
            words.append(f"{key}={value}")
    return f"{head}{sep}{' '.join(words)}"


class Reader:
    """The scratch checkout, the folders the commands made, and running one step."""

    def __init__(self, work: Path) -> None:
        self.work, self.home = work, work / "home"
        self.home.mkdir(exist_ok=True)
        self.runs: list[Path] = []
        self.sweep: Path | None = None
        self.note(set())  # a kept folder's runs and sweep

    def env(self, venv: Path | None = None) -> dict:
        """The reader's environment: ``venv`` (default the checkout's) first on PATH, its own
        HOME, and no MUJOCO_GL (headless rendering is the project's default, as a reader finds
        it)."""
        path = f"{(venv or self.work / '.venv') / 'bin'}:{os.environ['PATH']}"
        env = {**os.environ, "HOME": str(self.home), "PATH": path}
        env.pop("MUJOCO_GL", None)
        return env

    def placed(self, command: str) -> str:
        """The placeholders filled with the folders the earlier commands made: ``outputs/<run>``,
        ``<run folder>`` and ``<run>`` the latest run, ``<cartpole run>`` the latest of that
        robot, the sweep's forms the latest sweep."""
        def run(match: re.Match) -> str:
            robot = match.group(1)
            found = [r for r in self.runs if not robot or f"_{robot.strip()}_" in r.name]
            if not found:
                raise RuntimeError(f"{match.group(0)}: no earlier command made one")
            return str(found[-1])

        command = re.sub(r"(?:outputs/)?<(\w+ )?run(?: folder)?>", run, command)
        for mark in ("multirun/<date>/<time>_<pid>", "multirun/<date>/<time>", "<sweep folder>"):
            if mark in command:
                if self.sweep is None:
                    raise RuntimeError(f"{mark}: no earlier command made one")
                command = command.replace(mark, str(self.sweep))
        return command

    def installed(self) -> Path:
        """A venv outside the checkout with the project installed plainly (``pip install``,
        not editable), made at its first use: an installed user's."""
        venv = self.home / "installed"
        if not (venv / "bin" / "mujoco-rl-train").is_file():
            subprocess.run(["bash", "-c", f"python3.11 -m venv {venv} && {venv}/bin/pip install -q {self.work}"],
                           cwd=self.home, env=self.env(venv), check=True, timeout=900)
        return venv

    def folders(self) -> set[Path]:
        """Every run and sweep folder, in the checkout and in HOME (an installed user's)."""
        found = set()
        for top in (self.work / "outputs", self.work / "multirun", self.home / "outputs"):
            found |= {p for p in top.glob("*/*") if p.is_dir()} if top.is_dir() else set()
        return found

    def stopped(self, sweep: bool) -> None:
        """A run (or a sweep of two seeds) stopped by Ctrl-C once it trains, for a ``resume=``
        command to continue."""
        args = ["-m", "seed=0,1"] if sweep else []
        before = self.folders()
        proc = subprocess.Popen([str(self.work / ".venv" / "bin" / "python"), "train.py", *args,
                                 "max_episodes=300", "log_every=1"], cwd=self.work, env=self.env(),
                                text=True, stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        for line in proc.stdout:
            if line.split("] ")[-1].startswith("episode "):  # training: its first progress line
                break
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=120)
        self.note(before)

    def note(self, before: set[Path]) -> None:
        """Takes in the folders made since ``before``: the latest sweep, the runs in order."""
        for folder in sorted(self.folders() - before, key=lambda p: p.stat().st_mtime):
            if folder.parts[-2].count("-") == 2 and folder.parent.parent.name == "multirun":
                self.sweep = folder
            elif folder.parent.parent.name == "outputs" and "_eval_" not in folder.name:
                self.runs.append(folder)

    def do(self, step: Step) -> tuple[bool, str, str]:
        """Runs ``step``; ``(ok, output, what ran)``."""
        if step.file:
            path = Path(step.file.replace("~", str(self.home), 1))
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(step.command)
            return True, "", f"wrote {path}"
        if "resume=" in step.command and not step.python:
            self.stopped(sweep="sweep" in step.command)
        command = step.command if step.python else self.placed(step.command)
        command = command if step.python or step.expect is not None else budgeted(command)
        before = self.folders()
        where, env = (self.home, self.env(self.installed())) if step.installed else (self.work, self.env())
        proc = subprocess.run(["bash", "-c", command], cwd=where, env=env, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, timeout=900)
        self.note(before)
        if step.expect is not None:
            missing = [line for line in step.expect  # a line the page cuts with "..." matches its start
                       if line.removesuffix("...").rstrip(", ") not in proc.stdout]
            return proc.returncode != 0 and not missing, proc.stdout + "".join(
                f"\nmissing from the output: {line}" for line in missing), command
        return proc.returncode == 0, proc.stdout, command


def copy_checkout(to: Path) -> None:
    """The checkout's tracked and untracked-not-ignored files, into ``to``."""
    listed = subprocess.run(["git", "ls-files", "-co", "--exclude-standard", "-z"], cwd=ROOT,
                            capture_output=True, text=True, check=True).stdout.split("\0")
    for name in filter(None, listed):
        source = ROOT / name
        if source.is_file():
            (to / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, to / name)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--list", action="store_true", help="print the steps and what each runs, run nothing")
    parser.add_argument("--keep", action="store_true", help="leave the scratch folder")
    parser.add_argument("--again", type=Path, metavar="FOLDER", help="reuse a kept scratch folder (its "
                        "venv and folders), from the step --start (PAGE:LINE) on")
    parser.add_argument("--start", default=None, help="with --again: the first step to run")
    args = parser.parse_args(argv)
    todo = steps()
    if args.list:
        for step in todo:
            why = next((w for mark, w in SKIP.items() if mark in step.command), None)
            shown = step.command if step.expect is not None else budgeted(step.command)
            print(f"{step.where}: {'write ' + step.file if step.file else shown}"
                  f"{'   [installed, from HOME]' if step.installed else ''}"
                  f"{'   [skipped: ' + why + ']' if why else ''}")
        return 0
    work = args.again or Path(tempfile.mkdtemp(prefix="documented-"))
    if args.again:
        wheres = [step.where for step in todo]
        todo = todo[wheres.index(args.start):] if args.start else todo
        args.keep = True
    else:
        copy_checkout(work)
    reader, done, start = Reader(work), {}, time.monotonic()
    try:
        for step in todo:
            why = next((w for mark, w in SKIP.items() if mark in step.command), None)
            if why:
                print(f"skipped {step.where}: {why}", flush=True)
                continue
            if step.command in done and not step.file:
                print(f"same    {step.where}: as {done[step.command]}", flush=True)
                continue
            t0 = time.monotonic()
            ok, output, ran = reader.do(step)
            done.setdefault(step.command, step.where)
            print(f"{'ok' if ok else 'FAILED':7} {step.where} ({time.monotonic() - t0:.0f} s)", flush=True)
            if not ok:
                print(f"  {ran}\n"
                      + "\n".join("  | " + line for line in output.splitlines()[-30:]), file=sys.stderr)
                return 1
        print(f"every documented command ran ({time.monotonic() - start:.0f} s)")
        return 0
    finally:
        if not args.keep:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    sys.exit(main())
