"""The DQN family: variants are configs of one learner, and the learner learns."""

from pathlib import Path

import numpy as np
import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf
from tensordict import TensorDict

from runs.checkpoint import CheckpointError, load_model, save_model
from learners.base import StateMismatch
from learners.dqn import DQN
from learners.transitions import Transitions, unpack
from runs.evaluate import evaluate
from tests.inprocess import train_in_process
from runs.run import Run
from learners.schedules import LinearEpsilon
from runs.training_state import seed_everything
from robots.cartpole import CartPole
from tasks.env import RobotTaskEnv
from tasks.stay_up import StayUp

CONF = Path(__file__).resolve().parents[1] / "conf" / "learner"


def variant(name: str, **overrides) -> DQN:
    cfg = OmegaConf.load(CONF / f"{name}.yaml")
    for key, value in overrides.items():
        OmegaConf.update(cfg, key, value)
    return instantiate(cfg, _convert_="all")


def test_variants_build_the_networks_of_the_seed_table():
    task = StayUp(CartPole())
    expected = {"n1try": ([4, 24, 48, 2], torch.nn.Tanh), "mbalunovic": ([4, 16, 16, 2], torch.nn.ReLU),
                "ruippeixotog": ([4, 12, 12, 2], torch.nn.ReLU)}
    for name, (widths, act) in expected.items():
        learner = variant(name)
        learner.build(task)
        linears = [m for m in learner.actor.modules() if isinstance(m, torch.nn.Linear)]
        assert [linears[0].in_features] + [m.out_features for m in linears] == widths
        assert any(isinstance(m, act) for m in learner.actor.modules())
    assert variant("mbalunovic").target_update == 100
    assert variant("dqn").double_dqn and variant("dqn").loss_function == "smooth_l1"
    assert variant("ruippeixotog").run_episodes == 500


def fill_buffer(learner: DQN, env: RobotTaskEnv, steps: int) -> TensorDict:
    """Acts with the learner's exploration policy and stores every transition; returns them
    (``[steps * num_envs]``, in the order stored)."""
    td, seen = env.reset(), []
    for _ in range(steps):
        td, nxt = env.step_and_maybe_reset(learner.act(td))
        learner.store(td)
        seen.append(td)
        td = nxt
    return torch.cat(seen)


def test_n1try_learning_rate_decays_like_keras():
    learner = variant("n1try")
    learner.build(StayUp(CartPole()))
    env = RobotTaskEnv(StayUp(CartPole()), num_envs=4, seed=0)
    fill_buffer(learner, env, steps=20)
    learner.optimize(10)
    assert learner.lr_of(0) == pytest.approx(0.01 / (1 + 0.01 * 10))
    assert learner.stats(0)["alpha"] == learner.lr_of(0)


def test_terminal_reward_replacement_only_on_termination():
    learner = variant("mbalunovic")
    learner.build(StayUp(CartPole()))
    env = RobotTaskEnv(StayUp(CartPole(), max_episode_steps=6), num_envs=8, seed=0)
    seen = fill_buffer(learner, env, steps=30)
    data = learner.buffers[0].transitions()
    term = data.terminated.squeeze(-1)
    reward = data.reward.squeeze(-1)
    trunc = seen["next", "done"] & ~seen["next", "terminated"]
    assert torch.equal(term, seen["next", "terminated"].squeeze(-1))
    assert term.any() and trunc.any()
    assert (reward[term] == -200).all() and (reward[~term] == 1).all()


def test_reward_scale_multiplies_stored_rewards_after_the_terminal_replacement():
    learner = variant("mbalunovic", reward_scale=0.01)
    learner.build(StayUp(CartPole()))
    env = RobotTaskEnv(StayUp(CartPole(), max_episode_steps=6), num_envs=8, seed=0)
    fill_buffer(learner, env, steps=30)
    data = learner.buffers[0].transitions()
    term = data.terminated.squeeze(-1)
    reward = data.reward.squeeze(-1)
    assert term.any()
    assert torch.allclose(reward[term], torch.tensor(-2.0))
    assert torch.allclose(reward[~term], torch.tensor(0.01))


def test_the_buffer_gives_back_what_was_stored_and_samples_like_torchrl():
    learner = variant("dqn", batch_size=32)
    learner.build(StayUp(CartPole()))
    seen = fill_buffer(learner, RobotTaskEnv(StayUp(CartPole()), num_envs=4, seed=0), steps=25)
    for ours, theirs in zip(learner.buffers[0].transitions(), Transitions.of(seen)):
        assert (ours is None and theirs is None) or torch.equal(ours, theirs)  # (steps: n-step rows only)
    torch.manual_seed(7)
    ours = learner.buffers[0].sample_transitions(len(learner.buffers[0]))
    torch.manual_seed(7)
    theirs = unpack(learner.buffers[0].sample())  # TorchRL's RandomSampler: the same draw
    assert all((a is None and b is None) or torch.equal(a, b) for a, b in zip(ours, theirs))



def random_baseline(seed: int, episodes: int = 20) -> float:
    env = RobotTaskEnv(StayUp(CartPole()), num_envs=episodes, seed=seed)
    gen = torch.Generator().manual_seed(seed)

    def act(td):
        td["action"] = torch.randint(0, 2, (episodes,), generator=gen)
        return td
    return evaluate(env, act)["mean_length"]


def train_and_eval(learner: str, tmp_path, num_envs: int, episodes: int, seed: int = 0) -> float:
    """``learner`` (its conf/learner file, untuned) trained for ``episodes`` episodes through
    ``train.py``; its greedy policy's mean episode length on 20 fresh starts."""
    member = train_in_process(tmp_path / "run", f"learner={learner}", "~tuned", f"seed={seed}",
                              f"num_envs={num_envs}", f"max_episodes={episodes}", "eval_episodes=0",
                              "stop_when_solved=false", "quiet=true")
    with member.greedy():
        return evaluate(RobotTaskEnv(StayUp(CartPole()), num_envs=20, seed=seed + 10_000),
                        member.policy)["mean_length"]


def test_dqn_learns_cartpole(tmp_path):
    greedy = train_and_eval("dqn", tmp_path, num_envs=8, episodes=400)
    random = random_baseline(10_000)
    assert greedy >= 5 * random, (greedy, random)


@pytest.mark.slow  # a learning check: CI's sibling is test_dqn_learns_cartpole
def test_n1try_learns_cartpole(tmp_path):
    greedy = train_and_eval("n1try", tmp_path, num_envs=1, episodes=300)
    random = random_baseline(10_000)
    assert greedy >= 5 * random, (greedy, random)


def test_checkpoint_rebuilds_the_network_and_rejects_mismatch(tmp_path):
    task = StayUp(CartPole())
    a = variant("dqn")
    a.build(task, torch.Generator().manual_seed(1))
    save_model(tmp_path / "model.pt", a.member(0), meta={})
    b = variant("dqn")
    b.build(task, torch.Generator().manual_seed(2))
    obs = torch.randn(1, 5, 4)
    assert not torch.equal(a.net.q(a.params, obs), b.net.q(b.params, obs))
    load_model(tmp_path / "model.pt", b.member(0))
    assert torch.equal(a.net.q(a.params, obs), b.net.q(b.params, obs))
    assert torch.equal(b.target, b.params)  # the target network starts as the loaded one
    c = variant("n1try")
    c.build(task)
    with pytest.raises(CheckpointError, match="does not fit"):
        load_model(tmp_path / "model.pt", c.member(0))
    from learners.qlearn import QLearn
    q = QLearn()
    q.build(task)
    with pytest.raises(CheckpointError, match="'dqn' learner"):
        load_model(tmp_path / "model.pt", q.member(0))


def test_bad_dqn_values_are_one_line_errors():
    from params import ConfigError
    for kwargs, key in ((dict(lr=-0.1), "learner.lr"), (dict(gamma=1.5), "learner.gamma"),
                        (dict(double_dqn=True, target_update=0, tau=0.0), "learner.double_dqn"),
                        (dict(batch_size=10, buffer_size=5), "learner.batch_size")):
        with pytest.raises(ConfigError, match=key):
            DQN(epsilon=LinearEpsilon(), **kwargs)



@pytest.mark.parametrize("loss,double,tau", [("huber", True, 0.01), ("l2", False, 0.01), ("l2", False, 0.0)])
def test_td_loss_equals_torchrl_dqnloss(loss, double, tau):
    """The plain-tensor TD loss computes what TorchRL's DQNLoss + TD(0) computes."""
    from torchrl.objectives import DQNLoss

    from learners.dqn import td_loss

    torch.manual_seed(0)
    learner = variant("dqn", loss=loss, double_dqn=double, tau=tau)
    learner.build(StayUp(CartPole()))
    env = RobotTaskEnv(StayUp(CartPole()), num_envs=8, seed=0)
    batch = fill_buffer(learner, env, steps=40)  # 320 transitions, some terminated
    if tau:  # make online and target networks differ
        learner.target.add_(0.1 * torch.randn_like(learner.target))
    learner.net.load(learner.params[0])  # the actor holds member 0's network
    reference = DQNLoss(learner.actor, loss_function=learner.loss_function, delay_value=bool(tau),
                        double_dqn=double, action_space=learner.actor.spec)
    reference.make_value_estimator(gamma=learner.gamma)
    target_net = {k: v.clone() for k, v in learner.net.load(learner.target[0]).state_dict().items()}
    learner.net.load(learner.params[0])
    for name, p in target_net.items() if tau else ():
        reference.target_value_network_params["module", "0", "module", *name.split(".")].data.copy_(p)
    assert batch.get(("next", "terminated")).any()

    def q_of(params):
        return lambda x: learner.net.q(params, x.unsqueeze(0)).squeeze(0)
    ours = td_loss(q_of(learner.params), q_of(learner.target), Transitions.of(batch), learner.gamma, double,
                   learner.loss_function)
    theirs = reference(batch)["loss"]
    torch.testing.assert_close(ours, theirs)


def test_rows_put_land_as_one_extend_per_put_would():
    """``put`` writes rows into the storage at once and books them with TorchRL when TorchRL
    reads the buffer: the storage after every put, and the cursor and length once booked,
    are those of TorchRL's ``extend`` per call, across wrap-arounds of the ring; ``stored``
    tells the length without booking."""
    from torchrl.data import RandomSampler, ReplayBuffer, TensorStorage

    from learners.member import RowReplayBuffer

    ours = RowReplayBuffer(50, 3, batch_size=4)
    theirs = ReplayBuffer(storage=TensorStorage(torch.zeros(50, 3)), sampler=RandomSampler())
    theirs.empty()
    gen = torch.Generator().manual_seed(0)
    for step, size in enumerate([7, 16, 1, 16, 16, 30, 5, 16, 49, 3, 16] * 3):
        rows = torch.randn(size, 3, generator=gen)
        ours.put(rows)
        theirs.extend(rows)
        unbooked = ours._unbooked
        assert ours.stored() == len(theirs) and ours._unbooked == unbooked  # not booked by stored()
        assert torch.equal(ours.rows, theirs.storage._storage)  # written already
        if step % 4 == 3:  # read by TorchRL now and then
            assert len(ours) == len(theirs) and ours._unbooked == 0
    state, expected = ours.state_dict(), theirs.state_dict()
    assert torch.equal(state["_storage"]["_storage"], expected["_storage"]["_storage"])
    assert state["_storage"]["_len"] == expected["_storage"]["_len"]
    assert state["_writer"] == expected["_writer"]
    again = RowReplayBuffer(50, 3, batch_size=4)
    again.load_state_dict(state)
    ours.put(torch.ones(3, 3))
    again.put(torch.ones(3, 3))
    assert torch.equal(again.rows, ours.rows) and again.state_dict()["_writer"] == ours.state_dict()["_writer"]


def test_training_state_roundtrip_and_old_format_refused():
    task = StayUp(CartPole())
    a = variant("dqn", batch_size=16)
    a.build(task)
    fill_buffer(a, RobotTaskEnv(StayUp(CartPole()), num_envs=4, seed=0), steps=10)
    a.optimize(3)
    state = a.training_state(0)
    b = variant("dqn", batch_size=16)
    b.build(task)
    b.load_training_state(0, state)
    assert len(b.buffers[0]) == 40 and torch.equal(b.buffers[0].rows, a.buffers[0].rows)
    assert b.steps[0] == 3 and torch.equal(b.params, a.params) and torch.equal(b.exp_avg_sq, a.exp_avg_sq)
    assert torch.equal(b.target, a.target) and torch.equal(b.generators[0].get_state(), a.generators[0].get_state())
    old = {k: v for k, v in state.items() if k != "format"}  # saved before format 2
    with pytest.raises(StateMismatch, match="format 1"):
        b.load_training_state(0, old)


def test_device_cuda_without_a_gpu_is_a_one_line_error():
    from params import ConfigError
    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    with pytest.raises(ConfigError, match="learner.device=cuda needs a GPU"):
        DQN(epsilon=LinearEpsilon(), device="cuda")


@pytest.mark.parametrize("learner", ["dqn", "mbalunovic", "n1try", "ruippeixotog"])
def test_device_is_a_declared_setting_of_every_dqn_checked_before_anything_is_built(learner):
    from params import ConfigError
    from tasks.catalog import compose
    from runs.settings import check_run_config

    assert compose(overrides=[f"learner={learner}"]).learner.device == "cpu"  # a setting, no '+' needed
    check_run_config(compose(overrides=[f"learner={learner}", "learner.device=auto"]))
    with pytest.raises(ConfigError) as err:
        check_run_config(compose(overrides=[f"learner={learner}", "learner.device=tpu"]))
    assert str(err.value) == ("learner.device must be cpu, cuda, cuda:N (GPU N) or auto (cuda where torch sees "
                              "a GPU, else cpu); got 'tpu'")
    if not torch.cuda.is_available():
        for device in ("cuda", "cuda:1"):
            with pytest.raises(ConfigError, match=f"^learner.device={device} needs a GPU that torch can use; "
                                                  "this torch sees none"):
                check_run_config(compose(overrides=[f"learner={learner}", f"learner.device={device}"]))


def test_device_auto_is_the_gpu_where_torch_sees_one_else_the_cpu():
    learner = variant("dqn", device="auto", batch_size=16)
    assert learner.device == ("cuda" if torch.cuda.is_available() else "cpu")
    learner.build(StayUp(CartPole()))
    assert learner.params.device.type == learner.device


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
def test_device_cuda_keeps_networks_and_buffer_on_the_gpu():
    learner = variant("dqn", device="cuda", batch_size=16)
    learner.build(StayUp(CartPole()))
    seen = fill_buffer(learner, RobotTaskEnv(StayUp(CartPole()), num_envs=4, seed=0), steps=10)
    learner.optimize(3)
    assert learner.buffers[0].rows.is_cuda and learner.params.is_cuda and learner.exp_avg.is_cuda
    assert seen["action"].device.type == "cpu" and learner.train_stats(0)["updates"] == 3


def test_obs_scale_multiplies_named_observations_before_the_network(tmp_path):
    """``obs_scale``: a fixed factor per named observation in front of the layers, saved
    with the model (a model without it does not load into one with it); an unknown name
    is a one-line error naming the task's observations."""
    from params import ConfigError

    task = StayUp(CartPole())
    names = list(task.observation_names)
    scaled = variant("dqn", obs_scale={names[0]: 0.5, names[2]: 10.0})
    scaled.build(task)
    plain = variant("dqn")
    plain.build(task)
    # the layers after the scale are plain's layers: copy them over and compare the values
    scaled.params.copy_(plain.params)
    obs = torch.randn(1, 7, len(names))
    factor = torch.ones(len(names))
    factor[0], factor[2] = 0.5, 10.0
    assert torch.allclose(scaled.net.q(scaled.params, obs), plain.net.q(plain.params, obs * factor))
    save_model(tmp_path / "model.pt", scaled.member(0), meta={})
    again = variant("dqn", obs_scale={names[0]: 0.5, names[2]: 10.0})
    again.build(task)
    load_model(tmp_path / "model.pt", again.member(0))
    assert torch.equal(again.net.q(again.params, obs), scaled.net.q(scaled.params, obs))
    with pytest.raises(CheckpointError, match="does not fit"):
        load_model(tmp_path / "model.pt", plain.member(0))
    with pytest.raises(ConfigError, match=f"learner.obs_scale names no observation of this task; its "
                                          f"observations: {', '.join(names)}"):
        variant("dqn", obs_scale={"wheel": 2.0}).build(task)
