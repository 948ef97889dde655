"""The whole state of a training run at a step boundary, to save and to resume.

A training checkpoint (``checkpoint.pt`` in the run folder) holds everything
the next step depends on, so a resumed run continues bit for bit:

- the learner's training state (``learner.training_state()``: Q-table or
  networks, optimiser, target network, schedules, counters, replay buffer);
- the environment: every physics copy's state, controls and sensors, elapsed
  steps, the env's random generator and the task's and robot's declared per-copy
  state (their ``state_dict()``);
- the observation tensordict the next step acts on;
- the run's bookkeeping (episodes so far, partial returns; see ``Run``);
- the global torch, numpy and ``random`` generators.

Everything is stored as tensors and plain Python values, so it loads with
``torch.load(weights_only=True)``.
"""

from __future__ import annotations

import random
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase

from learners.checkpoint import CheckpointError, load_checkpoint, save_checkpoint

FORMAT = 2  # 2: the task's and robot's declared state_dict (1: scanned attributes)


def _tensors(state: dict[str, np.ndarray]) -> dict[str, torch.Tensor]:
    return {k: torch.from_numpy(np.array(v, copy=True)) for k, v in state.items()}


def _arrays(state: dict[str, torch.Tensor]) -> dict[str, np.ndarray]:
    return {k: v.numpy().copy() for k, v in state.items()}


def env_state(env) -> dict:
    """Physics, counters and randomness of a ``RobotTaskEnv``."""
    physics = env.physics
    return {
        "num_envs": env.num_envs,
        "nstate": physics.nstate,
        "physics": torch.from_numpy(physics.state.copy()),
        "ctrl": torch.from_numpy(physics.ctrl.copy()),
        "sensordata": torch.from_numpy(physics.sensordata.copy()),
        "elapsed_steps": torch.from_numpy(env.elapsed_steps.copy()),
        "divergences": int(getattr(env, "divergences", 0)),
        "rng": env._rng.bit_generator.state,
        "task": _tensors(env.task.state_dict()),
        "robot": _tensors(env.task.robot.state_dict()),
    }


def load_env_state(env, state: dict, path: Path) -> None:
    if state["num_envs"] != env.num_envs or state["nstate"] != env.physics.nstate:
        raise CheckpointError(
            f"checkpoint {path} was taken with {state['num_envs']} physics copies of "
            f"{state['nstate']} state values; this run has {env.num_envs} of {env.physics.nstate}")
    physics = env.physics
    physics.state[:] = state["physics"].numpy()  # in place: qpos/qvel are views of it
    physics.ctrl[:] = state["ctrl"].numpy()
    physics.sensordata[:] = state["sensordata"].numpy()
    env.elapsed_steps[:] = state["elapsed_steps"].numpy()
    if hasattr(env, "divergences"):
        env.divergences = int(state["divergences"])
    env._rng.bit_generator.state = state["rng"]
    env.task.load_state_dict(_arrays(state["task"]))
    env.task.robot.load_state_dict(_arrays(state["robot"]))


def global_rng_state() -> dict:
    kind, keys, pos, has_gauss, cached = np.random.get_state()
    return {
        "torch": torch.get_rng_state(),
        "numpy": [kind, torch.from_numpy(keys.astype(np.int64)), int(pos), int(has_gauss), float(cached)],
        "python": _python_rng_state(),
    }


def _python_rng_state() -> list:
    version, internal, gauss = random.getstate()
    return [version, torch.tensor(internal, dtype=torch.int64), gauss]


def load_global_rng_state(state: dict) -> None:
    torch.set_rng_state(state["torch"])
    kind, keys, pos, has_gauss, cached = state["numpy"]
    np.random.set_state((kind, keys.numpy().astype(np.uint32), pos, has_gauss, cached))
    version, internal, gauss = state["python"]
    random.setstate((version, tuple(int(v) for v in internal.tolist()), gauss))


def save_training_state(path: Path, learner, env, run, td: TensorDictBase) -> None:
    """Writes the run's whole state to ``path`` atomically."""
    save_checkpoint(path, {
        "kind": "training_state",
        "format": FORMAT,
        "learner_kind": learner.kind,
        "learner": learner.training_state(),
        "env": env_state(env),
        "td": td.to_dict(),
        "run": run.state_dict(),
        "rng": global_rng_state(),
    })


def load_training_state(path: Path, learner, env, run) -> TensorDictBase:
    """Restores what :func:`save_training_state` wrote; returns the next step's input.

    A temporary file left by a save that a kill interrupted is removed: the
    rename never happened, so ``path`` is the last complete checkpoint.
    """
    for leftover in Path(path).parent.glob(Path(path).name + ".*.tmp"):
        leftover.unlink(missing_ok=True)
    state = load_checkpoint(path, kind="training_state")
    if state.get("format") != FORMAT:
        raise CheckpointError(f"checkpoint {path} has format {state.get('format')}, this code reads {FORMAT}")
    if state["learner_kind"] != learner.kind:
        raise CheckpointError(f"checkpoint {path} holds a {state['learner_kind']!r} learner, "
                              f"but this run's learner is {learner.kind!r}")
    try:
        load_env_state(env, state["env"], path)
        learner.load_training_state(state["learner"])
        run.load_state_dict(state["run"])
        load_global_rng_state(state["rng"])
        td = TensorDict(state["td"], batch_size=[env.num_envs])
    except CheckpointError:
        raise
    except (KeyError, RuntimeError, ValueError, TypeError) as err:
        raise CheckpointError(f"checkpoint {path} does not fit this run ({type(err).__name__}: "
                              f"{str(err).splitlines()[0] if str(err) else ''})") from None
    return td
