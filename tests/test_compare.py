"""The comparison (sweeps.comparison; compare.py re-runs it) tells the truth about a
sweep: one row per setting of the swept hyperparameters, the task's own measure per
seed summarized by its IQM and a 95% bootstrap interval, every job that did not
finish listed as what it is, and no traceback on a damaged job folder. A sweep
prints it when it ends (sweeps.state's callback), never failing the sweep.

The fast tests build fake sweep folders (multirun.yaml and job folders as
train.py writes them) in ``tmp_path``; one test runs a real tiny sweep.
"""

from __future__ import annotations

import csv
import json
import math
import os
import subprocess
import sys
import warnings
from itertools import product
from pathlib import Path

import numpy as np
import pytest

from inprocess import run_train
from omegaconf import OmegaConf

import compare
from sweeps import comparison
from sweeps.stats import iqm, iqm_ci
from sweeps.state import RecordSweep

ROOT = Path(__file__).resolve().parents[1]
BASE = ["max_episodes=5", "eval_episodes=0", "quiet=True"]


def write_multirun(sweep: Path, task_overrides: list[str]) -> None:
    """A multirun.yaml as Hydra saves it, with the parts compare.py reads."""
    sweep.mkdir(parents=True, exist_ok=True)
    lines = ["hydra:", "  sweeper:",
             "    _target_: hydra._internal.core_plugins.basic_sweeper.BasicSweeper",
             "    max_batch_size: null", "    params: null",
             "  overrides:", "    task:", *(f"    - {o}" for o in task_overrides),
             "  runtime:", "    choices:", "      learner: qlearn", "      robot: cartpole",
             "      task: stay_up", "seed: 0"]
    (sweep / "multirun.yaml").write_text("\n".join(lines) + "\n")


def write_job(sweep: Path, num: int, overrides: list[str], status: str = "finished",
              episodes: int = 5, solved_at: int | None = None) -> Path:
    """Job folder ``num`` as train.py leaves it: ``finished``, ``failed`` (error.txt),
    ``interrupted`` (Ctrl-C: summary.json says so), ``killed`` (metrics.csv and
    checkpoint.pt, no summary.json) or ``hydra-only`` (Hydra made it, train.py did not run)."""
    given = dict(o.split("=", 1) for o in overrides)
    job = sweep / f"{num}_cartpole_qlearn_seed{given.get('seed', 0)}"
    (job / ".hydra").mkdir(parents=True)
    (job / ".hydra" / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides))
    if status == "hydra-only":
        return job
    (job / "config.yaml").write_text(f"seed: {given.get('seed', 0)}\n")
    (job / "run.json").write_text(json.dumps({"robot": "cartpole", "task": "stay_up", "learner": "qlearn",
                                              "tuned": "cartpole_qlearn", "seed": int(given.get("seed", 0)),
                                              "overrides": overrides}))
    if status == "failed":
        (job / "error.txt").write_text("error: learner.alpha must be a finite number in (0, 1]; got -1\n")
        return job
    with open(job / "metrics.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["episode", "env_index", "reward", "length", "terminated", "env_steps", "length_mean100"])
        w.writerows([i, 0, 10.0 * i, 10 * i, 1, 55 * i, 5.0 * i] for i in range(1, episodes + 1))
    with open(job / "timing.csv", "w", newline="") as f:
        csv.writer(f).writerows([["episode", "wall_s"], *([i, 0.1 * i] for i in range(1, episodes + 1))])
    (job / "checkpoint.pt").write_bytes(b"fake")
    if status != "killed":
        (job / "summary.json").write_text(json.dumps(summary(episodes, solved_at, status == "interrupted")))
    return job


def summary(episodes: int, solved_at: int | None, interrupted: bool) -> dict:
    """summary.json as train.py writes it (the returns those of ``write_job``'s metrics.csv)."""
    returns = [10.0 * i for i in range(1, episodes + 1)]
    out = {"solved": solved_at is not None, "decided_by": "training", "episodes": episodes,
           "solved_at": solved_at, "measure": "length", "unit": "steps", "description": "steps balanced",
           "threshold": 250.0, "judge": "training", "window": 100, "min_episodes": 100,
           "judged_length": 7.0, "train_return_mean": sum(returns) / episodes,
           "train_return_last100": sum(returns[-100:]) / len(returns[-100:]),
           "train_length_best_rolling100": 7.0, "train_length_last100": 7.0, "train_length_best100_mean": 9.0,
           "greedy_length": None, "greedy_return": None, "evaluations": 0,
           "env_steps": 55 * episodes, "wall_s": 0.5, "divergences": 0}
    return out | ({"interrupted": True} if interrupted else {})


def old_summary(episodes: int) -> dict:
    """summary.json as train.py wrote it before every number was named for what it is."""
    return {"solved": False, "decided_by": "training", "episodes": episodes, "solved_at": None,
            "measure": "length", "unit": "steps", "description": "steps balanced", "threshold": 250.0,
            "judge": "training", "window": 100, "min_episodes": 100, "value": 7.0, "best_rolling": 7.5,
            "last_rolling": 7.0, "mean_of_100_best_episodes": 9.0, "greedy": 6.5, "evaluations": 1,
            "score": 30.0, "env_steps": 55 * episodes, "wall_s": 0.5, "divergences": 0}


def fake_sweep(sweep: Path, sweeps: dict[str, list[str]], statuses: dict[int, str] | None = None) -> list:
    """multirun.yaml sweeping ``sweeps`` (key -> values) and one job folder per job, in
    BasicSweeper's order; ``statuses``: job number -> status (``missing``: no folder)."""
    write_multirun(sweep, [f"{k}={','.join(v)}" for k, v in sweeps.items()] + BASE)
    jobs = [[f"{k}={v}" for k, v in zip(sweeps, values)] + BASE for values in product(*sweeps.values())]
    for num, overrides in enumerate(jobs):
        status = (statuses or {}).get(num, "finished")
        if status != "missing":
            write_job(sweep, num, overrides, status)
    return jobs


def table(sweep: Path, capsys) -> tuple[list[dict], str]:
    """compare.py's main on ``sweep``: comparison.csv's rows and what it printed."""
    assert compare.main([str(sweep)]) == 0
    out = capsys.readouterr().out
    assert "Traceback" not in out
    with open(sweep / "comparison.csv") as f:
        return list(csv.DictReader(f)), out


def test_two_values_of_a_swept_hyperparameter_are_two_rows_not_two_seeds(tmp_path, capsys):
    fake_sweep(tmp_path, {"seed": ["0", "1"], "learner.alpha": ["0.05", "1.0"]})
    rows, out = table(tmp_path, capsys)
    assert [(r["swept"], r["seeds"], r["finished"]) for r in rows] == [
        ("learner.alpha=0.05", "2", "2"), ("learner.alpha=1.0", "2", "2")]
    assert "learner.alpha=1.0" in out and "| learner.alpha=0.05 |" in (tmp_path / "comparison.md").read_text()


def test_seeds_alone_are_one_row(tmp_path, capsys):
    fake_sweep(tmp_path, {"seed": ["0", "1", "2"]})
    rows, _ = table(tmp_path, capsys)
    assert [(r["swept"], r["seeds"], r["finished"], r["solved"]) for r in rows] == [("-", "3", "3", "0/3")]


def test_every_swept_key_but_the_seed_makes_the_group(tmp_path, capsys):
    fake_sweep(tmp_path, {"learner.alpha": ["0.1", "0.5"], "learner.gamma": ["0.9", "0.99"], "seed": ["0", "1"]})
    rows, _ = table(tmp_path, capsys)
    assert len(rows) == 4 and all(r["seeds"] == "2" for r in rows)
    assert rows[0]["swept"] == "learner.alpha=0.1 learner.gamma=0.9"


def test_failed_interrupted_killed_and_never_started_jobs_are_listed_as_such(tmp_path, capsys):
    statuses = {1: "failed", 2: "interrupted", 3: "killed", 4: "missing", 5: "hydra-only"}
    jobs = fake_sweep(tmp_path, {"seed": [str(s) for s in range(6)]}, statuses)
    rows, out = table(tmp_path, capsys)
    assert len(rows) == 1
    row = rows[0]
    assert (row["seeds"], row["finished"], row["failed"], row["interrupted"], row["never_started"]) == \
        ("6", "1", "1", "2", "2")
    assert row["solved"] == "0/1"  # only the finished job is judged
    lines = out.split("jobs that did not finish")[1]
    assert "failed: " in lines and "learner.alpha must be a finite number" in lines
    assert f"interrupted: {tmp_path / '2_cartpole_qlearn_seed2'}: stopped after episode 5 (Ctrl-C)" in lines
    assert f"resume with: python train.py resume={tmp_path / '3_cartpole_qlearn_seed3'}" in lines
    assert f"never started: job 4 ({' '.join(jobs[4])}): no folder 4_* in {tmp_path}" in lines
    assert f"never started: {tmp_path / '5_cartpole_qlearn_seed5'}" in lines
    assert "Jobs that did not finish" in (tmp_path / "comparison.md").read_text()


def test_a_partial_interrupted_job_does_not_enter_the_numbers(tmp_path, capsys):
    write_multirun(tmp_path, ["seed=0,1", *BASE])
    write_job(tmp_path, 0, ["seed=0", *BASE], episodes=5)
    write_job(tmp_path, 1, ["seed=1", *BASE], status="interrupted", episodes=300, solved_at=None)
    rows, _ = table(tmp_path, capsys)
    assert rows[0]["finished"] == "1" and rows[0]["interrupted"] == "1"
    assert rows[0]["train_return_last100"].startswith("30 ")  # episodes 1..5 of the finished job only


def test_a_sweep_where_no_job_started_is_all_never_started(tmp_path, capsys):
    write_multirun(tmp_path, ["learner.alpha=0.05,1.0", *BASE])
    rows, out = table(tmp_path, capsys)
    assert [(r["swept"], r["never_started"], r["finished"]) for r in rows] == [
        ("learner.alpha=0.05", "1", "0"), ("learner.alpha=1.0", "1", "0")]
    assert out.count("never started: job") == 2


def test_without_multirun_yaml_the_jobs_own_overrides_tell_the_groups(tmp_path, capsys):
    fake_sweep(tmp_path, {"learner.alpha": ["0.05", "1.0"]})
    (tmp_path / "multirun.yaml").unlink()
    rows, out = table(tmp_path, capsys)
    assert [r["swept"] for r in rows] == ["learner.alpha=0.05", "learner.alpha=1.0"]
    assert "multirun.yaml is missing" in out


def test_a_folder_of_another_sweep_is_not_taken_for_a_planned_job(tmp_path, capsys):
    write_multirun(tmp_path, ["learner.alpha=0.05", *BASE])
    write_job(tmp_path, 0, ["learner.alpha=0.5", *BASE])  # left by an earlier sweep into the same folder
    rows, out = table(tmp_path, capsys)
    assert sorted((r["swept"], r["finished"], r["never_started"]) for r in rows) == [
        ("learner.alpha=0.05", "0", "1"), ("learner.alpha=0.5", "1", "0")]
    assert "not one of multirun.yaml's jobs" in out


def test_job_folders_named_otherwise_are_found_by_their_overrides(tmp_path, capsys):
    fake_sweep(tmp_path, {"learner.alpha": ["0.05", "1.0"]})
    for job in list(tmp_path.glob("*_cartpole_*")):
        job.rename(tmp_path / f"run_{job.name.split('_')[0]}")  # another hydra.sweep.subdir
    rows, out = table(tmp_path, capsys)
    assert [(r["swept"], r["finished"]) for r in rows] == [("learner.alpha=0.05", "1"), ("learner.alpha=1.0", "1")]
    assert "did not finish" not in out


GARBAGE = [
    ("summary.json", "{\"solved\": tr", "summary.json is not valid JSON"),
    ("summary.json", "", "summary.json is empty"),
    ("summary.json", "[1, 2]", "summary.json holds no JSON object"),
    ("summary.json", "{\"solved\": false}", "summary.json: measure is missing"),
    ("summary.json", json.dumps(summary(5, 9, False)), "metrics.csv has 5 episodes, summary.json says solved at 9"),
    ("metrics.csv", "", "metrics.csv is empty"),
    ("metrics.csv", None, "no metrics.csv"),
    ("metrics.csv", "episode,reward\n1,2\n", "metrics.csv has no column length, env_steps, length_mean100"),
    ("metrics.csv", "reward,length,env_steps,length_mean100\nx,1,2,3\n", "a reward cell is not a number"),
    ("metrics.csv", b"\xff\xfe\x00garbage", "metrics.csv is unreadable (UnicodeDecodeError)"),
    ("error.txt", "", "error.txt is empty"),
    ("run.json", "{{{", "run.json is not valid JSON"),
    ("run.json", None, None),
    ("config.yaml", ": : :\n\t-", None),
    ("timing.csv", "nonsense", None),
    ("eval.json", "{]", "eval.json is not valid JSON"),
    ("checkpoint.pt", None, None),
    ("summary.json", None, "no summary.json: killed before it finished, or still running; resume with"),
]


@pytest.mark.parametrize("name, content, message", GARBAGE)
def test_a_damaged_job_is_one_line_and_the_others_are_tabulated(tmp_path, capsys, name, content, message):
    fake_sweep(tmp_path, {"learner.alpha": ["0.05", "1.0"], "seed": ["0", "1"]})
    bad = next(tmp_path.glob("3_*"))
    path = bad / name
    if content is None:
        path.unlink()
    elif isinstance(content, bytes):
        path.write_bytes(content)
    else:
        path.write_text(content)
    rows, out = table(tmp_path, capsys)
    assert [r["swept"] for r in rows] == ["learner.alpha=0.05", "learner.alpha=1.0"]
    assert rows[0]["finished"] == "2"  # the healthy jobs' row
    if message:
        assert sum(str(bad) in line for line in out.splitlines()) == 1
        assert message in out
    if name in ("summary.json", "metrics.csv", "error.txt"):  # never counted as finished
        assert rows[1]["finished"] == "1" and int(rows[1]["failed"]) + int(rows[1]["interrupted"]) == 1


@pytest.mark.parametrize("content", ["not: [yaml", "", "hydra: 3\n", b"\x00\xff"])
def test_a_damaged_multirun_yaml_falls_back_on_the_job_folders(tmp_path, capsys, content):
    fake_sweep(tmp_path, {"learner.alpha": ["0.05", "1.0"]})
    path = tmp_path / "multirun.yaml"
    path.write_bytes(content) if isinstance(content, bytes) else path.write_text(content)
    rows, out = table(tmp_path, capsys)
    assert [r["swept"] for r in rows] == ["learner.alpha=0.05", "learner.alpha=1.0"]
    assert "multirun.yaml is unreadable" in out and "jobs that never started cannot be listed" in out


def test_a_folder_without_jobs_is_an_error(tmp_path, capsys):
    assert compare.main([str(tmp_path)]) == 2
    assert "holds no run folders" in capsys.readouterr().err


def test_a_date_folder_of_sweeps_says_to_give_one_of_them(tmp_path, capsys):
    """Issue 67: ``compare.py multirun/<date>`` named no way on: it lists the sweeps below."""
    for name in ("10-00-00_1", "11-00-00_2"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "multirun.yaml").write_text("{}\n")
    assert compare.main([str(tmp_path)]) == 2
    assert "it holds sweeps, give one of them: 10-00-00_1, 11-00-00_2" in capsys.readouterr().err


def test_a_swept_label_leaves_out_the_defaults():
    """Issue 67: the swept column ran past 200 characters of '(default)'."""
    from sweeps.folder import swept_label

    keys = ["learner.alpha", "learner.gamma", "learner.epsilon"]
    assert swept_label({"overrides": ["learner.alpha=0.1"]}, keys) == "learner.alpha=0.1"
    assert swept_label({"overrides": ["seed=3"]}, keys) == "(defaults)"


def test_iqm_is_the_mean_of_the_middle_half_and_few_values_are_their_mean():
    assert iqm([1, 2, 3, 4]) == 2.5
    assert iqm([4, 1, 100, 2, 3, -50, 2.5, 3.5]) == 2.75  # 2, 2.5, 3, 3.5
    assert iqm([1, 2, 3]) == 2.0 and iqm([1, 2]) == 1.5
    assert iqm([1, None, float("nan"), 3]) == 2.0 and math.isnan(iqm([]))


def test_iqm_ci_holds_the_iqm_and_is_the_same_every_time():
    centre, low, high = iqm_ci([1, 2, 3, 4, 10, 0.5])
    assert centre == iqm([1, 2, 3, 4, 10, 0.5]) and 0.5 <= low < centre < high <= 10
    assert iqm_ci([1, 2, 3, 4, 10, 0.5]) == (centre, low, high)
    assert iqm_ci([10, 0.5, 4, 1, 3, 2]) == (centre, low, high)  # issue 65: the seeds' order is not the interval's
    narrow = iqm_ci([1, 2, 3, 4, 10, 0.5], confidence=0.5)
    assert low <= narrow[1] <= narrow[2] <= high
    for few in ([1, 2], [1, 2, 3]):  # a percentile bootstrap of their mean
        centre, low, high = iqm_ci(few)
        assert min(few) <= low <= centre <= high <= max(few)


@pytest.mark.parametrize("values", [[1, 2, 3, 4, 10, 0.5], [0.2, 7.1, 6.8, 58.1, 66.3, 70.2, 71.4, 74.0, 6.9, 69.5],
                                    [250, 1000, 1000, 1000, 980, 12], [1.5, 2.0]])
def test_the_numpy_iqm_and_interval_are_scipys(values):
    """sweeps.stats replaces scipy.stats.trim_mean and bootstrap (percentile) for speed: the
    IQM is scipy's exactly, the interval's ends within 5 % of its width (other resamples)."""
    from scipy.stats import bootstrap, trim_mean

    x = np.sort(np.array(values, dtype=float))  # (iqm_ci resamples the sorted values: any order, one interval)
    assert iqm(values) == pytest.approx(float(trim_mean(x, 0.25)), abs=1e-12)
    theirs = bootstrap((x,), lambda s, axis=-1: trim_mean(s, 0.25, axis=axis), vectorized=True,
                       n_resamples=9999, confidence_level=0.95, method="percentile",
                       random_state=np.random.default_rng(1)).confidence_interval
    _, low, high = iqm_ci(values)
    width = theirs.high - theirs.low
    assert abs(low - theirs.low) <= 0.05 * width and abs(high - theirs.high) <= 0.05 * width


def test_iqm_ci_of_one_seed_has_no_interval_and_equal_seeds_a_point():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no scipy warning on a degenerate sample
        centre, low, high = iqm_ci([4.7])
        assert centre == 4.7 and math.isnan(low) and math.isnan(high)
        assert iqm_ci([5.0, 5.0, 5.0]) == (5.0, 5.0, 5.0)
        assert all(math.isnan(v) for v in iqm_ci([]))
    with pytest.raises(ValueError, match="confidence must be in"):
        iqm_ci([1, 2], confidence=95)


def set_last_means(sweep: Path, means: dict[int, float], **summary_fields) -> None:
    """The summary.json of job ``num`` says the mean of its last 100 episodes is ``means[num]``."""
    for num, value in means.items():
        path = next(sweep.glob(f"{num}_*")) / "summary.json"
        path.write_text(json.dumps(json.loads(path.read_text()) | {"train_length_last100": value} | summary_fields))


def test_each_row_is_headed_by_the_iqm_of_its_seeds_with_a_bootstrap_interval(tmp_path, capsys):
    fake_sweep(tmp_path, {"learner.alpha": ["0.05", "1.0"], "seed": ["0", "1", "2", "3"]})
    set_last_means(tmp_path, {0: 1.0, 1: 2.0, 2: 3.0, 3: 4.0, 4: 5.0, 5: 5.0, 6: 5.0, 7: 5.0})
    rows, out = table(tmp_path, capsys)
    assert [(r["headline"], r["IQM [95% CI]"], r["iqm"]) for r in rows] == [
        ("train_length_last100", "2.5 [1, 4; 4 seeds: rough]", "2.5"), ("train_length_last100", "5 [5, 5; 4 seeds: rough]", "5.0")]
    assert float(rows[0]["ci_low"]) <= 2.5 <= float(rows[0]["ci_high"])
    assert rows[0]["mean +- std"] == "2.5 +- 1.1"
    assert "IQM [95% CI]" in out.splitlines()[0] and "2.5 [1, 4; 4 seeds: rough]" in out
    assert "| 2.5 [1, 4; 4 seeds: rough] |" in (tmp_path / "comparison.md").read_text()


def test_a_greedily_judged_task_is_headed_by_its_greedy_policy_and_tasks_are_never_pooled(tmp_path, capsys):
    fake_sweep(tmp_path, {"robot": ["cartpole", "cube"], "seed": ["0", "1"]})
    for num in (2, 3):  # the cube's jobs: another task, measure and judge
        job = next(tmp_path.glob(f"{num}_*"))
        names = json.loads((job / "run.json").read_text())
        (job / "run.json").write_text(json.dumps(names | {"robot": "cube", "task": "one_disk_walk"}))
    set_last_means(tmp_path, {2: 0.1, 3: 0.2}, judge="greedy")
    (next(tmp_path.glob("2_*")) / "eval.json").write_text(json.dumps({"value": 0.9, "mean_length": 5, "mean_return": 1}))
    rows, _ = table(tmp_path, capsys)
    assert [(r["robot/task"], r["headline"], r["IQM [95% CI]"]) for r in rows] == [
        ("cartpole/stay_up", "train_length_last100", "7 [7, 7; 2 seeds: rough]"),
        ("cube/one_disk_walk", "greedy_length; train_length_last100", "0.55 [0.2, 0.9; 2 seeds: rough]")]
    assert rows[1]["greedy_length"].startswith("0.9 ") and rows[1]["greedy_return"].startswith("1 ")


def test_a_sweep_written_before_the_numbers_were_named_reads_the_same(tmp_path, capsys):
    """Old job folders (summary.json with ``greedy``, ``best_rolling``, ``last_rolling``,
    ``mean_of_100_best_episodes``, ``value``, ``score``) are compared under the new names:
    the old keys mapped on read, the returns from metrics.csv."""
    from runs.summary import summarize_run

    fake_sweep(tmp_path, {"seed": ["0", "1"]})
    for job in tmp_path.glob("*_cartpole_*"):
        (job / "summary.json").write_text(json.dumps(old_summary(5)))
    job = summarize_run(next(tmp_path.glob("0_*")))
    assert job["status"] == "ok" and "warning" not in job
    assert (job["greedy_length"], job["greedy"], job["train_length_best_rolling100"], job["train_length_last100"],
            job["train_length_best100_mean"], job["judged_length"]) == (6.5, 6.5, 7.5, 7.0, 9.0, 7.0)
    assert job["train_return_mean"] == 30.0 and job["train_return_last100"] == 30.0  # metrics.csv: 10, ..., 50
    assert (job["headline"], job["headline_value"]) == ("train_length_last100", 7.0)
    assert not [key for key in job if "score" in key]
    rows, out = table(tmp_path, capsys)
    assert [(r["headline"], r["IQM [95% CI]"], r["greedy_length"], r["train_return_last100"]) for r in rows] == [
        ("train_length_last100", "7 [7, 7; 2 seeds: rough]", "6.5 +- 0", "30 +- 0")]


def test_a_sweep_prints_its_comparison_when_it_ends(tmp_path, capsys):
    fake_sweep(tmp_path, {"seed": ["0", "1", "2"]})
    callback, config = RecordSweep(), OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path)}}})
    callback.on_multirun_start(config)
    callback.on_multirun_end(config)
    out = capsys.readouterr().out
    assert "IQM [95% CI]" in out and "7 [7, 7; 3 seeds: rough]" in out and (tmp_path / "comparison.csv").is_file()
    callback.on_multirun_end(config)  # once per sweep (train.py asks again after a stop)
    assert capsys.readouterr().out == ""


def test_a_broken_comparison_is_one_line_and_never_fails_the_sweep(tmp_path, capsys, monkeypatch):
    callback, config = RecordSweep(), OmegaConf.create({"hydra": {"sweep": {"dir": str(tmp_path)}}})
    callback.on_multirun_start(config)
    callback.on_multirun_end(config)  # a sweep folder without jobs (a study's sweep of no new trials)
    assert capsys.readouterr() == ("\nno job of this sweep ran: nothing to compare\n", "")
    fake_sweep(tmp_path, {"seed": ["0", "1"]})

    def broken(folder, rows, lines, x="env_steps"):
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(comparison, "write_outputs", broken)
    callback.on_multirun_start(config)
    callback.on_multirun_end(config)
    out, err = capsys.readouterr()
    assert "IQM [95% CI]" in out  # the table came first
    assert err == "comparison failed: OSError: [Errno 28] No space left on device\n"


def test_a_stopped_sweep_compares_what_finished(tmp_path, capsys):
    fake_sweep(tmp_path, {"seed": ["0", "1", "2"]}, {1: "interrupted", 2: "missing"})
    (tmp_path / ".stop").write_text("SIGINT\n")
    rows, out = table(tmp_path, capsys)
    assert out.startswith("the sweep was stopped (SIGINT)")
    assert (rows[0]["finished"], rows[0]["interrupted"], rows[0]["never_started"]) == ("1", "1", "1")
    assert rows[0]["IQM [95% CI]"] == "7 [1 seed: no CI]"


def test_a_ctrl_c_before_the_sweep_folder_exists_still_skips_the_jobs_not_started(tmp_path, monkeypatch, capsys):
    """A Ctrl-C as the sweep starts, before Hydra made its folder (no ``.stop`` can be
    written yet): the jobs this process has not begun still see the sweep stopped."""
    import signal

    from sweeps import state

    monkeypatch.setitem(state.SWEEP, "dir", tmp_path / "sweep")
    monkeypatch.setitem(state.SWEEP, "signal", None)
    assert not state.sweep_stopped()
    state.stop_sweep(signal.SIGINT, None)
    assert not (tmp_path / "sweep").exists() and "jobs not started are skipped" in capsys.readouterr().err
    assert state.sweep_stopped()


def test_a_real_two_learner_three_seed_sweep_ends_with_its_comparison(tmp_path, capsys):
    """train.py -m over two learners and three seeds prints the comparison last; compare.py
    re-runs it to the same comparison.csv (the intervals are seeded)."""
    sweep = tmp_path / "sweep"
    proc = run_train("-m", "learner=qlearn,n1try", "seed=0,1,2", "max_episodes=5", "eval_episodes=0", "quiet=true",
                     f"hydra.sweep.dir={sweep}")  # in this process (tests/inprocess.py)
    assert proc.returncode == 0, proc.stderr[-2000:]
    tail = proc.stdout.rsplit("VERDICT", 1)[1].splitlines()[2:]
    assert tail[0].split()[:5] == ["robot/task", "learner", "swept", "headline", "IQM"]
    assert [line.split()[:2] for line in tail[1:3]] == [["cartpole/stay_up", "n1try"], ["cartpole/stay_up", "qlearn"]]
    assert all("train_length_last100" in line and "] " in line for line in tail[1:3])
    assert tail[-1] == f"wrote {sweep / 'comparison.csv'}, comparison.md and comparison.png"
    first = (sweep / "comparison.csv").read_text()
    rows = list(csv.DictReader(first.splitlines()))
    assert [(r["learner"], r["seeds"], r["finished"]) for r in rows] == [("n1try", "3", "3"), ("qlearn", "3", "3")]
    assert all(float(r["ci_low"]) <= float(r["iqm"]) <= float(r["ci_high"]) for r in rows)
    _, out = table(sweep, capsys)
    assert (sweep / "comparison.csv").read_text() == first and "did not finish" not in out


def test_comparing_a_finished_sweep_loads_neither_torch_nor_mujoco(tmp_path):
    """compare.py only reads CSV and JSON: its answer comes without importing torch,
    tensordict, TorchRL or MuJoCo (about 1.3 s of CPU here instead of 3.7 s;
    bench/answers.py measures it)."""
    sweep = tmp_path / "sweep"
    write_multirun(sweep, ["seed=0,1"])
    for seed in (0, 1):
        write_job(sweep, seed, [f"seed={seed}"])
    code = ("import runpy, sys; sys.argv = ['compare.py', sys.argv[1]]\n"
            "try:\n    runpy.run_path('compare.py', run_name='__main__')\nexcept SystemExit as e:\n"
            "    assert not e.code, e.code\n"
            "loaded = sorted({'torch', 'tensordict', 'torchrl', 'mujoco', 'dm_control'} & set(sys.modules))\n"
            "assert not loaded, loaded\n"
            "assert (__import__('pathlib').Path(sys.argv[1]) / 'comparison.csv').is_file()")
    proc = subprocess.run([sys.executable, "-c", code, str(sweep)], cwd=ROOT, capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
