"""``RobotTaskEnv.step_and_maybe_reset`` restarts ended copies in one pass; it must
give exactly what TorchRL's generic path (``EnvBase``: step, step_mdp, maybe_reset
with a partial ``_reset``) gives, to trainers, ``rollout`` and collectors alike:
a done transition keeps its true terminal observation in ``("next", "observation")``
and the next step's input holds the new episode's first observation."""

import numpy as np
import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.envs import EnvBase

from tasks import factory
from tasks import catalog
from tasks.env import RobotTaskEnv


class GenericPathEnv(RobotTaskEnv):
    """The same env through TorchRL's own step-and-reset machinery (the reference)."""

    _step_and_maybe_reset = EnvBase._step_and_maybe_reset


def make_pair(robot, num_envs, seed=0, max_episode_steps=None):
    cfg = catalog.compose(robot)

    def build(cls):
        task = factory.build_task(cfg)
        if max_episode_steps is not None:
            task.max_episode_steps = max_episode_steps
        return cls(task, num_envs=num_envs, seed=seed)
    return build(RobotTaskEnv), build(GenericPathEnv)


def assert_same(a, b):
    keys_a, keys_b = set(a.keys(True, True)), set(b.keys(True, True))
    assert keys_a == keys_b
    for key in keys_a:
        x, y = a.get(key), b.get(key)
        assert x.dtype == y.dtype and x.shape == y.shape, key
        assert torch.equal(x, y), key


def assert_same_env_state(env, ref):
    np.testing.assert_array_equal(env.physics.state, ref.physics.state)
    np.testing.assert_array_equal(env.elapsed_steps, ref.elapsed_steps)
    assert env._rng.bit_generator.state == ref._rng.bit_generator.state
    assert env.ended_info.keys() == ref.ended_info.keys()
    for key in env.ended_info:
        np.testing.assert_array_equal(env.ended_info[key], ref.ended_info[key])


@pytest.mark.parametrize("robot, n, steps", [
    ("cartpole", 6, 80), ("cartpole", 1, 80), ("cube", 6, 40), ("turtlebot", 6, 40)])
def test_one_pass_step_and_reset_equals_torchrl_generic_path(robot, n, steps):
    """Step by step, as the trainers call it: both tensordicts, every entry (a policy's
    extra entries too: zeroed in restarted rows as TorchRL pads them in a partial
    reset, kept when every copy restarts, as with one copy), the env's counters,
    random generator and ``ended_info``."""
    env, ref = make_pair(robot, n, seed=3, max_episode_steps=25)  # truncations too
    gen = torch.Generator().manual_seed(0)
    tds = [env.reset(), ref.reset()]
    ended = 0
    for _ in range(steps):
        action = torch.randint(0, env.task.n_actions, (n,), generator=gen)
        extra = torch.rand(n, 2, generator=gen)
        outs = []
        for k, e in enumerate((env, ref)):
            tds[k]["action"] = action.clone()
            tds[k]["policy_extra"] = extra.clone()
            tds[k]["policy"] = TensorDict(hidden=extra.clone() + 1, batch_size=[n])
            outs.append(e.step_and_maybe_reset(tds[k]))
        (out, nxt), (ref_out, ref_nxt) = outs
        assert_same(out, ref_out)
        assert_same(nxt, ref_nxt)
        assert_same_env_state(env, ref)
        done = out["next", "done"].reshape(n)
        ended += int(done.sum())
        if done.any():
            assert not nxt["done"].any()
        if done.any() and not done.all():
            assert (nxt["action"][done] == 0).all() and (nxt["policy", "hidden"][done] == 0).all()
        tds = [nxt, ref_nxt]
    assert ended >= 3


def test_rollout_keeps_terminal_observations_and_restarts_from_reset_ones():
    n, steps = 4, 120
    env, ref = make_pair("cartpole", n, seed=1)
    torch.manual_seed(0)
    data = env.rollout(steps, break_when_any_done=False)
    torch.manual_seed(0)
    assert_same(data, ref.rollout(steps, break_when_any_done=False))
    check_restarts(data, env.task)


def check_restarts(data, task):
    """``data`` (copies x time): done rows keep the terminal observation, the next row
    starts from a reset one; rows that did not end chain their observations."""
    done = data["next", "done"].squeeze(-1)
    terminated = data["next", "terminated"].squeeze(-1)
    obs, next_obs = data["observation"], data["next", "observation"]
    i, t = torch.nonzero(done[:, :-1], as_tuple=True)
    assert len(i) >= 3
    # Reset observations lie within the start noise; terminal ones past a limit.
    assert (obs[i, t + 1].abs() <= task.reset_noise + 1e-6).all()
    term = next_obs[terminated]
    beyond = (term[:, 0].abs() >= task.max_base_pose_x) | (term[:, 2].abs() >= task.max_pole_angle)
    assert beyond.all() and len(term) >= 3
    assert not torch.equal(obs[i, t + 1], next_obs[i, t])
    i, t = torch.nonzero(~done[:, :-1], as_tuple=True)
    assert torch.equal(obs[i, t + 1], next_obs[i, t])


def test_collector_data_matches_the_generic_path_and_restarts_correctly():
    n, frames = 4, 4 * 100
    batches = []
    for env in make_pair("cartpole", n, seed=2):
        torch.manual_seed(0)
        collector = Collector(env, None, frames_per_batch=frames, total_frames=2 * frames)
        batches.append([batch.clone() for batch in collector])
        collector.shutdown()
    task = factory.build_task(catalog.compose("cartpole"))
    for ours, reference in zip(*batches):
        assert_same(ours, reference)
        check_restarts(ours, task)


def test_outputs_are_fresh_tensors_every_call(make_cartpole_env):
    """Nothing returned is a reused buffer (``rollout`` and collectors stack the calls'
    tensordicts), and the next input never shares the step's restarted rows."""
    n = 8
    env = make_cartpole_env(n, seed=0)
    td = env.reset()
    kept, seen, restarted = [], set(), 0
    for k in range(60):
        td["action"] = torch.full((n,), k % 2)
        out, td = env.step_and_maybe_reset(td)
        for key in ("observation", "reward", "done", "terminated", "truncated"):
            kept.append(out["next", key])  # alive: a freed buffer's address may come back
            assert kept[-1].data_ptr() not in seen
            seen.add(kept[-1].data_ptr())
        if out["next", "done"].any():
            restarted += 1
            terminal = out["next", "observation"].clone()
            td["observation"].add_(1.0)
            assert torch.equal(out["next", "observation"], terminal)
    assert restarted >= 2


def test_step_alone_never_resets(make_cartpole_env):
    """Only ``step_and_maybe_reset`` restarts copies: ``step`` leaves an ended episode
    as it ended (this is no TorchRL auto-reset env), as ``adapters.gym_env`` and the
    evaluation rely on."""
    env = make_cartpole_env(2, seed=0)
    td = env.reset()
    for k in range(200):
        td["action"] = torch.ones(2, dtype=torch.int64)
        nxt = env.step(td)["next"]
        if nxt["done"].any():
            break
        td = nxt
    assert nxt["done"].any()
    ended = nxt["done"].reshape(2).numpy()
    assert (env.elapsed_steps[ended] == k + 1).all()
    # The physics still holds the terminal state the observation reports.
    now = torch.from_numpy(env.task.observation(env.physics).astype(np.float32))
    assert torch.equal(nxt["observation"], now)
