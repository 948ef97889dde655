"""PPO (learners/ppo.py): its losses are TorchRL's ClipPPOLoss's, its rollouts learn every
rollout_steps env steps over epochs of minibatches, and it learns. (Its members learn bit
for bit as alone: tests/test_members.py.)"""

from __future__ import annotations

import torch
from tensordict import TensorDict
from torchrl.modules import ValueOperator
from torchrl.objectives import ClipPPOLoss

import test_sac
from learners.ppo import PPO, ppo_losses

S = 64  # a minibatch


def built(robot: str = "pendulum", overrides=()) -> tuple[PPO, object]:
    return test_sac.built(robot, overrides, "ppo")


def test_its_losses_are_torchrl_clipppoloss():
    """Member 0's clipped objective and value loss, and the actor's gradient, on a minibatch
    of its own draws, as ClipPPOLoss's."""
    learner, env = built()
    g = torch.Generator().manual_seed(3)
    observation = torch.randn(S, learner.n_obs, generator=g)
    with torch.no_grad():  # the policy's draws, slightly off the current policy (old log-probs)
        nets = {name: group.open(None) for name, group in learner.groups.items()}
        drawn = learner.act_with(nets["actor"], observation.unsqueeze(0), learner.draw_act(g, S).unsqueeze(0))
        action, preimage, log_prob = drawn["action"], drawn["action_preimage"], drawn["action_log_prob"]
    old = log_prob[0] + 0.1 * torch.randn(S, generator=g)
    advantage, returns = torch.randn(S, generator=g), torch.randn(S, generator=g)

    actor = learner.policy(learner.groups["actor"].net.load(learner.groups["actor"].params[0]))
    critic = ValueOperator(learner.groups["critic"].net.load(learner.groups["critic"].params[0]),
                           in_keys=["observation"])
    loss = ClipPPOLoss(actor, critic, clip_epsilon=0.2, entropy_bonus=False, critic_coeff=0.5,
                       loss_critic_type="l2", normalize_advantage=True)
    loss.set_keys(sample_log_prob="action_log_prob", value_target="value_target")
    td = TensorDict({"observation": observation, "action": action[0], "action_log_prob": old,
                     "advantage": advantage.unsqueeze(-1), "value_target": returns.unsqueeze(-1)}, [S])
    theirs = loss(td)
    (theirs["loss_objective"] + theirs["loss_critic"]).backward()
    their_actor_grad = torch.cat([p.grad.reshape(-1) for p in actor.parameters()])

    nets = {name: group.open(None) for name, group in learner.groups.items()}
    minibatch = {"observation": observation.unsqueeze(0), "preimage": preimage, "log_prob": old.unsqueeze(0),
                 "advantage": advantage.unsqueeze(0), "returns": returns.unsqueeze(0)}
    mine = ppo_losses(nets["actor"], nets["critic"], minibatch, 0.2, 0.5, 0.0)
    torch.testing.assert_close(mine["loss_objective"][0], theirs["loss_objective"], rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(mine["loss_critic"][0], theirs["loss_critic"], rtol=1e-5, atol=1e-6)
    (mine["loss_objective"] + mine["loss_critic"]).sum().backward()
    torch.testing.assert_close(learner.groups["actor"].grads[0], their_actor_grad, rtol=1e-3, atol=1e-5)
    env.close()


def test_it_learns_from_each_full_rollout_over_epochs_of_minibatches():
    """Every rollout_steps env steps, epochs x minibatches updates; none in between."""
    learner, env = built(overrides=["learner.rollout_steps=10", "learner.epochs=3", "learner.minibatches=2"])
    td = env.reset()
    updates = []
    for _ in range(25):
        td = learner.act(td)
        td, nxt = env.step_and_maybe_reset(td)
        learner.observe(td)
        updates.append(learner.steps[0])
        td = nxt
    assert updates[8] == 0 and updates[9] == 6 and updates[18] == 6 and updates[19] == 12 and learner.filled[0] == 5
    env.close()


def test_ppo_learns_the_cartpoles_continuous_form(tmp_path):
    """Through train.py (its conf/learner file, untuned, its 2,048-step rollouts as 8 copies x
    256 steps), 20,480 env steps: the final greedy policy balances at least five times as long
    as the untrained one (a run of one step, seed 0: 8.4 steps; trained: 1000, its episodes'
    limit; 20 s of training against 45 s with one copy)."""
    import csv

    from inprocess import run_train

    def greedy_length(steps: int) -> float:
        run = tmp_path / f"run{steps}"
        done = run_train("learner=ppo", "num_envs=8", "learner.rollout_steps=256", "max_episodes=0",
                         f"max_env_steps={steps}", "eval_every=0", f"eval_every_steps={steps}", "eval_episodes=10",
                         "quiet=true", "stop_when_solved=false", f"hydra.run.dir={run}")
        assert done.returncode == 0, done.stderr[-1500:]
        rows = list(csv.DictReader((run / "evals.csv").open()))
        assert int(rows[-1]["env_steps"]) == steps
        return float(rows[-1]["length"])

    untrained, trained = greedy_length(8), greedy_length(20480)
    assert trained >= 5 * untrained, (untrained, trained)
