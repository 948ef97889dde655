"""The learner contract: what a learner is given, and what it must provide.

A learner is a dataclass made from its config node (``conf/learner/<name>.yaml``,
its parameters checked in ``__post_init__``). The run package (:mod:`runs`) then:

1. calls ``build(task, generator)`` once: the learner sizes its networks or table
   from the task's observations, tabular state and actions;
2. calls ``train(env, loop)`` (:func:`train`, the same loop for every learner):
   ``begin()``, then step by step ``act(td)`` on the batched ``env``,
   ``observe(td)`` to learn from the batch of transitions, ``end_episode()`` once
   per finished episode, every step handed to ``loop`` (a :class:`Loop`), which
   books episodes, evaluates, checkpoints and says when to stop;
3. reads ``policy`` (inside ``with learner.greedy():`` for greedy acting) to
   evaluate or film the trained policy;
4. saves and loads: ``model_state()`` is what ``model.pt`` holds (the trained
   policy), ``training_state()`` everything the next update depends on (for an
   exact resume); both are dicts of tensors and plain values, and the matching
   ``load_*`` raises :class:`StateMismatch` for a state of another shape.

A learner knows nothing of folders, files or consoles: the run package writes
and reads the files and reports what ``stats`` and ``train_stats`` give.
"""

from __future__ import annotations

from contextlib import AbstractContextManager
from typing import Any, Mapping, Protocol, runtime_checkable

import torch
from tensordict import TensorDictBase


class StateMismatch(ValueError):
    """A saved learner state that does not fit this learner (another shape or format)."""


class Loop(Protocol):
    """What a learner's ``train`` drives, step by step::

        td = loop.start(env)
        while not loop.done:
            td = policy(td)
            td, td_next = env.step_and_maybe_reset(td)
            ...  # learn from td (it holds "next")
            for episode in loop.record_step(env, td, learner.stats):
                ...  # per-episode work (epsilon decay, updates)
            td = loop.end_step(td_next)
    """

    @property
    def done(self) -> bool: ...

    def start(self, env) -> TensorDictBase: ...

    def record_step(self, env, td: TensorDictBase, stats: Mapping[str, float] | None = None) -> list: ...

    def end_step(self, td: TensorDictBase) -> TensorDictBase: ...


@runtime_checkable
class Learner(Protocol):
    """A learning algorithm, as the run package uses it (see the module docstring)."""

    kind: str  # the learner family a saved state belongs to ("qlearn", "dqn")
    nepisodes: int  # the training budget in episodes
    nsteps: int  # steps per episode at most

    def build(self, task, generator: torch.Generator | None = None) -> Any: ...

    @property
    def policy(self) -> Any: ...

    def greedy(self) -> AbstractContextManager[None]: ...

    @property
    def stats(self) -> dict[str, float]: ...

    def train_stats(self, reset: bool = True) -> dict[str, float]: ...

    def begin(self) -> None: ...

    def act(self, tensordict: TensorDictBase) -> TensorDictBase: ...

    def observe(self, tensordict: TensorDictBase) -> None: ...

    def end_episode(self) -> None: ...

    def train(self, env, loop: Loop) -> None: ...

    def model_state(self) -> dict: ...

    def load_model_state(self, state: Mapping, where: str) -> None: ...

    def training_state(self) -> dict: ...

    def load_training_state(self, state: Mapping) -> None: ...


def train(learner: Learner, env, loop: Loop) -> None:
    """Acts on the batched ``env`` and learns from each batch of transitions until
    ``loop.done``; ``end_episode`` once per episode the step finished."""
    learner.begin()
    td = loop.start(env)
    while not loop.done:
        td = learner.act(td)
        td, td_next = env.step_and_maybe_reset(td)
        learner.observe(td)
        for _ in loop.record_step(env, td, learner.stats):
            learner.end_episode()
        td = loop.end_step(td_next)
