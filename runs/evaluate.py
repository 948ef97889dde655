"""Greedy evaluation: one episode in each copy of an env with a fixed policy, and
what it measured.

:class:`MemberEvaluations` is every run's greedy evaluation: a learner's members' greedy
policies, each on a seed block of one env from its seed's starts (the same starts every
time), several at once (a batch's periodic evaluations beside its training, the final ones
of the seeds that end at one step) or one made at once (:meth:`MemberEvaluations.alone`).
:func:`evaluate` runs any policy (a random one, a benchmark's); :func:`measure_of` reads
the task's success measure from the result and :func:`describe_evaluation` puts it in one
line.
"""

from __future__ import annotations

from typing import Callable, Mapping, Sequence

import numpy as np
import torch
from omegaconf import DictConfig
from tensordict import TensorDict

from learners.base import greedy_stream
from tasks.base import Success
from tasks.factory import build_env


def _keep_info(info: dict[str, np.ndarray], info_fn, physics, copies: np.ndarray) -> None:
    """Stores the task's ``episode_info`` of the ``copies`` (a mask) in ``info``."""
    for key, value in info_fn(physics).items():
        info.setdefault(key, np.zeros(len(copies)))[copies] = np.asarray(value)[copies]


def evaluate(env, policy, max_steps: int | None = None) -> dict:
    """Runs one episode in each copy of ``env`` with ``policy``; length and return stats.
    A copy whose episode has ended is held (:meth:`~robots.physics.BatchedPhysics.hold`):
    the physics steps only the copies still running.

    If the task has ``episode_info(physics) -> dict[str, ndarray]`` (one value
    per copy), each copy's values at its episode end are reported too, with
    their mean under ``info_mean``.
    """
    return _summary(*_episodes(env, policy, max_steps))


def _episodes(env, policy, max_steps: int | None) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """One episode in each copy of ``env``: per copy its return, its length and its task's
    ``episode_info`` values (see :func:`evaluate`)."""
    n = env.num_envs
    ret, length = np.zeros(n), np.zeros(n, dtype=np.int64)
    alive = np.ones(n, dtype=bool)
    info: dict[str, np.ndarray] = {}
    td = env.reset()
    steps = 0
    try:
        with torch.no_grad():
            while alive.any() and (max_steps is None or steps < max_steps):
                td = env.step(policy(td))
                nxt = td.get("next")
                _book_step(env, nxt, ret, length, alive, info)
                td = nxt.exclude("reward", "done", "terminated", "truncated")
                steps += 1
    finally:
        env.physics.release()
    info_fn = getattr(env.task, "episode_info", None)
    if info_fn is not None and alive.any():  # cut off by max_steps
        _keep_info(info, info_fn, env.physics, alive)
    return ret, length, info


def _book_step(env, nxt, ret: np.ndarray, length: np.ndarray, alive: np.ndarray,
               info: dict[str, np.ndarray]) -> None:
    """Books a step's ``next`` for the copies ``alive`` marks: their rewards and lengths
    added; those whose episode ended have their ``episode_info`` kept in ``info``, are held
    (:meth:`~robots.physics.BatchedPhysics.hold`: they step no more) and are alive no more."""
    n = env.num_envs
    ret += nxt.get("reward").reshape(n).numpy() * alive
    length += alive
    ended = alive & nxt.get("done").reshape(n).numpy()
    if ended.any():
        info_fn = getattr(env.task, "episode_info", None)
        if info_fn is not None:
            _keep_info(info, info_fn, env.physics, ended)
        env.physics.hold(ended)
    alive &= ~ended


def start_spread(observations: torch.Tensor, names: Sequence[str]) -> dict[str, float]:
    """How far an evaluation's starts spread: each observation entry's standard deviation
    over its episodes' first observations (0 everywhere: every episode starts alike)."""
    std = observations.double().std(0, unbiased=False) if len(observations) > 1 else torch.zeros(len(names))
    return {name: round(float(v), 6) for name, v in zip(names, std)}


def _summary(ret: np.ndarray, length: np.ndarray, info: dict[str, np.ndarray]) -> dict:
    """An evaluation's result from its copies' returns, lengths and episode infos."""
    return {
        "episodes": len(ret),
        "mean_length": float(length.mean()), "std_length": float(length.std()),
        "mean_return": float(ret.mean()), "std_return": float(ret.std()),
        "lengths": length.tolist(), "returns": ret.tolist(),
        "info": {k: v.tolist() for k, v in info.items()},
        "info_mean": {k: float(v.mean()) for k, v in info.items()},
    }


def measure_of(result: Mapping, measure: str) -> float:
    """The mean of ``measure`` over the episodes of an :func:`evaluate` result."""
    return float(result["mean_length"] if measure == "length" else result["info_mean"][measure])


def episode_values(result: Mapping, measure: str) -> list[float]:
    """``measure`` of each episode of an :func:`evaluate` result."""
    return list(result["lengths"] if measure == "length" else result["info"][measure])


def pass_rate(result: Mapping, success: Success) -> float:
    """The share of an :func:`evaluate` result's episodes whose measure reaches the task's
    threshold (:meth:`tasks.base.Success.pass_rate`)."""
    return success.pass_rate(episode_values(result, success.measure))


def starts_seed(seed: int, k: int) -> int:
    """The seed of a run's ``k``-th greedy evaluation's starts, from its evaluation seed:
    ``seed`` itself for the first, then one of its own for each (every evaluation from
    fresh starts, the same in every replay of the run)."""
    if k == 0:
        return int(seed)
    return int(np.random.SeedSequence([int(seed), int(k)]).generate_state(1)[0])


class MemberEvaluations:
    """Greedy evaluations of a learner's members, each on a seed block of one env of ``blocks``
    blocks of ``copies`` copies, from its seed's starts: each the result it gives alone (a
    copy's episode depends on its own start, policy and physics only). An evaluation starts when asked (:meth:`start`); every one under way
    takes one step per :meth:`step`, all of them in one physics call. The training loop
    steps a batch's periodic evaluations once a training step while their members'
    training waits (``runs.loop``): alone, an evaluation's episodes are a few hundred
    narrow steps of its own, made while the whole batch waits."""

    def __init__(self, cfg: DictConfig, learner, blocks: int, copies: int) -> None:
        self.learner = learner
        self.env = build_env(cfg, blocks * int(copies), list(range(blocks)))  # each block seeded as it starts
        n = self.env.num_envs
        self.env.physics.hold(np.ones(n, dtype=bool))
        self.ret, self.length = np.zeros(n), np.zeros(n, dtype=np.int64)
        self.alive = np.zeros(n, dtype=bool)
        self.info: dict[str, np.ndarray] = {}
        self.observation = torch.zeros(n, len(self.env.task.observation_names))
        self.null_action = self.env.action_spec.zero()  # the rows of blocks not evaluating
        # The members evaluating: each one's block and the stream that breaks its greedy ties.
        self.running: dict[int, tuple[int, torch.Generator]] = {}
        self.spread: dict[int, dict[str, float]] = {}  # each one's starts: how far they spread

    @property
    def members(self) -> list[int]:
        """The members whose evaluation is under way, in the order of their blocks."""
        return sorted(self.running, key=lambda b: self.running[b][0])

    def start(self, member: int, seed: int, block: int | None = None) -> None:
        """``member``'s evaluation starts on ``block`` (default: the member's own): the block's
        episodes from ``seed``'s starts, as its evaluator's env starts them. None: the result
        comes from a later :meth:`step`."""
        block = member if block is None else block
        rows = self.env.block(block)
        self.observation[rows] = self.env.renew_block(block, seed)
        self.ret[rows], self.length[rows], self.alive[rows] = 0.0, 0, True
        self.running[member] = block, greedy_stream()
        self.spread[member] = start_spread(self.observation[rows], self.env.task.observation_names)

    def step(self) -> dict[int, dict]:
        """One step of every evaluation under way, each member's greedy policy acting on its
        block; the results of those whose episodes have all ended, by member."""
        members, env = self.members, self.env
        acting = np.zeros(env.num_envs, dtype=bool)
        for member in members:
            acting[env.block(self.running[member][0])] = True
        rows = torch.from_numpy(acting)
        observed = TensorDict({"observation": self.observation[rows]}, batch_size=[int(acting.sum())])
        action = self.null_action.clone()
        with torch.no_grad():
            action[rows] = self.learner.act_members(observed, members, True,
                                                    [self.running[m][1] for m in members]).get("action")
        nxt = env.step_actions(action)
        _book_step(env, nxt, self.ret, self.length, self.alive, self.info)
        self.observation = nxt.get("observation")
        results = {}
        for member in members:
            block = env.block(self.running[member][0])
            if not self.alive[block].any():
                results[member] = {**_summary(self.ret[block].copy(), self.length[block].copy(),
                                              {k: v[block].copy() for k, v in self.info.items()}),
                                   "start_spread": self.spread.pop(member)}
                del self.running[member]
        return results

    def alone(self, member: int, seed: int, progress: Callable[[int], None] | None = None) -> dict:
        """``member``'s evaluation from ``seed``'s starts on block 0, made now (none other
        under way): its result. ``progress``: told after each step how many of its episodes
        have ended."""
        self.start(member, seed, 0)
        rows = self.env.block(0)
        while True:
            results = self.step()
            if member in results:
                return results[member]
            if progress is not None:
                progress(int((~self.alive[rows]).sum()))

    def drop(self, member: int) -> None:
        """``member``'s evaluation, if one is under way, ends unfinished (its run failed)."""
        running = self.running.pop(member, None)
        self.spread.pop(member, None)
        if running is not None:
            self.alive[self.env.block(running[0])] = False
            self.env.physics.hold(self.env.block_mask(running[0]))

    def close(self) -> None:
        self.env.close()


def describe_evaluation(result: dict, success: Success) -> str:
    """``greedy evaluation over N episodes: <measure> m +- s <unit>, length ..., return ...``."""
    values = result["lengths"] if success.measure == "length" else result["info"][success.measure]
    extra = "".join(f", {k} {v:.3f}" for k, v in result["info_mean"].items() if k != success.measure)
    passed = int(round(pass_rate(result, success) * len(values)))
    return (f"greedy evaluation over {result['episodes']} episodes: {success.description} "
            f"{measure_of(result, success.measure):.4g} +- {np.std(values):.3g} {success.unit}, "
            f"{passed}/{len(values)} episodes >= {success.threshold:g} (solved at {success.rate:.0%}, "
            f"confirmed from fresh starts), length {result['mean_length']:.1f} +- "
            f"{result['std_length']:.1f}, return {result['mean_return']:.1f} +- "
            f"{result['std_return']:.1f}{extra}")
