"""SAC (learners/sac.py): its losses are TorchRL's SACLoss's, its policy is TorchRL's actor, a
learner that cannot act on a task's actions is refused in one line, and it learns. (Its
members learn bit for bit as alone, renewed or with their own settings: tests/test_members.py;
its runs resume exactly: tests/test_resume.py.)"""

from __future__ import annotations

import pytest
import torch
from hydra.utils import instantiate
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.modules import ValueOperator
from torchrl.objectives import SACLoss

from learners.sac import SAC
from learners.transitions import Transitions
from params import ConfigError
from tasks.catalog import compose
from tasks.factory import build_env

B = 64  # a minibatch


def built(robot: str = "pendulum", overrides=(), learner: str = "sac") -> tuple[SAC, object]:
    """A ``learner`` (32-32 networks) of one member on ``robot``'s task, and its env of one copy."""
    cfg = compose(robot, learner=learner, overrides=["learner.hidden=[32,32]", *overrides])
    env = build_env(cfg, 1, 0)
    learner = instantiate(cfg.learner, _convert_="all")
    learner.build(env.task, [torch.Generator().manual_seed(5)])
    return learner, env


def minibatch(n_obs: int, dims: int) -> Transitions:
    g = torch.Generator().manual_seed(3)
    return Transitions(torch.randn(B, n_obs, generator=g), torch.rand(B, dims, generator=g) * 2 - 1,
                       torch.randn(B, 1, generator=g), torch.randn(B, n_obs, generator=g),
                       torch.rand(B, 1, generator=g) < 0.2)


def torchrl_loss(learner: SAC, gamma: float) -> SACLoss:
    """TorchRL's SACLoss over modules holding member 0's actor and critics."""
    groups = learner.groups
    learner.policy(groups["actor"].net.load(groups["actor"].params[0]))
    actor = learner.policy_module
    critics = []
    for name in ("q1", "q2"):
        net = groups[name].net.load(groups[name].params[0])
        critics.append(TensorDict.from_module(ValueOperator(net, in_keys=["observation", "action"])).clone())
        qvalue = ValueOperator(net, in_keys=["observation", "action"])
    loss = SACLoss(actor, qvalue, num_qvalue_nets=2, loss_function="l2", alpha_init=1.0, target_entropy=-1.0)
    loss.make_value_estimator(gamma=gamma)
    with torch.no_grad():
        stacked = torch.stack(critics)
        loss.qvalue_network_params.data.update_(stacked)
        loss.target_qvalue_network_params.data.update_(stacked)
    return loss


def test_its_losses_are_torchrl_sacloss():
    """Member 0's three losses and its actor's gradient, with the draws TorchRL's loss makes
    on torch's stream (the next actions', then the current ones'), as SACLoss's."""
    learner, env = built()
    batch = minibatch(learner.n_obs, learner.n_actions)
    td = TensorDict({"observation": batch.observation, "action": batch.action,
                     "next": {"observation": batch.next_observation, "reward": batch.reward,
                              "done": batch.terminated, "terminated": batch.terminated}}, [B])
    loss = torchrl_loss(learner, gamma=0.99)
    torch.manual_seed(7)
    theirs = loss(td)
    (theirs["loss_actor"] + theirs["loss_qvalue"] + theirs["loss_alpha"]).backward()
    their_actor_grad = torch.cat([p.grad.reshape(-1) for p in learner.policy_module.parameters()])

    noise = learner.draw_update(torch.Generator().manual_seed(7), B).unsqueeze(0)
    nets = {name: group.open(None) for name, group in learner.groups.items()}
    stacked = Transitions(*(None if x is None else x.unsqueeze(0) for x in batch))
    total, stepped, *_ = learner.losses(nets, stacked, noise, 0.99, [learner])
    from learners.sac import sac_losses

    mine = sac_losses(nets["actor"], nets["q1"], nets["q2"], nets["alpha"].value, stacked, noise, 0.99, -1.0)
    for key in ("loss_actor", "loss_qvalue", "loss_alpha"):
        torch.testing.assert_close(mine[key].mean(), theirs[key], rtol=1e-5, atol=1e-6, msg=key)
    torch.testing.assert_close(-mine["log_prob"].mean(), theirs["entropy"], rtol=1e-5, atol=1e-6)
    total.sum().backward()
    torch.testing.assert_close(learner.groups["actor"].grads[0], their_actor_grad, rtol=1e-4, atol=1e-6)
    assert stepped == ("actor", "q1", "q2", "alpha")
    env.close()


def test_its_policy_is_torchrl_actor():
    """model.pt's actor is TorchRL's ProbabilisticActor: loaded alone, its deterministic action
    is the member's greedy action."""
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    learner, env = built("point_mass")
    state = learner.model_state(0)
    actor = learner.policy(learner.templates["actor"])
    actor.load_state_dict(state["actor"])
    observation = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        theirs = actor(observation.clone()).get("action")
    member = learner.member(0)
    with member.greedy():
        mine = member.policy(observation.clone()).get("action")
    torch.testing.assert_close(mine, theirs)
    assert mine.shape == (1, 2) and mine.abs().max() <= 1
    env.close()


@pytest.mark.parametrize("learner", ["sac", "td3", "ppo"])
def test_obs_scale_multiplies_named_observations_before_every_network(learner):
    """``obs_scale`` on a continuous learner: a fixed factor per named observation in front
    of every network (a critic's action inputs by 1), in the policy model.pt holds; a saved
    state without it does not load into a learner with it; an unknown name is one line
    naming the task's observations."""
    from learners.base import StateMismatch

    scale = ["~tuned", "learner.obs_scale={wheel_speed: 0.01, yaw: 10.0}"]  # not conf/tuned/cube_sac.yaml's
    scaled, env = built("cube", scale, learner=learner)
    plain, plain_env = built("cube", ["~tuned"], learner=learner)
    plain_env.close()
    names = list(env.task.observation_names)
    factor = torch.ones(len(names))
    factor[names.index("wheel_speed")], factor[names.index("yaw")] = 0.01, 10.0

    def outputs(net, params, x):  # an actor's (loc, scale) as one tensor
        found = net.q(params, x)
        return torch.cat(found, -1) if isinstance(found, tuple) else found

    for name, group in scaled.groups.items():
        if group.net is None:
            continue
        inputs = torch.randn(1, 5, group.net.template[1].in_features)
        by = torch.cat((factor, torch.ones(inputs.shape[-1] - len(names))))
        params = plain.groups[name].params  # the same layers after the scale
        assert torch.equal(outputs(group.net, params, inputs), outputs(plain.groups[name].net, params, inputs * by))
    saved = scaled.model_state(0)["actor"]
    assert [torch.equal(v, factor) for k, v in saved.items() if k.endswith(".scale")] == [True]
    with pytest.raises(StateMismatch, match="does not fit this run"):
        scaled.load_model_state(0, plain.model_state(0), "model.pt")
    with pytest.raises(ConfigError, match=f"learner.obs_scale names no observation of this task; its "
                                          f"observations: {', '.join(names)}"):
        built("cube", ["~tuned", "learner.obs_scale={wheel: 2.0}"], learner=learner)
    env.close()


@pytest.mark.parametrize("robot, task", [("cartpole", None), ("cube", None), ("turtlebot", "maze"),
                                         ("turtlebot", "wall"), ("pendulum", None), ("point_mass", None),
                                         ("acrobot", None), ("double_pendulum", None)])
def test_every_shipped_task_offers_both_forms(robot, task):
    """The env of a continuous learner acts on the task's continuous form: a bounded float
    action per command in [-1, 1]; a discrete learner's on its table."""
    for learner, form in (("sac", "continuous"), ("dqn", "discrete")):
        env = build_env(compose(robot, task, learner=learner), 2, 0)
        assert env.actions == form
        spec = env.action_spec
        if form == "continuous":
            assert spec.dtype == torch.float32 and spec.shape == (2, env.task.action_range.dims)
            assert torch.equal(spec.space.low, -torch.ones(spec.shape))
        else:
            assert spec.dtype == torch.int64 and spec.shape == (2,)
        env.close()


def test_a_learner_that_cannot_act_on_the_tasks_actions_is_one_line():
    continuous_only = ["~task.actions", "+task.actions={continuous: [torque]}"]
    with pytest.raises(ConfigError, match=r"learner=dqn acts on discrete actions and task .* declares none "
                                          r"\(it offers continuous: use learner=sac\)") as err:
        build_env(compose("pendulum", learner="dqn", overrides=continuous_only), 1, 0)
    assert "\n" not in str(err.value)
    no_range = ["task.actions={values: {torque: [1.0]}}"]  # one value: no span, and the model gives one
    env = build_env(compose("pendulum", learner="sac", overrides=no_range), 1, 0)
    assert list(env.task.action_range.low) == [-1.0]  # the model's control range
    env.close()


@pytest.mark.slow  # a learning check (about 3 minutes); CI's sibling: tests/test_ppo.py's
@pytest.mark.parametrize("learner", ["sac", "td3"])
def test_it_learns_the_cartpoles_continuous_form(tmp_path, learner):
    """Through train.py: the final greedy policy balances at least five times as long as the
    untrained one (seed 0, 15k env steps: sac 12 -> 1000 steps, td3 18 -> 258)."""
    import csv

    from inprocess import run_train

    run = tmp_path / "run"
    done = run_train(f"learner={learner}", "max_episodes=0", "max_env_steps=15000", "eval_every=20", "quiet=true",
                     "stop_when_solved=false", f"hydra.run.dir={run}")
    assert done.returncode == 0, done.stderr[-1500:]
    rows = list(csv.DictReader((run / "evals.csv").open()))
    first, last = float(rows[0]["length"]), float(rows[-1]["length"])
    assert last >= 5 * first, (first, last)
