"""Every config composes and instantiates; the task follows the robot; tuned values follow both."""

import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException
from omegaconf import OmegaConf

import train
from runs.command import one_line
from hydra.utils import instantiate
from tasks import catalog
from tasks import factory
from params import ConfigError
from runs.settings import check_run_config

CONF = Path(__file__).resolve().parents[1] / "conf"
ROBOTS = sorted(p.stem for p in (CONF / "robot").glob("*.yaml"))
TASKS = sorted(p.stem for p in (CONF / "task").glob("*.yaml"))
LEARNERS = sorted(p.stem for p in (CONF / "learner").glob("*.yaml"))


def compose_cfg(*overrides: str):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides), return_hydra_config=True)


@pytest.mark.parametrize("robot", ROBOTS)
@pytest.mark.parametrize("learner", LEARNERS)
def test_every_robot_learner_pair_composes_and_builds(robot, learner):
    """Every shipped robot x learner pair (their tuned files included) passes the run's checks,
    builds, acts and steps."""
    cfg = compose_cfg(f"robot={robot}", f"learner={learner}")
    check_run_config(cfg)
    OmegaConf.resolve(cfg)
    env = factory.build_env(cfg, num_envs=2, seed=0)
    try:
        agent = instantiate(cfg.learner, _convert_="all")
        agent.build(env.task)
        td = agent.member(0).policy(env.reset())
        assert env.step(td)["next", "observation"].shape[0] == 2
    finally:
        env.close()


@pytest.mark.parametrize("robot", ROBOTS)
@pytest.mark.parametrize("task", TASKS)
def test_task_fits_robot_or_says_which_robot_it_needs(robot, task):
    cfg = compose_cfg(f"robot={robot}", f"task={task}")
    default_task = catalog.default_task(robot)  # composed once a robot (kept by the catalog)
    if task == default_task:
        factory.build_task(cfg)
        return
    try:
        factory.build_task(cfg)
    except Exception as err:  # noqa: BLE001 - a mismatch must name the robot needed
        message = one_line(err)
        # A declared task on another model names what the model lacks (tests/test_mjcf_robot.py).
        assert ("needs robot=" in message or "the model has no" in message), message
        assert len(message.splitlines()) == 1
    # Tasks that happen to fit more than one robot are allowed to build.


def test_every_task_fits_a_robot_and_every_robot_its_default_task():
    defaults = {robot: catalog.default_task(robot) for robot in ROBOTS}
    for robot, task in defaults.items():
        assert catalog.built(robot, task) is not None, f"robot {robot} does not fit its default task {task}"
    for task in set(TASKS) - set(defaults.values()):  # a task no robot defaults to: the first that fits
        assert any(catalog.built(robot, task) for robot in ROBOTS), f"task {task} fits no robot"


def test_no_config_of_the_project_sets_hydras_mode():
    """train.py takes a command's mode from ``-m`` without composing for it
    (``params.private_api.mode_of_the_flag``): exact only while no file of conf/ sets
    ``hydra.mode`` (a ``hydra:`` section's, or a ``conf/hydra/`` group's own ``mode``)."""
    import yaml

    for path in sorted(CONF.rglob("*.yaml")):
        text = yaml.safe_load(path.read_text()) or {}
        if not isinstance(text, dict):
            continue
        in_hydra_group = path.relative_to(CONF).parts[0] == "hydra"
        assert "mode" not in (text.get("hydra") or {}) and not (in_hydra_group and "mode" in text), path


def test_every_tuned_file_names_a_robot_and_a_learner(monkeypatch):
    """Hydra applies conf/tuned/<robot>_<learner>.yaml to that pair only: any other name never."""
    orphans = [name for name, pair in catalog.tuned_pairs().items() if pair is None]
    assert not orphans, f"conf/tuned files naming no <robot>_<learner> pair: {orphans}"
    real = catalog.names
    monkeypatch.setattr(catalog, "names",
                        lambda group: real(group) + (["cartpole_dqnn"] if group == "tuned" else []))
    assert catalog.tuned_pairs()["cartpole_dqnn"] is None
    assert catalog.tuned_pairs()["cartpole_dqn"] == ("cartpole", "dqn")


def test_task_follows_robot_and_can_be_overridden():
    cfg = compose_cfg("robot=cartpole")
    assert cfg.hydra.runtime.choices.task == "stay_up"
    assert cfg.task._target_ == "tasks.stay_up.StayUp"
    cfg = compose_cfg("robot=cartpole", "task.pos_step=0.5")
    assert cfg.task.pos_step == 0.5


def test_tuned_parameters_follow_robot_and_learner_yet_stay_overridable():
    base = OmegaConf.load(CONF / "learner" / "qlearn.yaml")
    tuned = OmegaConf.load(CONF / "tuned" / "cartpole_qlearn.yaml")
    cfg = compose_cfg("robot=cartpole", "learner=qlearn")
    for key, value in tuned.learner.items():
        assert cfg.learner[key] == value
    assert any(base[k] != v for k, v in tuned.learner.items())  # tuning changes something
    cfg = compose_cfg("robot=cartpole", "learner=qlearn", "learner.alpha=0.33")
    assert cfg.learner.alpha == 0.33


def test_rainbow_is_the_papers_settings_and_its_studies_keep_the_replay_period():
    """The rainbow's settings where they are not Atari's scale, an update every 4 env steps
    among them; its studies do not search that (ranked by env steps, they would buy env
    steps with updates of ~3x a plain one's cost)."""
    cfg = catalog.compose("cartpole", learner="rainbow", overrides=["~tuned"]).learner
    assert (cfg.double_dqn, cfg.n_step, cfg.prioritized, cfg.dueling, cfg.noisy, cfg.distributional) == (
        True, 3, True, True, True, True)
    assert (cfg.priority_alpha, cfg.priority_beta, cfg.noisy_sigma, cfg.atoms, cfg.updates) == (0.5, 0.4, 0.5, 51, 0.25)
    space = OmegaConf.load(CONF / "search" / "rainbow.yaml")
    assert "learner.updates" not in space and "learner.n_step" in space
    assert "updates" not in OmegaConf.load(CONF / "tuned" / "cartpole_rainbow.yaml").learner


def test_unknown_option_and_key_fail_with_hydra_message():
    with pytest.raises(ConfigCompositionException, match="robot"):
        compose_cfg("robot=submarine")
    with pytest.raises(ConfigCompositionException, match="no_such_key"):
        compose_cfg("learner.no_such_key=1")


@pytest.mark.parametrize("override, key", [
    ("learner.alpha=-0.1", "learner.alpha"),
    ("learner.epsilon=1.5", "learner.epsilon"),
    ("learner.gamma=2", "learner.gamma"),
    ("task.n_actions=3", "task.n_actions"),
    ("task.running_step=0", "task.running_step"),
    ("learner.number_splits.cart_pos=0", "learner.number_splits"),
    ("+learner.number_splits.wheel=3", "learner.number_splits"),
])
def test_bad_values_give_one_line_naming_the_key(override, key):
    cfg = compose_cfg(override)
    with pytest.raises(Exception) as err:
        learner = instantiate(cfg.learner, _convert_="all")
        env = factory.build_env(cfg, num_envs=1, seed=0)
        learner.build(env.task)
    message = one_line(err.value)
    assert key in message and "got" in message, message
    assert isinstance(err.value, ConfigError) or isinstance(err.value.__cause__, ConfigError)


# -- the per-task tuned layer: conf/tuned/<robot>_<task>_<learner>.yaml on top of the robot's --
@pytest.fixture
def task_layer(tmp_path):
    """A config folder (as ``--config-dir``) holding a per-task tuned file for cartpole /
    stay_up / qlearn that changes two of cartpole_qlearn.yaml's values and adds one."""
    (tmp_path / "tuned").mkdir()
    (tmp_path / "tuned" / "cartpole_stay_up_qlearn.yaml").write_text(
        "# @package _global_\n# a test's layer\nlearner:\n  alpha: 0.31\n  gamma: 0.93\n  epsilon_min: 0.011\n")
    catalog.use_config_dirs([tmp_path])
    yield tmp_path
    catalog.use_config_dirs([])


def test_a_task_tuned_file_applies_on_top_of_the_robot_one(task_layer):
    robot_file = OmegaConf.load(CONF / "tuned" / "cartpole_qlearn.yaml")
    cfg = catalog.compose("cartpole", learner="qlearn")
    assert (cfg.learner.alpha, cfg.learner.gamma, cfg.learner.epsilon_min) == (0.31, 0.93, 0.011)
    assert cfg.num_envs == robot_file.num_envs and cfg.max_episodes == robot_file.max_episodes
    assert catalog.tuned_layers("cartpole", "stay_up", "qlearn") == ["cartpole_qlearn", "cartpole_stay_up_qlearn"]
    assert catalog.tuned_targets()["cartpole_stay_up_qlearn"] == ("cartpole", "stay_up", "qlearn")
    assert catalog.tuned_pairs()["cartpole_stay_up_qlearn"] == ("cartpole", "qlearn")
    # the command line still wins, and only that pair's task gets the layer
    assert catalog.compose("cartpole", learner="qlearn", overrides=["learner.gamma=0.5"]).learner.gamma == 0.5
    assert catalog.compose("cartpole", learner="dqn").learner.gamma == OmegaConf.load(
        CONF / "tuned" / "cartpole_dqn.yaml").learner.get("gamma", 0.99)
    choices = catalog._compose(["robot=cartpole", "learner=qlearn"]).hydra.runtime.choices
    assert catalog.run_choices(choices) == {"robot": "cartpole", "task": "stay_up", "learner": "qlearn",
                                            "tuned": "cartpole_qlearn", "tuned_task": "cartpole_stay_up_qlearn"}


def test_no_tuned_drops_both_layers(task_layer):
    plain = OmegaConf.load(CONF / "learner" / "qlearn.yaml")
    cfg = catalog.compose("cartpole", learner="qlearn", overrides=["~tuned"])
    assert (cfg.learner.alpha, cfg.learner.gamma, cfg.learner.epsilon_min) == (plain.alpha, plain.gamma, plain.epsilon_min)
    assert cfg.num_envs == 1
    # the task's layer alone can be left out by its own key
    cfg = catalog.compose("cartpole", learner="qlearn", overrides=[f"~{catalog.TASK_TUNED}"])
    assert cfg.learner.alpha == OmegaConf.load(CONF / "tuned" / "cartpole_qlearn.yaml").learner.alpha
    assert catalog.with_tuned_layers(["a=1", "~tuned", "b=2"]) == ["a=1", "~tuned", "~tuned@_global_", "b=2"]
    assert catalog.with_tuned_layers(["~tuned", "~tuned@_global_"]) == ["~tuned", "~tuned@_global_"]


def test_a_composition_is_made_once_and_made_again_when_a_config_file_changes(task_layer, monkeypatch):
    """catalog.compose keeps each composition for the process and hands out copies; an
    edited, added or removed YAML file of a config folder makes it anew."""
    made = []
    real = catalog._hydra_compose
    monkeypatch.setattr(catalog, "_hydra_compose", lambda overrides: made.append(1) or real(overrides))
    catalog._composed.cache_clear()
    first = catalog.compose("cartpole", learner="qlearn")
    assert first.learner.alpha == 0.31 and len(made) == 1
    first.learner.alpha = -1.0  # a copy: the next one is untouched
    assert catalog.compose("cartpole", learner="qlearn").learner.alpha == 0.31
    assert len(made) == 1  # kept, not made again
    layer = task_layer / "tuned" / "cartpole_stay_up_qlearn.yaml"
    layer.write_text(layer.read_text().replace("0.31", "0.42"))  # same size, same second
    assert catalog.compose("cartpole", learner="qlearn").learner.alpha == 0.42 and len(made) == 2
    layer.unlink()
    robot_file = OmegaConf.load(CONF / "tuned" / "cartpole_qlearn.yaml")
    assert catalog.compose("cartpole", learner="qlearn").learner.alpha == robot_file.learner.alpha
    assert len(made) == 3


def test_a_task_tuned_file_without_a_robot_one_applies_alone(tmp_path):
    (tmp_path / "tuned").mkdir()
    (tmp_path / "tuned" / "acrobot_swingup_mbalunovic.yaml").write_text("# @package _global_\nlearner:\n  gamma: 0.9\n")
    catalog.use_config_dirs([tmp_path])
    try:  # (the acrobot has no mbalunovic file of its own)
        assert catalog.compose("acrobot", learner="mbalunovic").learner.gamma == 0.9
        assert catalog.compose("acrobot", learner="mbalunovic", overrides=["~tuned"]).learner.gamma == 0.99
        assert catalog.tuned_layers("acrobot", "swingup", "mbalunovic") == ["acrobot_swingup_mbalunovic"]
    finally:
        catalog.use_config_dirs([])


def test_a_tuned_file_naming_neither_a_pair_nor_a_task_of_one_is_an_orphan(monkeypatch):
    real = catalog.names
    monkeypatch.setattr(catalog, "names",
                        lambda group: real(group) + (["cartpole_stayup_dqn"] if group == "tuned" else []))
    assert catalog.tuned_pairs()["cartpole_stayup_dqn"] is None
    assert catalog.tuned_targets()["cartpole_stayup_dqn"] is None
    assert catalog.tuned_targets()["cartpole_dqn"] == ("cartpole", None, "dqn")


def test_help_is_the_projects_own_page_in_one_screen():
    """``train.py --help``: how to pick a robot, task and learner, the names of each, the main
    settings and where every setting is explained; not Hydra's stock page nor its config dump."""
    from tests.inprocess import run_train

    done = run_train("--help")
    assert done.returncode == 0, done.stderr[-2000:]
    page = done.stdout
    assert "powered by Hydra" not in page and "== Config ==" not in page
    assert "python train.py robot=<robot>" in page and "docs/reference/parameters.md" in page
    for group in ("robot: ", "task: ", "learner: "):
        assert any(line.startswith(group) for line in page.splitlines()), group
    assert "cartpole" in page and "qlearn" in page and "rainbow" in page
    assert len(page.strip().splitlines()) <= 40


def test_help_names_the_command_the_user_ran(monkeypatch):
    """Issue 67: the installed ``mujoco-rl-train --help`` said ``python train.py``."""
    from runs.layout import compare_command, train_command

    assert (train_command(), compare_command()) == ("python train.py", "python compare.py")
    monkeypatch.setattr(sys, "argv", ["/venv/bin/mujoco-rl-train", "--help"])
    assert (train_command(), compare_command()) == ("mujoco-rl-train", "mujoco-rl-compare")
    page = OmegaConf.create({"t": "${train_command:} robot=<robot>; ${compare_command:} <sweep>"})
    assert page.t == "mujoco-rl-train robot=<robot>; mujoco-rl-compare <sweep>"
