"""Every task in conf/task/ and every robot in conf/robot/ fulfils its contract
(tasks.base.Task, robots.base.Robot), and taking a member away breaks it."""

from __future__ import annotations

import functools
import types

import numpy as np
import pytest
import torch

from runs.training_state import env_state
from robots.base import CONTRACT as ROBOT_CONTRACT
from robots.base import Robot, check_robot
from tasks import factory
from tasks import catalog
from tasks.base import CONTRACT as TASK_CONTRACT
from tasks.base import Task, check_task

TASKS = sorted(p.stem for p in (catalog.conf_dir() / "task").glob("*.yaml"))
ROBOTS = catalog.robot_names()


@functools.cache  # every robot built once per task and worker, not once per test (160 tests use it)
def robot_of(task: str) -> str:
    """The one robot ``task`` fits (the others are refused with a config error)."""
    fits = []
    for robot in ROBOTS:
        try:
            factory.build_task(catalog.compose(robot, task))
            fits.append(robot)
        except ValueError:
            pass
    assert len(fits) == 1, f"task {task} fits robots {fits}"
    return fits[0]


def env_of(task: str, num_envs: int = 3, seed: int = 0):
    return factory.build_env(catalog.compose(robot_of(task), task), num_envs, seed)


def random_steps(env, n: int, seed: int = 0):
    gen = torch.Generator().manual_seed(seed)
    td = env.reset()
    for _ in range(n):
        td.set("action", torch.randint(0, env.task.n_actions, (env.num_envs,), generator=gen))
        td, td = env.step_and_maybe_reset(td)
    return td


@pytest.mark.parametrize("task", TASKS)
def test_every_task_fulfils_the_contract(task):
    env = env_of(task)
    t = env.task
    check_task(t)
    check_robot(t.robot)
    td = random_steps(env, 5)
    assert td["observation"].shape == (3, len(t.observation_names))
    assert t.n_substeps * t.physics_timestep == pytest.approx(t.running_step)
    info = t.episode_info(env.physics)
    assert t.success.measure == "length" or t.success.measure in info
    assert all(np.shape(v) == (3,) for v in info.values())
    assert set(t.tabular_bounds.names) <= set(t.observation_names)
    env.close()


@pytest.mark.parametrize("task", TASKS)
def test_declared_state_is_the_whole_state_of_a_task(task):
    """A fresh env given another env's physics and the task's declared state goes on
    exactly as that env does: the checkpoint needs nothing else of the task."""
    a, b = env_of(task), env_of(task)
    td = random_steps(a, 7)
    saved = env_state(a)
    assert set(saved["task"]) == set(a.task.state_dict())
    b.reset()
    b.physics.state[:] = a.physics.state
    b.physics.ctrl[:] = a.physics.ctrl
    b.physics.sensordata[:] = a.physics.sensordata
    b.elapsed_steps[:] = a.elapsed_steps
    b.task.load_state_dict(a.task.state_dict())
    action = torch.arange(3) % a.task.n_actions
    out_a = a.step(td.clone().set("action", action))["next"]
    out_b = b.step(td.clone().set("action", action))["next"]
    assert torch.equal(out_a["observation"], out_b["observation"])
    assert torch.equal(out_a["reward"], out_b["reward"])
    for env in (a, b):
        env.close()


@pytest.mark.parametrize("robot", ROBOTS)
def test_every_robot_fulfils_the_contract(robot):
    r = factory.build_robot(catalog.compose(robot))
    check_robot(r)
    assert r.state_dict() == {}


def _without(cls: type, member: str) -> type:
    """A copy of ``cls`` lacking ``member`` of its own."""
    namespace = {k: v for k, v in vars(cls).items() if k not in (member, "__dict__", "__weakref__")}
    return type(cls.__name__, cls.__bases__, namespace)


@pytest.mark.parametrize("task", TASKS)
@pytest.mark.parametrize("member", TASK_CONTRACT)
def test_a_task_without_a_contract_member_fails(task, member):
    t = factory.build_task(catalog.compose(robot_of(task), task))
    cls = type(t)
    if member in vars(cls) and callable(vars(cls)[member]) and member in Task.__abstractmethods__:
        with pytest.raises(TypeError, match=member):
            _without(cls, member)(robot=t.robot)  # abstract: the class cannot be built
        return
    if member in ("bind", "state_dict", "load_state_dict"):  # the base's, over the declared state
        member = "per_copy"
    if member in vars(t):
        delattr(t, member)
    if member in vars(cls):  # a class attribute, or a dataclass field's default
        t.__class__ = _without(cls, member)
    with pytest.raises(TypeError, match=member):
        check_task(t)


@pytest.mark.parametrize("robot", ROBOTS)
@pytest.mark.parametrize("member", ROBOT_CONTRACT)
def test_a_robot_without_a_contract_member_fails(robot, member):
    r = factory.build_robot(catalog.compose(robot))
    cls = type(r)
    if member in Robot.__abstractmethods__:
        with pytest.raises(TypeError, match=member):
            _without(cls, member)()
        return
    # Anything with every other member: an object that is not a Robot lacks the base's too.
    stand_in = types.SimpleNamespace(**{m: getattr(r, m) for m in ROBOT_CONTRACT if m != member})
    with pytest.raises(TypeError, match=member):
        check_robot(stand_in)
