"""Seeds in one process (runs/lifecycle.py, the ``seeds`` launcher): a seed trained in a batch
(a member of one learner) is the run it makes alone, file for file (wall-clock numbers
aside), bit for bit for qlearn and dqn; a seed whose own work fails ends alone; a failed
learner call ends every seed with its trace; the launcher batches a multirun's seeds."""

from __future__ import annotations

import csv
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from inprocess import run_train
import torch

from learners.qlearn import QLearn
from runs import lifecycle as batch_module
from runs.lifecycle import Job, check_batch, run_jobs
from tasks.catalog import compose
from runs.training_state import load_run_config, read_run_json
from runs.run import Run
from runs.lifecycle import EVAL_SEED_OFFSET, execute
from runs.settings import check_run_config
from params import ConfigError

ROOT = Path(__file__).resolve().parents[1]
SEEDS = (4, 9)
WALL_CLOCK = {"wall_s", "process_s", "first_step_s"}  # summary.json's clock readings
CLOCK_SCALARS = ("wall_s.csv", "updates_per_s.csv")  # the logger's clock readings (their files' sizes vary)
SAME_FILES = ("metrics.csv", "evals.csv", "eval.json", "success.json", "config.yaml")
BUDGETS = {
    "qlearn": ["max_episodes=60", "eval_every=20", "eval_episodes=4", "checkpoint_every=20"],
    "dqn": ["max_env_steps=2000", "eval_every=20", "eval_episodes=4", "checkpoint_every=20"],
}


def jobs(learner: str, root: Path, prefix: str, extra=(), seeds=SEEDS) -> list[Job]:
    choices = {"robot": "cartpole", "task": "stay_up", "learner": learner, "tuned": f"cartpole_{learner}"}
    found = []
    for seed in seeds:
        cfg = compose("cartpole", learner=learner, overrides=[f"seed={seed}", "quiet=true",
                                                               *BUDGETS[learner], *extra])
        check_run_config(cfg)
        found.append(Job(cfg, root / f"{prefix}{seed}", choices))
    return found


def tensors_equal(a, b) -> bool:
    if isinstance(a, torch.Tensor):
        return isinstance(b, torch.Tensor) and torch.equal(a, b)
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(tensors_equal(a[k], b[k]) for k in a)
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(tensors_equal(x, y) for x, y in zip(a, b))
    return a == b


def run_alone(learner: str, root: Path, seeds=SEEDS) -> None:
    for job in jobs(learner, root, "alone"):
        if job.cfg.seed in seeds:
            job.run_dir.mkdir()
            execute(job.cfg, job.run_dir, choices=job.choices)


@pytest.mark.parametrize("learner", ["qlearn", "dqn"])
def test_a_seed_in_a_batch_is_its_run_alone(tmp_path, learner):
    """Every seed's files are its run's alone."""
    batch = jobs(learner, tmp_path, "batch")
    run_jobs(batch)
    run_alone(learner, tmp_path)
    same_files(tmp_path, SEEDS)


@pytest.mark.parametrize("learner", ["qlearn", "dqn"])
def test_seeds_that_end_at_one_step_are_evaluated_together_as_each_alone(tmp_path, monkeypatch, learner):
    """An env-step budget ends every seed at one step: their final greedy evaluations run
    beside each other in the batch's evaluation env (each member's own block, as its
    periodic ones), and each seed's files are still its run's alone."""
    # No periodic evaluation (eval_every=0): one that fell on a seed's last episode would
    # leave it owing no final one (the cart-pole dqn's seed 4 ends at episode 140).
    budget = ["max_env_steps=1200", "max_episodes=100000", "stop_when_solved=false",
              "eval_every=0", "eval_episodes=4", "checkpoint_every=20"]
    monkeypatch.setitem(BUDGETS, learner, budget)
    together, real = [], batch_module.MemberEvaluations.start
    monkeypatch.setattr(batch_module.MemberEvaluations, "start",
                        lambda self, member, seed, block=None: together.append((member, seed, block))
                        or real(self, member, seed, block))
    run_jobs(jobs(learner, tmp_path, "batch"))
    assert together == [(b, seed + EVAL_SEED_OFFSET, None) for b, seed in enumerate(SEEDS)]
    for seed in SEEDS:  # its starts and how far they spread: the cart-pole's reset noise
        spread = json.loads((tmp_path / f"batch{seed}" / "eval.json").read_text())["start_spread"]
        assert set(spread) == {"cart_pos", "cart_vel", "pole_angle", "pole_vel"} and all(v > 0 for v in spread.values())
    run_alone(learner, tmp_path)
    same_files(tmp_path, SEEDS)


@pytest.mark.parametrize("learner, threshold", [("qlearn", 30), ("dqn", 6)])
def test_members_wait_for_their_evaluations_beside_the_others_training_each_as_alone(tmp_path, learner, threshold):
    """A batch's periodic evaluations and the evaluations that confirm a training window
    that met the rule are made beside the other members' training (its member waits for
    its own): seeds solve at a confirming evaluation, or try again; each seed's files are
    its run's alone."""
    seeds = (4, 9, 11)
    rule = [f"task.win.threshold={threshold}", "task.win.window=10", "task.win.min_episodes=10", "max_episodes=80",
            "eval_every=15", "eval_episodes=4", "checkpoint_every=20"]
    steps, real = [], batch_module.MemberEvaluations.step
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(batch_module.MemberEvaluations, "step", lambda self: steps.append(self.members) or real(self))
        run_jobs(jobs(learner, tmp_path, "batch", rule, seeds))
    assert any(len(members) > 1 for members in steps)  # evaluations under way side by side
    assert any(len(members) < len(seeds) for members in steps)  # and beside others' training
    for job in jobs(learner, tmp_path, "alone", rule, seeds):
        job.run_dir.mkdir()
        execute(job.cfg, job.run_dir, choices=job.choices)
    same_files(tmp_path, seeds)
    verdicts = [json.loads((tmp_path / f"batch{seed}" / "summary.json").read_text()) for seed in seeds]
    assert any(v["solved"] for v in verdicts), verdicts
    confirming = [row for seed in seeds for row in csv.DictReader(open(tmp_path / f"batch{seed}" / "evals.csv"))
                  if int(row["episode"]) % 15]  # off the schedule: a training window that met the rule
    assert confirming


def same_files(tmp_path: Path, seeds) -> None:
    for seed in seeds:
        same_run_files(tmp_path / f"batch{seed}", tmp_path / f"alone{seed}")


def same_run_files(together: Path, alone: Path) -> None:
    """The run in ``together`` (trained in a batch) is the run in ``alone``, file for file."""
    for name in SAME_FILES:
        assert (together / name).read_bytes() == (alone / name).read_bytes(), (together.name, name)
    summaries = [json.loads((d / "summary.json").read_text()) for d in (together, alone)]
    assert [{k: v for k, v in s.items() if k not in WALL_CLOCK} for s in summaries][0] == \
        {k: v for k, v in summaries[1].items() if k not in WALL_CLOCK}
    for name, keys in (("model.pt", ("meta", "checksum")), ("checkpoint.pt", ("identity", "checksum"))):
        a, b = (torch.load(d / name, weights_only=True) for d in (together, alone))
        for state, folder in ((a, together), (b, alone)):
            state.get("run", {}).pop("wall_s", None)  # the run's clock
            if "log_sizes" in state.get("run", {}):  # the logger's files, under the folder's name
                state["run"]["log_sizes"] = {k.replace(f"/{folder.name}/", "/RUN/"): v
                                             for k, v in state["run"]["log_sizes"].items()
                                             if not k.endswith(CLOCK_SCALARS)}
        assert tensors_equal({k: v for k, v in a.items() if k not in keys},
                             {k: v for k, v in b.items() if k not in keys}), (together.name, name)


@pytest.mark.parametrize("learner, settings", [
    ("qlearn", ["learner.alpha=0.3", "learner.number_splits=6", "eval_every=7"]),
    pytest.param("dqn", ["learner.lr=0.003", "learner.batch_size=16", "learner.buffer_size=600"],
                 marks=pytest.mark.slow),  # 19 s; a dqn member renewed as fresh in CI: tests/test_members.py
])
def test_freed_members_train_the_next_jobs_each_as_its_run_alone(tmp_path, learner, settings):
    """A batch of two members handed three more jobs as its members free (another trial's
    two seeds, then a third seed of the first trial): every run is its run alone, file for
    file, and the source of jobs hears which ended."""
    short = ["max_env_steps=1200"] if learner == "dqn" else []
    queue = [*jobs(learner, tmp_path, "batch_b", [*short, *settings]), *jobs(learner, tmp_path, "batch_a", short, (7,))]
    calls = []

    def more(ended, free):
        calls.append(([job.run_dir.name for job in ended], free))
        given = queue[:free]
        del queue[:free]
        return given

    summaries = run_jobs(jobs(learner, tmp_path, "batch_a", short), more=more)
    assert not queue and len(summaries) == 5 and not any("failed" in s for s in summaries)
    ended = [name for names, _ in calls for name in names]
    assert sorted(ended) == sorted(f"batch_{t}{s}" for t, s in (("a", 4), ("a", 9), ("b", 4), ("b", 9), ("a", 7)))
    for extra, seeds, trial in ((short, (*SEEDS, 7), "a"), ([*short, *settings], SEEDS, "b")):
        for job in jobs(learner, tmp_path, f"alone_{trial}", extra, seeds):
            job.run_dir.mkdir()
            execute(job.cfg, job.run_dir, choices=job.choices)
        for seed in seeds:
            same_run_files(tmp_path / f"batch_{trial}{seed}", tmp_path / f"alone_{trial}{seed}")


def test_a_job_that_does_not_fit_the_batch_is_refused_in_its_folder(tmp_path):
    """A job handed in for a freed member that differs in a setting members may not (its
    tabular quirk) ends at once with one line in its error.txt; the next job takes the member."""
    unfit = jobs("qlearn", tmp_path, "unfit", ["learner.noise_exploration=true"], (5,))
    queue = [*unfit, *jobs("qlearn", tmp_path, "next", (), (6,))]

    def more(ended, free):
        given = queue[:1]
        del queue[:1]
        return given

    summaries = run_jobs(jobs("qlearn", tmp_path, "batch"), more=more)
    error = (tmp_path / "unfit5" / "error.txt").read_text()
    assert "cannot share a batch" in error and "\n" not in error.strip()
    assert [("failed" in s) for s in summaries] == [False, False, True, False]
    assert json.loads((tmp_path / "next6" / "summary.json").read_text())["episodes"] > 0


def test_a_job_whose_member_would_not_fit_the_free_memory_is_refused_in_its_folder(tmp_path, monkeypatch):
    """A job handed in for a freed member whose training state would take most of the memory
    then free ends at once with one line naming what to shrink; the batch goes on."""
    reads = []

    def available():  # unknown while the batch is built (its own check passes), then 1 MiB free
        reads.append(1)
        return None if len(reads) == 1 else 2**20

    monkeypatch.setattr(batch_module, "available_bytes", available)
    queue = jobs("dqn", tmp_path, "big", ["learner.buffer_size=1000000", "max_env_steps=1200"], (5,))

    def more(ended, free):
        given = queue[:1]
        del queue[:1]
        return given

    summaries = run_jobs(jobs("dqn", tmp_path, "batch", ["max_env_steps=1200"]), more=more)
    error = (tmp_path / "big5" / "error.txt").read_text().strip()
    assert "member needs about" in error and "learner.buffer_size" in error and "\n" not in error
    assert [("failed" in s) for s in summaries] == [False, False, True]


def test_a_ctrl_c_while_the_next_jobs_are_made_starts_none_of_them(tmp_path):
    """Ctrl-C arriving while the source of jobs makes the next ones: the runs still training
    stop with their checkpoint, and the jobs just made are handed back as stopped, untrained
    (so a sweep stops too, and its next run takes their trials over)."""
    queue = jobs("qlearn", tmp_path, "next", (), (5,))

    def more(ended, free):
        os.kill(os.getpid(), signal.SIGINT)  # as a Ctrl-C in the middle of making them
        given = queue[:free]
        del queue[:free]
        return given

    summaries = run_jobs(jobs("qlearn", tmp_path, "batch"), more=more)
    assert len(summaries) == 3 and summaries[-1] == {"interrupted": True, "signal": signal.SIGINT}
    assert sum(bool(s.get("interrupted")) for s in summaries[:2]) == 1  # the one still training
    assert not (tmp_path / "next5" / "summary.json").exists()


def test_a_job_that_fails_to_start_in_a_freed_member_fails_alone(tmp_path, monkeypatch):
    """A job whose start in a freed member raises (here its member's renewal) ends with its
    trace in its error.txt; the batch goes on and the next job takes the member."""
    real = QLearn.renew

    def renew(self, b, generator, variant=None):
        if generator.initial_seed() == 5:
            raise RuntimeError("no member for seed 5")
        return real(self, b, generator, variant)

    monkeypatch.setattr(QLearn, "renew", renew)
    queue = [*jobs("qlearn", tmp_path, "bad", (), (5,)), *jobs("qlearn", tmp_path, "next", (), (6,))]

    def more(ended, free):
        given = queue[:1]
        del queue[:1]
        return given

    summaries = run_jobs(jobs("qlearn", tmp_path, "batch"), more=more)
    assert "RuntimeError: no member for seed 5" in (tmp_path / "bad5" / "error.txt").read_text()
    assert [("failed" in s) for s in summaries] == [False, False, True, False]
    assert json.loads((tmp_path / "next6" / "summary.json").read_text())["episodes"] > 0


@pytest.mark.parametrize("learner, settings", [
    ("qlearn", ["learner.alpha=0.3", "learner.gamma=0.9", "learner.epsilon_discount=0.99"]),
    pytest.param("dqn", ["learner.lr=0.003", "learner.tau=0.05", "learner.updates=3"],
                 marks=pytest.mark.slow),  # 17 s; dqn trials side by side in CI: the own-sizes case below
    # each run's own schedules (a searched eval_every) and a DQN's own buffer and minibatch sizes
    ("qlearn", ["learner.alpha=0.3", "eval_every=7", "checkpoint_every=9", "log_every=5"]),
    ("dqn", ["learner.batch_size=16", "learner.buffer_size=600", "learner.lr=0.003", "eval_every=9"]),
    ("qlearn", ["learner.alpha=0.3", "eval_every=0", "eval_every_steps=150"]),  # evaluations by env steps
])
def test_trials_side_by_side_are_each_their_run_alone(tmp_path, learner, settings):
    """Two trials (other member-wise settings, schedules) x two seeds, one seed in both, as one
    batch of four members: each run is its run alone, file for file."""
    short = ["max_env_steps=1200"] if learner == "dqn" else []  # 700 env steps of updates
    trials = jobs(learner, tmp_path, "batch_a", short), jobs(learner, tmp_path, "batch_b", [*short, *settings])
    run_jobs([*trials[0], *trials[1]])
    for extra, batch in zip((short, [*short, *settings]), trials):
        for job in jobs(learner, tmp_path, "alone_" + batch[0].run_dir.name[6], extra):
            job.run_dir.mkdir()
            execute(job.cfg, job.run_dir, choices=job.choices)
    for seed in SEEDS:
        for trial in "ab":
            same_run_files(tmp_path / f"batch_{trial}{seed}", tmp_path / f"alone_{trial}{seed}")
    assert (tmp_path / f"batch_a{SEEDS[0]}" / "metrics.csv").read_bytes() != \
        (tmp_path / f"batch_b{SEEDS[0]}" / "metrics.csv").read_bytes()  # the settings made a difference


def test_a_stopped_batch_seed_resumes_alone_to_its_uninterrupted_run(tmp_path, monkeypatch):
    """A batch stopped after 20 episodes leaves each seed the checkpoint its run alone writes:
    ``resume`` continues it alone to the metrics of a run never stopped."""
    real_end_step = Run.end_step

    def end_step(self, td):
        td = real_end_step(self, td)
        if self.n_episodes >= 20:
            self.request_stop()
        return td

    monkeypatch.setattr(Run, "end_step", end_step)
    summaries = run_jobs(jobs("qlearn", tmp_path, "batch"))
    assert all(s["interrupted"] for s in summaries)
    monkeypatch.setattr(Run, "end_step", real_end_step)
    folder = tmp_path / f"batch{SEEDS[1]}"
    execute(load_run_config(folder), folder, resume=True, choices=read_run_json(folder))
    alone = jobs("qlearn", tmp_path, "alone")[1]
    alone.run_dir.mkdir()
    execute(alone.cfg, alone.run_dir, choices=alone.choices)
    for name in ("metrics.csv", "evals.csv", "eval.json"):
        assert (folder / name).read_bytes() == (alone.run_dir / name).read_bytes(), name


@pytest.mark.parametrize("learner", ["qlearn", "dqn"])
def test_a_stopped_sweep_resumes_as_one_batch_to_each_seeds_uninterrupted_run(tmp_path, monkeypatch, learner):
    """A batch stopped at a step, then ``resume=<sweep folder>`` (sweeps.resume): its seeds
    continue together from their checkpoints (learners, env blocks, runs, random streams,
    a DQN's Adam state) and end with the files of each seed's run never stopped."""
    from sweeps.resume import resume_sweep

    real_end_step = Run.end_step
    limit = 20  # episodes; the dqn's updates began before (its Adam state is saved and taken back)

    def end_step(self, td):
        td = real_end_step(self, td)
        if self.n_episodes >= limit and (learner == "qlearn" or self.env_steps >= 1200):
            self.request_stop()
        return td

    sweep = tmp_path / "sweep"
    sweep.mkdir()
    (sweep / "multirun.yaml").write_text("{}\n")  # what makes a folder a sweep's
    monkeypatch.setattr(Run, "end_step", end_step)
    summaries = run_jobs(jobs(learner, sweep, "batch"))
    assert all(s["interrupted"] for s in summaries)
    if learner == "dqn":
        state = torch.load(sweep / f"batch{SEEDS[0]}" / "checkpoint.pt", weights_only=True)["learner"]
        assert state["optimizer_steps"] > 0 and state["optimizer"]["state"]
    monkeypatch.setattr(Run, "end_step", real_end_step)
    resumed = []
    monkeypatch.setattr(batch_module.Run, "continue_from",
                        lambda self, td, real=Run.continue_from: resumed.append(self.n_episodes) or real(self, td))
    summaries = resume_sweep(compose("cartpole", learner=learner, overrides=[f"resume={sweep}"]), [f"resume={sweep}"])
    assert len(summaries) == len(SEEDS) and not any(s.get("interrupted") or s.get("failed") for s in summaries)
    assert len(resumed) == len(SEEDS) and min(resumed) >= limit  # each from its checkpoint
    run_alone(learner, tmp_path)
    for seed in SEEDS:
        together, alone = sweep / f"batch{seed}", tmp_path / f"alone{seed}"
        for name in SAME_FILES:
            assert (together / name).read_bytes() == (alone / name).read_bytes(), (seed, name)
        a, b = (torch.load(d / "model.pt", weights_only=True) for d in (together, alone))
        assert tensors_equal({k: v for k, v in a.items() if k not in ("meta", "checksum")},
                             {k: v for k, v in b.items() if k not in ("meta", "checksum")}), seed
    assert (sweep / "comparison.csv").is_file()


def test_a_failing_seed_ends_alone(tmp_path, monkeypatch):
    """A seed's own work failing (here its run's booking, after 10 episodes) ends it alone,
    with its files; the other seed trains on, its files still its run's alone."""
    real_record = Run.record

    def record(self, *args, **kwargs):
        if self.run_dir.name == f"batch{SEEDS[0]}" and self.n_episodes >= 10:
            raise FloatingPointError("the metrics diverged")
        return real_record(self, *args, **kwargs)

    monkeypatch.setattr(Run, "record", record)
    summaries = run_jobs(jobs("qlearn", tmp_path, "batch"))
    failed, healthy = (tmp_path / f"batch{s}" for s in SEEDS)
    assert "FloatingPointError: the metrics diverged" in (failed / "error.txt").read_text()
    assert summaries[0]["failed"] == "FloatingPointError: the metrics diverged"
    assert not (healthy / "error.txt").exists() and summaries[1]["episodes"] == 60
    assert (failed / "model.pt").is_file() and (healthy / "eval.json").is_file()
    monkeypatch.setattr(Run, "record", real_record)
    run_alone("qlearn", tmp_path, seeds=SEEDS[1:])
    same_files(tmp_path, SEEDS[1:])


def test_a_failed_learner_call_ends_every_seed_with_its_trace(tmp_path, monkeypatch):
    """The seeds share a learner call's state: when the call fails, each seed ends there
    (its files, its error.txt with the trace), none trains on."""
    real_observe, calls = QLearn.observe, []

    def observe(self, *args):
        calls.append(1)
        if len(calls) == 40:
            raise RuntimeError("no memory for the Q-tables")
        real_observe(self, *args)

    monkeypatch.setattr(QLearn, "observe", observe)
    summaries = run_jobs(jobs("qlearn", tmp_path, "batch"))
    for seed, summary in zip(SEEDS, summaries):
        folder = tmp_path / f"batch{seed}"
        assert summary["failed"] == "RuntimeError: no memory for the Q-tables", summary
        assert "the seeds' learner failed" in (folder / "error.txt").read_text()
        assert (folder / "model.pt").is_file() and summary["episodes"] < 60


@pytest.mark.parametrize("change, message", [
    (lambda js: js[1].cfg.__setitem__("seed", js[0].cfg.seed), "appears twice"),
    (lambda js: js[1].cfg.learner.__setitem__("first_visit_reward", True), "differ in more than their seed"),
    (lambda js: js[1].cfg.__setitem__("mode", "eval"), "fresh or resumed runs only"),
])
def test_a_batch_of_unlike_jobs_is_refused_before_any_work(tmp_path, change, message):
    batch = jobs("qlearn", tmp_path, "batch")
    change(batch)
    with pytest.raises(ConfigError, match=message):
        check_batch(batch)
    with pytest.raises(ConfigError, match=message):
        run_jobs(batch)
    assert not any(job.run_dir.exists() for job in batch)


def run_cli(args: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """``train.py <args>`` in this process (tests/inprocess.py); every folder is given."""
    return run_train(*args)


def test_a_multirun_trains_its_seeds_in_one_batch_per_group(tmp_path):
    """``-m learner=qlearn,dqn seed=0,1`` makes two batches (one per learner), each seed with
    its own job folder; the comparison reads them as ever."""
    proc = run_cli(["-m", "learner=qlearn,dqn", "seed=0,1", "max_episodes=20", "max_env_steps=600",
                    "eval_episodes=2", "quiet=true", f"hydra.sweep.dir={tmp_path / 'sweep'}"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.count("Training 2 seeds together") == 2, proc.stdout[-2000:]
    jobs_done = sorted(p.name for p in (tmp_path / "sweep").iterdir() if (p / "summary.json").is_file())
    assert len(jobs_done) == 4, jobs_done
    assert "[seed 1] VERDICT" in proc.stdout and (tmp_path / "sweep" / "comparison.csv").is_file()
    # Nothing of a finished sweep to resume: one line, nothing touched.
    before = sorted(p.name for p in (tmp_path / "sweep").iterdir())
    proc = run_cli([f"resume={tmp_path / 'sweep'}"], tmp_path)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == [
        f"error: resume={tmp_path / 'sweep'}: every run of this sweep is finished; nothing to continue "
        f"(compare it with: python compare.py {tmp_path / 'sweep'})"], proc.stderr[-2000:]
    assert sorted(p.name for p in (tmp_path / "sweep").iterdir()) == before  # no .hydra-resume/


def test_a_resumed_sweep_runs_the_jobs_that_never_started_together_into_their_folders(tmp_path):
    """A launcher stopped before two jobs (here: their folders removed, as if they never
    began): the resume trains them as one batch, each into the folder its sweep would have
    given it and as the uninterrupted sweep made it; then the sweep is whole."""
    sweep = tmp_path / "sweep"
    proc = run_cli(["-m", "hydra/launcher=basic", "seed=0,1,2", "max_episodes=10", "eval_episodes=0", "quiet=true",
                    f"hydra.sweep.dir={sweep}"], tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    made = {p.name: (p / "metrics.csv").read_bytes() for p in sweep.glob("[12]_*")}
    for name in made:
        shutil.rmtree(sweep / name)
    proc = run_cli([f"resume={sweep}"], tmp_path)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert f"starting 2 jobs of {sweep} together: 1_cartpole_qlearn_seed1, 2_cartpole_qlearn_seed2" in proc.stdout, \
        proc.stdout[-2000:]
    assert {name: (sweep / name / "metrics.csv").read_bytes() for name in made} == made
    assert (sweep / "1_cartpole_qlearn_seed1" / ".hydra" / "overrides.yaml").is_file()
    assert "comparison" in proc.stdout and (sweep / "comparison.csv").is_file()
    proc = run_cli([f"resume={sweep}"], tmp_path)  # nothing left: finished, and never-started none
    assert proc.returncode == 2 and "every run of this sweep is finished" in proc.stderr, proc.stderr[-2000:]


def test_a_seed_given_twice_is_one_line_and_nothing_runs(tmp_path):
    proc = run_cli(["-m", "seed=3,3", f"hydra.sweep.dir={tmp_path / 'sweep'}"], tmp_path)
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert proc.returncode == 2 and lines == ["error: seed=3 is given twice in one sweep; give each seed once"]
    assert not any((tmp_path / "sweep").glob("*/config.yaml"))


def test_a_batch_that_would_not_fit_in_memory_is_one_line_before_training(tmp_path, monkeypatch):
    monkeypatch.setattr(batch_module, "available_bytes", lambda: 2**20)
    copies = int(jobs("dqn", tmp_path, "batch")[0].cfg.num_envs)  # the tuned file's
    shown = f"{copies} cop{'y' if copies == 1 else 'ies'}"
    with pytest.raises(ConfigError, match=rf"a batch of 2 seeds x {shown} needs about .* GiB free"):
        run_jobs(jobs("dqn", tmp_path, "batch"))
    assert not any((job.run_dir / "metrics.csv").exists() for job in jobs("dqn", tmp_path, "batch"))


def test_a_batchs_memory_counts_each_members_own_replay_buffer(monkeypatch):
    """Trials side by side may differ in their replay buffer's size: the estimate before
    training adds up each member's own (a 2M-row buffer: ~0.08 GiB more than a 1000-row one)."""
    from tasks.factory import build_env

    monkeypatch.setattr(batch_module, "available_bytes", lambda: 1)
    needs = []
    for sizes in ((1000, 1000), (1000, 2_000_000)):
        cfgs = [compose("cartpole", learner="dqn", overrides=[f"learner.buffer_size={size}"]) for size in sizes]
        env = build_env(cfgs[0], 2 * int(cfgs[0].num_envs), [0, 1])
        with pytest.raises(ConfigError, match="needs about") as err:
            batch_module._check_memory(env, cfgs)
        env.close()
        needs.append(float(str(err.value).split("needs about ")[1].split(" GiB")[0]))
    assert 0.05 < needs[1] - needs[0] < 0.2, needs


def test_a_batchs_memory_builds_one_learner_per_size_not_per_trial(monkeypatch):
    """The estimate builds a learner of one per value of the settings that size a member
    (``SIZING``), not per config: four trials in two learning rates and two buffer sizes
    build two."""
    from tasks.factory import build_env

    built = []
    real = batch_module.instantiate
    monkeypatch.setattr(batch_module, "instantiate", lambda cfg, **kw: built.append(cfg) or real(cfg, **kw))
    cfgs = [compose("cartpole", learner="dqn", overrides=[f"learner.buffer_size={size}", f"learner.lr={lr}"])
            for size in (1000, 2000) for lr in (0.001, 0.0005)]
    env = build_env(cfgs[0], 4 * int(cfgs[0].num_envs), [0, 1, 2, 3])
    batch_module._check_memory(env, cfgs)
    env.close()
    assert sorted(cfg.buffer_size for cfg in built) == [1000, 2000]


def test_a_run_updates_with_denormal_numbers_flushed_and_leaves_the_process_as_it_was(tmp_path, monkeypatch):
    """Adam's first moment of a dead unit's weights sticks in denormal numbers, where the
    CPU's arithmetic is ~5x slower: a run's updates compute them as 0
    (``denormals_flushed``); after the run a product below float32's normal range is kept."""
    import learners.member as dqn_module

    real_adam, flushed = dqn_module.adam_step, []

    def adam_step(*args, **kwargs):
        flushed.append((torch.tensor([1e-30]) * 1e-10).item() == 0.0)
        return real_adam(*args, **kwargs)

    monkeypatch.setattr(dqn_module, "adam_step", adam_step)
    job = jobs("dqn", tmp_path, "run")[0]
    job.run_dir.mkdir()
    execute(job.cfg, job.run_dir, choices=job.choices)
    assert flushed and all(flushed), len(flushed)
    assert (torch.tensor([1e-30]) * 1e-10).item() > 0.0
    with batch_module.denormals_flushed():
        assert (torch.tensor([1e-30]) * 1e-10).item() == 0.0


def test_a_sweeps_jobs_are_composed_as_hydra_composes_each(monkeypatch):
    """``compose_jobs``: jobs that differ only in values (seed, trial, searched settings, a
    list among them) are copies of one composition given their values; the first job of
    another robot or learner, or with a value of another kind (null for a list), is composed
    by Hydra, the next ones copied from it. Every config, its ``hydra`` node too, is the one
    Hydra's ``load_sweep_config`` makes for that job."""
    from hydra import initialize_config_dir
    from hydra.core.global_hydra import GlobalHydra
    from hydra.types import RunMode
    from omegaconf import OmegaConf

    from sweeps.seed_batch import compose_jobs
    from tasks.catalog import conf_dir

    jobs = [["robot=cartpole", "learner=dqn", f"learner.lr={lr}", f"learner.hidden={hidden}", f"seed={seed}",
             f"trial={trial}"] for trial, (lr, hidden) in enumerate([(0.001, "[64,64]"), (3e-3, "[32]"), (5e-4, "null")])
            for seed in (0, 1)]
    jobs += [["robot=cube", "learner=dqn", "learner.lr=0.001", "learner.hidden=[64,64]", f"seed={seed}", "trial=3"]
             for seed in (0, 1)]
    jobs += [["robot=cartpole", "learner=qlearn", "learner.alpha=0.5", "learner.gamma=0.9", "seed=0", "trial=4"]]
    with initialize_config_dir(config_dir=str(conf_dir()), version_base=None):
        loader = GlobalHydra.instance().config_loader()
        master = loader.load_configuration("config", ["hydra/sweeper=optuna"], RunMode.MULTIRUN)
        calls = []
        hydras = loader.load_sweep_config
        monkeypatch.setattr(loader, "load_sweep_config", lambda m, o: calls.append(o) or hydras(m, o))
        ours = compose_jobs(loader, master, jobs)
        # one composition per robot and learner, and one for a null where the first had a list
        assert calls == [jobs[0], jobs[4], jobs[-3], jobs[-1]]
        theirs = [hydras(master, job) for job in jobs]
    assert [OmegaConf.to_yaml(cfg) for cfg in ours] == [OmegaConf.to_yaml(cfg) for cfg in theirs]
    assert [(cfg.learner.lr, cfg.learner.hidden, cfg.seed) for cfg in ours[:3]] == [
        (0.001, [64, 64], 0), (0.001, [64, 64], 1), (3e-3, [32], 0)]


def test_the_multirun_sweeper_leaves_composing_the_jobs_to_the_seeds_launcher():
    """hydra/sweeper=seeds composes no job beforehand when the seeds launcher will (it composes
    every job before any starts); with any other launcher it checks each job as Hydra's does."""
    from types import SimpleNamespace

    from hydra._internal.core_plugins.basic_launcher import BasicLauncher

    from hydra_plugins.rl_seed_launcher.seed_launcher import SeedBatchLauncher, SeedBatchSweeper

    calls = []
    sweeper = SeedBatchSweeper(max_batch_size=None, params=None)
    sweeper.config = object()
    sweeper.hydra_context = SimpleNamespace(config_loader=SimpleNamespace(
        load_sweep_config=lambda master_config, sweep_overrides: calls.append(sweep_overrides)))
    batch = [["seed=0"], ["seed=1"]]
    sweeper.launcher = SeedBatchLauncher()
    sweeper.validate_batch_is_legal(batch)
    assert calls == []
    sweeper.launcher = BasicLauncher()  # (hydra/launcher=basic; joblib and submitit alike)
    sweeper.validate_batch_is_legal(batch)
    assert calls == batch
