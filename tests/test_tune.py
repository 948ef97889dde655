"""Tuning with Optuna through Hydra (hydra/sweeper=optuna): search spaces, their checks,
the trial jobs' reports and pruning, a study shared by two workers, the tuned file."""

import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import optuna
import pytest
from omegaconf import OmegaConf

from inprocess import run_train
from runs.settings import check_run_config
from sweeps.tuning import (TrialLink, batch_size, check_space, current_trial, load_space, open_storage, parse_space,
                             tuned_text)
from params import ConfigError
from tasks.catalog import compose, conf_dir

ROOT = Path(__file__).resolve().parents[1]
LEARNERS = sorted(p.stem for p in (conf_dir() / "learner").glob("*.yaml"))


def cli(*args: str, cwd: Path = ROOT, timeout: int = 600) -> subprocess.CompletedProcess:
    if cwd == ROOT:  # in this process (tests/inprocess.py); a project copy needs its own
        return run_train(*args)
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    return subprocess.run([sys.executable, "train.py", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout, env=env)


# -- search spaces ---------------------------------------------------------------
def test_sweep_grammar_becomes_optuna_distributions():
    space = parse_space({"learner.lr": "tag(log, interval(1e-4, 1e-2))", "learner.gamma": "interval(0.9, 0.99)",
                         "learner.updates": "int(interval(1, 16))", "learner.hidden": "choice([64,64],[128,128])",
                         "num_envs": "range(4, 17, 4)"}, "test")
    lr = space["learner.lr"].distribution
    assert isinstance(lr, optuna.distributions.FloatDistribution) and lr.log and (lr.low, lr.high) == (1e-4, 1e-2)
    assert isinstance(space["learner.gamma"].distribution, optuna.distributions.FloatDistribution)
    assert isinstance(space["learner.updates"].distribution, optuna.distributions.IntDistribution)
    hidden = space["learner.hidden"]
    assert hidden.distribution.choices == ("[64,64]", "[128,128]")
    assert hidden.value("[128,128]") == [128, 128]
    envs = space["num_envs"].distribution
    assert (envs.low, envs.high, envs.step) == (4, 16, 4)
    assert space["learner.lr"].value(0.00123456789) == 0.001235  # 4 significant digits, as the job gets it


@pytest.mark.parametrize("expr, words", [
    ("interval(0.5, 0.1)", "empty range"),
    ("interval(0.1, 0.1)", "empty range"),
    ("range(5, 5)", "empty range"),
    ("tag(log, interval(0, 1))", "log scale"),
    ("0.5", "one value, not a range"),
    ("interval(0.1,", "does not parse"),
])
def test_a_bad_range_is_one_line(expr, words):
    with pytest.raises(ConfigError) as err:
        parse_space({"learner.lr": expr}, "conf/search/x.yaml")
    message = str(err.value)
    assert words in message and "learner.lr" in message and "\n" not in message


def test_an_unknown_setting_in_a_space_is_named_with_the_closest_one():
    base = ["learner=dqn"]
    with pytest.raises(ConfigError, match=r"learner\.lrr is not a setting of this run; did you mean learner\.lr\?"):
        check_space(parse_space({"learner.lrr": "interval(0.1, 0.2)"}, "s.yaml"), compose(overrides=base), "s.yaml",
                    check_run_config)


def test_a_range_the_run_refuses_is_refused_before_any_trial():
    base = ["learner=dqn"]
    with pytest.raises(ConfigError, match=r"learner\.lr can be -0\.1, which the run refuses: learner\.lr must be"):
        check_space(parse_space({"learner.lr": "interval(-0.1, 0.2)"}, "s.yaml"), compose(overrides=base), "s.yaml",
                    check_run_config)


def test_every_learner_has_a_search_space():
    assert {p.stem for p in (conf_dir() / "search").glob("*.yaml")} >= set(LEARNERS)


@pytest.mark.parametrize("name", sorted(p.stem for p in (conf_dir() / "search").glob("*.yaml")))
def test_every_search_space_fits_its_learner(name):
    """conf/search/<learner>, <robot>_<learner> or <robot>_<task>_<learner> (a task's space)."""
    from tasks.catalog import names, robot_names

    robot, _, learner = name.rpartition("_") if name not in LEARNERS else ("", "", name)
    task = None
    if robot and robot not in robot_names():  # <robot>_<task>
        robot, task = next((r, robot[len(r) + 1:]) for r in robot_names() if robot.startswith(f"{r}_"))
        assert task in names("task"), f"conf/search/{name}.yaml names no task"
    base = [f"robot={robot or 'cartpole'}", *([f"task={task}"] if task else []), f"learner={learner}",
            "max_env_steps=1000", "stop_when_solved=false"]
    space = load_space(conf_dir() / "search" / f"{name}.yaml")
    check_space(space, compose(overrides=base), name, check_run_config)


@pytest.mark.parametrize("url", ["postgresql://nobody@127.0.0.1:1/none", "not a url", "sqlite:////proc/x/y.db",
                                 "journal:///proc/x/y.log"])
def test_a_storage_that_cannot_be_opened_is_one_line(url):
    with pytest.raises(ConfigError, match=r"hydra\.sweeper\.storage=.* cannot be opened: ") as err:
        open_storage(url)
    assert "\n" not in str(err.value)


# -- the trial jobs' link to the study ---------------------------------------------
def test_a_trial_below_the_median_is_pruned_and_reports_only_from_its_first_seed(tmp_path):
    url = f"sqlite:///{tmp_path / 's.db'}"
    pruner = {"n_startup_trials": 1, "n_warmup_steps": 0}
    study = optuna.create_study(study_name="s", storage=url, direction="maximize",
                                pruner=optuna.pruners.MedianPruner(**pruner))
    good = study.ask()
    for step in (10, 20):
        good.report(100.0, step)
    study.tell(good, 100.0)
    poor = study.ask()
    lead = TrialLink(url, "s", poor.number, lead=True, pruner=pruner, every=10, run_dir=tmp_path / "a")
    other = TrialLink(url, "s", poor.number, lead=False, pruner=pruner, every=10, run_dir=tmp_path / "b")
    assert other(10, 1.0) is False  # reports nothing, and nothing is reported yet
    assert lead(10, 1.0) is True
    assert other(20, 500.0) is True  # the first seed's values decide for every seed
    frozen = study.trials[poor.number]
    assert frozen.intermediate_values == {10: 1.0}
    assert frozen.user_attrs["run_dir"] == str(tmp_path / "a")
    study.tell(poor, state=optuna.trial.TrialState.PRUNED)
    assert lead(20, 1.0) is False  # a trial already told (a resumed job) is left alone


def batched_study(tmp_path: Path, learner: str, space: str, *extra: str) -> tuple[subprocess.CompletedProcess, str]:
    """A small cart-pole study of ``learner`` over the search ``space`` (a file's text), two
    trials a batch x seeds 0 and 1, no pruner, its storage an SQLite file in ``tmp_path``
    (returned); ``extra`` overrides after the others."""
    (tmp_path / "space.yaml").write_text(space)
    url = f"sqlite:///{tmp_path / 's.db'}"
    proc = cli("-m", "hydra/sweeper=optuna", "robot=cartpole", f"learner={learner}", "num_envs=2", "eval_episodes=2",
               "hydra.sweeper.trials_per_batch=2", "hydra.sweeper.seeds=[0,1]", "hydra.sweeper.budget_steps=1000",
               "hydra.sweeper.pruner=null", f"hydra.sweeper.search={tmp_path / 'space.yaml'}",
               f"hydra.sweeper.storage={url}", f"hydra.sweep.dir={tmp_path / 'sweep'}", *extra)
    return proc, url


def test_trials_that_differ_in_member_wise_settings_train_as_one_batch(tmp_path):
    """trials_per_batch=2 with a space of member-wise settings only: the two trials x two seeds
    train as the four members of one batch, each job reporting to its study from there."""
    proc, url = batched_study(tmp_path, "dqn", "learner.lr: tag(log, interval(0.0001, 0.01))\n"
                              "learner.gamma: interval(0.9, 0.999)\n",
                              "hydra.sweeper.n_trials=2", "hydra.sweeper.report_every=100")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    out = proc.stdout + proc.stderr
    assert "Training 4 runs together: trial 0 seed 0, trial 0 seed 1, trial 1 seed 0, trial 1 seed 1" in out, out[-3000:]
    study = optuna.load_study(study_name="cartpole-stay_up-dqn", storage=url)
    trials = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    assert len(trials) == 2 and all(t.intermediate_values for t in trials)
    assert trials[0].params != trials[1].params


def test_with_refill_freed_members_take_the_studys_next_trials_in_the_same_batch(tmp_path):
    """refill=true: a study of 5 trials, 2 at a time, trains in one batch of 4 members; as a
    trial's jobs end, the next trial is asked and takes its members; every trial is told."""
    proc, url = batched_study(tmp_path, "qlearn", "learner.alpha: interval(0.05, 0.5)\n"
                              "learner.gamma: interval(0.9, 0.999)\n", "hydra.sweeper.n_trials=5",
                              "hydra.sweeper.report_every=250", "hydra.sweeper.refill=true",
                              "hydra.sweeper.startup_trials=2", "hydra.sweeper.sampler_seed=0")
    out = proc.stdout + proc.stderr
    assert proc.returncode == 0, out[-3000:]
    assert out.count("Training 4 runs together, freed members taking the next ones") == 1, out[-3000:]
    study = optuna.load_study(study_name="cartpole-stay_up-qlearn", storage=url)
    assert [t.state for t in study.trials] == [optuna.trial.TrialState.COMPLETE] * 5
    assert len({tuple(sorted(t.params.items())) for t in study.trials}) == 5
    for trial in study.trials:
        assert f"trial {trial.number}: success_and_speed" in out
    folders = [p for p in (tmp_path / "sweep").iterdir() if (p / "summary.json").is_file()]
    assert len(folders) == 10


@pytest.mark.parametrize("per_batch, startup, sizes", [
    (12, 5, [5, 7]),  # the random trials together, then the rest asked from what they found
    (4, 5, [4, 1, 4, 3]),  # never a guided trial asked before the fifth random one finished
    (1, 5, [1] * 12),  # one at a time as before
    (12, 0, [12]),  # no random start: all at once
    (3, 20, [3, 3, 3, 3]),  # a study shorter than its random start
])
def test_a_batched_study_asks_the_samplers_random_trials_before_the_ones_it_guides(per_batch, startup, sizes):
    """Batches of a 12-trial study: while fewer than ``startup`` trials have finished, only
    the random ones still due are asked (each batch finishes before the next is asked)."""
    asked, finished = [], 0
    while finished < 12:
        asked.append(batch_size(per_batch, 12 - finished, finished, startup))
        finished += asked[-1]
    assert asked == sizes


def tuning(tmp_path: Path, study: str, folder: str, kill: str | None = None, *extra: str,
           cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """A small qlearn study on the cart-pole (one trial, two seeds), killed where ``kill`` says
    (tests/kill_at.py); ``extra`` overrides after the others."""
    args = ["-m", "hydra/sweeper=optuna", "robot=cartpole", "learner=qlearn", "num_envs=2", "eval_episodes=2",
            "checkpoint_every=10", "hydra.sweeper.n_trials=1", "hydra.sweeper.seeds=[0,1]",
            "hydra.sweeper.budget_steps=1500", "hydra.sweeper.pruner=null", "hydra.sweeper.sampler_seed=0",
            f"hydra.sweeper.storage=sqlite:///{tmp_path / 's.db'}", f"hydra.sweeper.study={study}",
            f"hydra.sweep.dir={tmp_path / folder}", *extra]
    if not kill and cwd == ROOT:
        return run_train(*args)
    script = ["tests/kill_at.py", kill] if kill else ["train.py"]
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    return subprocess.run([sys.executable, *script, *args], cwd=cwd, capture_output=True, text=True,
                          timeout=600, env=env)


def test_a_killed_study_is_taken_over_by_the_next_sweep_and_ends_as_never_stopped(tmp_path):
    """A tuning sweep killed (SIGKILL) while its first trial trains leaves the trial running
    in the study; the same command again resumes that trial's jobs from their checkpoints,
    tells the study the value an unstopped sweep finds, and goes on: no trial lost, none
    counted twice, none left running."""
    killed = tuning(tmp_path, "s", "first", kill="checkpoint:4")
    assert killed.returncode == -9, killed.stdout[-2000:] + killed.stderr[-2000:]
    study = optuna.load_study(study_name="s", storage=f"sqlite:///{tmp_path / 's.db'}")
    assert [t.state for t in study.trials] == [optuna.trial.TrialState.RUNNING]
    again = tuning(tmp_path, "s", "second")
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    assert "trial 0 was left running by a sweep that stopped: resuming its jobs" in again.stdout
    plain = tuning(tmp_path, "plain", "plain")
    assert plain.returncode == 0, plain.stderr[-2000:]
    study = optuna.load_study(study_name="s", storage=f"sqlite:///{tmp_path / 's.db'}")
    unstopped = optuna.load_study(study_name="plain", storage=f"sqlite:///{tmp_path / 's.db'}")
    assert [t.state for t in study.trials] == [optuna.trial.TrialState.COMPLETE] * 2
    assert study.trials[0].value == unstopped.trials[0].value  # as if never stopped
    assert study.trials[0].params == unstopped.trials[0].params


def test_a_current_configuration_outside_the_space_is_scored_and_kept_unless_beaten(tmp_path):
    """The cart-pole's tuned qlearn (bins per entry) lies outside qlearn's space: the study
    scores it once on its seeds and budget, and its tuned file replaces it only if the best
    trial beats it (the message says which)."""
    proc = tuning(tmp_path, "s", "sweep")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "current configuration (outside the space): success_and_speed " in proc.stdout
    # valued beside the first round's trial, one batch (not a batch of its own after the study)
    assert "Training 4 runs together: trial 0 seed 0, trial 0 seed 1, seed 0, seed 1" in proc.stdout, proc.stdout
    study = optuna.load_study(study_name="s", storage=f"sqlite:///{tmp_path / 's.db'}")
    current, best = study.user_attrs["current_value"], study.best_value
    assert study.user_attrs["tuned_kept"] == (current >= best)
    assert ("stays as it is" in proc.stdout) == (current >= best)
    written = (tmp_path / "sweep" / "tuned_cartpole_qlearn.yaml").read_text()  # a replacement says what it beat
    replacing = f"# replacing the settings the study began with: success_and_speed {current:.4g} on the same seeds"
    assert (replacing in written) == (current < best), written
    again = tuning(tmp_path, "s", "again")  # scored once per study
    assert again.returncode == 0 and "current configuration (outside" not in again.stdout


def test_the_learners_own_values_are_valued_once_beside_the_first_round(tmp_path):
    """``value_defaults``: the learner's own values of the searched settings (qlearn's
    defaults, which the cart-pole's tuned file changes) are valued on the study's seeds and
    budget in the first round's batch, once per study; the file takes them only where they
    beat every trial and the configuration the study began with."""
    proc = tuning(tmp_path, "s", "sweep", None, "hydra.sweeper.value_defaults=true")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    # trial 0's two seeds, the current configuration's (outside the space), the learner's own
    assert "Training 6 runs together: trial 0 seed 0, trial 0 seed 1, seed 0, seed 1, seed 0, seed 1" in proc.stdout
    assert "the learner's own values of the searched settings: success_and_speed " in proc.stdout, proc.stdout
    jobs = sorted((tmp_path / "sweep").glob("[0-9]*_cartpole_qlearn_seed*"), key=lambda d: int(d.name.split("_")[0]))
    assert [OmegaConf.load(d / "config.yaml").learner.alpha for d in jobs[4:]] == [0.1, 0.1]  # qlearn.yaml's
    study = optuna.load_study(study_name="s", storage=f"sqlite:///{tmp_path / 's.db'}")
    mine, current, best = study.user_attrs["defaults_value"], study.user_attrs["current_value"], study.best_value
    written = (tmp_path / "sweep" / "tuned_cartpole_qlearn.yaml").read_text()
    assert ("# written instead: the learner's own values" in written) == (mine > max(best, current)), written
    again = tuning(tmp_path, "s", "again", None, "hydra.sweeper.value_defaults=true")
    assert again.returncode == 0 and "the learner's own values of the searched settings:" not in again.stdout


def test_the_learners_own_values_above_every_trial_are_the_tuned_file(project_copy, tmp_path):
    """Where the learner's own values beat every trial (qlearn.yaml's, valued above any
    success_and_speed: set in the study, which takes them as valued), the tuned file holds
    them, and says so;
    a later sweep that tells no trial leaves that file as it is, byte for byte."""
    own = OmegaConf.load(ROOT / "conf" / "learner" / "qlearn.yaml")
    space = load_space(conf_dir() / "search" / "qlearn.yaml")
    study = optuna.create_study(study_name="d", storage=f"sqlite:///{tmp_path / 's.db'}", direction="maximize")
    study.set_user_attr("defaults", {key: OmegaConf.select(own, key.removeprefix("learner.")) for key in space})
    study.set_user_attr("defaults_value", 5.0)
    proc = tuning(tmp_path, "d", "sweep", None, "hydra.sweeper.value_defaults=true", "hydra.sweeper.write_tuned=true",
                  cwd=project_copy)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "the learner's own values of the searched settings (success_and_speed 5) beat every trial" in proc.stdout
    path = project_copy / "conf" / "tuned" / "cartpole_qlearn.yaml"
    text = path.read_text()
    assert "# written instead: the learner's own values of the searched settings, success_and_speed 5 " in text
    tuned = OmegaConf.create(text)
    for key in space:
        assert OmegaConf.select(tuned, key) == OmegaConf.select(own, key.removeprefix("learner.")), key
    again = tuning(tmp_path, "d", "again", None, "hydra.sweeper.value_defaults=true", "hydra.sweeper.write_tuned=true",
                   "hydra.sweeper.n_trials=0", cwd=project_copy)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    assert "this sweep told no trial and cartpole_qlearn.yaml is already the study's: it stays as it is" in again.stdout
    assert path.read_text() == text


def test_a_sweep_that_tells_no_trial_leaves_the_studys_file_and_its_later_edits_alone(project_copy, tmp_path):
    """A finished study's file edited since (a setting and a note added by hand): a sweep of
    no trials that values the learner's own values below the best trial (set in the study:
    valued already) leaves it as it is, byte for byte."""
    first = tuning(tmp_path, "e", "sweep", None, "hydra.sweeper.write_tuned=true", cwd=project_copy)
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    path = project_copy / "conf" / "tuned" / "cartpole_qlearn.yaml"
    edited = path.read_text() + "video_steps: 400  # added after the study, with this note\n"
    path.write_text(edited)
    study = optuna.load_study(study_name="e", storage=f"sqlite:///{tmp_path / 's.db'}")
    study.set_user_attr("defaults", {"learner.alpha": 0.1})
    study.set_user_attr("defaults_value", -1.0)
    again = tuning(tmp_path, "e", "again", None, "hydra.sweeper.value_defaults=true", "hydra.sweeper.write_tuned=true",
                   "hydra.sweeper.n_trials=0", cwd=project_copy)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    assert "this sweep told no trial and cartpole_qlearn.yaml is already the study's: it stays as it is" in again.stdout
    assert path.read_text() == edited


def test_a_replacement_file_says_what_it_replaced(tmp_path):
    """A study whose starting settings were valued below every trial writes a file that
    replaces them, and its header says with what value (the line the benchmark's tuned files
    carry)."""
    study = optuna.create_study(study_name="r", storage=f"sqlite:///{tmp_path / 's.db'}", direction="maximize")
    study.set_user_attr("current_value", -1.0)  # valued already: below any trial's success_and_speed
    proc = tuning(tmp_path, "r", "sweep")
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    assert "current configuration (outside" not in proc.stdout and "stays as it is" not in proc.stdout
    written = (tmp_path / "sweep" / "tuned_cartpole_qlearn.yaml").read_text()
    assert "# replacing the settings the study began with: success_and_speed -1 on the same seeds and budget\n" \
        in written, written


def test_a_trial_killed_before_its_jobs_could_continue_is_asked_again(tmp_path):
    """Killed after the first checkpoint of one seed (the other seed has none): the next sweep
    tells the stopped trial failed, runs its values again, then its own new trial."""
    killed = tuning(tmp_path, "s", "first", kill="checkpoint:1")
    assert killed.returncode == -9, killed.stderr[-2000:]
    again = tuning(tmp_path, "s", "second")
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    assert "trial 0 was left running by a sweep that stopped before all its jobs could continue" in again.stdout
    trials = optuna.load_study(study_name="s", storage=f"sqlite:///{tmp_path / 's.db'}").trials
    complete = optuna.trial.TrialState.COMPLETE  # the retry, then the sweep's own n_trials=1
    assert [t.state for t in trials] == [optuna.trial.TrialState.FAIL, complete, complete]
    assert trials[1].params == trials[0].params and trials[1].user_attrs["retry_of"] == 0


def test_every_seed_reports_and_the_mean_is_the_trials_value_and_a_prune_stops_its_siblings(tmp_path):
    """A trial asked with its seeds: each seed's job reports its value at a step; once both
    have, their mean is the trial's intermediate value there. Pruned by one seed's report,
    the trial stops the other seed's run in this process at its next step (``pruned``)."""
    url = f"sqlite:///{tmp_path / 's.db'}"
    pruner = {"n_startup_trials": 1, "n_warmup_steps": 0}
    study = optuna.create_study(study_name="s", storage=url, direction="maximize",
                                pruner=optuna.pruners.MedianPruner(**pruner))
    good = study.ask()
    good.report(100.0, 10)
    study.tell(good, 100.0)
    poor = study.ask()
    poor.set_user_attr("seeds", [0, 1])
    links = [TrialLink(url, "s", poor.number, lead=seed == 0, pruner=pruner, every=10,
                       run_dir=tmp_path / f"j{seed}", seed=seed) for seed in (0, 1)]
    assert links[1](10, 3.0) is False and not links[0].pruned  # one seed in: no trial value yet
    assert study.trials[poor.number].intermediate_values == {}
    assert links[0](10, 1.0) is True  # both in: mean 2.0, below the median 100
    assert study.trials[poor.number].intermediate_values == {10: 2.0}
    assert links[1].pruned and study.trials[poor.number].user_attrs["run_dir_seed1"] == str(tmp_path / "j1")


def test_a_seed_that_stopped_solved_counts_its_value_at_the_later_steps_of_its_trial(tmp_path):
    """A solved seed stops reporting: the steps its sibling reports after that still get the
    trial's intermediate value, the solved seed counting with the value it stopped at."""
    url = f"sqlite:///{tmp_path / 's.db'}"
    study = optuna.create_study(study_name="s", storage=url, direction="maximize")
    trial = study.ask()
    trial.set_user_attr("seeds", [0, 1])
    links = [TrialLink(url, "s", trial.number, lead=seed == 0, pruner=None, every=10,
                       run_dir=tmp_path / f"j{seed}", seed=seed) for seed in (0, 1)]
    links[0](10, 4.0), links[1](10, 2.0)
    links[1](20, 3.0)  # reported before seed 0 says it stopped solved at 15: completed then
    links[0].solved(15, 250.0)
    links[1](30, 5.0)
    assert study.trials[trial.number].intermediate_values == {10: 3.0, 20: 126.5, 30: 127.5}


@pytest.mark.parametrize("summary, value", [
    ({"greedy": 300.0, "solved": True, "steps_to_solve": 2500}, 1.75),   # success, solved at a quarter
    ({"greedy": 300.0, "solved": False, "steps_to_solve": None}, 1.0),  # success the verdict never saw
    ({"greedy": 125.0, "solved": True, "steps_to_solve": 2500}, 0.5),   # solved, but not at the end
    ({"greedy": None, "headline_value": 50.0, "solved": False, "steps_to_solve": None}, 0.2),  # no greedy
    ({"greedy": -25.0, "solved": False, "steps_to_solve": None}, -0.1),
])
def test_success_and_speed_orders_runs_as_the_benchmark(summary, value):
    from runs.summary import success_and_speed, succeeded

    summary = {"status": "ok", "threshold": 250.0, **summary}
    assert success_and_speed(summary, 10_000) == pytest.approx(value)
    assert succeeded(summary) == (value >= 1)
    assert success_and_speed({**summary, "status": "failed"}, 10_000) is None


def test_a_kept_file_keeps_its_notes_and_settings_under_the_studys_header():
    from sweeps.tuning import kept_text

    hand = "# @package _global_\n# why: measured\nlearner:\n  alpha: 0.2\n"
    once = kept_text(hand, ["Kept by Optuna (t1): study s", "best trial 0: 1.9"])
    assert once.splitlines()[:3] == ["# @package _global_", "# Kept by Optuna (t1): study s", "# best trial 0: 1.9"]
    assert once.endswith("# why: measured\nlearner:\n  alpha: 0.2\n")
    again = kept_text(once, ["Kept by Optuna (t2): study s"])  # a later study's header replaces the earlier one
    assert again.count("Kept by Optuna") == 1 and "(t2)" in again and again.endswith(hand.split("\n", 1)[1])
    assert OmegaConf.create(again) == OmegaConf.create(hand)


def test_the_tuned_file_keeps_the_previous_ones_other_settings():
    text = tuned_text({"learner.alpha": 0.3, "learner.number_splits": 7},
                      {"num_envs": 8, "learner": {"alpha": 0.1, "gamma": 0.99}}, ["study x", "best 1.2"])
    assert text.startswith("# @package _global_\n# study x\n# best 1.2\n")
    conf = OmegaConf.create(text)
    assert conf.num_envs == 8 and conf.learner.alpha == 0.3 and conf.learner.gamma == 0.99
    assert conf.learner.number_splits == 7


# -- the budget a trial gets ----------------------------------------------------------
def test_max_env_steps_ends_training_and_stop_when_solved_false_trains_past_solved(tmp_path):
    base = ["quiet=true", "eval_episodes=0", "num_envs=4", "task.win.threshold=5", "task.win.min_episodes=1"]
    stop = cli(f"hydra.run.dir={tmp_path / 'a'}", *base, "max_episodes=40")
    past = cli(f"hydra.run.dir={tmp_path / 'b'}", *base, "max_episodes=40", "stop_when_solved=false")
    steps = cli(f"hydra.run.dir={tmp_path / 'c'}", *base, "max_episodes=100000", "max_env_steps=300",
                "stop_when_solved=false")
    for proc in (stop, past, steps):
        assert proc.returncode == 0, proc.stderr[-2000:]
    first = OmegaConf.load(tmp_path / "a" / "summary.json")
    assert first.solved and first.episodes == first.solved_at
    later = OmegaConf.load(tmp_path / "b" / "summary.json")
    assert later.solved and later.solved_at == first.solved_at and later.episodes == 40
    capped = OmegaConf.load(tmp_path / "c" / "summary.json")
    assert 300 <= capped.env_steps < 304
    assert "or 300 env steps, training past 'solved'" in steps.stdout


# -- the sweeper end to end -------------------------------------------------------------
@pytest.fixture
def project_copy(tmp_path):
    """The project in a scratch folder: the study writes conf/tuned/ there, not here."""
    copy = tmp_path / "project"
    copy.mkdir()
    for name in ("train.py", "robots", "tasks", "learners", "runs", "sweeps", "params", "conf", "hydra_plugins"):
        src = ROOT / name
        if src.is_dir():
            shutil.copytree(src, copy / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy(src, copy / name)
    return copy


@pytest.mark.slow  # the benchmark's grid (run by hand, 39 s); its studies are the sweeper's, tested here
def test_the_grid_command_tunes_each_pair_once_and_resumes_to_its_count(project_copy):
    """``python -m bench.benchmark --tune``: a pair's study asks its trials, writes the pair's
    tuned file with the study in its header and keeps its record in bench/studies/; the
    same command again finds the study complete and runs nothing."""
    shutil.copytree(ROOT / "bench", project_copy / "bench", ignore=shutil.ignore_patterns("__pycache__", "studies"))
    plan = OmegaConf.load(project_copy / "bench" / "benchmark.yaml")
    plan.tasks.cartpole.budget_steps = 1000  # one episode, the least a study takes
    plan.tuning = {"trials": 2, "seeds": [0], "pruner": "successive_halving", "first_rung": 4}
    OmegaConf.save(plan, project_copy / "bench" / "benchmark.yaml")
    # A hand pick inside qlearn's space: the study's trial 0, so the best trial is never worse
    (project_copy / "conf" / "tuned" / "cartpole_qlearn.yaml").write_text("# @package _global_\nnum_envs: 8\n")
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}

    def grid() -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "bench.benchmark", "--tune", "--tasks", "cartpole",
                               "--learners", "qlearn"], cwd=project_copy, capture_output=True, text=True,
                              timeout=600, env=env)

    first = grid()
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    record = project_copy / "bench" / "studies" / "cartpole_qlearn.log"
    study = optuna.load_study(study_name="bench-cartpole-qlearn", storage=open_storage(f"journal://{record}"))
    assert len(study.trials) == 2 and all(t.state.is_finished() for t in study.trials)
    grid_runs = (project_copy / "bench" / "studies" / "grid_runs.csv").read_text().splitlines()
    assert len(grid_runs) == 2 and grid_runs[1].split(",")[2:5] == ["1", "1", "cartpole_qlearn"], grid_runs
    tuned = (project_copy / "conf" / "tuned" / "cartpole_qlearn.yaml").read_text()
    again = grid()
    assert again.returncode == 0 and "cartpole_qlearn: study complete (2 trials)" in again.stdout, again.stdout
    assert "study bench-cartpole-qlearn in journal://bench/studies/cartpole_qlearn.log" in tuned
    (project_copy / "conf" / "tuned" / "cartpole_qlearn.yaml").write_text("# @package _global_\nnum_envs: 4\n")
    rewrite = grid()  # a finished study whose file is not its own: a sweep of no new trials writes it
    assert rewrite.returncode == 0 and "0 to ask" in rewrite.stdout, rewrite.stdout[-2000:] + rewrite.stderr[-2000:]
    rewritten = (project_copy / "conf" / "tuned" / "cartpole_qlearn.yaml").read_text()

    def settings(text: str) -> list[str]:
        return [line for line in text.splitlines() if not line.startswith("#")]

    assert settings(rewritten) == settings(tuned) and "study bench-cartpole-qlearn in" in rewritten
    plan.tuning.value_defaults = True  # a finished study values the learner's own values with a sweep of no trials
    OmegaConf.save(plan, project_copy / "bench" / "benchmark.yaml")
    valued = grid()
    assert valued.returncode == 0 and "0 to ask" in valued.stdout, valued.stdout[-2000:] + valued.stderr[-2000:]
    study = optuna.load_study(study_name="bench-cartpole-qlearn", storage=open_storage(f"journal://{record}"))
    assert "defaults_value" in study.user_attrs and len(study.trials) == 2
    after = (project_copy / "conf" / "tuned" / "cartpole_qlearn.yaml").read_text()
    assert after == rewritten or "# written instead: the learner's own values" in after, after
    assert "cartpole_qlearn: study complete (2 trials)" in grid().stdout


@pytest.mark.filterwarnings("ignore::optuna.exceptions.ExperimentalWarning")  # set_metric_names
def test_a_study_of_an_earlier_objective_is_not_asked_to_value_the_learners_own_values(tmp_path):
    """The grid's maze studies of greedy laps cannot be continued on success_and_speed: they
    count as done for ``value_defaults``; a study of the sweeper's objective counts once it has
    valued them."""
    from bench.tune_grid import ROOT as GRID_ROOT, defaults_valued, journal_study

    record = tmp_path / "s.log"
    for name, metric in (("laps", "greedy_laps"), ("now", "success_and_speed")):
        study = optuna.create_study(study_name=name, storage=open_storage(f"journal://{record}"), direction="maximize")
        study.set_metric_names([metric])
    relative = Path(os.path.relpath(record, GRID_ROOT))
    laps, now = (journal_study(name, relative) for name in ("laps", "now"))
    assert defaults_valued(laps) and not defaults_valued(now)
    study.set_user_attr("defaults_value", None)  # found it had begun with them
    assert defaults_valued(journal_study("now", relative)) and journal_study("gone", relative) is None
    assert not defaults_valued(None)


@pytest.mark.slow  # 27 s; two sweeps sharing a study run in CI (test_two_sweeps_at_once_share_one_study...)
def test_two_workers_share_one_study_and_the_next_run_uses_its_tuned_file(project_copy, tmp_path):
    url = f"sqlite:///{tmp_path / 'studies.db'}"
    (project_copy / "conf" / "tuned" / "cartpole_n1try.yaml").unlink(missing_ok=True)  # a pair without a file
    proc = cli("-m", "hydra/sweeper=optuna", "hydra/launcher=joblib", "hydra.launcher.n_jobs=2",
               "robot=cartpole", "learner=n1try", "eval_episodes=2", "num_envs=4",
               "hydra.sweeper.n_trials=2", "hydra.sweeper.trials_per_batch=2", "hydra.sweeper.seeds=[3]",
               "hydra.sweeper.budget_steps=1000", "hydra.sweeper.report_every=100", "hydra.sweeper.write_tuned=true",
               f"hydra.sweeper.storage={url}", f"hydra.sweep.dir={tmp_path / 'sweep'}", cwd=project_copy)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    study = optuna.load_study(study_name="cartpole-stay_up-n1try", storage=url)
    trials = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    assert len(trials) == 2
    assert all(t.intermediate_values for t in trials)  # reported from inside the jobs
    assert len({t.user_attrs["worker"] for t in trials}) == 2  # two processes, one study
    # The objective by its name: the study's metric, the console's lines (each seed's value
    # with its measure at the end).
    assert study.metric_names == ["success_and_speed"]
    assert "objective: success_and_speed (mean over the seeds)" in proc.stdout
    assert len(re.findall(r"^trial \d+: success_and_speed \S+ \(seeds \S+ \(length ", proc.stdout, re.M)) == 2
    assert re.search(r"^best trial \d+: success_and_speed ", proc.stdout, re.M)
    tuned = project_copy / "conf" / "tuned" / "cartpole_n1try.yaml"
    assert tuned.read_text().startswith("# @package _global_\n# Tuned by Optuna")
    best = OmegaConf.create(tuned.read_text())
    assert "best trial" in proc.stdout and f"wrote {tuned}" in proc.stdout
    assert "trial=0" in proc.stdout and "cannot be listed" not in proc.stdout + proc.stderr  # the comparison

    run = cli("robot=cartpole", "learner=n1try", "max_episodes=2", "eval_episodes=0", "quiet=true",
              f"hydra.run.dir={tmp_path / 'next'}", cwd=project_copy)
    assert run.returncode == 0, run.stderr[-2000:]
    assert "tuned: conf/tuned/cartpole_n1try.yaml" in run.stdout
    used = OmegaConf.load(tmp_path / "next" / "config.yaml")
    assert used.learner.lr == best.learner.lr and used.learner.batch_size == best.learner.batch_size


@pytest.mark.parametrize("args, words", [
    (["seed=0,1"], "the study picks the values"),
    (["hydra.sweeper.storage=postgresql://nobody@127.0.0.1:1/none"], "cannot be opened"),
    (["hydra/launcher=basic", "hydra.sweeper.refill=true"], "refill=true trains a study's trials as members"),
])
def test_bad_tuning_input_is_one_line(tmp_path, args, words):
    storage = [] if any("storage" in a for a in args) else [f"hydra.sweeper.storage=sqlite:///{tmp_path / 's.db'}"]
    proc = cli("-m", "hydra/sweeper=optuna", "learner=qlearn", f"hydra.sweep.dir={tmp_path / 'sweep'}",
               *storage, *args)
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and words in lines[0], proc.stderr
    assert not (tmp_path / "sweep").exists()  # refused before any job: nothing written


@pytest.mark.parametrize("settings, args, words", [
    ({"n_trials": -1}, [], "hydra.sweeper.n_trials must be an integer >= 0 and <= 1e+06; got -1"),
    ({"n_trials": 1.5}, [], "hydra.sweeper.n_trials must be an integer >= 0 and <= 1e+06; got 1.5"),
    ({"budget_steps": 1e308}, [], "hydra.sweeper.budget_steps must be an integer >= 1 and <= 1e+12; got 1e+308"),
    ({"startup_trials": -1}, [], "hydra.sweeper.startup_trials must be an integer >= 0 and <= 1e+06; got -1"),
    ({"report_every": "5"}, [], "hydra.sweeper.report_every must be an integer >= 1"),
    ({"study": ""}, [], "hydra.sweeper.study must be a non-empty name; got ''"),
    ({"write_tuned": "maybe"}, [], "hydra.sweeper.write_tuned must be true or false; got 'maybe'"),
    ({"write_tuned": 1}, [], "hydra.sweeper.write_tuned must be true or false; got 1"),
    ({"start_from_current": "yes"}, [], "hydra.sweeper.start_from_current must be true or false"),
    ({"refill": "yes"}, [], "hydra.sweeper.refill must be true or false; got 'yes'"),
    ({"seeds": [1, 1]}, [], "hydra.sweeper.seeds must be distinct seeds"),
    ({"seeds": [-1]}, [], "hydra.sweeper.seeds must be distinct seeds, at least one, each an integer"),
    ({"sampler_seed": 2**40}, [], "hydra.sweeper.sampler_seed must be null or an integer"),
    ({"pruner": {"n_warmup_steps": -1}}, [], "hydra.sweeper.pruner.n_warmup_steps must be an integer >= 0"),
    ({"pruner": {"n_warmup_step": 1}}, [], "did you mean hydra.sweeper.pruner.n_warmup_steps?"),
    ({"pruner": 5}, [], "hydra.sweeper.pruner must be null, one of median, successive_halving, hyperband, or a"),
    ({"pruner": {"kind": "asha"}}, [], "hydra.sweeper.pruner.kind must be one of median, successive_halving"),
    ({"pruner": {"kind": "successive_halving", "n_warmup_steps": 5}}, [],
     "hydra.sweeper.pruner.n_warmup_steps is not a setting of the successive_halving pruner"),
    ({"pruner": {"kind": "hyperband", "reduction_factor": 1}}, [],
     "hydra.sweeper.pruner.reduction_factor must be an integer >= 2"),
    ({"pruner": {"kind": "hyperband", "min_resource": "soon"}}, [],
     "hydra.sweeper.pruner.min_resource must be an integer >= 1 and <= 1e+09 or auto"),
    ({}, ["learner.lr=0.1,0.2"], "the study picks the values"),
    ({}, ["trial=3"], "the sweeper sets trial for each job"),
    ({}, ["max_env_steps=10"], "hydra.sweeper.budget_steps"),
])
def test_the_sweepers_own_checks(settings, args, words):
    from sweeps.optuna_sweep import TuningSweep

    sweep = TuningSweep(**{"study": "s", "storage": "sqlite://", **settings})
    with pytest.raises(ConfigError, match=re.escape(words)):
        sweep._check_settings()
        sweep._fixed(args)


@pytest.mark.parametrize("settings, kind", [
    (None, optuna.pruners.NopPruner),
    ({"n_startup_trials": 2}, optuna.pruners.MedianPruner),
    ({"kind": "successive_halving", "min_resource": 50, "reduction_factor": 3}, optuna.pruners.SuccessiveHalvingPruner),
    ({"kind": "hyperband", "min_resource": "auto", "max_resource": 400}, optuna.pruners.HyperbandPruner),
])
def test_each_pruner_kind_is_optunas(settings, kind):
    from sweeps.tuning import make_pruner

    assert type(make_pruner(settings)) is kind


def test_checked_sweeper_settings_keep_their_types():
    from sweeps.optuna_sweep import TuningSweep

    sweep = TuningSweep(study="s", storage="sqlite://", n_trials=3.0, seeds=OmegaConf.create([2, 0]),
                        pruner=OmegaConf.create({"n_warmup_steps": 10}))
    sweep._check_settings()
    assert (sweep.n_trials, sweep.seeds, sweep.pruner) == (3, [2, 0], {"kind": "median", "n_warmup_steps": 10})
    assert type(sweep.n_trials) is int and sweep.write_tuned is False


def test_a_space_reaching_zero_bins_is_refused_before_any_trial():
    with pytest.raises(ConfigError, match=r"learner\.number_splits can be 0, which the run refuses"):
        check_space(parse_space({"learner.number_splits": "int(interval(0, 14))"}, "s.yaml"), compose(),
                    "s.yaml", check_run_config)


def test_a_missing_search_space_is_one_line():
    with pytest.raises(ConfigError, match="no search space MISSING.yaml"):
        load_space(Path("MISSING.yaml"))


def test_trial_outside_a_tuning_sweep_is_one_line(tmp_path):
    proc = cli("trial=3", "max_episodes=1", f"hydra.run.dir={tmp_path / 'run'}")
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "trial=3 is set by hydra/sweeper=optuna" in lines[0], proc.stderr


def test_the_learners_own_values_of_the_wall_dqns_space_include_a_null_one():
    """The learner's own values of the searched settings: the dqn's ``done_episode_reward`` is
    null (the task's reward kept), a value like any other; a key the config lacks gives none."""
    from sweeps.tuning import searched_values

    space = load_space(conf_dir() / "search" / "turtlebot_wall_dqn.yaml")
    own = searched_values(space, compose("turtlebot", "wall", "dqn", ["~tuned"]))
    assert own is not None and own["learner.done_episode_reward"] is None and own["learner.gamma"] == 0.99
    assert searched_values({**space, "learner.no_such_key": space["learner.gamma"]},
                           compose("turtlebot", "wall", "dqn", ["~tuned"])) is None


def test_a_new_study_starts_from_the_current_configuration_where_the_space_holds_it():
    space = load_space(conf_dir() / "search" / "dqn.yaml")
    defaults = current_trial(space, compose(overrides=["learner=dqn", "~tuned"]))
    assert defaults["num_envs"] == "1" and defaults["learner.lr"] == 0.001 and defaults["learner.hidden"] == "[64,64]"
    # Training per finished episode (the cart-pole's former hand pick) lies outside this space;
    # the file the cart-pole's study wrote (its best trial's values) inside it.
    per_episode = ["learner=dqn", "learner.train_every=episode", "learner.updates=8"]
    assert current_trial(space, compose(overrides=per_episode)) is None
    assert current_trial(space, compose(overrides=["learner=dqn"])) is not None
    cube = current_trial(load_space(conf_dir() / "search" / "cube_qlearn.yaml"),
                         compose(overrides=["robot=cube", "learner=qlearn"]))
    assert cube["learner.number_splits.wheel_speed"] == 24 and cube["learner.gamma"] == 0.9611  # its study's file


def test_a_trial_that_loses_its_study_warns_once_and_trains_on(tmp_path, capsys):
    import math

    from runs.run import Hooks, Run
    from tasks.base import Success

    url = f"sqlite:///{tmp_path / 's.db'}"
    study = optuna.create_study(study_name="s", storage=url, direction="maximize")
    link = TrialLink(url, "s", study.ask().number, lead=True, pruner=None, every=10, run_dir=tmp_path / "a")

    def lost(*args):
        raise RuntimeError("database is gone")

    link._storage.get_trial = lost
    run = Run(tmp_path / "run", 1, 1000, Success("length", "steps", "steps balanced", math.inf), quiet=True,
              hooks=Hooks(progress=link))
    for n in (10, 20, 30):
        run.episodes.n_episodes, run.episodes.env_steps = n, n  # reports go by env steps
        run.episodes.values.append(1.0)
        run.end_step(None)
    warned = [line for line in capsys.readouterr().out.splitlines() if "cannot reach the study" in line]
    assert len(warned) == 1 and "database is gone" in warned[0]
    assert run.pruned_at is None and not run.done


def test_a_pruned_run_makes_no_final_evaluation(tmp_path):
    """A run its tuning study pruned ends without a final greedy evaluation: the study asks
    no value of a pruned trial (ruippeixotog's 500-episode run phase in pruned jobs was over
    a third of the replayed cart-pole study's copy-steps)."""
    from runs.job import Job
    from runs.lifecycle import Seed, final_evaluation, owes_final_evaluation
    from runs.run import Hooks, Run
    from tasks.base import Success

    class Prunes:
        every, pruned = 10, False

        def __call__(self, env_steps: int, rolling: float) -> bool:
            return True

        def solved(self, env_steps: int, value: float) -> None:
            raise AssertionError("not solved")

    class Evaluated(Seed):
        def evaluate(self, episodes: int) -> dict:
            raise AssertionError("a pruned run was evaluated")

    run = Run(tmp_path / "run", 1, 1000, Success("length", "steps", "steps balanced", math.inf), quiet=True,
              hooks=Hooks(progress=Prunes()))
    session = Evaluated(Job(OmegaConf.create({"eval_episodes": 20}), tmp_path / "run", {}), 0, member=object())
    assert owes_final_evaluation(session, run)  # an unpruned run at its end would be evaluated
    run.episodes.n_episodes, run.episodes.env_steps = 10, 10
    run.episodes.values.append(1.0)
    run.end_step(None)
    assert run.pruned_at == 10 and run.done
    assert not owes_final_evaluation(session, run) and final_evaluation(session, run) is None


# -- a study shared by sweeps running at once: a database server, a journal file ------------
POSTGRES = os.environ.get("RL_TEST_POSTGRES_URL")  # .ci/run starts a throwaway server and sets it
NO_SERVER = "no PostgreSQL server: RL_TEST_POSTGRES_URL=postgresql://user:pw@127.0.0.1:port/db (.ci/postgres start)"


def need_postgres() -> str:
    """The server's URL; a skip on a machine without one, a failure where CI promised one."""
    if not POSTGRES:
        if os.environ.get("RL_TEST_REQUIRE_POSTGRES"):
            pytest.fail(f"RL_TEST_REQUIRE_POSTGRES is set but {NO_SERVER}")
        pytest.skip(NO_SERVER)
    return POSTGRES


def storage_url(kind: str, tmp_path: Path) -> str:
    if kind == "postgresql":
        return need_postgres()
    return f"journal://{tmp_path / 'shared' / 'studies.log'}"


def start_sweep(url: str, study: str, sweep: Path) -> subprocess.Popen:
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    args = ["-m", "hydra/sweeper=optuna", "robot=cartpole", "learner=qlearn", "num_envs=4", "eval_episodes=2",
            "hydra.sweeper.n_trials=2", "hydra.sweeper.seeds=[0]", "hydra.sweeper.budget_steps=1000",
            "hydra.sweeper.pruner=null", "hydra.sweeper.start_from_current=false", f"hydra.sweeper.storage={url}",
            f"hydra.sweeper.study={study}", f"hydra.sweep.dir={sweep}"]
    return subprocess.Popen([sys.executable, "train.py", *args], cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=env)


@pytest.mark.parametrize("kind", ["postgresql", "journal"])
def test_two_sweeps_at_once_share_one_study_each_trial_once_and_find_its_best(tmp_path, kind):
    """Two tuning sweeps (two processes, as on two machines) on one study in a PostgreSQL
    server or a journal file: four trials, each run by one job of one sweep and told once,
    both sweeps contributing; the sweep that ends last names the study's best trial."""
    import re
    import uuid

    url, study_name = storage_url(kind, tmp_path), f"shared-{uuid.uuid4().hex[:8]}"
    procs = [start_sweep(url, study_name, tmp_path / f"sweep{i}") for i in (0, 1)]
    outs = [p.communicate(timeout=900) for p in procs]
    for proc, (out, err) in zip(procs, outs):
        assert proc.returncode == 0, out[-2000:] + err[-3000:]
    study = optuna.load_study(study_name=study_name, storage=open_storage(url))
    trials = study.trials
    assert sorted(t.number for t in trials) == list(range(4))
    assert all(t.state == optuna.trial.TrialState.COMPLETE for t in trials)
    jobs = {str(p) for i in (0, 1) for p in (tmp_path / f"sweep{i}").iterdir() if (p / "summary.json").is_file()}
    assert sorted(t.user_attrs["run_dir"] for t in trials) == sorted(jobs)  # one job per trial, no job twice
    for t in trials:
        job = OmegaConf.load(Path(t.user_attrs["run_dir"]) / "config.yaml")
        assert job.trial == t.number and job.seed == 0
    told = [re.findall(r"^trial (\d+): ", out, re.M) for out, _ in outs]
    assert sorted(int(n) for n in told[0] + told[1]) == list(range(4)) and all(told)  # each told once, by both
    best = max(t.value for t in trials)
    assert study.best_value == best
    named = [re.search(r"^best trial (\d+): ", out, re.M) for out, _ in outs]
    assert all(named) and best in [study.trials[int(m.group(1))].value for m in named]
    assert all("***@" in out or kind == "journal" for out, _ in outs)  # the password is never printed
    if kind == "postgresql":
        assert url.split("@")[0].rsplit(":", 1)[1] not in "".join(o + e for o, e in outs)


def test_a_database_that_refuses_the_login_is_one_line_and_writes_nothing(tmp_path):
    head, _, tail = need_postgres().partition("@")
    wrong = f"{head.rsplit(':', 1)[0]}:not-the-password@{tail}"
    proc = cli("-m", "hydra/sweeper=optuna", "learner=qlearn", f"hydra.sweep.dir={tmp_path / 'sweep'}",
               f"hydra.sweeper.storage={wrong}")
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "cannot be opened" in lines[0] and "password authentication failed" in lines[0]
    assert "not-the-password" not in proc.stderr + proc.stdout and ":***@" in lines[0]
    assert not (tmp_path / "sweep").exists()


def test_a_tuned_file_replaced_keeps_the_old_one_and_says_what_changed(tmp_path):
    from sweeps.tuning import replace_tuned

    path, study = tmp_path / "cartpole_qlearn.yaml", tmp_path / "sweep"
    study.mkdir()
    old = "# @package _global_\n# hand-tuned\nlearner:\n  alpha: 0.2\n  gamma: 0.995\nnum_envs: 8\n"
    path.write_text(old)
    new = tuned_text({"learner.alpha": 0.78}, {"learner": {"alpha": 0.2, "gamma": 0.995}, "num_envs": 8}, ["h"])
    line = replace_tuned(path, new, study)
    assert "\n" not in line
    assert line == (f"wrote {path} (the previous one kept as {study / 'previous_cartpole_qlearn.yaml'}): "
                    "learner.alpha 0.2 -> 0.78")
    assert (study / "previous_cartpole_qlearn.yaml").read_text() == old and path.read_text() == new


# -- a task other than the robot's default: the task's tuned file --------------------------
def test_a_study_of_a_task_other_than_the_robots_default_writes_the_tasks_tuned_file(tmp_path, capsys):
    """turtlebot / wall (the maze is its default task): the study's tuned file is
    <robot>_<task>_<learner>.yaml, applied on top of <robot>_<learner>.yaml; on the robot's
    default task it stays <robot>_<learner>.yaml. (Its _finish on a study of one trial.)"""
    from sweeps.optuna_sweep import TuningSweep, _per_task, search_file
    from sweeps.tuning import Plan

    assert _per_task("turtlebot", "wall", None) and not _per_task("turtlebot", "maze", "turtlebot_maze_qlearn")
    assert search_file("turtlebot", "dqn", "maze") == conf_dir() / "search" / "turtlebot_dqn.yaml"
    assert search_file("cartpole", "dqn", "stay_up") == conf_dir() / "search" / "dqn.yaml"
    space = parse_space({"learner.gamma": "interval(0.6, 0.999)"}, "test")
    for task, written in (("wall", "turtlebot_wall_qlearn"), ("maze", "turtlebot_qlearn")):
        sweep = TuningSweep(study="s", storage=f"sqlite:///{tmp_path / 'x.db'}")
        sweep._check_settings()
        sweep.config = OmegaConf.create({"hydra": {"overrides": {"hydra": []}, "runtime": {"choices": {
            "robot": "turtlebot", "task": task, "learner": "qlearn", "tuned": "turtlebot_qlearn",
            "tuned@_global_": f"turtlebot_{task}_qlearn"}}}})
        study = optuna.create_study(direction="maximize")
        study.add_trial(optuna.trial.create_trial(params={"learner.gamma": 0.95},
                                                  distributions={"learner.gamma": space["learner.gamma"].distribution},
                                                  value=51.0))
        plan = Plan("turtlebot", task, "qlearn", [], [], Path("test.yaml"), space, "distance", "greedy_distance")
        folder = tmp_path / task
        folder.mkdir()
        sweep._finish(study, plan, folder)
        out = capsys.readouterr().out
        text = (folder / f"tuned_{written}.yaml").read_text()
        assert OmegaConf.create(text).learner.gamma == 0.95
        assert f"cp {folder / f'tuned_{written}.yaml'} {conf_dir() / 'tuned' / f'{written}.yaml'}" in out
        assert ("for task wall only: applied on top of turtlebot_qlearn.yaml" in text) == (task == "wall")


def _asked(url: str, trials: int) -> list[float]:
    """The values a sweep with ``sampler_seed=0`` asks of study ``s`` in ``url`` (told at once)."""
    from types import SimpleNamespace

    from sweeps.optuna_sweep import TuningSweep

    sweep = TuningSweep(study="s", storage=url, sampler_seed=0, pruner=None)
    sweep._check_settings()
    study = sweep._open_study(SimpleNamespace(measure="length", objective="success_and_speed"))
    space = {"x": optuna.distributions.FloatDistribution(0.0, 1.0)}
    values = []
    for _ in range(trials):
        trial = study.ask(space)
        values.append(trial.params["x"])
        study.tell(trial, trial.params["x"])
    return values


def test_a_continued_study_with_a_fixed_sampler_seed_asks_new_values(tmp_path):
    """Issue 63: a second sweep on a study, with the same ``sampler_seed``, asked the first
    sweep's values again (its sampler restarted from that seed). Its sampler's seed now mixes
    in the trials the study holds: new values, and a fresh study with that seed still asks
    the first sweep's values."""
    first = _asked(f"sqlite:///{tmp_path / 'a.db'}", 3)
    again = _asked(f"sqlite:///{tmp_path / 'a.db'}", 3)
    assert not set(again) & set(first), (first, again)
    assert _asked(f"sqlite:///{tmp_path / 'b.db'}", 3) == first  # a fresh study: the seed's own draws
