"""A robot made of a MuJoCo model and YAML (robots/mjcf_robot.py, tasks/declared.py): the
shipped examples behave physically, names reach the model's own values, the timestep and
control modes follow the config, and a folder outside the package trains and gets ids."""

from __future__ import annotations

import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch
from omegaconf import OmegaConf

from tasks import catalog
from adapters.gym_env import register_envs
from tasks.factory import build_env

ROOT = Path(__file__).resolve().parents[1]


def env_of(robot: str, *overrides: str, num_envs: int = 1, seed: int = 0):
    return build_env(catalog.compose(robot, overrides=list(overrides)), num_envs, seed)


def hold(env, action: int, steps: int) -> list:
    """Steps every copy with ``action`` (no resets); each step's ``next`` tensordict."""
    td, out = env.reset(), []
    for _ in range(steps):
        td = env.step(td.set("action", torch.full((env.num_envs,), action)))["next"]
        out.append(td)
    return out


def action_of(env, *commands: float) -> int:
    """The index of the action whose commands are ``commands`` (in the order of the task's
    actuators)."""
    return [tuple(row) for row in env.task._commands].index(tuple(commands))


def test_the_double_pendulum_falls_without_control():
    """Cart command 0 (the middle action): from near upright, the poles fall and the episode
    terminates on the tip height (below 1 m) within 2 s."""
    env = env_of("double_pendulum", num_envs=4)
    middle = list(env.task._commands[:, 0]).index(0.0)
    steps = hold(env, middle, 40)  # 2 s
    ended = np.stack([td["terminated"].numpy().ravel() for td in steps])
    assert ended.any(axis=0).all(), "a pole stayed up with no force on the cart"
    env.close()


def test_the_acrobot_hanging_down_stays_down_and_its_tip_height_is_geometry():
    """Hanging at rest with no torque the acrobot stays down; the tip height read by name (a
    frame sensor on the model's ``tip`` site) is 2 + cos(shoulder) + cos(shoulder + elbow)."""
    env = env_of("acrobot", "task.reset.position_noise=0.0", "task.reset.velocity_noise=0.0")
    tip = env.task._terms["tip_height"]
    env.reset()
    assert tip.value(env.physics)[0, 0] == pytest.approx(0.0, abs=1e-4)
    hold(env, 1, 50)  # action 1: elbow command 0
    q = env.physics.qpos[0]
    assert abs(q[0] - math.pi) < 1e-3 and abs(q[1]) < 1e-3
    env.physics.qpos[0] = [2.5, -0.7]
    env.physics.forward(np.ones(1, dtype=bool))
    assert tip.value(env.physics)[0, 0] == pytest.approx(2 + math.cos(2.5) + math.cos(1.8), abs=1e-9)
    env.close()


def test_the_elbow_torque_swings_the_acrobot():
    """Full elbow torque one way then the other (pumping) raises the tip from the bottom: the
    motor, found by name, drives the model."""
    env = env_of("acrobot", "task.reset.position_noise=0.0", "task.reset.velocity_noise=0.0")
    td, highest = env.reset(), 0.0
    for t in range(60):
        td = env.step(td.set("action", torch.tensor([0 if (t // 5) % 2 else 2])))["next"]
        highest = max(highest, float(env.task._terms["tip_height"].value(env.physics)[0, 0]))
    assert highest > 0.5
    env.close()


def test_the_timestep_is_the_models_unless_the_task_sets_one():
    env = env_of("acrobot")
    assert env.model.opt.timestep == 0.01 and env.task.n_substeps == 10  # acrobot.xml's option
    assert env.model.opt.integrator == 1  # RK4, the model's: its <option> is kept
    env.close()
    env = env_of("acrobot", "task.physics_timestep=0.005")
    assert env.model.opt.timestep == 0.005 and env.task.n_substeps == 20
    env.close()


def test_a_position_servo_on_the_elbow_holds_the_commanded_angle():
    """robot.control turns the model's elbow motor into a position servo: the command is the
    elbow angle it goes to."""
    env = env_of("acrobot", "robot.control={elbow: {mode: position, gain: 50}}",
                 "task.actions={values: {elbow: [0.0, 0.5]}}", "task.reset.position_noise=0.0",
                 "task.reset.velocity_noise=0.0")
    hold(env, 1, 40)
    assert env.physics.qpos[0, 1] == pytest.approx(0.5, abs=0.05)
    env.close()


def test_rewards_are_the_declared_weighted_sum():
    """The double pendulum's rewards: 1 alive, -0.1 (tip height - 2)^2, ...; at rest
    upright the tip is at 1.2 m, so the first reward is 1 - 0.064 less tiny terms (Gymnasium's / 10)."""
    env = env_of("double_pendulum", "task.reset.position_noise=0.0",
                 "task.reset.velocity_noise=0.0")
    middle = list(env.task._commands[:, 0]).index(0.0)
    td = hold(env, middle, 1)[0]
    assert td["reward"].item() == pytest.approx(1 - 0.1 * 0.8**2, abs=1e-3)
    env.close()


def test_the_acrobot_measure_counts_a_reached_line_and_ends_the_episode():
    env = env_of("acrobot")
    td = env.reset()
    env.physics.qpos[0] = [0.0, 0.0]  # straight up: the tip at 4 m
    td = env.step(td.set("action", torch.tensor([1])))["next"]
    assert td["terminated"].item()
    assert env.task.episode_info(env.physics)["reached"][0] == 1.0
    env.close()


def test_the_point_mass_reaches_the_motors_terminal_speed_and_reads_the_target_geom():
    """dm_control's point mass: a motor's full push (0.1 N) against the slide's damping
    (1 N s/m) settles at 0.1 m/s; the target, a geom of the world at the origin, is read by
    name: ``to_target`` is its position minus the ball's, ``distance`` their gap."""
    env = env_of("point_mass", "task.reset.joints={root_x: -0.2, root_y: 0.1}",
                 "task.reset.position_noise=0.0")
    push_x = action_of(env, 1.0, 0.0)
    td = hold(env, push_x, 20)[-1]  # 2 s, some 7 time constants (0.3 kg / 1 N s/m)
    (x, y), (vx, vy) = env.physics.qpos[0], env.physics.qvel[0]
    assert vx == pytest.approx(0.1 * (1 - math.exp(-2 / 0.3)), rel=1e-3) and vy == pytest.approx(0.0, abs=1e-9)
    # Frame quantities are read at the start of the last physics step: one 0.02 s step old.
    assert td["observation"][0, 0].item() == pytest.approx(-(x - 0.02 * vx), abs=1e-5)  # target 0 - ball x
    assert td["observation"][0, 1].item() == pytest.approx(-y, abs=1e-6)  # (float32)
    env.physics.forward(np.ones(1, dtype=bool))
    gap = env.task._terms["to_target"].value(env.physics)[0, 0]
    assert gap == pytest.approx(math.hypot(x, y), abs=1e-6)
    env.close()


@pytest.mark.parametrize("start, held", [(0.0, 1.0), (0.05, 0.0)])
def test_the_point_mass_measure_holds_only_inside_the_target(start, held):
    """At rest in the target (1.5 cm radius) for the whole episode the measure is 1; at rest
    5 cm away it is 0."""
    env = env_of("point_mass", f"task.reset.joints={{root_x: {start}, root_y: 0.0}}",
                 "task.reset.position_noise=0.0")
    steps = hold(env, action_of(env, 0.0, 0.0), env.task.max_episode_steps)
    assert steps[-1]["truncated"].item()
    assert env.task.episode_info(env.physics)["held"][0] == held
    env.close()


def test_the_pendulum_hangs_at_rest_and_its_motor_alone_cannot_lift_it():
    """dm_control's pendulum: hanging at rest it stays down (``upright`` = cos of the tilt =
    -1); a constant full torque (1 N m, under the 4.9 N m that holding the 1 kg ball level at
    0.5 m takes) only tilts it to asin(1 / 4.9) = 11.8 degrees; pumping, the torque along the
    velocity, swings it up."""
    env = env_of("pendulum", "task.reset.position_noise=0.0", "task.reset.velocity_noise=0.0")
    upright = env.task._terms["upright"]
    index = {u: action_of(env, u) for u in (-1.0, 0.0, 1.0)}
    hold(env, index[0.0], 50)
    assert env.physics.qpos[0, 0] == pytest.approx(math.pi, abs=1e-3)
    assert upright.value(env.physics)[0, 0] == pytest.approx(-1.0, abs=1e-6)
    hold(env, index[1.0], 150)  # 15 s: the damped swing settles
    tilt = abs(env.physics.qpos[0, 0] - math.pi)
    assert tilt == pytest.approx(math.asin(1 / (9.81 * 0.5)), abs=0.02)
    assert upright.value(env.physics)[0, 0] == pytest.approx(-math.cos(tilt), abs=1e-3)  # nearly at rest
    td, highest = env.reset(), -1.0
    for _ in range(100):
        push = index[1.0] if env.physics.qvel[0, 0] >= 0 else index[-1.0]
        td = env.step(td.set("action", torch.tensor([push])))["next"]
        highest = max(highest, float(upright.value(env.physics)[0, 0]))
    assert highest > 0.9
    env.close()


def _copy_acrobot(folder: Path) -> Path:
    """A user's config folder, outside the package: the acrobot as ``my_acrobot`` with task
    ``my_swingup`` and its model files."""
    shutil.copytree(ROOT / "conf" / "models" / "acrobot", folder / "models" / "acrobot")
    (folder / "robot").mkdir()
    (folder / "task").mkdir()
    robot = (ROOT / "conf" / "robot" / "acrobot.yaml").read_text().replace("swingup", "my_swingup")
    (folder / "robot" / "my_acrobot.yaml").write_text(robot)
    shutil.copy(ROOT / "conf" / "task" / "swingup.yaml", folder / "task" / "my_swingup.yaml")
    return folder


def test_a_config_folder_outside_the_package_trains_from_anywhere(tmp_path):
    """``train.py --config-dir <folder> robot=my_acrobot`` from another working folder: the
    model path is resolved against the copied folder, and the run ends with a verdict; with
    ``learner=sac``, on the tutorial's task's continuous form (a user's robot with the
    continuous learners, issue 66; dqn on a declared robot is every other test here)."""
    folder = _copy_acrobot(tmp_path / "my_robots")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    cmd = [sys.executable, str(ROOT / "train.py"), "--config-dir", str(folder), "robot=my_acrobot",
           "learner=sac", "max_episodes=2", "eval_episodes=0", "quiet=true",
           f"hydra.run.dir={tmp_path / 'run'}"]
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(cmd, cwd=elsewhere, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip().splitlines()[-1].startswith("VERDICT solved=false episodes=2")
    saved = OmegaConf.load(tmp_path / "run" / "config.yaml")
    assert saved.robot.model == str(folder / "models" / "acrobot" / "acrobot.xml")
    # mode=eval of that run without its --config-dir: found from the run's record (issue 67)
    cmd = [sys.executable, str(ROOT / "train.py"), "mode=eval", f"checkpoint={tmp_path / 'run'}", "eval_episodes=2",
           "quiet=true", f"hydra.run.dir={tmp_path / 'eval'}"]
    proc = subprocess.run(cmd, cwd=elsewhere, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "greedy evaluation over 2 episodes" in proc.stdout
    shutil.rmtree(folder)  # the folder gone: one line naming it and what to pass
    proc = subprocess.run([*cmd[:-1], f"hydra.run.dir={tmp_path / 'eval2'}"], cwd=elsewhere, capture_output=True,
                          text=True, timeout=300, env=env)
    assert proc.returncode == 2 and proc.stderr.strip().splitlines() == [
        f"error: checkpoint={tmp_path / 'run'} is a run of robot=my_acrobot task=my_swingup, whose config no "
        f"config folder given holds (it was made with --config-dir {folder}, which no longer holds it); pass the "
        "--config-dir that holds it"], proc.stderr[-2000:]


def test_a_config_folder_gets_gymnasium_ids(tmp_path):
    folder = _copy_acrobot(tmp_path / "my_robots")
    try:
        ids = register_envs(config_dirs=[str(folder)])
        assert "MujocoRL/MyAcrobotMySwingup-v0" in ids
        env = gym.make("MujocoRL/MyAcrobotMySwingup-v0")
        obs, _ = env.reset(seed=0)
        assert obs.shape == (6,) and env.spec.max_episode_steps == 500
        env.close()
    finally:
        catalog.use_config_dirs([])
        gym.registry.pop("MujocoRL/MyAcrobotMySwingup-v0", None)


# -- bad input: one line each, before anything runs, nothing written ------------------------
BROKEN = '<mujoco><worldbody><body><joint name="j"/><geom size=".1"/></body></worldbody>' \
         '<actuator><motor joint="nope"/></actuator></mujoco>'


@pytest.mark.parametrize("args, words", [
    (["+task.observations.x={joint_pos: elbw}"],
     ["task.observations.x: the model has no joint 'elbw'; close matches: elbow; its joints: "
      "shoulder, elbow"]),
    (["+task.terms.b={body_pos: upperarm}"], ["no body 'upperarm'", "close matches: upper_arm",
                                             "its bodies: upper_arm, lower_arm"]),
    (["+task.terms.s={sensor: accel}"], ["no sensor 'accel'", "its sensors: none"]),
    (["~task.actions.values.elbow", "+task.actions.values.elbw=[1.0]"],
     ["task.actions: the model has no actuator 'elbw'; close matches: elbow; its actuators: elbow"]),
    (["robot.control={elbw: {mode: position}}"], ["robot.control.elbw: the model has no actuator"]),
    (["+robot.joints={elbow: {damping: -1}}"], ["robot.joints.elbow.damping must be a finite number >= 0"]),
    (["+robot.joints={elbow: {dampin: 1}}"], ["robot.joints.elbow must be {damping, frictionloss"]),
    (["robot.model=/nonexistent/robot.xml"],
     ["robot.model must be an MJCF file that exists; got '/nonexistent/robot.xml'"]),
    (["robot.model=BROKEN"], ["MuJoCo cannot compile it", "unknown", "nope", "broken.xml"]),
    (["+task.rewards.tip={site_pos: tip}"],
     ["task.rewards.tip must be one number per step; tip has 3 (pick one with axis or index)"]),
    (["task.actions.values.elbow=[]"], ["task.actions must hold at least one action"]),
    (["+task.termination.tipp=[0,1]"], ["task.termination.tipp: no such term; the declared terms",
                                         "tip_height"]),
])
def test_a_bad_model_or_declaration_is_one_line_and_nothing_written(args, words, tmp_path,
                                                                    monkeypatch, capsys):
    from test_bad_inputs import cli

    broken = tmp_path / "broken.xml"
    broken.write_text(BROKEN)
    args = [a.replace("BROKEN", str(broken)) for a in args]
    code = cli(["robot=acrobot", "learner=dqn", *args], tmp_path, monkeypatch)
    err = [ln for ln in capsys.readouterr().err.splitlines() if ln.strip() and not ln.startswith("[")]
    assert code == 2 and len(err) == 1 and err[0].startswith("error: "), err
    for word in words:
        assert word in err[0], err[0]
    assert not (tmp_path / "run" / "config.yaml").exists()


@pytest.mark.slow
@pytest.mark.parametrize("robot", ["acrobot", "double_pendulum", "point_mass", "pendulum"])
def test_dqn_solves_the_shipped_example(robot, tmp_path):
    """The shipped examples are learnable as shipped: dqn with the tuned file, seed 0, ends
    with the task's verdict true (acrobot ~45 s, double pendulum ~90 s, point mass ~10 s,
    pendulum ~15 s on 2 cores)."""
    cmd = [sys.executable, "train.py", f"robot={robot}", "learner=dqn", "quiet=true",
           "max_episodes=5000", f"hydra.run.dir={tmp_path}"]
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=900, env=env)
    assert proc.stdout.strip().splitlines()[-1].startswith("VERDICT solved=true"), proc.stdout[-2000:]


def test_a_model_with_a_mesh_folder_and_no_option_loads(tmp_path):
    """``<compiler meshdir>`` and a mesh file are found relative to the model; with no
    ``<option>`` the timestep is MuJoCo's default (0.002 s)."""
    from robots.mjcf_robot import MjcfRobot
    from tasks.env import compile_model

    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "tet.obj").write_text(
        "v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nv 0 0 0.1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    (tmp_path / "robot.xml").write_text(
        '<mujoco><compiler meshdir="meshes"/><asset><mesh name="tet" file="tet.obj"/></asset>'
        '<worldbody><body name="b"><joint name="j"/><geom type="mesh" mesh="tet"/></body>'
        '</worldbody><actuator><motor name="m" joint="j"/></actuator></mujoco>')
    robot = MjcfRobot(model=str(tmp_path / "robot.xml"))
    assert robot.timestep == 0.002 and robot.names("actuator") == ["m"]
    model = compile_model(robot.mjcf_model)
    assert model.nmesh == 1 and model.nu == 1


def test_the_arm_reaches_24_cm_and_its_target_stays_where_placed():
    """The two-link arm: the fingertip at full stretch is 24 cm from the shoulder (two 12 cm
    links), folded it is at the shoulder; a motor's full command turns its link; the target,
    placed over a 20 cm disc at rest, does not move while the arm swings (no contacts, no
    gravity along its slides)."""
    env = env_of("arm", "learner=sac", num_envs=64)
    td = env.reset()
    target = env.physics.qpos[:, 2:4].copy()
    assert np.hypot(*target.T).max() <= 0.2 and not env.physics.qvel[:, 2:].any()
    for _ in range(25):
        td = env.step(td.set("action", torch.ones(64, 2)))["next"]
    assert np.array_equal(env.physics.qpos[:, 2:4], target)
    assert (env.physics.qvel[:, :2] > 0.5).all()  # both links turned the way commanded
    env.physics.qpos[:, :2] = 0.0  # stretched along x
    env.physics.forward(np.ones(64, dtype=bool))
    reach = env.task._terms["distance"]
    tip_to_target = reach.value(env.physics)[:, 0]
    assert np.allclose(tip_to_target, np.hypot(target[:, 0] - 0.24, target[:, 1]), atol=1e-6)
    env.close()


def test_the_finger_flicks_the_spinner_past_15_rad_s_and_it_slows_down():
    """dm_control's finger with its spin damping (robot.joints): sweeping the finger back and
    forth (both motors full, 2 Hz) flicks the spinner clockwise past the task's 15 rad/s within
    10 s (seed 0: all 8 starts, at 20-38 rad/s); left alone at 20 rad/s it slows by about 1
    rad/s a step (friction loss, then damping), below 15 within 0.12 s and below 3 within 0.6 s."""
    env = env_of("finger", "learner=sac", num_envs=8)
    td = env.reset()
    fastest = np.zeros(8)
    for t in range(500):
        a = float(np.sign(np.sin(t * 0.02 * 2 * np.pi * 2.0)))
        td = env.step(td.set("action", torch.tensor([[a, -a]] * 8)))["next"]
        fastest = np.minimum(fastest, env.physics.qvel[:, 2])
    assert (fastest < -15).sum() >= 7, fastest
    env = env_of("finger", "learner=sac", "task.reset.joints.proximal.position=1.9",
                 "task.reset.joints.distal.position=0", num_envs=2)  # the finger clear of the spinner
    td = env.reset()
    env.physics.qvel[:, 2] = -20.0
    speeds = []
    for _ in range(30):
        td = env.step(td.set("action", torch.zeros(2, 2)))["next"]
        speeds.append(-env.physics.qvel[0, 2])
    assert 18 < speeds[0] < 20 and speeds[5] < 15 and speeds[-1] < 3, speeds
    assert all(0 < a - b < 1.2 for a, b in zip(speeds, speeds[1:])), speeds
    env.close()


def test_a_joints_damping_set_in_yaml_slows_it_as_mujoco_says():
    """robot.joints sets the spinner's damping: spun at 20 rad/s and left alone, it keeps 18.9
    rad/s after one 0.02 s env step at dm_control's spin value (0.03), 10.2 at the model's 0.5."""
    kept = {}
    for damping in (0.5, 0.03):
        env = env_of("finger", f"robot.joints.hinge.damping={damping}")
        td = env.reset()
        physics, hinge = env.physics, env.task.robot.reader("joint_pos", "hinge", "test")
        env.task.robot.bind(physics)
        hinge.joint.set(physics, np.ones(1, bool), np.zeros(1), np.full(1, -20.0))
        env.step(td.set("action", torch.full((1,), action_of(env, 0.0, 0.0))))
        kept[damping] = float(hinge.joint.vel(physics)[0])
    assert kept[0.03] == pytest.approx(-18.9, abs=0.1) and kept[0.5] == pytest.approx(-10.2, abs=0.1)


def test_the_spinners_touch_is_observed_as_dm_control_scales_it():
    """apply: log1p: the finger's touch sensors (hundreds of N at a flick) reach the learner
    as log(1 + N), a few units, as dm_control's finger observes them."""
    seen = {}
    for apply in ("log1p", "null"):
        env = env_of("finger", "learner=sac", f"task.observations.touchtop.apply={apply}", num_envs=8)
        td, rows = env.reset(), []
        for t in range(150):
            a = float(np.sign(np.sin(t * 0.02 * 2 * np.pi * 2.0)))
            td = env.step(td.set("action", torch.tensor([[a, -a]] * 8)))["next"]
            rows.append(td["observation"][:, 7].numpy().copy())
        seen[apply] = np.concatenate(rows)
    assert seen["null"].max() > 100 and seen["log1p"].max() < 8
    assert np.allclose(seen["log1p"], np.log1p(seen["null"]), atol=1e-5)
