"""TD3 (learners/td3.py): its losses are TorchRL's TD3Loss's, its actor updates every
policy_delay updates, and its policy is TorchRL's Actor. (Its members learn bit for bit as
alone: tests/test_members.py.)"""

from __future__ import annotations

import torch
from tensordict import TensorDict
from torchrl.data import Bounded
from torchrl.modules import ValueOperator
from torchrl.objectives import TD3Loss

import test_sac
from test_sac import B, minibatch
from learners.td3 import TD3, td3_losses
from learners.transitions import Transitions


def built(robot: str = "pendulum", overrides=()) -> tuple[TD3, object]:
    return test_sac.built(robot, overrides, "td3")


def test_its_losses_are_torchrl_td3loss():
    """Member 0's critic and actor losses and the actor's gradient, with the smoothing noise
    TorchRL's loss draws on torch's stream, as TD3Loss's."""
    learner, env = built()
    batch = minibatch(learner.n_obs, learner.n_actions)
    td = TensorDict({"observation": batch.observation, "action": batch.action,
                     "next": {"observation": batch.next_observation, "reward": batch.reward,
                              "done": batch.terminated, "terminated": batch.terminated}}, [B])
    groups = learner.groups
    actor = learner.policy(groups["actor"].net.load(groups["actor"].params[0]))
    critics = []
    for name in ("q1", "q2"):
        net = groups[name].net.load(groups[name].params[0])
        critics.append(TensorDict.from_module(ValueOperator(net, in_keys=["observation", "action"])).clone())
        qvalue = ValueOperator(net, in_keys=["observation", "action"])
    spec = Bounded(-1.0, 1.0, shape=(learner.n_actions,))
    loss = TD3Loss(actor, qvalue, action_spec=spec, num_qvalue_nets=2, policy_noise=learner.policy_noise,
                   noise_clip=learner.noise_clip, loss_function="l2")
    loss.make_value_estimator(gamma=0.99)
    with torch.no_grad():
        stacked = torch.stack(critics)
        loss.qvalue_network_params.data.update_(stacked)
        loss.target_qvalue_network_params.data.update_(stacked)
    torch.manual_seed(7)
    theirs = loss(td)
    (theirs["loss_actor"] + theirs["loss_qvalue"]).backward()
    their_actor_grad = torch.cat([p.grad.reshape(-1) for p in actor.parameters()])

    noise = learner.draw_update(torch.Generator().manual_seed(7), B).unsqueeze(0)
    nets = {name: group.open(None) for name, group in learner.groups.items()}
    stacked = Transitions(*(None if x is None else x.unsqueeze(0) for x in batch))
    mine = td3_losses(nets["actor"], nets["q1"], nets["q2"], stacked, noise, 0.99, learner.policy_noise,
                      learner.noise_clip, True)
    for key in ("loss_actor", "loss_qvalue"):
        torch.testing.assert_close(mine[key].mean(), theirs[key], rtol=1e-5, atol=1e-6, msg=key)
    (mine["loss_actor"].mean() + mine["loss_qvalue"].mean()).backward()
    torch.testing.assert_close(learner.groups["actor"].grads[0], their_actor_grad, rtol=1e-4, atol=1e-6)
    env.close()


def test_the_actor_and_the_targets_move_every_policy_delay_updates():
    learner, env = built(overrides=["learner.policy_delay=3", "learner.learning_starts=20", "learner.batch_size=8"])
    td = env.reset()
    actor, target = [], []
    for _ in range(40):
        td = learner.act(td)
        td, nxt = env.step_and_maybe_reset(td)
        learner.observe(td)
        actor.append(learner.groups["actor"].params[0].clone())
        target.append(learner.groups["q1"].target[0].clone())
        td = nxt
    moved = [t for t in range(1, 40) if not torch.equal(actor[t], actor[t - 1])]
    followed = [t for t in range(1, 40) if not torch.equal(target[t], target[t - 1])]
    assert learner.steps[0] == 21 and len(moved) == 7 and moved == followed
    env.close()
