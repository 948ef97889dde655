"""The training loop: every run's, a single run's (one member) and a seed batch's alike.

    train(learner, env, lanes, end_done)

``env`` holds every member's copies, member ``b``'s block being rows ``b * n`` to
``(b + 1) * n``; ``lanes`` are the members' runs (:class:`Lane`). A step is::

    act (every member, one call) -> env step -> observe (one call)
    -> each lane books its block's finished episodes (its Run)
    -> end_episodes (one call: epsilon schedules, the updates the episodes owe)
    -> each lane ends the step (evaluation, checkpoint when due; a run that finished no
       episode and has nothing due only counts the step: ``Run.end_quiet_step``)
    -> one step of the batch's evaluations under way (``side``)

A lane whose greedy evaluation is due waits (a single run's too: a batch of one): its
block of the env is held and its state kept, its evaluation steps in the batch's evaluation
env (one physics call for every evaluation under way, once a step) while the other lanes
train on, and once its episodes have ended the lane takes the result and trains again from
where it stopped, as if its evaluation had been made at that step.

A lane that is done (solved, out of budget, stopped, failed) is handed to ``end_done``,
which ends it (and holds its copies); the others go on. ``refill`` may then start new
lanes in the freed members (a tuning study's next trial x seed), from the next step on. A
lane's own work that fails ends that lane alone (its :meth:`Lane.guarded`); a learner call
that fails ends every lane in it (:meth:`Lane.fail`: each keeps the trace), since they
share its state.
"""

from __future__ import annotations

import traceback
from typing import Callable, Protocol, Sequence

import torch
from tensordict import TensorDictBase

from learners.base import Learner, Member
from runs.evaluate import MemberEvaluations
from runs.run import Run
from runs.training_state import env_state, load_env_state

# Steps an evaluated lane waits at most to train again in phase with another (:func:`_evaluate`).
ALIGN_STEPS = 16


class Lane(Protocol):
    """One member's run inside the loop."""

    index: int  # the learner's member
    member: Member  # that member seen alone
    run: Run
    env: object  # its block of the env
    failed: str | None

    @property
    def done(self) -> bool: ...

    def guarded(self, work: Callable[[], object]) -> bool: ...

    def fail(self, error: BaseException, trace: str) -> None: ...


def train(learner: Learner, env, lanes: Sequence[Lane],
          end_done: Callable[[list[Lane]], list[Lane]],
          refill: Callable[[TensorDictBase, list[Lane], list[Lane]], tuple[TensorDictBase, list[Lane]]] | None = None,
          side: MemberEvaluations | None = None) -> None:
    """Acts on ``env`` and learns from each step until every lane is done (see the module
    docstring); ``end_done(live)`` ends the lanes of ``live`` that are done and returns the
    others; ``refill(td, ended, live)``, after a step where lanes ended, may start new lanes
    in the freed members: it returns the next step's input (their blocks' first
    observations in it) and the new lanes. ``side``: the batch's periodic evaluations,
    started by the lanes' runs (which then wait) and stepped here once a step."""
    learner.begin()
    starts = [lane.run.start(lane.env) for lane in lanes]
    if len(starts) > 1:  # a run resumed from its first step has a reset's keys, one from later a step's too
        common = set.intersection(*(set(start.keys()) for start in starts))
        starts = [start.select(*common) for start in starts]  # the step's input: the rest is made anew
    td = starts[0] if len(starts) == 1 else torch.cat(starts)
    live = end_done(list(lanes))  # a run resumed at its end ends here
    paused: dict[int, dict] = {}  # a waiting lane's member: its block's env state when it stopped
    ready: dict[int, int] = {}  # of those, a member whose evaluations are made: the steps it has waited since
    while live:
        training = [lane for lane in live if lane.index not in paused]
        if training:
            td = _step(learner, env, live, training, td, paused, side)
            if td is None:  # the learner's call failed: every live lane with it
                end_done(live)
                return
        if paused:
            td = _evaluate(learner, env, live, td, paused, side, ready)
        stay = {id(lane) for lane in end_done([lane for lane in live if lane.index not in paused])}
        going = [lane for lane in live if id(lane) in stay or lane.index in paused]
        if refill is not None and len(going) < len(live):
            still = {id(lane) for lane in going}
            td, added = refill(td, [lane for lane in live if id(lane) not in still], going)
            going = going + list(added)
        live = going


def _step(learner: Learner, env, live: list[Lane], training: list[Lane], td: TensorDictBase,
          paused: dict[int, dict], side: MemberEvaluations | None) -> TensorDictBase | None:
    """One training step of the ``training`` lanes (the others' copies held); each then ends
    its step, and one whose run waits for an evaluation pauses (its block's state kept in
    ``paused``). The next step's input; None if a learner call failed (the ``live`` lanes
    with it)."""
    acted = _together(live, lambda: learner.act(td, _indices(training)))
    if acted is None:
        return None
    acted, next_td = env.step_and_maybe_reset(acted)
    _together(live, lambda: learner.observe(acted, _indices(training)))
    sound = _sound(training)
    ended, booked = _book(learner, sound, acted)
    if ended:
        _together(sound, lambda: learner.end_episodes(ended))
    for lane in _sound(sound):
        if lane.index not in booked and lane.run.end_quiet_step(next_td):
            continue  # most steps: nothing finished and nothing due
        lane.guarded(lambda lane=lane: lane.run.end_step(next_td))
        if lane.run.waiting:
            if lane.failed is None:
                paused[lane.index] = _pause(env, lane)
            elif side is not None:
                side.drop(lane.index)
    return next_td


def _evaluate(learner: Learner, env, live: list[Lane], td: TensorDictBase, paused: dict[int, dict],
              side: MemberEvaluations, ready: dict[int, int]) -> TensorDictBase:
    """One step of the evaluations under way; a lane whose evaluation ended takes its result
    (and starts the confirmation it may owe: it waits on), and once it owes none trains
    again from where it stopped (its block's state and rows of ``td`` as they were), at a
    step where it is in phase with a training lane (:meth:`Learner.phase`), or after
    :data:`ALIGN_STEPS` steps. A waiting lane that failed is no longer waited for. The
    next step's input."""
    waiting = [lane for lane in live if lane.index in paused]
    results = (_together(waiting, side.step) or {}) if side.members else {}
    for lane in waiting:  # each result taken at once: a confirmation it owes starts now
        if lane.index in results and lane.guarded(lambda lane=lane: lane.run.evaluated(results[lane.index])):
            if not lane.run.waiting:
                ready[lane.index] = 0
    phases = {learner.phase(lane.index) for lane in live if lane.index not in paused} - {None}
    for lane in waiting:
        if lane.failed is not None:
            side.drop(lane.index)
            ready.pop(lane.index, None)
            del paused[lane.index]
        elif lane.index in ready:
            waited = ready.pop(lane.index)
            own = learner.phase(lane.index)
            if (not lane.run.done and own is not None and own not in phases and own[0] in {p[0] for p in phases}
                    and waited < ALIGN_STEPS):
                ready[lane.index] = waited + 1
                continue
            td = _resume(env, lane, paused.pop(lane.index), td)
            lane.guarded(lane.run.end_boundary)
    return td


def _pause(env, lane: Lane) -> dict:
    """The lane's block of ``env`` held (its copies step no more) and its state as it is
    (the env computes every block's step: a held block's counters and starts move on)."""
    env.physics.hold(env.block_mask(lane.index))
    return env_state(lane.env)


def _resume(env, lane: Lane, state: dict, td: TensorDictBase) -> TensorDictBase:
    """The lane's block of ``env`` back to ``state`` and stepping again; ``td`` with the
    lane's rows of the step input it paused at (its run's ``last_td``)."""
    load_env_state(lane.env, state, lane.run.run_dir)
    env.physics.release(env.block_mask(lane.index))
    rows = env.block(lane.index)
    td = td.clone()
    td[rows] = lane.run.last_td[rows]
    return td


def _book(learner: Learner, lanes: list[Lane], td: TensorDictBase) -> tuple[dict[int, int], set[int]]:
    """Each lane's Run books its block of the step (its finished episodes, with its member's
    numbers); per member, how many episodes it booked, and the members whose block finished
    an episode (the others' runs only count the step)."""
    nxt = td.get("next")
    reward, done, terminated = (nxt.get(key).reshape(-1).numpy() for key in ("reward", "done", "terminated"))
    n = len(reward) // learner.members
    ended: dict[int, int] = {}
    booked: set[int] = set()

    def book(lane: Lane, rows: slice) -> None:
        view = lane.env
        lane.run.divergences = getattr(view, "divergences", 0)  # a diverged copy's episode ends
        count = len(lane.run.record(reward[rows], done[rows], terminated[rows], lane.member.stats,
                                    getattr(view, "ended_info", None)))
        if count:
            ended[lane.index] = count

    for lane in lanes:
        rows = slice(lane.index * n, (lane.index + 1) * n)
        if not done[rows].any():  # most steps: the run only counts the step
            lane.run.episodes.step(reward[rows])
            continue
        booked.add(lane.index)
        lane.guarded(lambda lane=lane, rows=rows: book(lane, rows))
    return ended, booked


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
