"""``BatchedPhysics`` steps narrow batches on the calling thread and wide ones on rollout's
thread pool (``POOL_FROM_S``): the results are the same either way, bit for bit, and the
choice follows the price of a copy-step measured on the calling thread."""

from __future__ import annotations

import numpy as np

from robots import physics as physics_module
from robots.physics import BatchedPhysics
from tasks.catalog import make_env


def test_a_step_on_the_pool_is_bit_for_bit_the_step_on_the_calling_thread():
    env = make_env("turtlebot", "maze", num_envs=1, seed=0)  # contacts and laser sensors
    model, substeps = env.physics.model, env.task.n_substeps
    env.close()
    pooled, alone = BatchedPhysics(model, 6, nthread=2), BatchedPhysics(model, 6, nthread=2)
    pooled._pooled_step = lambda copies, steps: True
    alone._pooled_step = lambda copies, steps: False
    rng = np.random.default_rng(0)
    for _ in range(30):
        controls = rng.uniform(-1, 1, pooled.ctrl.shape) * 5
        for batch in (pooled, alone):
            batch.ctrl[:] = controls
            batch.step(substeps)
    assert np.array_equal(pooled.state, alone.state)
    assert np.array_equal(pooled.sensordata, alone.sensordata)
    assert pooled.time[0] > 0
    pooled.close()
    alone.close()


def test_the_pool_takes_steps_whose_priced_work_reaches_pool_from(monkeypatch):
    env = make_env("cartpole", num_envs=1, seed=0)
    model = env.physics.model
    env.close()
    batch = BatchedPhysics(model, 4, nthread=2)
    runs = []
    for name in ("_pool", "_alone"):
        runner = getattr(batch, name)
        monkeypatch.setattr(batch, name, type("Spy", (), {
            "rollout": lambda self, *a, _r=runner, _n=name, **k: runs.append(_n) or _r.rollout(*a, **k),
            "close": lambda self, _r=runner: _r.close()})())

    for _ in range(physics_module.FIRST_ALONE + 3):  # 4 cart-poles are far below 2 ms of work
        batch.step(10)
    assert set(runs) == {"_alone"}
    assert batch._copy_step_s[10][0] > 0  # priced on the calling thread

    runs.clear()
    batch._copy_step_s[10][0] = physics_module.POOL_FROM_S  # as if a copy-step cost 2 ms
    for _ in range(physics_module.REPRICE_EVERY):
        batch.step(10)
    assert runs.count("_pool") == physics_module.REPRICE_EVERY - 1  # one in REPRICE_EVERY reprices
    assert runs[-1] == "_alone"
    batch.close()


def test_one_thread_never_wakes_a_pool():
    env = make_env("cartpole", num_envs=1, seed=0)
    batch = BatchedPhysics(env.physics.model, 3, nthread=1)
    env.close()
    batch._copy_step_s[10] = [1.0, 100]  # a copy-step priced at a second
    assert not batch._pooled_step(3, 10)
    batch.close()
