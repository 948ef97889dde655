"""A batch of copies of one compiled MuJoCo model, stepped together.

The whole batch's physics state lives in one ``(num_envs, nstate)`` array
(MuJoCo's ``mjSTATE_FULLPHYSICS`` layout); controls in ``(num_envs, nu)``.
``step`` advances every copy by the same number of substeps in one call to
``mujoco.rollout``, whose C thread pool does the work: no per-copy Python.
Robots and tasks read and write the batch through the named views ``qpos``,
``qvel``, ``ctrl`` and ``sensordata``.
"""

from __future__ import annotations

import os

import mujoco
import numpy as np
from mujoco import rollout

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS


def default_threads() -> int:
    """Threads for the rollout pool: the cores this process may use, at most 8."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - non-Linux
        cores = os.cpu_count() or 1
    return max(1, min(8, cores))


class BatchedPhysics:
    """``num_envs`` independent copies of ``model``.

    Sensor readings (``sensordata``) are the ones MuJoCo computed at the start
    of the last substep of a ``step`` (one ``timestep`` old), and exact after a
    ``reset``.  Joint positions and velocities (``qpos``, ``qvel``) are exact.
    """

    def __init__(self, model: mujoco.MjModel, num_envs: int, nthread: int | None = None):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.model = model
        self.num_envs = num_envs
        nthread = default_threads() if nthread is None else nthread
        nthread = max(1, min(nthread, num_envs))
        self._datas = [mujoco.MjData(model) for _ in range(nthread)]
        self._models = [model] * num_envs
        # A pool only pays off with more than one thread.
        self._pool = rollout.Rollout(nthread=nthread if nthread > 1 else 0)

        data = self._datas[0]
        mujoco.mj_forward(model, data)
        self.nstate = mujoco.mj_stateSize(model, _FULL)
        self._initial = np.empty(self.nstate)
        mujoco.mj_getState(model, data, self._initial, _FULL)
        self._initial_sensordata = data.sensordata.copy()

        self.state = np.tile(self._initial, (num_envs, 1))
        self.ctrl = np.zeros((num_envs, model.nu))
        self.sensordata = np.tile(self._initial_sensordata, (num_envs, 1))
        # Views into ``state`` (FULLPHYSICS order: time, qpos, qvel, act, ...).
        self.time = self.state[:, 0]
        self.qpos = self.state[:, 1 : 1 + model.nq]
        self.qvel = self.state[:, 1 + model.nq : 1 + model.nq + model.nv]
        self._warmstart = np.zeros((num_envs, model.nv))
        self._out_state: np.ndarray | None = None
        self._out_sensor: np.ndarray | None = None
        self._control: np.ndarray | None = None

    @property
    def timestep(self) -> float:
        return float(self.model.opt.timestep)

    def step(self, nsubsteps: int) -> None:
        """Advances every copy by ``nsubsteps`` physics steps with ``ctrl`` held."""
        if self._out_state is None or self._out_state.shape[1] != nsubsteps:
            shape = (self.num_envs, nsubsteps)
            self._out_state = np.empty(shape + (self.nstate,))
            self._out_sensor = np.empty(shape + (self.model.nsensordata,))
            self._control = np.empty(shape + (self.model.nu,))
        self._control[:] = self.ctrl[:, None, :]
        # Arguments are already in rollout's final form, so its checks are skipped.
        self._pool.rollout(
            self._models,
            self._datas,
            self.state,
            self._control,
            nstep=nsubsteps,
            initial_warmstart=self._warmstart,
            state=self._out_state,
            sensordata=self._out_sensor,
            skip_checks=True,
        )
        self.state[:] = self._out_state[:, -1]
        if self.model.nsensordata:
            self.sensordata[:] = self._out_sensor[:, -1]

    def reset(self, mask: np.ndarray) -> None:
        """Puts the copies where ``mask`` is true back to the model's initial state."""
        self.state[mask] = self._initial
        self.ctrl[mask] = 0.0
        self.sensordata[mask] = self._initial_sensordata

    def forward(self, mask: np.ndarray) -> None:
        """Recomputes sensor readings of the masked copies from their current state."""
        if not self.model.nsensordata:
            return
        data = self._datas[0]
        for i in np.flatnonzero(mask):
            mujoco.mj_setState(self.model, data, self.state[i], _FULL)
            data.ctrl[:] = self.ctrl[i]
            mujoco.mj_forward(self.model, data)
            self.sensordata[i] = data.sensordata

    def load_into(self, data: mujoco.MjData, index: int = 0) -> None:
        """Copies copy ``index`` into ``data`` (for rendering), with derived quantities."""
        mujoco.mj_setState(self.model, data, self.state[index], _FULL)
        data.ctrl[:] = self.ctrl[index]
        mujoco.mj_forward(self.model, data)

    def close(self) -> None:
        self._pool.close()
