"""A batch of copies of one compiled MuJoCo model, stepped together.

The whole batch's physics state lives in one ``(num_envs, nstate)`` array
(MuJoCo's ``mjSTATE_FULLPHYSICS`` layout); controls in ``(num_envs, nu)``.
``step`` advances every copy by the same number of substeps in one call to
``mujoco.rollout``: no per-copy Python. A step whose work is large enough runs on
rollout's C thread pool, a smaller one on the calling thread (see ``POOL_FROM_S``).
Robots and tasks read and write the batch through the named views ``qpos``,
``qvel``, ``ctrl`` and ``sensordata``.

Divergence. When MuJoCo finds a copy unstable during a substep (a NaN, an
infinity or a value beyond ``mjMAXVAL`` in its positions, velocities,
accelerations or controls) it issues a warning and, for positions, velocities
and accelerations, resets that copy's data to the model's initial state;
``mujoco.rollout`` then stops stepping that copy (on any warning, also a full
contact buffer) and repeats its last state for the remaining substeps. Either
way the copy's clock does not read ``time + nsubsteps * timestep`` at the end
of the step. ``step`` checks exactly that, and that the final state and
sensor readings are finite and within ``mjMAXVAL`` (MuJoCo only checks a
state at the start of the next substep), all vectorised over the batch.
Copies that fail are rolled back to their state before the step and flagged
in ``diverged``; the caller (``tasks.env.RobotTaskEnv``) ends their episodes.
MuJoCo's own instability warnings go to this module's logger at DEBUG level
(the env reports each divergence with its copy and step instead).
"""

from __future__ import annotations

import logging
import math
import os
import time

import mujoco
import numpy as np
from mujoco import rollout

_FULL = mujoco.mjtState.mjSTATE_FULLPHYSICS
_NO_SENSORS = int(mujoco.mjtDisableBit.mjDSBL_SENSOR)
_MAXVAL = float(mujoco.mjMAXVAL)  # MuJoCo's own "huge value" threshold
_min, _max = np.minimum.reduce, np.maximum.reduce  # (array, None): over all its entries
_log = logging.getLogger(__name__)

POOL_FROM_S = 2e-3
"""A step runs on the thread pool when its copies would take at least this many seconds on one
thread (a copy-step priced by the steps made on the calling thread). Waking the pool's threads
costs a few hundred microseconds a step when other work runs between steps (a learner's), and
the pool always costs more CPU time than one thread. Measured on 2 cores (``python
bench/env_throughput.py --pool``, steps 2 ms apart, 2026-12-06), microseconds a step on the
calling thread against pooled: the cart-pole's 10 copies 642 against 708, the TurtleBot's 10
1,163 against 1,220 and its 20 2,251 against 1,771, the cube's 10 3,747 against 2,338, the
pendulum's 80 645 against 1,381. Either way each copy's result is the same, bit for bit."""
REPRICE_EVERY = 100
"""A pooled step in this many runs on the calling thread, keeping the price of a copy-step current."""
FIRST_ALONE = 5
"""The first steps of a length that run on the calling thread (and price it) whatever their width."""


def _mujoco_warning(message: str) -> None:
    """MuJoCo's warning handler: instability messages are DEBUG (the caller of
    ``BatchedPhysics.step`` reports each divergence); anything else a WARNING."""
    if "simulation is unstable" in message:
        _log.debug("MuJoCo: %s", message)
    else:
        _log.warning("MuJoCo: %s", message)


def route_mujoco_warnings() -> None:
    """Sends MuJoCo's warnings (process-wide) to Python logging via this module's
    logger, instead of stdout and ``MUJOCO_LOG.TXT`` or dm_control's absl line
    per event (one per diverged copy: thousands on an unstable model)."""
    if mujoco.get_mju_user_warning() is not _mujoco_warning:
        mujoco.set_mju_user_warning(_mujoco_warning)


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
    ``diverged`` (bool, ``(num_envs,)``) marks the copies whose last ``step``
    diverged; they hold their state from before that step.
    """

    def __init__(self, model: mujoco.MjModel, num_envs: int, nthread: int | None = None):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.model = model
        self.num_envs = num_envs
        self._threads = max(1, min(default_threads() if nthread is None else nthread, num_envs))
        self._datas = [mujoco.MjData(model) for _ in range(self._threads)]
        self._models = [model] * num_envs
        # A pool only pays off with more than one thread, and on wide enough steps.
        self._pool = rollout.Rollout(nthread=self._threads if self._threads > 1 else 0)
        self._alone = rollout.Rollout(nthread=0)
        self._copy_step_s: dict[int, list] = {}  # nsubsteps -> [seconds a copy-step on one thread, steps priced]
        self._pooled = 0  # pooled steps since the last one on the calling thread

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
        self._nsensordata = model.nsensordata
        self._opt = model.opt  # a live view of the model's options
        self._elapsed = np.empty(num_envs)
        self._arrays: dict[int, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._none_diverged = np.zeros(num_envs, dtype=bool)
        self._none_diverged.flags.writeable = False
        self.diverged = self._none_diverged
        self._held = np.zeros(num_envs, dtype=bool)
        self._stepping: np.ndarray | None = None  # indices of the copies that step (None: all)
        route_mujoco_warnings()

    def hold(self, mask: np.ndarray) -> None:
        """From now on the ``mask`` copies no longer step: their state stays as it is (the
        copies of a finished run in a batch of runs); every other copy steps as before."""
        self._held |= np.asarray(mask, dtype=bool)
        self._stepping = np.flatnonzero(~self._held) if self._held.any() else None

    def release(self, mask: np.ndarray | None = None) -> None:
        """The ``mask`` copies (None: every copy) step again (see :meth:`hold`)."""
        if mask is None:
            self._held[:] = False
        else:
            self._held &= ~np.asarray(mask, dtype=bool)
        self._stepping = np.flatnonzero(~self._held) if self._held.any() else None

    @property
    def timestep(self) -> float:
        return float(self.model.opt.timestep)

    def step(self, nsubsteps: int) -> None:
        """Advances every copy by ``nsubsteps`` physics steps with ``ctrl`` held.

        Copies that diverge are flagged in ``diverged`` and keep their state
        and sensor readings from before the step (see the module docstring).
        Copies put on :meth:`hold` do not step.
        """
        if self._stepping is not None:
            return self._step_some(nsubsteps, self._stepping)
        last, sensor = self._rollout(self.state, self.ctrl, nsubsteps, self._warmstart)
        elapsed = np.subtract(last[:, 0], self.time, out=self._elapsed)
        lo, hi = self._clock_bounds(nsubsteps)
        if not self._take_if_fine(slice(None), elapsed, last, sensor, lo, hi):
            self._keep_good((elapsed < lo) | (elapsed > hi), last, sensor)

    def _step_some(self, nsubsteps: int, some: np.ndarray) -> None:
        """:meth:`step` for the copies ``some`` (indices) only; the others keep their state."""
        if not len(some):
            self.diverged = self._none_diverged
            return
        stepped, stepped_sensor = self._rollout(self.state[some], self.ctrl[some], nsubsteps,
                                                self._warmstart[some])
        lo, hi = self._clock_bounds(nsubsteps)
        if self._take_if_fine(some, np.subtract(stepped[:, 0], self.time[some]), stepped, stepped_sensor, lo, hi):
            return
        last = self.state.copy()
        last[some] = stepped
        sensor = None
        if self._nsensordata:
            sensor = self.sensordata.copy()
            sensor[some] = stepped_sensor
        elapsed = np.full(self.num_envs, nsubsteps * self._opt.timestep)
        elapsed[some] = last[some, 0] - self.time[some]
        self._keep_good((elapsed < lo) | (elapsed > hi), last, sensor)
        if not self.diverged.any():
            self.diverged = self._none_diverged

    def _clock_bounds(self, nsubsteps: int) -> tuple[float, float]:
        """How far a copy's clock may move in ``nsubsteps`` substeps: MuJoCo adds the timestep
        once per substep, so a copy whose clock moved by half a timestep more or less was
        reset or stopped by a warning."""
        timestep = self._opt.timestep
        return (nsubsteps - 0.5) * timestep, (nsubsteps + 0.5) * timestep

    def _take_if_fine(self, rows: slice | np.ndarray, elapsed: np.ndarray, states: np.ndarray,
                      sensors: np.ndarray | None, lo: float, hi: float) -> bool:
        """A step's fast path: if every stepped copy is fine (its clock moved by ``lo`` to
        ``hi``, its state within mjMAXVAL and its sensors finite), the ``rows`` take their
        ``states`` and ``sensors``; whether they did. NaN fails every comparison, so these
        few reductions (the ufuncs' own: no Python frames) only pass when all is fine."""
        if not (_min(elapsed, None) >= lo and _max(elapsed, None) <= hi
                and -_MAXVAL <= _min(states, None) and _max(states, None) <= _MAXVAL
                and (sensors is None or math.isfinite(_min(sensors, None) + _max(sensors, None)))):
            return False
        self.diverged = self._none_diverged
        self.state[rows] = states
        if sensors is not None:
            self.sensordata[rows] = sensors
        return True

    def _rollout(self, initial: np.ndarray, ctrl: np.ndarray, nsubsteps: int,
                 warmstart: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """``nsubsteps`` substeps of the copies starting at ``initial`` (rows) with ``ctrl``
        held: their final states and the sensor readings of the last substep (None without
        sensors). Sensors are computed in that last substep only: only its readings are
        kept, and a TurtleBot's laser rays computed in every substep would be most of its step
        (``bench/env_throughput.py``). Sensors do not act on the dynamics; the last substep starts its constraint
        solver cold (as every step already does), which can move the state by the solver's
        tolerance."""
        copies, steps = len(initial), nsubsteps
        pooled = self._pooled_step(copies, steps)
        start = time.perf_counter()
        models = self._models[:copies]
        if self._nsensordata and nsubsteps > 1:
            flags = self._opt.disableflags
            self._opt.disableflags = flags | _NO_SENSORS
            try:
                initial = self._substeps(models, initial, ctrl, nsubsteps - 1, warmstart, pooled)[0][:, -1]
            finally:
                self._opt.disableflags = flags
            nsubsteps = 1
        states, sensors = self._substeps(models, np.ascontiguousarray(initial), ctrl, nsubsteps, warmstart, pooled)
        if not pooled and self._threads > 1:  # the price (an average of the latest steps', the last weighing a fifth)
            price = self._copy_step_s.setdefault(steps, [0.0, 0])
            seconds = (time.perf_counter() - start) / copies
            price[0] = seconds if not price[1] else 0.8 * price[0] + 0.2 * seconds
            price[1] += 1
        return states[:, -1], sensors[:, -1] if self._nsensordata else None

    def _pooled_step(self, copies: int, nsubsteps: int) -> bool:
        """Whether a step of ``copies`` runs on the thread pool: with more than one thread, when
        their copy-steps' price on the calling thread adds up to ``POOL_FROM_S``; the first
        ``FIRST_ALONE`` steps of a length, and one pooled step in ``REPRICE_EVERY``, run on the
        calling thread (and price it)."""
        price = self._copy_step_s.get(nsubsteps)
        if self._threads < 2 or price is None or price[1] < FIRST_ALONE or copies * price[0] < POOL_FROM_S:
            return False
        self._pooled = (self._pooled + 1) % REPRICE_EVERY
        return self._pooled != 0

    def _substeps(self, models: list, initial: np.ndarray, ctrl: np.ndarray, nsubsteps: int,
                  warmstart: np.ndarray, pooled: bool) -> tuple[np.ndarray, np.ndarray]:
        """One ``mujoco.rollout`` call (on the thread pool, or the calling thread): every
        substep's states and sensor readings (the buffers', overwritten by the next call of
        this shape)."""
        out_state, out_sensor, control = self._buffers(len(initial), nsubsteps)
        control[:] = ctrl[:, None, :]
        # Arguments are already in rollout's final form, so its checks are skipped.
        runner, datas = (self._pool, self._datas) if pooled else (self._alone, self._datas[:1])
        runner.rollout(models, datas, initial, control, nstep=nsubsteps,
                       initial_warmstart=warmstart, state=out_state, sensordata=out_sensor,
                       skip_checks=True)
        return out_state, out_sensor

    def _buffers(self, copies: int, nsubsteps: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``mujoco.rollout``'s output (states, sensor readings) and control arrays for
        ``copies`` and ``nsubsteps``: the first ``copies`` rows (contiguous) of arrays for every
        copy, allocated once per ``nsubsteps`` and reused (the copies still stepping, one fewer
        at each episode that ends, would otherwise keep arrays of every width they passed)."""
        if nsubsteps not in self._arrays:
            shape = (self.num_envs, nsubsteps)
            self._arrays[nsubsteps] = (np.empty(shape + (self.nstate,)), np.empty(shape + (self._nsensordata,)),
                                       np.empty(shape + (self.model.nu,)))
        return tuple(array[:copies] for array in self._arrays[nsubsteps])

    def _keep_good(self, diverged: np.ndarray, last: np.ndarray, sensor: np.ndarray | None) -> None:
        """The slow path of a step where some copy failed: ``diverged`` (the copies whose
        clock is off) widened by non-finite or huge states and sensors; the good copies
        take the step's results, the diverged ones keep their state from before it (or
        the initial state if even that was bad)."""
        diverged |= ~(np.abs(last) <= _MAXVAL).all(axis=1)
        if sensor is not None:
            diverged |= ~np.isfinite(sensor).all(axis=1)
        self.diverged = diverged
        ok = ~diverged
        self.state[ok] = last[ok]
        if sensor is not None:
            self.sensordata[ok] = sensor[ok]
        bad = diverged & ~(np.abs(self.state) <= _MAXVAL).all(axis=1)
        bad |= diverged & ~np.isfinite(self.sensordata).all(axis=1)
        if bad.any():
            self.reset(bad)

    def reset(self, mask: np.ndarray) -> None:
        """Puts the copies where ``mask`` is true back to the model's initial state."""
        self.state[mask] = self._initial
        self.ctrl[mask] = 0.0
        if self._nsensordata:
            self.sensordata[mask] = self._initial_sensordata

    def forward(self, mask: np.ndarray) -> None:
        """Recomputes sensor readings of the masked copies from their current state."""
        if not self._nsensordata:
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
        self._alone.close()
