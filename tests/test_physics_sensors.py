"""``BatchedPhysics`` computes sensors in a step's last substep only: the readings and the
states are those of stepping every substep with sensors on (to the constraint solver's
tolerance), and the model's own flags are left as they were."""

from __future__ import annotations

import mujoco
import numpy as np

from tasks.catalog import make_env


def test_sensors_in_the_last_substep_read_what_every_substep_would():
    env = make_env("turtlebot", "maze", num_envs=4, seed=3)
    physics, model = env.physics, env.physics.model
    assert model.nsensordata > 0
    rng = np.random.default_rng(0)
    data = mujoco.MjData(model)
    for _ in range(10):
        physics.ctrl[:] = rng.uniform(-1, 1, physics.ctrl.shape) * 5
        start, ctrl = physics.state.copy(), physics.ctrl.copy()
        physics.step(25)
        assert model.opt.disableflags == 0  # the flag is the step's, not the model's
        for i in range(physics.num_envs):  # the reference: all 25 substeps with sensors on
            mujoco.mj_setState(model, data, start[i], mujoco.mjtState.mjSTATE_FULLPHYSICS)
            data.qacc_warmstart[:] = 0  # each step starts its solver cold
            data.ctrl[:] = ctrl[i]
            for _ in range(25):
                mujoco.mj_step(model, data)
                if _ == 23:
                    mujoco.mj_forward(model, data)  # the readings at the last substep's start
                    sensors = data.sensordata.copy()
            np.testing.assert_allclose(physics.qpos[i], data.qpos, atol=1e-6)
            np.testing.assert_allclose(physics.qvel[i], data.qvel, atol=1e-4)
            np.testing.assert_allclose(physics.sensordata[i], sensors, atol=1e-6)
    env.close()
