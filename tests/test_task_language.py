"""The declared task's grammar against MuJoCo's own numbers: geom terms, distances between
frames and vector differences (read after a reset, where sensors are exact, against
``mj_forward`` on each copy's state), every measure kind (windows, ``below``, ``held``) on
a scripted sequence, and dm_control's ``tolerance`` as a reward term."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
import torch
from dm_control.utils import rewards

from params import ConfigError
from robots.mjcf_robot import MjcfRobot
from tasks.declared import DeclaredTask
from tasks.env import RobotTaskEnv

ARM = """
<mujoco model="arm">
  <option timestep="0.01"/>
  <worldbody>
    <geom name="target" type="sphere" size="0.05" pos="0.3 0.2 1.0" contype="0" conaffinity="0"/>
    <body name="upper" pos="0 0 1">
      <joint name="shoulder" type="hinge" axis="0 1 0"/>
      <geom name="upper_geom" type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
      <body name="lower" pos="0.3 0 0">
        <joint name="elbow" type="hinge" axis="0 1 0"/>
        <geom name="lower_geom" type="capsule" fromto="0 0 0 0.3 0 0" size="0.02"/>
        <site name="tip" pos="0.3 0 0"/>
      </body>
    </body>
  </worldbody>
  <actuator><motor name="elbow" joint="elbow" gear="1" ctrlrange="-1 1"/></actuator>
</mujoco>
"""

TERMS = {
    "target_pos": {"geom_pos": "target"},
    "lower_z": {"geom_zaxis": "lower_geom"},
    "lower_quat": {"geom_quat": "lower_geom"},
    "reach": {"distance": ["tip", "target"]},
    "reach_xy": {"distance": ["site:tip", "geom:target"], "axes": ["x", "y"]},
    "to_target": {"from": "tip", "to": "target"},
    "to_target_z": {"from": "tip", "to": "target", "axis": "z"},
    "tip_z": {"site_pos": "tip", "axis": "z"},
}


def task(tmp_path, **extra) -> DeclaredTask:
    (tmp_path / "arm.xml").write_text(ARM)
    spec = {"observations": TERMS, "actions": {"values": {"elbow": [-1.0, 0.0, 1.0]}},
            "rewards": {"near": {"term": "reach", "tolerance": {"bounds": [0.0, 0.05], "margin": 0.3,
                                                                "sigmoid": "long_tail"}}},
            "reset": {"position_noise": 1.0, "velocity_noise": 0.5}, "running_step": 0.05,
            "max_episode_steps": 50, **extra}
    return DeclaredTask(robot=MjcfRobot(model=str(tmp_path / "arm.xml")), **spec)


def test_geom_terms_distances_and_differences_are_mujocos_numbers(tmp_path):
    made = task(tmp_path)
    env = RobotTaskEnv(made, num_envs=4, seed=3)
    td = env.reset()
    data = mujoco.MjData(env.physics.model)
    names = list(made.observation_names)
    for copy in range(4):
        env.physics.load_into(data, copy)
        obs = td["observation"][copy].numpy().astype(np.float64)
        seen = {n: obs[names.index(n)] for n in names}

        def geom(name):
            return mujoco.mj_name2id(env.physics.model, mujoco.mjtObj.mjOBJ_GEOM, name)

        tip = data.site_xpos[mujoco.mj_name2id(env.physics.model, mujoco.mjtObj.mjOBJ_SITE, "tip")]
        target = data.geom_xpos[geom("target")]
        quat = np.empty(4)
        mujoco.mju_mat2Quat(quat, data.geom_xmat[geom("lower_geom")])
        expected = {"target_pos": target, "lower_z": data.geom_xmat[geom("lower_geom")].reshape(3, 3)[:, 2],
                    "lower_quat": quat * np.sign(quat[0] * seen["lower_quat_0"] or 1),
                    "reach": [np.linalg.norm(target - tip)], "reach_xy": [np.linalg.norm((target - tip)[:2])],
                    "to_target": target - tip, "to_target_z": [(target - tip)[2]], "tip_z": [tip[2]]}
        for name, want in expected.items():
            got = [seen[n] for n in names if n == name or n.startswith(name + "_") and n[len(name) + 1:].isdigit()]
            np.testing.assert_allclose(got, np.ravel(want), atol=2e-5, err_msg=f"{name}, copy {copy}")
        # dm_control's tolerance of the reach, as the reward term gives it
        shaped = rewards.tolerance(np.linalg.norm(target - tip), bounds=(0.0, 0.05), margin=0.3,
                                   sigmoid="long_tail")
        term = made._rewards[0]
        np.testing.assert_allclose(term.value(env.physics, made.per_copy.command)[copy], shaped, atol=1e-5)
    env.close()


class Fixed:
    """A one-number term whose value this step is set by the test."""

    size = 1

    def __init__(self):
        self.now = None

    def value(self, physics):
        return self.now[:, None]


MEASURES = {
    "best": {"term": "tip_z"},
    "low": {"term": "tip_z", "reduce": "min", "below": 0.5},
    "mean_last3": {"term": "tip_z", "reduce": "mean", "last": 3},
    "max_last_half_s": {"term": "tip_z", "reduce": "max", "seconds": 0.1},
    "sum_last3": {"term": "tip_z", "reduce": "sum", "last": 3},
    "end": {"term": "tip_z", "reduce": "last", "last": 3, "above": 0.9},
    "held_last4": {"term": "tip_z", "above": 0.9, "last": 4, "held": 0.75},
    "held_all": {"term": "tip_z", "below": 0.5, "held": 0.5},
}


def test_every_measure_kind_on_a_scripted_episode(tmp_path):
    made = task(tmp_path, terms={}, measures=MEASURES)
    env = RobotTaskEnv(made, num_envs=2, seed=0)
    env.reset()
    # copy 0: up at the end; copy 1: low throughout, one spike
    script = np.array([[0.1, 0.2], [0.95, 0.3], [0.2, 1.5], [0.95, 0.1], [1.0, 0.2], [0.92, 0.4]])
    fixed = Fixed()
    for m in made._measures.values():
        m.term = fixed
    for row in script:
        fixed.now = row
        made._book_measures(env.physics)
    got = made.episode_info(env.physics)
    v = script
    expected = {
        "best": v.max(0),
        "low": (v.min(0) <= 0.5).astype(float),
        "mean_last3": v[-3:].mean(0),
        "max_last_half_s": v[-2:].max(0),  # 0.1 s of 0.05 s steps
        "sum_last3": v[-3:].sum(0),
        "end": (v[-1] >= 0.9).astype(float),
        "held_last4": ((v[-4:] >= 0.9).sum(0) / 4 >= 0.75).astype(float),
        "held_all": ((v <= 0.5).sum(0) / len(v) >= 0.5).astype(float),
    }
    for name, want in expected.items():
        np.testing.assert_allclose(got[name], want, err_msg=name)
    assert got["held_last4"].tolist() == [1.0, 0.0] and got["end"].tolist() == [1.0, 0.0]
    env.close()


@pytest.mark.parametrize("measure, says", [
    ({"term": "tip_z", "above": 1, "below": 0}, "takes above or below, not both"),
    ({"term": "tip_z", "held": 0.5}, "held needs above or below"),
    ({"term": "tip_z", "above": 1, "held": 1.5}, "held must be a fraction in (0, 1]"),
    ({"term": "tip_z", "above": 1, "held": 0.5, "reduce": "max"}, "takes reduce or held"),
    ({"term": "tip_z", "last": 0}, "last must be a whole number of steps"),
    ({"term": "tip_z", "last": 3, "seconds": 1}, "takes last (steps) or seconds"),
])
def test_a_bad_measure_is_one_line(tmp_path, measure, says):
    with pytest.raises(ConfigError, match=says.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        task(tmp_path, terms={}, measures={"m": measure})


@pytest.mark.parametrize("term, says", [
    ({"distance": ["tip"]}, "must be {distance: [frame, frame]}"),
    ({"distance": ["tip", "nowhere"]}, "the model has no frame"),
    ({"distance": ["tip", "target"], "axes": ["w"]}, "axes must be a list of x, y and z"),
    ({"from": "tip"}, "must be {from: frame, to: frame}"),
    ({"distance": ["body:tip", "target"]}, "the model has no body 'tip'"),
])
def test_a_bad_frame_term_is_one_line(tmp_path, term, says):
    with pytest.raises(ConfigError, match=says.replace("[", r"\[").replace("{", r"\{").replace("}", r"\}")):
        task(tmp_path, terms={"bad": term})


def test_an_unnamed_actuator_is_named_by_its_joint(tmp_path):
    """Gymnasium's models leave their motors unnamed: ``task.actions`` names them by joint."""
    (tmp_path / "arm.xml").write_text(ARM.replace(
        '<actuator><motor name="elbow"', '<actuator><motor joint="shoulder" gear="1"/><motor name="elbow"'))
    robot = MjcfRobot(model=str(tmp_path / "arm.xml"))
    assert robot.actuators() == ["shoulder", "elbow"]
    made = DeclaredTask(robot=robot, observations={"tip_z": {"site_pos": "tip", "axis": "z"}},
                        actions={"values": {"shoulder": [-1.0, 1.0], "elbow": [0.5]}}, rewards={"t": {"alive": True}})
    env = RobotTaskEnv(made, num_envs=2, seed=0)
    td = env.reset()
    td["action"] = torch.tensor([0, 1])
    env.step(td)
    np.testing.assert_allclose(env.physics.ctrl, [[-1.0, 0.5], [1.0, 0.5]])
    env.close()
    with pytest.raises(ConfigError, match="the model has no actuator 'wrist'"):
        DeclaredTask(robot=MjcfRobot(model=str(tmp_path / "arm.xml")), observations={"z": {"site_pos": "tip"}},
                     actions={"values": {"wrist": [1.0]}}, rewards={"t": {"alive": True}})
