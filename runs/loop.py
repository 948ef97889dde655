"""The training loop: every run's, a single run's (one member) and a seed batch's alike.

    train(learner, env, lanes, end_done)

``env`` holds every member's copies, member ``b``'s block being rows ``b * n`` to
``(b + 1) * n``; ``lanes`` are the members' runs (:class:`Lane`). A step is::

    act (every member, one call) -> env step -> observe (one call)
    -> each lane books its block's finished episodes (its Run)
    -> end_episodes (one call: epsilon schedules, the updates the episodes owe)
    -> each lane ends the step (evaluation, checkpoint when due)

A lane that is done (solved, out of budget, stopped, failed) is handed to ``end_done``,
which ends it (and holds its copies); the others go on. ``refill`` may then start new
lanes in the freed members (a tuning study's next trial x seed), from the next step on. A
lane's own work that fails ends that lane alone (its :meth:`Lane.guarded`); a learner call
that fails ends every lane in it (:meth:`Lane.fail`: a single run raises, a batch's seed
keeps the trace), since they share its state.
"""

from __future__ import annotations

import traceback
from dataclasses import dataclass
from typing import Callable, Protocol, Sequence

import torch
from tensordict import TensorDictBase

from learners.base import Learner
from runs.run import Run


class Lane(Protocol):
    """One member's run inside the loop."""

    index: int  # the learner's member
    run: Run
    env: object  # its block of the env (the env itself for a single run)
    failed: str | None

    @property
    def done(self) -> bool: ...

    def guarded(self, work: Callable[[], object]) -> bool: ...

    def fail(self, error: BaseException, trace: str) -> None: ...


def train(learner: Learner, env, lanes: Sequence[Lane],
          end_done: Callable[[list[Lane]], list[Lane]],
          refill: Callable[[TensorDictBase, list[Lane], list[Lane]], tuple[TensorDictBase, list[Lane]]] | None = None
          ) -> None:
    """Acts on ``env`` and learns from each step until every lane is done (see the module
    docstring); ``end_done(live)`` ends the lanes of ``live`` that are done and returns the
    others; ``refill(td, ended, live)``, after a step where lanes ended, may start new lanes
    in the freed members: it returns the next step's input (their blocks' first
    observations in it) and the new lanes."""
    learner.begin()
    starts = [lane.run.start(lane.env) for lane in lanes]
    td = starts[0] if len(starts) == 1 else torch.cat(starts)
    live = end_done(list(lanes))  # a run resumed at its end ends here
    while live:
        td = _together(live, lambda: learner.act(td, _indices(live)))
        if td is None:  # the call failed: every live lane with it
            end_done(live)
            return
        td, next_td = env.step_and_maybe_reset(td)
        _together(live, lambda: learner.observe(td, _indices(live)))
        sound = _sound(live)
        ended = _book(learner, sound, td)
        if ended:
            _together(sound, lambda: learner.end_episodes(ended))
        for lane in _sound(sound):
            lane.guarded(lambda lane=lane: lane.run.end_step(next_td))
        td = next_td
        going = end_done(live)
        if refill is not None and len(going) < len(live):
            still = {id(lane) for lane in going}
            td, added = refill(td, [lane for lane in live if id(lane) not in still], going)
            going = going + list(added)
        live = going


def _book(learner: Learner, lanes: list[Lane], td: TensorDictBase) -> dict[int, int]:
    """Each lane's Run books its block of the step (its finished episodes, with its member's
    numbers); per member, how many episodes it booked."""
    nxt = td.get("next")
    reward, done, terminated = (nxt.get(key).reshape(-1).numpy() for key in ("reward", "done", "terminated"))
    n = len(reward) // learner.members
    ended: dict[int, int] = {}

    def book(lane: Lane) -> None:
        rows = slice(lane.index * n, (lane.index + 1) * n)
        view, finished = lane.env, done[rows]
        lane.run.divergences = getattr(view, "divergences", 0)
        if not finished.any():  # most steps: the run only counts the step
            lane.run.record(reward[rows], finished, terminated[rows])
            return
        count = len(lane.run.record(reward[rows], finished, terminated[rows], learner.stats(lane.index),
                                    getattr(view, "ended_info", None)))
        if count:
            ended[lane.index] = count

    for lane in lanes:
        lane.guarded(lambda lane=lane: book(lane))
    return ended


def _together(lanes: list[Lane], work):
    """A learner call for ``lanes``; if it fails, every one of them ends (they share its state)."""
    try:
        return work()
    except Exception as error:  # noqa: BLE001 - reported by each lane
        trace = traceback.format_exc()
        for lane in lanes:
            if lane.failed is None:
                lane.fail(error, trace)
        return None


def _sound(lanes: list[Lane]) -> list[Lane]:
    """The lanes that have not failed (one stopped mid-step still ends it, as alone)."""
    return [lane for lane in lanes if lane.failed is None]


def _indices(lanes: list[Lane]) -> list[int]:
    return [lane.index for lane in lanes]


@dataclass
class Solo:
    """A single run's lane: member ``index`` (0: the learner's only one), its failures raised."""

    run: Run
    env: object
    index: int = 0
    failed: str | None = None

    @property
    def done(self) -> bool:
        return self.run.done

    def guarded(self, work: Callable[[], object]) -> bool:
        work()
        return True

    def fail(self, error: BaseException, trace: str) -> None:
        raise error


def train_single(learner: Learner, env, run: Run) -> None:
    """:func:`train` of a single run: ``learner``'s one member on ``env``, booked by ``run``."""
    train(learner, env, [Solo(run, env)], _unfinished)


def _unfinished(live: list[Lane]) -> list[Lane]:
    return [lane for lane in live if not lane.done]
