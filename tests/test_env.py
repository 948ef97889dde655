"""The batched TorchRL environment: specs, seeding, partial resets, done flags."""

import numpy as np
import pytest
import torch
from torchrl.envs.utils import check_env_specs


@pytest.mark.parametrize("num_envs", [1, 8])
def test_check_env_specs(make_cartpole_env, num_envs):
    env = make_cartpole_env(num_envs)
    check_env_specs(env)
    assert env.batch_size == torch.Size([num_envs])
    assert set(env.full_done_spec.keys()) == {"done", "terminated", "truncated"}


def rollout_obs(env, seed, steps=150):
    env.set_seed(seed)
    gen = torch.Generator().manual_seed(0)
    td = env.reset()
    obs = []
    for _ in range(steps):
        td["action"] = torch.randint(0, env.task.n_actions, (env.num_envs,), generator=gen)
        stepped, td = env.step_and_maybe_reset(td)
        obs.append(stepped["next", "observation"])
    return torch.stack(obs)


def test_same_seed_identical_different_seed_different(make_cartpole_env):
    a = rollout_obs(make_cartpole_env(4), seed=7)
    b = rollout_obs(make_cartpole_env(4), seed=7)
    c = rollout_obs(make_cartpole_env(4), seed=8)
    assert torch.equal(a, b)
    assert not torch.allclose(a, c)


def test_batch_copies_are_independent_of_batch_size(make_cartpole_env):
    """Copy 0 of a batch evolves exactly like a lone copy given the same start and actions."""
    single, batch = make_cartpole_env(1), make_cartpole_env(5)
    single.reset()
    batch.reset()
    batch.physics.state[:] = single.physics.state[0]
    for k in range(40):
        action = torch.tensor([k % 2])
        single.task.apply_action(single.physics, action.numpy())
        batch.task.apply_action(batch.physics, action.repeat(5).numpy())
        single.physics.step(single.task.n_substeps)
        batch.physics.step(batch.task.n_substeps)
    np.testing.assert_array_equal(batch.physics.state[0], single.physics.state[0])
    np.testing.assert_array_equal(batch.physics.state[4], single.physics.state[0])


def test_partial_reset_touches_only_masked_copies(make_cartpole_env):
    env = make_cartpole_env(4)
    td = env.reset()
    for _ in range(5):
        td["action"] = torch.ones(4, dtype=torch.int64)
        td = env.step(td)["next"]
    before = env.physics.state.copy()
    mask = torch.tensor([True, False, True, False]).unsqueeze(-1)
    td.set("_reset", mask)
    env.reset(td)
    after = env.physics.state
    np.testing.assert_array_equal(after[[1, 3]], before[[1, 3]])
    assert not np.allclose(after[[0, 2]], before[[0, 2]])
    assert (env.elapsed_steps == np.array([0, 5, 0, 5])).all()
    assert np.all(np.abs(env.physics.qpos[[0, 2]]) <= 0.05 + 1e-12)


def test_render_frame_is_an_image_of_the_scene(make_cartpole_env):
    env = make_cartpole_env(1)
    env.reset()
    frame = env.render(160, 120, camera="side")
    assert frame.shape == (120, 160, 3) and frame.dtype == np.uint8
    # The cart and pole colours differ from the floor and sky: the frame is not blank.
    assert frame.reshape(-1, 3).std(0).min() > 5
