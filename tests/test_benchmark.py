"""``python -m bench.benchmark``: end to end on the ``--quick`` preset with a tiny budget, and
its one-line errors for bad input."""

from __future__ import annotations

import csv
import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from bench import benchmark
from sweeps import child

ROOT = Path(__file__).resolve().parents[1]


def _readme(tmp_path: Path) -> Path:
    readme = tmp_path / "README.md"
    readme.write_text(f"# x\n\n## Benchmark\n\n{benchmark.BEGIN}\nold table\n{benchmark.END}\n\n## After\n")
    return readme


@pytest.mark.parametrize("solo", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_quick_benchmark_end_to_end(tmp_path, solo):
    out, readme = tmp_path / "results", _readme(tmp_path)
    cmd = [sys.executable, "-m", "bench.benchmark", "--quick", "--seeds", "2", "--budget", "1600",
           "--out", str(out), "--readme", str(readme), *(["--solo"] if solo else ["--jobs", "2"]),
           "--", "task.max_episode_steps=100", "eval_episodes=4"]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    with open(out / "seeds.csv") as f:
        seeds = list(csv.DictReader(f))
    # the quick preset: cart-pole x qlearn and dqn with their tuned files, seeds 1000 and 1001
    assert [(r["learner"], r["setting"], r["seed"]) for r in seeds] == [
        ("qlearn", "tuned", "1000"), ("qlearn", "tuned", "1001"),
        ("dqn", "tuned", "1000"), ("dqn", "tuned", "1001")]
    for row in seeds:
        assert row["status"] == "ok" and row["measure"] == "length"
        assert int(row["env_steps"]) <= 1600 + 16  # the budget, up to one batched step
        assert float(row["greedy"]) > 0
        # success is the final greedy policy meeting the threshold, nothing else
        assert (row["success"] == "True") == (float(row["greedy"]) >= float(row["threshold"]))
        assert Path(row["run_dir"], "eval.json").is_file()
    with open(out / "benchmark.csv") as f:
        pairs = list(csv.DictReader(f))
    assert [(p["learner"], p["seeds"], p["budget_steps"]) for p in pairs] == [
        ("qlearn", "2", "1600"), ("dqn", "2", "1600")]
    text = readme.read_text()
    assert "old table" not in text and text.endswith("## After\n")
    table = text.split(benchmark.BEGIN)[1].split(benchmark.END)[0]
    assert "**cartpole** (cartpole/stay_up, success: greedy length >= 250" in table
    assert "| qlearn | tuned (cartpole_qlearn) | " in table and "| dqn | tuned (cartpole_dqn) | " in table
    assert "greedy_length IQM [95% CI]" in table
    # the page's figure beside it: sample efficiency and the final IQM of each pair
    assert "](assets/benchmark/benchmark-cartpole.png)" in table
    assert (tmp_path / "assets" / "benchmark" / "benchmark-cartpole.png").stat().st_size > 10_000
    # --solo: what training the seeds in one process saved, against the first seed alone
    assert (table.count("2 seeds in one process: ") == 2 and "one seed alone" in table) == solo
    assert Path(str(out / "cartpole" / "dqn_tuned") + "_solo", "summary.json").is_file() == solo
    # --jobs 2: the two pairs trained at once (the second started before the first ended)
    first, second = (json.loads((out / "cartpole" / f"{name}_tuned.json").read_text()) for name in ("qlearn", "dqn"))
    overlap = time.mktime(time.strptime(second["started"], "%Y-%m-%dT%H:%M:%S")) < (
        time.mktime(time.strptime(first["started"], "%Y-%m-%dT%H:%M:%S")) + first["wall_s"])
    assert overlap != solo
    # Read back from its folder, the run gives the same table (its command line aside), and
    # so it does from its records alone (a results folder kept in the repository: no job folders).
    figure = (tmp_path / "assets" / "benchmark" / "benchmark-cartpole.png").read_bytes()
    strip = lambda s: s.split("\n", 1)[1]  # noqa: E731 - the first line names the command
    for folders in ("kept", "removed"):
        if folders == "removed":
            for sweep in (out / "cartpole").iterdir():
                if sweep.is_dir():
                    shutil.rmtree(sweep)
        again = tmp_path / "again" / "README.md"
        again.parent.mkdir(exist_ok=True)
        again.write_text(readme.read_text().replace(table, "\nx\n"))
        benchmark.main(["--read", str(out), "--readme", str(again)])
        assert strip(again.read_text().split(benchmark.BEGIN)[1]) == strip(text.split(benchmark.BEGIN)[1]), folders
        assert (again.parent / "assets" / "benchmark" / "benchmark-cartpole.png").read_bytes() == figure, folders
    with open(out / "seeds.csv") as f:
        assert [(r["learner"], r["seed"], r["greedy"]) for r in csv.DictReader(f)] == [
            (r["learner"], r["seed"], r["greedy"]) for r in seeds]
    record = json.loads((out / "cartpole" / "qlearn_tuned.json").read_text())
    assert record["tuned_file"] == "cartpole_qlearn" and len(record["seeds"]) == 2
    assert all(len(row["evaluations"]) >= 1 for row in record["seeds"])


@pytest.mark.parametrize("argv, says", [
    (["--tasks", "moon"], "unknown task 'moon'; the benchmark's tasks: cartpole, cube, cube_minus_y, maze, wall"),
    (["--learners", "sarsa"], "unknown learner 'sarsa'; learners: dqn, mbalunovic, n1try, ppo, qlearn, rainbow, "
                              "ruippeixotog, sac, td3, dqn_nstep"),
    (["--seeds", "0"], "--seeds must be at least 1, got 0"),
    (["--budget", "-3"], "--budget must be a positive number of env steps, got -3"),
    (["--settings", "best"], "unknown setting 'best'; settings: published, tuned"),
    (["--tune", "--jobs", "0"], "--jobs must be at least 1 (studies at once), got 0"),
    (["--quick", "--jobs", "0"], "--jobs must be at least 1 (pairs at once), got 0"),
    (["--quick", "--threads", "0"], "--threads must be at least 1 (torch threads a pair's process), got 0"),
    (["--tune", "--threads", "2"], "--threads is for training pairs; a study (--tune) is one process of one thread"),
    (["--quick", "--solo", "--jobs", "2"], "--solo times a seed alone beside nothing else: give it --jobs 1"),
    (["--tune", "--studies", "/etc"], "--studies must be a folder inside the project (its journals are kept "
                                      "with it), got /etc"),
    (["--tune", "--minutes", "--studies", "bench/no_such_folder"],
     "no study journal (<task>_<learner>.log) in bench/no_such_folder"),
    (["--quick", "--budget", "100"], "a budget of 100 env steps cannot finish an episode of cartpole x qlearn "
                                     "(tuned): 8 copies x up to 1000 steps need 8000; give --budget 8000 or more"),
    (["--read", "/no/such/folder"], "--read /no/such/folder: no such results folder"),
    (["--quick", "--", "learner.no_such_knob=3"], "cartpole x qlearn (tuned): "),
])
def test_bad_input_is_one_line(argv, says, tmp_path):
    out = ["--out", str(tmp_path / "o")]
    at = argv.index("--") if "--" in argv else len(argv)
    with pytest.raises(SystemExit) as exc:
        benchmark.main([*argv[:at], *out, *argv[at:]])
    message = str(exc.value)
    assert message.startswith("error: ") and says in message and "\n" not in message
    assert not (tmp_path / "o").exists()  # nothing ran


@pytest.mark.skipif(not (ROOT / ".git").exists(), reason="not a git checkout")
def test_a_results_folder_in_the_repository_keeps_its_records_not_its_job_folders():
    """``--out bench/results/<name>``: git keeps the plan, the tables and each pair's record;
    its sweeps' job folders (and a --solo run's), and the pairs' consoles, stay out."""
    def ignored(path: str) -> bool:
        return subprocess.run(["git", "check-ignore", "-q", "--no-index", path], cwd=ROOT).returncode == 0

    base = "bench/results/main"
    for kept in ("plan.json", "seeds.csv", "benchmark.csv", "benchmark.md", "cartpole/qlearn_tuned.json"):
        assert not ignored(f"{base}/{kept}"), kept
    for left in ("cartpole/qlearn_tuned/", "cartpole/qlearn_tuned/0_cartpole_qlearn_seed1000/metrics.csv",
                 "cartpole/qlearn_tuned_solo/", "cartpole/qlearn_tuned.log"):
        assert ignored(f"{base}/{left}"), left


def test_missing_markers_is_one_line(tmp_path):
    readme = tmp_path / "README.md"
    readme.write_text("# no markers\n")
    with pytest.raises(benchmark.BadInput, match="has no <!-- benchmark:begin --> ... "):
        benchmark.rewrite_readme(readme, "table\n")


@pytest.mark.parametrize("page", ["missing.md", "no_markers.md", "binary.md"])
def test_a_page_that_cannot_take_the_table_is_refused_before_any_pair_runs(tmp_path, page):
    """``--readme`` naming a missing page, one that is not text, or one without the markers:
    one line, before the benchmark trains anything (its results folder not even made)."""
    (tmp_path / "no_markers.md").write_text("# no markers\n")
    (tmp_path / "binary.md").write_bytes(b"\x89PNG\xff\xfe")
    out = tmp_path / "results"
    with pytest.raises(SystemExit) as stop:
        benchmark.main(["--quick", "--seeds", "1", "--out", str(out), "--readme", str(tmp_path / page)])
    message = str(stop.value.code)
    assert message.startswith("error: ") and "\n" not in message
    assert ("has no <!-- benchmark:begin -->" if page == "no_markers.md" else "cannot read it") in message
    assert not out.exists()


def test_a_results_folder_takes_more_jobs_and_keeps_finished_ones(tmp_path):
    """``--out`` of an earlier benchmark: new pairs join its plan, a finished pair is never
    rerun nor replaced by other settings, an unfinished one is replaced."""
    job = lambda learner, budget=1000: benchmark.Job(  # noqa: E731
        "cartpole", "cartpole", "stay_up", learner, "tuned", budget, (1000, 1001))
    done, stopped = job("qlearn"), job("dqn")
    (tmp_path / "cartpole").mkdir()
    (tmp_path / "cartpole" / "qlearn_tuned.json").write_text('{"returncode": 0, "wall_s": 3.0}')
    (tmp_path / "cartpole" / "dqn_tuned.json").write_text('{"returncode": -9, "wall_s": 3.0}')
    merged = benchmark.merge([done, stopped], [job("n1try"), job("dqn", 2000), done], tmp_path)
    assert merged == [done, job("dqn", 2000), job("n1try")]
    assert benchmark.finished(done, tmp_path) and not benchmark.finished(stopped, tmp_path)
    with pytest.raises(benchmark.BadInput, match="already holds cartpole/qlearn_tuned run with other"):
        benchmark.merge([done], [job("qlearn", 5000)], tmp_path)


def test_a_pair_another_process_trains_is_left_to_it(tmp_path, capsys):
    """Two benchmarks on one ``--out``: the second leaves a pair whose seeds the first trains
    now (a seed folder's lock held), with a line; it starts no run there and writes no record
    for it, so the first's record and console stay its own."""
    from runs.folder import run_lock

    argv = ["--quick", "--learners", "qlearn", "--seeds", "1", "--out", str(tmp_path), "--no-readme"]
    [job] = benchmark.plan_jobs(benchmark.parse_args(argv), benchmark.load_plan(True))
    seed = tmp_path / job.folder / "0_cartpole_qlearn_seed1000"
    seed.mkdir(parents=True)
    assert not benchmark.trained_elsewhere(job, tmp_path)  # a folder nobody holds
    with run_lock(seed):
        benchmark.main(argv)
        assert f"{job.folder}: trained now by another process (pid {os.getpid()}); left to it" \
            in capsys.readouterr().out
    assert sorted(p.name for p in (tmp_path / job.folder).iterdir()) == ["0_cartpole_qlearn_seed1000"]
    assert not (tmp_path / job.folder).with_suffix(".json").exists()
    assert not benchmark.trained_elsewhere(job, tmp_path)  # its holder gone: the next run takes it


def test_a_pair_another_process_took_after_the_plan_gets_no_record(tmp_path, capsys):
    """Two benchmarks on one ``--out``, the second taking a pair the first had planned: the
    first's run of it is refused (the folder is the other's) and writes no record, so the page
    reads the other's, not a pair of failed seeds."""
    from runs.folder import run_lock

    argv = ["--quick", "--learners", "qlearn", "--seeds", "1", "--out", str(tmp_path), "--no-readme"]
    [job] = benchmark.plan_jobs(benchmark.parse_args(argv), benchmark.load_plan(True))
    seed = tmp_path / job.folder / "0_cartpole_qlearn_seed1000"
    seed.mkdir(parents=True)
    with run_lock(seed), benchmark.tqdm(total=1, disable=True) as bar:
        benchmark.run_pairs([job], tmp_path, bar)
    assert (tmp_path / job.folder).with_suffix(".log").read_text().startswith("error: ")  # refused
    assert sorted(p.name for p in (tmp_path / job.folder).iterdir()) == ["0_cartpole_qlearn_seed1000"]
    assert f"{job.folder}: trained now by another process (pid {os.getpid()}); left to it" in capsys.readouterr().out
    assert not (tmp_path / job.folder).with_suffix(".json").exists()


def test_the_tuned_setting_names_and_uses_a_task_tuned_file(tmp_path):
    """A task's tuned file (conf/tuned/<robot>_<task>_<learner>.yaml) counts as a tuned file of
    the job, applies on top of the robot's in what the job's runs compose, is named in the
    table's setting; the published setting leaves both files out."""
    from tasks import catalog

    (tmp_path / "tuned").mkdir()
    (tmp_path / "tuned" / "acrobot_swingup_mbalunovic.yaml").write_text("# @package _global_\nlearner:\n  gamma: 0.9\n")
    (tmp_path / "tuned" / "cartpole_stay_up_qlearn.yaml").write_text("# @package _global_\nlearner:\n  gamma: 0.93\n")
    job = lambda learner, setting="tuned": benchmark.Job(  # noqa: E731
        "cartpole", "cartpole", "stay_up", learner, setting, 8000, (1000,))
    acrobot = benchmark.Job("acrobot", "acrobot", "swingup", "mbalunovic", "tuned", 8000, (1000,))  # no robot file
    assert not benchmark.has_tuned_file(acrobot)
    catalog.use_config_dirs([tmp_path])
    try:
        assert benchmark.has_tuned_file(acrobot)  # the task's file alone
        assert benchmark.tuned_files(acrobot) == ["acrobot_swingup_mbalunovic"]
        assert benchmark.tuned_files(job("qlearn")) == ["cartpole_qlearn", "cartpole_stay_up_qlearn"]
        tuned = catalog.compose(overrides=benchmark.overrides(job("qlearn")))
        assert tuned.learner.gamma == 0.93 and tuned.num_envs == 8  # both layers
        published = catalog.compose(overrides=benchmark.overrides(job("qlearn", "published")))
        assert published.learner.gamma == 0.7 and published.num_envs == 1
        # the table names what the runs recorded in run.json, else what conf/tuned/ has now
        run = tmp_path / "run"
        run.mkdir()
        rows = [{"run_dir": str(run)}]
        assert benchmark.applied_tuned(job("qlearn"), rows) == "cartpole_qlearn + cartpole_stay_up_qlearn"
        (run / "run.json").write_text('{"tuned": "cartpole_qlearn", "tuned_task": null}')
        assert benchmark.applied_tuned(job("qlearn"), rows) == "cartpole_qlearn"
        assert benchmark.applied_tuned(job("qlearn", "published"), rows) == ""
        row = benchmark.pair_row(job("qlearn"), [], None)
        assert row["tuned_file"] == ""
    finally:
        catalog.use_config_dirs([])


def test_a_tuned_budget_is_its_benchmark_tasks_budget():
    """A tuned file that sets max_env_steps (the cube's, the wall dqn's) sets the benchmark's
    budget for that task, so `python train.py` with it trains as the table's row did."""
    from tasks import catalog

    plan = benchmark.load_plan(quick=False)
    checked = 0
    for spec in plan["tasks"].values():
        robot, task, budget = spec["robot"], spec["task"], int(spec["budget_steps"])
        for learner in spec.get("learners", plan["learners"]):  # a task's own list, where it has one
            learner = plan["variants"].get(learner, {}).get("learner", learner)  # a variant: its config's
            steps = catalog.compose(robot, task, learner).max_env_steps
            if steps:
                assert steps == budget, f"{robot}/{task}/{learner}: max_env_steps {steps}, benchmark {budget}"
                checked += 1
    assert checked >= 6  # cube qlearn, cube dqn, wall dqn; the continuous tasks' sac


def small_pair(tmp_path: Path) -> tuple[list[str], benchmark.Job, Path]:
    """The benchmark's arguments for one small pair (qlearn on the cart-pole, two seeds,
    a checkpoint every 5 episodes), its job and its results folder."""
    out = tmp_path / "results"
    args = ["--quick", "--learners", "qlearn", "--seeds", "2", "--budget", "1600", "--out", str(out),
            "--no-readme", "--", "task.max_episode_steps=100", "eval_episodes=2", "checkpoint_every=5"]
    return args, benchmark.plan_jobs(benchmark.parse_args(args), benchmark.load_plan(True))[0], out


def goes_on(args: list[str], job: benchmark.Job, out: Path) -> None:
    """The same benchmark command, run again, resumes the stopped pair's seeds from their
    checkpoints and finishes both on the whole budget (not what was left of it)."""
    proc = subprocess.run([sys.executable, "-m", "bench.benchmark", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "resuming" in (out / job.folder).with_suffix(".log").read_text()
    assert benchmark.job_record(job, out)["resumed"] is True
    with open(out / "seeds.csv") as f:
        seeds = list(csv.DictReader(f))
    assert [(r["seed"], r["status"]) for r in seeds] == [("1000", "ok"), ("1001", "ok")]
    assert all(int(r["env_steps"]) >= 1600 for r in seeds)


@pytest.mark.slow  # a benchmark run by hand (15 s); a run resumed from its checkpoints: tests/test_resume*.py
def test_a_pair_stopped_part_way_continues_from_its_checkpoints(tmp_path):
    """A benchmark killed while a pair trains (its seeds' checkpoints on disk, no record of
    the pair): the same command resumes those seeds (``train.py resume=<the pair's sweep>``)
    instead of refusing their folders, and tabulates them."""
    args, job, out = small_pair(tmp_path)
    sweep = out / job.folder
    killed = subprocess.run(
        [sys.executable, "tests/kill_at.py", "checkpoint:3", "-m", "quiet=true", f"hydra.sweep.dir={sweep}",
         f"seed={','.join(map(str, job.seeds))}", *benchmark.overrides(job)],
        cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert killed.returncode == -9, killed.stderr[-2000:]
    assert not any(sweep.glob("*/summary.json")) and any(sweep.glob("*/checkpoint.pt"))
    at = args.index("--")
    goes_on([*args[:at], "--threads", "2", *args[at:]], job, out)  # going on with two torch threads
    assert benchmark.job_record(job, out)["torch_threads"] == 2


def test_a_pairs_threads_reach_its_command_begun_or_going_on(tmp_path):
    """``--threads T``: the pair's process runs with T torch threads, begun or resumed."""
    _, job, out = small_pair(tmp_path)
    fresh, resumed = benchmark.pair_command(job, out, 2)
    assert fresh[-1] == "torch_threads=2" and not resumed
    assert not any("torch_threads" in part for part in benchmark.pair_command(job, out)[0])
    (out / job.folder).mkdir(parents=True)
    (out / job.folder / "multirun.yaml").write_text("{}")
    going_on, resumed = benchmark.pair_command(job, out, 2)
    assert resumed and going_on[2:] == [f"resume={out / job.folder}", "torch_threads=2"]


STOPPER = """
import pathlib, signal, sys, time
out, got = pathlib.Path(sys.argv[1]), []
signal.signal(signal.SIGINT, lambda *a: got.append(1))
signal.signal(signal.SIGTERM, lambda *a: got.append(15))
(out / "ready").write_text("")
while not got:
    time.sleep(0.01)
time.sleep(0.5)  # saving its checkpoint
(out / "saved").write_text(" ".join(map(str, got)))
sys.exit(130)
"""

CALLER = """
import sys
sys.path.insert(0, {root!r})
from sweeps import child
try:
    child.call([sys.executable, "-c", {stopper!r}, {out!r}], cwd={out!r})
except child.Stopped as stop:
    print("stopped", int(stop.signum))
    sys.exit(3)
"""


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_ctrl_c_of_the_caller_reaches_its_child_once_and_waits_for_it(tmp_path, sig):
    """``kill -INT`` (or ``-TERM``) of the caller alone (a benchmark running a
    ``train.py``): its child gets exactly that signal once (train.py's
    'stop after this step and save'), is given the time it takes, and the caller stops after
    it; ``subprocess.call`` had killed it a quarter of a second later, before it saved, and a
    SIGTERM had left it running alone."""
    script = CALLER.format(root=str(ROOT), stopper=STOPPER, out=str(tmp_path))
    caller = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not (tmp_path / "ready").exists():
        assert time.monotonic() < deadline and caller.poll() is None
        time.sleep(0.05)
    os.kill(caller.pid, sig)
    out, _ = caller.communicate(timeout=60)
    assert caller.returncode == 3 and out.strip() == f"stopped {int(sig)}"
    assert (tmp_path / "saved").read_text() == ("1" if sig == signal.SIGINT else "15")


POOL = """
import sys
sys.path.insert(0, {root!r})
from pathlib import Path
from sweeps import child
outs = [{out!r} + f"/{{i}}" for i in range(3)]
try:
    child.call_all([[sys.executable, "-c", {stopper!r}, out] for out in outs], cwd={out!r}, jobs=2,
                   stdouts=[Path(out) / "console.log" for out in outs],
                   started=lambda i: print("started", i, flush=True))
except KeyboardInterrupt:
    print("stopped")
    sys.exit(3)
"""


def test_a_ctrl_c_reaches_every_child_running_at_once_and_starts_no_more(tmp_path):
    """``--tune --jobs 2``'s pool stopped: each of the two children running gets exactly one
    SIGINT and the time to save, the third command never starts (not even its console file
    is made), the caller stops after them."""
    for i in range(3):
        (tmp_path / str(i)).mkdir()
    script = POOL.format(root=str(ROOT), stopper=STOPPER, out=str(tmp_path))
    caller = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not all((tmp_path / str(i) / "ready").exists() for i in range(2)):
        assert time.monotonic() < deadline and caller.poll() is None
        time.sleep(0.05)
    os.kill(caller.pid, signal.SIGINT)
    out, _ = caller.communicate(timeout=60)
    assert caller.returncode == 3 and out.split() == ["started", "0", "started", "1", "stopped"]
    assert [(tmp_path / str(i) / "saved").read_text() for i in range(2)] == ["1", "1"]
    assert all((tmp_path / str(i) / "console.log").is_file() for i in range(2))
    assert not any((tmp_path / "2").iterdir())


def test_the_pool_runs_its_commands_jobs_at_a_time_and_stops_starting_after_a_kill(tmp_path):
    """Exit codes in the commands' order; at most ``jobs`` running at once; a child ended by
    a signal starts no more (those running finish)."""
    log = tmp_path / "log"
    sleeper = ("import sys, time, pathlib; log = pathlib.Path(sys.argv[1]); "
               "log.open('a').write(f'+{sys.argv[2]}\\n'); time.sleep(0.3); log.open('a').write(f'-{sys.argv[2]}\\n'); "
               "sys.exit(int(sys.argv[3]))")
    cmds = [[sys.executable, "-c", sleeper, str(log), str(i), code] for i, code in enumerate(["0", "2", "0"])]
    assert child.call_all(cmds, cwd=tmp_path, jobs=2, every=0.05) == [0, 2, 0]
    running = peak = 0
    for line in log.read_text().split():
        running += 1 if line[0] == "+" else -1
        peak = max(peak, running)
    assert peak == 2
    killer = [sys.executable, "-c", "import os, signal; os.kill(os.getpid(), signal.SIGKILL)"]
    assert child.call_all([killer, cmds[0]], cwd=tmp_path, jobs=1, every=0.05) == [-9, None]


@pytest.mark.slow  # a benchmark run by hand; the signal to its children: the sweeps.child tests above
def test_a_benchmark_stopped_by_ctrl_c_saves_and_goes_on(tmp_path):
    """SIGINT to the benchmark while a pair trains: its seeds stop after their step with a
    checkpoint (train.py's own stop), no process is left, and the same command finishes them."""
    args, job, out = small_pair(tmp_path)
    sweep = out / job.folder
    proc = subprocess.Popen([sys.executable, "-m", "bench.benchmark", *args], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 300
    while not any(sweep.glob("*/checkpoint.pt")):
        assert time.monotonic() < deadline and proc.poll() is None, proc.communicate()
        time.sleep(0.2)
    os.kill(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 1 and "stopped; run the same command with --out" in err, err[-2000:]
    log = sweep.with_suffix(".log").read_text()
    assert "SIGINT: stopping after this step and saving a checkpoint" in log and "resume with" in log, log[-2000:]
    assert not sweep.with_suffix(".json").exists()  # no record: the pair is not done
    goes_on(args, job, out)
    assert len(json.loads((out / "plan.json").read_text())["commands"]) == 1  # the same command, listed once


def test_the_bar_counts_a_seed_ctrl_c_stopped_as_still_to_run(tmp_path):
    """A seed ended when it finished or failed; one whose summary.json says interrupted (or
    that has none yet) is still to run, so a stopped benchmark's bar does not count it."""
    for name, files in {"0": {"summary.json": '{"solved": true}'}, "1": {"summary.json": '{"interrupted": true}'},
                        "2": {"error.txt": "boom"}, "3": {"checkpoint.pt": ""}}.items():
        (tmp_path / name).mkdir()
        for file, text in files.items():
            (tmp_path / name / file).write_text(text)
    assert benchmark.seeds_ended(tmp_path) == 2
    assert benchmark.seeds_ended(tmp_path / "absent") == 0


def test_the_table_names_the_hand_picks_a_study_kept(tmp_path, monkeypatch):
    """A tuned file whose header says its study kept it (the hand pick valued at least as well
    as the study's best trial) is named; a file a study wrote, or none, is not."""
    from sweeps.tuning import KEPT
    from tasks import catalog

    (tmp_path / "hand.yaml").write_text(f"# @package _global_\n# {KEPT} (t): study s: at least as good\nx: 1\n")
    (tmp_path / "found.yaml").write_text("# @package _global_\n# Tuned by Optuna (t): study s\nx: 2\n")
    monkeypatch.setattr(catalog, "config_file", lambda group, name: (tmp_path / f"{name}.yaml")
                        if group == "tuned" and (tmp_path / f"{name}.yaml").is_file() else None)
    assert benchmark.kept_hand_picks("found + hand") == ["hand"]
    assert benchmark.kept_hand_picks("found") == benchmark.kept_hand_picks("") == []
    assert benchmark.kept_hand_picks("gone") == []
    assert benchmark.own_values_kept("found + hand") == []


def test_the_table_names_a_file_that_holds_the_learners_own_values(tmp_path, monkeypatch):
    """A tuned file whose study valued the learner's own values of the searched settings
    above every trial (its header's ``written instead`` line) is named; the line further down,
    below the settings, is not a header."""
    from sweeps.tuning import OWN_VALUES
    from tasks import catalog

    line = f"# written instead: {OWN_VALUES}, success_and_speed 0.19 on the same seeds and budget"
    (tmp_path / "own.yaml").write_text(f"# @package _global_\n# Tuned by Optuna (t): study s\n{line}\nx: 1\n")
    (tmp_path / "later.yaml").write_text(f"# @package _global_\n# Tuned by Optuna (t): study s\nx: 2\n{line}\n")
    monkeypatch.setattr(catalog, "config_file", lambda group, name: (tmp_path / f"{name}.yaml")
                        if group == "tuned" and (tmp_path / f"{name}.yaml").is_file() else None)
    assert benchmark.own_values_kept("later + own") == ["own"]
    assert benchmark.own_values_kept("gone") == benchmark.kept_hand_picks("own") == []


def test_a_pairs_notes_are_all_kept_and_a_task_not_run_first_still_names_its_measure():
    """A pair's note from the run (a kept hand pick) does not hide the row's own (a success never
    judged solved); a task whose first pair has no seeds yet takes its measure from a later pair."""
    job = benchmark.Job("cube", "cube", "move", "qlearn", "tuned", 1000, (1000, 1001))
    seed = {"success": True, "greedy": 1.2, "status": "ok", "measure": "distance", "error": "",
            "steps_to_solve": None, "wall_to_solve": None, "verdict": False}
    row = benchmark.pair_row(job, [seed, {**seed, "steps_to_solve": 500, "wall_to_solve": 9.0}], 10.0,
                             "a hand pick its study kept: cube_qlearn", "cube_qlearn")
    assert row["note"].startswith("a hand pick its study kept: cube_qlearn; 1 of 2 successes")
    assert row["steps_to_success"] == 500
    empty = benchmark.pair_row(job, [], None, "not run", "")
    assert empty["note"] == "not run" and empty["measure"] == ""
    dqn = benchmark.pair_row(benchmark.Job("cube", "cube", "move", "dqn", "tuned", 1000, (1000,)), [seed], 5.0, "", "")
    text = benchmark.markdown([empty, dqn], "plan", {"cube": "cube/move"})
    assert "greedy_distance IQM" in text and "greedy_measure" not in text
    assert "- qlearn (tuned): not run" in text
    running = {**seed, "success": False, "status": "interrupted", "greedy": None,
               "error": "no summary.json: killed before it finished, or still running"}
    text = benchmark.markdown([benchmark.pair_row(job, [seed, running], None, "unfinished", "")], "plan",
                              {"cube": "cube/move"})
    assert "| 1/2 (1 not finished) |" in text  # a pair still running reads as such, not as a failure


def test_a_pair_resumed_after_a_stop_says_its_wall_time_is_the_last_pieces(tmp_path):
    """A pair that Ctrl-C stopped and the same command resumed records only the last piece's
    wall seconds (its seeds' clocks span every piece): its row says so; a pair run in one go
    says nothing of it."""
    seed = {"success": True, "greedy": 1.2, "status": "ok", "measure": "distance", "error": "",
            "steps_to_solve": 500, "wall_to_solve": 600.0, "verdict": True}
    jobs = [benchmark.Job("cube", "cube", "move", name, "published", 1000, (1000,)) for name in ("qlearn", "dqn")]
    (tmp_path / "cube").mkdir()
    for job, resumed in zip(jobs, (True, False)):
        benchmark.write_record(job, tmp_path, {"returncode": 0, "wall_s": 300.0, "tuned_file": "", "seeds": [seed],
                                               **({"resumed": True} if resumed else {})})
    pairs, _ = benchmark.tabulate(jobs, jobs, tmp_path)
    assert pairs[0]["note"] == "resumed after a stop: its s, all seeds is the last piece's only"
    assert pairs[1]["note"] == ""


def test_the_pages_main_table_is_what_the_committed_records_say(tmp_path):
    """docs/benchmark.md's main table, row for row and note for note, is the one the records
    in bench/results/main make (read from a copy without job folders, as a clean clone has)."""
    source, records = ROOT / "bench" / "results" / "main", tmp_path / "main"
    shutil.copytree(source, records, ignore=lambda folder, names: [  # the tasks' folders, not the pairs'
        n for n in names if Path(folder) != source and (Path(folder) / n).is_dir()])
    jobs, commands = benchmark.read_plan(records)
    runnable = [job for job in jobs if job.setting == "published" or benchmark.has_tuned_file(job)]
    pairs, seeds = benchmark.tabulate(jobs, runnable, records)
    assert len(pairs) == 60 and all(p["seeds"] == 10 for p in pairs)
    made = benchmark.markdown(pairs, "", benchmark.specs_of(jobs, seeds))
    page = (ROOT / "docs" / "benchmark.md").read_text().split(benchmark.BEGIN)[1].split(benchmark.END)[0]

    def rows(text: str) -> list[str]:
        return [line for line in text.splitlines() if line.startswith(("|", "- ", "**"))]

    assert rows(page) == rows(made)


def test_a_learner_keeps_one_colour_in_a_tasks_figure():
    """Twelve rows on one figure: a learner's published and tuned rows share its colour (dashed
    and solid), and no two learners share one (the colour cycle had repeated after ten rows)."""
    from bench.benchmark_figures import styles

    learners = ["qlearn", "dqn", "n1try", "mbalunovic", "ruippeixotog", "rainbow"]
    pairs = [{"task": "wall", "learner": name, "setting": setting} for name in learners
             for setting in ("published", "tuned")] + [{"task": "maze", "learner": "x", "setting": "tuned"}]
    style = styles("wall", pairs)
    assert len(style) == 12 and ("x", "tuned") not in style
    for name in learners:
        assert style[name, "published"][0] == style[name, "tuned"][0]
        assert (style[name, "published"][1], style[name, "tuned"][1]) == ("--", "-")
    assert len({style[name, "tuned"][0] for name in learners}) == 6


def test_a_pair_not_run_is_left_out_of_its_tasks_figure(tmp_path):
    """A results folder's pair not run yet (no seeds, its IQM NaN), or still running (seeds, none
    finished: its IQM NaN too), draws no panel and no row at the end (it was drawn as "0/0", or
    "0/10", without a point)."""
    import matplotlib.image

    from bench.benchmark_figures import draw

    def pair(learner: str, seeds: int, finished: bool = True) -> dict:
        iqm = 2.0 if seeds and finished else float("nan")
        return {"task": "cube", "learner": learner, "setting": "published", "seeds": seeds, "success": seeds,
                "greedy_iqm": iqm, "ci_low": iqm, "ci_high": iqm, "measure": "distance_walked"}

    seeds = [{"task": "cube", "learner": "dqn", "setting": "published", "status": "ok", "threshold": 1.0,
              "evaluations": [[1000, 0.5], [2000, 2.0]]}]
    one = draw("cube", [pair("dqn", 1)], seeds, tmp_path / "one.png")
    both = draw("cube", [pair("dqn", 1), pair("n1try", 0)], seeds, tmp_path / "both.png")
    assert (matplotlib.image.imread(one) == matplotlib.image.imread(both)).all()
    running = draw("cube", [pair("dqn", 1), pair("sac", 10, finished=False)], seeds, tmp_path / "running.png")
    assert (matplotlib.image.imread(one) == matplotlib.image.imread(running)).all()


def test_a_replay_of_the_grid_keeps_its_journals_apart_and_writes_no_tuned_file():
    """``--tune --studies <folder>``: each pair's study in that folder's journal, its
    ``write_tuned`` off; the plan's own folder writes the tuned files."""
    from bench import tune_grid

    plan = benchmark.load_plan(False)
    spec, tuning = plan["tasks"]["maze"], plan["tuning"]
    replay = tune_grid.command("maze", spec, "dqn", tuning, 12, Path("s"), Path("bench/timing/x"), write=False)
    own = tune_grid.command("maze", spec, "dqn", tuning, 12, Path("s"))
    assert "hydra.sweeper.storage=journal://bench/timing/x/maze_dqn.log" in replay
    assert "hydra.sweeper.write_tuned=false" in replay and "hydra.sweeper.write_tuned=true" in own
    assert "hydra.sweeper.storage=journal://bench/studies/maze_dqn.log" in own
    # the plan's rounds: its random trials first, then the guided ones (startup_trials)
    assert f"hydra.sweeper.startup_trials={tuning['startup_trials']}" in own
    unnamed = {k: v for k, v in tuning.items() if k != "startup_trials"}  # the sweeper's own default
    assert not any("startup_trials" in arg for arg in tune_grid.command("maze", spec, "dqn", unnamed, 12, Path("s")))
    assert benchmark.check_studies(None) == tune_grid.STUDIES
    assert benchmark.check_studies(Path("bench/timing/x")) == Path("bench/timing/x")


def test_a_dry_run_of_the_whole_grid_skips_variants_of_another_learner_and_asks_for_ppo(tmp_path, capsys):
    """``--tune --dry-run`` over every pair of the plan: the dqn's switches are variants of the
    dqn (not tuned); ppo's entry, which only sets its evaluations, is ppo's own study."""
    from bench import tune_grid

    plan = benchmark.load_plan(False)
    left = tune_grid.tune(plan, ["cartpole", "cube"], ["dqn_c51", "ppo"], dry_run=True, studies=tmp_path)
    said = capsys.readouterr().out
    assert "cartpole_dqn_c51: a variant of dqn (overrides ['learner.distributional=true'])" in said
    assert "cartpole_ppo: 0 trials done" in said and "cube_ppo: 0 trials done" in said
    assert left == 2
    # its trials evaluate as its benchmark rows do: on the cube once a rollout, on the cart-pole as usual
    cube = next(line for line in said.splitlines() if "task=one_disk_walk learner=ppo" in line).split()
    assert cube[-2:] == ["eval_every=0", "eval_every_steps=16384"]
    assert not any("eval_every" in line for line in said.splitlines() if "task=stay_up learner=ppo" in line)


def test_studies_side_by_side_start_longest_first(monkeypatch):
    """With several studies at once the grid starts the longest first (its records' minutes
    times the share of trials left; a pair never run first of all), so the last to end is
    a short one."""
    from bench import tune_grid

    monkeypatch.setattr(tune_grid, "grid_minutes", lambda studies=None: [("a", 12, 10.0), ("b", 12, 30.0),
                                                                        ("d", 12, 40.0)])
    pending = [(name, [name], left) for name, left in (("a", 12), ("b", 12), ("c", 12), ("d", 6))]
    assert [name for name, _, _ in tune_grid.longest_first(pending, 12)] == ["c", "b", "d", "a"]


def test_a_grid_stopped_by_ctrl_c_records_its_time_and_the_pairs_it_started(tmp_path, monkeypatch):
    """A run of the grid command stopped part way is a piece of the grid's machine time: its
    row in ``grid_runs.csv`` names the studies it started, not the ones it never reached."""
    from bench import tune_grid

    monkeypatch.setattr(tune_grid, "ROOT", tmp_path)
    monkeypatch.setattr(tune_grid, "physics_speed", lambda: 50.0)

    def stopped_after_two(cmds, cwd, jobs, stdouts, started, ended):
        for i in range(2):
            started(i)
        ended(0, 0)
        raise KeyboardInterrupt

    monkeypatch.setattr(tune_grid.child, "call_all", stopped_after_two)
    folder = Path("bench") / "timing"
    with pytest.raises(KeyboardInterrupt):
        tune_grid.tune(benchmark.load_plan(False), ["maze"], ["qlearn", "dqn", "n1try"], jobs=2, studies=folder)
    rows = (tmp_path / folder / tune_grid.GRID_RUNS).read_text().splitlines()
    assert len(rows) == 2 and rows[1].split(",")[2:5] == ["2", "2", "maze_qlearn maze_dqn"], rows
    assert rows[1].endswith(",50.000")
    assert (tmp_path / folder / tune_grid.RUNS).read_text().splitlines()[1].startswith("maze_qlearn,")


def test_the_grids_minutes_add_up_its_sweeps_and_its_trials_run_time(tmp_path, monkeypatch, capsys):
    """``--tune --minutes``: the sweeps' wall minutes the command recorded (several runs of a
    pair added up) and the union of each study's trial spans (trials side by side once, the
    time between two batches not at all)."""
    import datetime as dt

    import optuna

    from bench import tune_grid
    from sweeps.tuning import open_storage

    monkeypatch.setattr(tune_grid, "ROOT", tmp_path)
    monkeypatch.setattr(benchmark, "ROOT", tmp_path)
    folder = Path("bench") / "timing"
    (tmp_path / folder).mkdir(parents=True)
    t0 = dt.datetime(2026, 11, 28, 12, 0, 0)
    spans = [(0, 10), (0, 12), (30, 35)]  # minutes: two side by side, then one after a gap
    study = optuna.create_study(study_name="bench-maze-dqn",
                                storage=open_storage(f"journal://{tmp_path / folder / 'maze_dqn.log'}"))
    for start, end in spans:
        study.add_trial(optuna.trial.FrozenTrial(
            number=0, state=optuna.trial.TrialState.COMPLETE, value=1.0, values=None,
            datetime_start=t0 + dt.timedelta(minutes=start), datetime_complete=t0 + dt.timedelta(minutes=end),
            params={}, distributions={}, user_attrs={}, system_attrs={}, intermediate_values={}, trial_id=0))
    tune_grid.record_run(folder, "maze_dqn", 14.5, 1, 1)  # stopped
    tune_grid.record_run(folder, "maze_dqn", 6.0, 0, 1)  # and run again to its end
    assert tune_grid.grid_minutes(folder) == [("maze_dqn", 3, pytest.approx(17.0))]
    assert tune_grid.run_minutes(folder) == {"maze_dqn": pytest.approx(20.5)}
    benchmark.print_grid_minutes(folder)
    out = capsys.readouterr().out
    assert "maze_dqn" in out and "20.5" in out and "17.0" in out
    assert "1 study: 0.34 hours of sweeps (1 recorded in bench/timing/runs.csv), 0.28 hours of trials" in out
    assert "wall time" not in out  # no run of the grid command recorded yet
    tune_grid.record_grid(folder, ["maze_dqn", "wall_dqn"], 12.0, 2, tune_grid.physics_speed(8, 0.05))
    tune_grid.record_grid(folder, ["maze_dqn"], 6.0, 1)
    assert tune_grid.grid_run_minutes(folder) == [pytest.approx(12.0), pytest.approx(6.0)]
    speed = [row.split(",")[-1] for row in (tmp_path / folder / tune_grid.GRID_RUNS).read_text().splitlines()]
    assert speed[0] == "cartpole_us_per_copy_step" and 0 < float(speed[1]) < 1e4 and speed[2] == ""
    benchmark.print_grid_minutes(folder)
    assert "the grid command's wall time: 0.30 hours over 2 runs" in capsys.readouterr().out


def test_every_tuned_file_of_the_plan_carries_its_pairs_budget():
    """Issue 65's one budget: a user's run with a pair's tuned files is the benchmark's row
    (max_env_steps the plan's budget_steps, no episode budget); the benchmark refuses a
    file that judges its pair with another budget, in one line naming the file."""
    jobs = benchmark.plan_jobs(benchmark.parse_args(["--settings", "tuned"]), benchmark.load_plan(False))
    assert {"pendulum", "sac"} <= {j.task for j in jobs} | {j.learner for j in jobs}
    for job in jobs:
        benchmark.check_tuned_budget(job)  # every file as committed (a pair without one: no check)
    job = next(j for j in jobs if j.task == "wall" and j.learner == "qlearn")
    other = dataclasses.replace(job, overrides=(*job.overrides, "max_episodes=2000"))
    with pytest.raises(benchmark.BadInput, match=r"^conf/tuned/turtlebot_qlearn.yaml \+ conf/tuned/"
                       r"turtlebot_wall_qlearn.yaml judges wall x qlearn with max_env_steps=100000 max_episodes=2000, "
                       r"the plan with 100000 env steps"):
        benchmark.check_tuned_budget(other)


@pytest.mark.parametrize("returncode", [128 + signal.SIGINT, 128 + signal.SIGTERM, -signal.SIGTERM])
def test_a_pair_a_signal_stopped_gets_no_record(tmp_path, monkeypatch, returncode):
    """A pair whose seeds a Ctrl-C or a SIGTERM stopped (train.py saved their checkpoints)
    gets no record, so the same command goes on with it: a SIGTERM's exit 143 was recorded
    as a pair that had ended, and the page counted its unfinished seeds 0/10."""
    from tqdm import tqdm

    _, job, out = small_pair(tmp_path)

    def pair_exits(code: int) -> None:
        def call_all(cmds, cwd, jobs, logs, started, ended, poll):
            for i, log in enumerate(logs):
                log.parent.mkdir(parents=True, exist_ok=True)
                log.write_text("its console\n")
                started(i)
                ended(i, code)

        monkeypatch.setattr(child, "call_all", call_all)
        with tqdm(total=len(job.seeds), disable=True) as bar:
            benchmark.run_pairs([job], out, bar)

    pair_exits(returncode)
    assert benchmark.job_record(job, out) == {}
    pair_exits(2)
    assert benchmark.job_record(job, out)["returncode"] == 2  # a pair that failed is recorded


def test_a_benchmark_run_stopped_part_way_is_continued_not_refused(tmp_path):
    """bench/sweep.py's ``run_to_solve`` into a folder holding a run stopped part way (a
    comparison stopped or killed at a session's end) continues it from its checkpoint, where
    ``train.py`` into a used folder would refuse."""
    from bench.sweep import run_to_solve

    run_dir = tmp_path / "run"
    overrides = ["learner=qlearn", "num_envs=1", "max_episodes=40", "checkpoint_every=10", "eval_episodes=0",
                 "seed=3"]
    killed = subprocess.run([sys.executable, "tests/kill_at.py", "second_checkpoint", "quiet=true",
                             f"hydra.run.dir={run_dir}", *overrides], cwd=ROOT, capture_output=True, text=True)
    assert killed.returncode == -signal.SIGKILL, killed.stderr[-1500:]
    assert not (run_dir / "summary.json").exists()
    summary = run_to_solve(overrides, run_dir)
    assert summary["status"] == "ok"
    assert len((run_dir / "metrics.csv").read_text().splitlines()) - 1 == 40  # each episode once


def test_a_benchmark_run_stopped_by_sigterm_stops_its_training_and_saves(tmp_path):
    """SIGTERM to a process running ``run_to_solve`` (a comparison stopped with ``pkill
    -TERM``) goes on to its train.py, which saves its checkpoint and ends: no training is
    left running on its own, and the same call goes on from it."""
    run_dir = tmp_path / "run"
    overrides = ["learner=qlearn", "num_envs=1", "max_episodes=5000", "checkpoint_every=10", "eval_episodes=0",
                 "seed=3"]
    script = f"import sys; sys.path.insert(0, {str(ROOT)!r}); from bench.sweep import run_to_solve; " \
             f"run_to_solve({overrides!r}, __import__('pathlib').Path({str(run_dir)!r}))"
    proc = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    metrics, deadline = run_dir / "metrics.csv", time.time() + 300
    while not (metrics.is_file() and len(metrics.read_text().splitlines()) > 20) and time.time() < deadline:
        assert proc.poll() is None, proc.stderr.read()[-1500:]
        time.sleep(0.05)
    proc.send_signal(signal.SIGTERM)
    out, err = proc.communicate(timeout=300)
    assert proc.returncode == 1 and "the same command continues it" in err, err[-1500:]
    ps = subprocess.run(["pgrep", "-f", f"hydra.run.dir={run_dir}"], capture_output=True, text=True)
    assert ps.stdout.strip() == ""  # its train.py ended with it
    from runs.summary import summarize_run

    assert "resume" in summarize_run(run_dir)  # stopped with a checkpoint to go on from


def test_the_physics_floor_steps_the_tasks_own_moving_episodes():
    """The seeds bench's physics floor prices copy-steps on the states a task's episodes visit
    (random actions, each copy's episodes started anew as they end), not on a model held
    still at its rest pose, which costs less (the cart-pole's upright pole at rest: 8-16 %)."""
    from bench.seed_batch import episode_steps, per_copy_step
    from tasks import catalog

    env = catalog.make_env("cartpole", num_envs=4)
    steps = episode_steps(env, 40)
    env.close()
    assert len(steps) == 40 and all(state.shape[0] == 4 == ctrl.shape[0] for state, ctrl in steps)
    states = np.stack([state for state, _ in steps])
    assert np.ptp(states[:, :, 1:], axis=0).min() > 0  # every copy's qpos and qvel moved
    assert len({ctrl.tobytes() for _, ctrl in steps}) > 10  # the controls changed with the actions
    assert 0 < per_copy_step("cartpole", 4, 0.05) < 0.01
    assert 0 < per_copy_step("cartpole", 4, 0.05, at_rest=True) < 0.01


@pytest.mark.parametrize("script", ["seed_batch", "async_bound"])
def test_a_seeds_bench_refuses_an_unknown_robot_before_it_runs_anything(script, monkeypatch, capsys):
    """``--robot`` names one of the robots there are configs of; anything else is argparse's
    error line, naming them, before a run starts."""
    import importlib

    main = importlib.import_module(f"bench.{script}").main
    monkeypatch.setattr(sys, "argv", [f"bench/{script}.py", "--robot", "nope"])
    with pytest.raises(SystemExit) as stop:
        main()
    assert stop.value.code == 2
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert "argument --robot: invalid choice: 'nope'" in error and "'cartpole'" in error


def test_the_async_bound_times_steps_and_updates_alone_and_together(monkeypatch, capsys):
    """``bench/async_bound.py``: a round's serial time is its env steps' and updates' (timed one
    after the other), and what it saved is that against the same work on two threads."""
    from bench import async_bound

    monkeypatch.setattr(sys, "argv", ["bench/async_bound.py", "--seeds", "3", "--steps", "100", "--rounds", "1"])
    async_bound.main()
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("cartpole: 3 copies, 100 env steps and 50 updates of 3 members (layers [4, 64, 64, 2]")
    found = dict(pair.split("=") for pair in out[-2].split()[2:])
    env_s, updates_s, serial_s, threads_s = (float(found[k]) for k in ("env_s", "updates_s", "serial_s", "threads_s"))
    assert min(env_s, updates_s, threads_s) > 0 and serial_s == pytest.approx(env_s + updates_s, abs=0.0015)
    assert float(found["saved"]) == pytest.approx((serial_s - threads_s) / serial_s, abs=0.02)
    assert out[-1] == f"BOUND saved={found['saved']} hidden={found['hidden']}"
    monkeypatch.setattr(sys, "argv", ["bench/async_bound.py", "--steps", "0"])
    with pytest.raises(SystemExit, match="must be >= 1"):
        async_bound.main()
