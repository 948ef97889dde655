"""Physics divergence: a copy whose simulation blows up ends its episode as
truncated, is reset alone and counted, and training goes on."""

import csv
import json
import logging

import mujoco
import numpy as np
import pytest
import torch

from learners.qlearn import QLearn
from runs.run import Run
from robots.physics import BatchedPhysics

HUGE_GAIN = 1e7  # N per unit command: about a third of the copies blow up per step


def unstable_cartpole(make, num_envs, seed=0):
    """Effort-controlled cart-pole whose motor gear (actuator gain) is made huge."""
    env = make(num_envs, seed=seed, control_type="effort")
    env.model.actuator_gear[:, 0] = HUGE_GAIN
    return env


def random_actions(seed):
    gen = torch.Generator().manual_seed(seed)
    return lambda env: torch.randint(0, env.task.n_actions, (env.num_envs,), generator=gen)


def all_finite(td):
    return all(torch.isfinite(v.float()).all() for v in td.values(True, True))


def test_a_normal_cartpole_never_diverges(make_cartpole_env):
    env = make_cartpole_env(8)
    act = random_actions(0)
    td = env.reset()
    for _ in range(300):
        td["action"] = act(env)
        _, td = env.step_and_maybe_reset(td)
        assert not env.physics.diverged.any()
    assert env.divergences == 0


def test_unstable_cartpole_truncates_diverged_copies_and_stays_finite(
        make_cartpole_env, caplog, capfd, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # MuJoCo's default handler would write MUJOCO_LOG.TXT here
    n = 16
    env = unstable_cartpole(make_cartpole_env, n)
    act = random_actions(1)
    td = env.reset()
    counted, mixed_steps = 0, 0
    with caplog.at_level(logging.WARNING, logger="tasks.env"):
        for _ in range(40):
            before = td["observation"].clone()
            td["action"] = act(env)
            stepped, td = env.step_and_maybe_reset(td)
            nxt = stepped["next"]
            div = torch.as_tensor(env.physics.diverged)
            counted += int(div.sum())
            mixed_steps += bool(0 < div.sum() < n)
            assert all_finite(stepped) and all_finite(td)
            assert np.isfinite(env.physics.state).all()
            # Diverged: truncated (not terminated), reward 0, observation as before the step.
            assert nxt["truncated"][div].all() and not nxt["terminated"][div].any()
            assert nxt["done"][div].all() and (nxt["reward"][div] == 0).all()
            assert torch.equal(nxt["observation"][div], before[div])
            # The others get the task's usual reward (+1 per step).
            assert (nxt["reward"][~div] == 1).all()
            # Every ended episode (diverged or not) was reset, those copies only.
            done = nxt["done"].reshape(n).numpy()
            assert (env.elapsed_steps[done] == 0).all() and (env.elapsed_steps[~done] > 0).all()
    assert env.divergences == counted > 20
    assert mixed_steps > 10  # copies diverge one by one, not the batch as a whole
    records = [r for r in caplog.records if r.name == "tasks.env"]
    assert len(records) == counted and all(r.levelno == logging.WARNING for r in records)
    assert f"({counted} divergences so far)" in records[-1].getMessage()
    assert "env copy" in records[0].getMessage()
    # MuJoCo's own per-event warnings neither reach the terminal nor a log file.
    out, err = capfd.readouterr()
    assert "unstable" not in out + err
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


def test_only_the_diverged_copies_are_reset_the_others_keep_their_state(make_cartpole_env):
    """Blow-ups planted in copies 1 (velocity beyond mjMAXVAL) and 2 (a NaN position)
    of one env; a twin env without them must match it exactly in copies 0 and 3."""
    env, twin = make_cartpole_env(4, seed=3), make_cartpole_env(4, seed=3)
    tds = [env.reset(), twin.reset()]
    for t in range(5):  # alternating pushes keep every pole up
        for k, e in enumerate((env, twin)):
            tds[k]["action"] = torch.full((4,), 1 - t % 2)
            _, tds[k] = e.step_and_maybe_reset(tds[k])
    env.physics.qvel[1, 0] = 1e12
    env.physics.qpos[2, 1] = np.nan
    for k, e in enumerate((env, twin)):
        tds[k]["action"] = torch.zeros(4, dtype=torch.int64)
        stepped, tds[k] = e.step_and_maybe_reset(tds[k])
        if e is env:
            nxt = stepped["next"]
    assert env.physics.diverged.tolist() == [False, True, True, False]
    assert not twin.physics.diverged.any()
    assert nxt["truncated"].reshape(-1).tolist() == [False, True, True, False]
    assert not nxt["terminated"].any() and all_finite(stepped) and all_finite(tds[0])
    assert env.divergences == 2 and twin.divergences == 0
    assert env.elapsed_steps.tolist() == [6, 0, 0, 6]
    np.testing.assert_array_equal(env.physics.state[[0, 3]], twin.physics.state[[0, 3]])
    assert np.isfinite(env.physics.state).all()
    assert np.all(np.abs(env.physics.qpos[[1, 2]]) <= 0.05 + 1e-12)  # freshly reset
    # Training-side view: the next step goes on normally for every copy.
    tds[0]["action"] = torch.ones(4, dtype=torch.int64)
    env.step_and_maybe_reset(tds[0])
    assert not env.physics.diverged.any() and env.divergences == 2


TINY = """
<mujoco>
  <option gravity="0 0 0"/>
  <worldbody><body><joint name="j" type="slide" range="-1 1" limited="true"/>
    <geom size=".1"/></body></worldbody>
  <actuator><motor joint="j"/></actuator>
  <sensor><jointvel joint="j"/></sensor>
</mujoco>
"""


def test_batched_physics_rolls_diverged_copies_back_to_their_state_before_the_step():
    model = mujoco.MjModel.from_xml_string(TINY)
    physics = BatchedPhysics(model, 3, nthread=1)
    physics.ctrl[:] = [[1.0], [1.0], [-1.0]]
    physics.step(5)
    assert not physics.diverged.any()
    before_state, before_sensor = physics.state.copy(), physics.sensordata.copy()
    physics.ctrl[1] = 1e12  # beyond mjMAXVAL: MuJoCo stops this copy after a substep
    physics.step(5)
    assert physics.diverged.tolist() == [False, True, False]
    np.testing.assert_array_equal(physics.state[1], before_state[1])
    np.testing.assert_array_equal(physics.sensordata[1], before_sensor[1])
    assert (physics.time[[0, 2]] == pytest.approx(10 * model.opt.timestep))
    assert physics.sensordata[0, 0] > before_sensor[0, 0]  # the others moved on
    physics.ctrl[1] = 1.0
    physics.step(5)
    assert not physics.diverged.any()
    physics.close()


def test_a_diverged_copy_among_some_stepping_rolls_back_and_the_held_ones_stay():
    """With copies on hold (a waiting run's block), only the stepping ones step: a diverged
    one among them is flagged and keeps its state, the held ones keep theirs, the rest move."""
    model = mujoco.MjModel.from_xml_string(TINY)
    physics = BatchedPhysics(model, 4, nthread=1)
    physics.ctrl[:] = [[1.0], [1.0], [-1.0], [1.0]]
    physics.hold(np.array([False, False, False, True]))
    physics.step(5)
    assert not physics.diverged.any()
    before_state, before_sensor = physics.state.copy(), physics.sensordata.copy()
    physics.ctrl[1] = 1e12
    physics.step(5)
    assert physics.diverged.tolist() == [False, True, False, False]
    np.testing.assert_array_equal(physics.state[[1, 3]], before_state[[1, 3]])
    np.testing.assert_array_equal(physics.sensordata[[1, 3]], before_sensor[[1, 3]])
    assert (physics.time[[0, 2]] == pytest.approx(10 * model.opt.timestep)) and physics.time[3] == 0
    physics.ctrl[1] = 1.0
    physics.step(5)
    assert not physics.diverged.any() and physics.time[1] > before_state[1, 0]
    physics.close()


def test_qlearning_keeps_training_on_an_unstable_cartpole(tmp_path, monkeypatch):
    """A run through ``train.py`` whose effort-controlled cart-pole has a huge motor gear."""
    from runs import lifecycle
    from tests.inprocess import train_in_process

    def unstable(*args, **kwargs):
        env = real(*args, **kwargs)
        env.model.actuator_gear[:, 0] = HUGE_GAIN
        made.append(env)
        return env

    real, made, episodes = lifecycle.build_env, [], 300
    monkeypatch.setattr(lifecycle, "build_env", unstable)
    member = train_in_process(tmp_path, "~tuned", "seed=0", "num_envs=4", f"max_episodes={episodes}",
                              "task.control_type=effort", "eval_episodes=0", "stop_when_solved=false", "quiet=true",
                              "learner.alpha=0.5", "learner.gamma=0.9", "learner.epsilon=0.5", "learner.number_splits=4")
    env, q = made[0], member.learner
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["episodes"] == episodes  # ran to the end of its budget
    assert env.divergences > 20
    # Diverged episodes are recorded as truncated (not terminated) ones.
    with open(tmp_path / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == episodes
    truncated = sum(row["terminated"] == "0" for row in rows)
    # (no episode reaches the time limit here; the last step may end some unrecorded ones)
    assert env.divergences - env.num_envs < truncated <= env.divergences
    assert all(np.isfinite(float(row["reward"])) for row in rows)
    assert torch.isfinite(q.table[0]).all() and q.visited[0].any()
