"""The whole state of a training run at a step boundary, to save and to resume, and the
seeding of the run's global random streams (:func:`seed_everything`) it holds.

A training checkpoint (``checkpoint.pt`` in the run folder) holds everything
the next step depends on, so a resumed run continues bit for bit:

- the learner's training state (``learner.training_state()``: Q-table or
  networks, optimiser, target network, schedules, counters, replay buffer);
- the environment: every physics copy's state, controls and sensors, elapsed
  steps, the env's random generator and the task's and robot's declared per-copy
  state (their ``state_dict()``);
- the observation tensordict the next step acts on;
- the run's bookkeeping (episodes so far, partial returns; see ``Run``);
- the global torch, numpy and ``random`` generators;
- the run's identity (:func:`run_identity`: the run folder's ``run_id`` and a
  hash of its ``config.yaml``), so another run's checkpoint copied into the
  folder is refused, and a checksum of all of it (:mod:`runs.checkpoint`).

Everything is stored as tensors and plain Python values, so it loads with
``torch.load(weights_only=True)``.

Resuming refuses a checkpoint before any file of the run folder is touched:
:func:`read_training_state` (read-only) checks the format, the checksum, the
learner and the identity; :func:`restore_training_state` loads the learner and the
env when the run is built (every tensor's key, shape and dtype checked before the
folder is written); :func:`load_training_state` then restores the rest in memory,
and only once all of it has loaded cuts the metrics files back to the checkpoint's
episodes. ``runs.folder.resumed_config`` calls
:func:`runs.settings.check_targets` and :func:`read_training_state` before the run starts.
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import importlib
import json
import random
import uuid
from pathlib import Path

import numpy as np
import torch
from omegaconf import DictConfig, OmegaConf
from tensordict import TensorDict, TensorDictBase

from learners.base import StateMismatch
from runs.checkpoint import CHECKSUM, CheckpointError, load_checkpoint, save_checkpoint
from params import ConfigError

# 3: the run's identity and a checksum; 2: the task's and robot's declared state_dict;
# 1: scanned attributes.
FORMAT = 3


# -- the run folder: identity, run.json, config.yaml ------------------------
def new_run_identity() -> dict:
    """``{"run_id": <random hex>}``, for a new run's ``run.json`` (its checkpoints carry it)."""
    return {"run_id": uuid.uuid4().hex}

def read_run_json(run_dir: Path | str) -> dict:
    """The run folder's ``run.json``, refused in one line unless it is a JSON object."""
    path = Path(run_dir) / "run.json"
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, ValueError) as err:
        raise CheckpointError(f"{path} is not readable JSON ({type(err).__name__}: "
                              f"{str(err).splitlines()[0] if str(err) else ''})") from None
    if not isinstance(data, dict):
        raise CheckpointError(f"{path} must hold a JSON object; got {type(data).__name__}")
    if "run_id" in data and not (isinstance(data["run_id"], str) and data["run_id"]):
        raise CheckpointError(f"{path}: run_id must be a non-empty string; got {data['run_id']!r}")
    return data

def load_run_config(run_dir: Path | str) -> DictConfig:
    """The run folder's ``config.yaml``, refused in one line if it does not parse as a mapping."""
    path = Path(run_dir) / "config.yaml"
    try:
        cfg = OmegaConf.load(path)
    except OSError as err:
        raise CheckpointError(f"{path} cannot be read ({err.strerror or type(err).__name__}); "
                              "allowed: resume= a run folder holding config.yaml and run.json") from None
    except Exception as err:  # noqa: BLE001 - yaml and OmegaConf raise many types
        raise CheckpointError(f"{path} does not parse ({type(err).__name__}: "
                              f"{str(err).strip().splitlines()[0] if str(err).strip() else ''})") from None
    if not isinstance(cfg, DictConfig):
        raise CheckpointError(f"{path} must hold a mapping of settings; got a list")
    return cfg


def run_identity(run_dir: Path | str) -> dict:
    """What a checkpoint must match to continue the run in ``run_dir``: ``run_id`` (run.json's;
    runs made before it existed: ``config-`` and a hash of config.yaml's bytes) and
    ``config_sha256``, a hash of config.yaml's settings (key order and layout aside)."""
    run_dir = Path(run_dir)
    config = run_dir / "config.yaml"
    try:
        raw = config.read_bytes()
    except OSError as err:
        raise CheckpointError(f"{config} is not readable ({type(err).__name__})") from None
    raw_sha256 = hashlib.sha256(raw).hexdigest()
    run_id = read_run_json(run_dir).get("run_id") or "config-" + raw_sha256[:32]
    return {"run_id": run_id, "config_sha256": _settings_sha256(str(run_dir), raw_sha256)}

@functools.lru_cache(maxsize=256)
def _settings_sha256(run_dir: str, raw_sha256: str) -> str:
    """The hash of ``run_dir``'s config.yaml settings, parsed once per content of the file
    (``raw_sha256``): a run saves its checkpoints under the same config.yaml, which a
    parse would otherwise read again at every save."""
    settings = OmegaConf.to_container(load_run_config(run_dir), resolve=False)
    canonical = json.dumps(settings, sort_keys=True, separators=(",", ":"), default=repr)
    return hashlib.sha256(canonical.encode()).hexdigest()

def _learner_kind(cfg: DictConfig) -> str | None:
    """The ``kind`` of the learner class ``cfg.learner._target_`` names (after :func:`runs.settings.check_targets`)."""
    target = OmegaConf.select(cfg, "learner._target_")
    if not isinstance(target, str):
        return None
    module_name, _, attr = target.rpartition(".")
    kind = getattr(getattr(importlib.import_module(module_name), attr, None), "kind", None)
    return kind if isinstance(kind, str) else None

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
    """Writes the run's whole state, with the identity of its run folder, to ``path`` atomically."""
    save_checkpoint(path, {
        "kind": "training_state",
        "format": FORMAT,
        "identity": run_identity(run.run_dir),
        "learner_kind": learner.kind,
        "learner": learner.training_state(),
        "env": env_state(env),
        "td": td.to_dict(),
        "run": run.state_dict(),
        "rng": global_rng_state(),
    })

def read_training_state(path: Path | str, run_dir: Path | str, learner_kind: str | None) -> dict:
    """Reads ``path`` and checks it may continue the run in ``run_dir``: readable, this
    format, intact (its checksum), ``learner_kind``'s (None: not checked) and this run's
    (:func:`run_identity`). Reads only; raises :class:`CheckpointError` with one line."""
    state = load_checkpoint(path, kind="training_state")
    if state.get("format") != FORMAT:
        raise CheckpointError(f"checkpoint {path} has format {state.get('format')}, this code reads {FORMAT}")
    if CHECKSUM not in state:
        raise CheckpointError(f"checkpoint {path} has no checksum, so its contents cannot be trusted")
    if learner_kind is not None and state.get("learner_kind") != learner_kind:
        raise CheckpointError(f"checkpoint {path} holds a {state.get('learner_kind')!r} learner, "
                              f"but this run's learner is {learner_kind!r}")
    theirs, ours = state.get("identity"), run_identity(run_dir)
    if not isinstance(theirs, dict):
        raise CheckpointError(f"checkpoint {path} does not say which run it belongs to")
    if theirs.get("run_id") != ours["run_id"]:
        raise CheckpointError(f"checkpoint {path} belongs to another run (run_id {theirs.get('run_id')}; "
                              f"this run folder's is {ours['run_id']}): it was copied in from elsewhere")
    if theirs.get("config_sha256") != ours["config_sha256"]:
        raise CheckpointError(f"checkpoint {path} was saved under another config: "
                              f"{Path(run_dir) / 'config.yaml'} changed since, or the checkpoint "
                              "is another run's")
    return state

def check_checkpoint(run_dir: Path | str, cfg: DictConfig) -> None:
    """Checks, reading only, that ``run_dir/checkpoint.pt`` may continue the run of ``cfg``
    (its resumed config, after :func:`check_targets`); see :func:`read_training_state`."""
    read_training_state(Path(run_dir) / "checkpoint.pt", run_dir, _learner_kind(cfg))

@contextlib.contextmanager
def _fits(path: Path | str):
    """A part of checkpoint ``path`` that does not fit this run: one :class:`CheckpointError`."""
    try:
        yield
    except CheckpointError:
        raise
    except StateMismatch as err:
        raise CheckpointError(str(err)) from None
    except (KeyError, RuntimeError, ValueError, TypeError, IndexError, AttributeError) as err:
        raise CheckpointError(f"checkpoint {path} does not fit this run ({type(err).__name__}: "
                              f"{str(err).splitlines()[0] if str(err) else ''})") from None

def restore_training_state(path: Path | str, run_dir: Path | str, learner, env) -> dict:
    """Reads and checks ``path`` (:func:`read_training_state`) and loads its env and learner
    parts into ``env`` and ``learner``: every tensor's key, shape and dtype is checked here,
    when the run is built, before any file of its folder is written. Returns the state, for
    :func:`load_training_state`."""
    state = read_training_state(path, run_dir, learner.kind)
    with _fits(path):
        load_env_state(env, state["env"], path)
        own = state["learner"]
        if "generator" not in own:  # written before each learner had its own stream: the run's torch stream
            own = {**own, "generator": state["rng"]["torch"]}
        learner.load_training_state(own)
        TensorDict(state["td"], batch_size=[env.num_envs])
        if len(state["run"]["ret"]) != env.num_envs:
            raise ValueError(f"the checkpoint has {len(state['run']['ret'])} copies, this run {env.num_envs}")
    return state

def load_training_state(path: Path, learner, env, run, state: dict | None = None) -> TensorDictBase:
    """Restores what :func:`save_training_state` wrote; returns the next step's input.
    ``state``: what :func:`restore_training_state` returned when the run was built (its
    learner loaded then; its env again now, a batch's first reset having come between);
    None: restored now.

    Every part is checked and loaded before any file changes: only then are the
    temporary files of a save that a kill interrupted removed (the rename never
    happened, so ``path`` is the last complete checkpoint) and the metrics files
    cut back to the checkpoint's episodes (``run.reopen``).
    """
    if state is None:
        state = restore_training_state(path, run.run_dir, learner, env)
    with _fits(path):
        load_env_state(env, state["env"], path)
        run.load_state_dict(state["run"], reopen=False)
        load_global_rng_state(state["rng"])
        td = TensorDict(state["td"], batch_size=[env.num_envs])
        for leftover in Path(path).parent.glob(Path(path).name + ".*.tmp"):
            leftover.unlink(missing_ok=True)
        run.reopen()
    return td

def seed_everything(seed: int) -> torch.Generator:
    """Seeds torch, numpy and Python's ``random`` globals; returns a dedicated torch generator."""
    torch.manual_seed(seed)
    np.random.seed(seed % (2**32))
    random.seed(seed)
    gen = torch.Generator()
    gen.manual_seed(seed)
    return gen
