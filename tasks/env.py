"""The TorchRL environment: a task (which has a robot) over a batch of physics copies.

``RobotTaskEnv`` compiles the task's arena once and steps ``num_envs`` copies
of it per call (``batch_size=[num_envs]``). Keys:

- ``observation``: float32 ``[num_envs, n_obs]``
- ``action``: int64 ``[num_envs]`` in ``[0, n_actions)``; with ``actions="continuous"``
  (the task's continuous form, for SAC and its kind), float32 ``[num_envs, dims]`` in
  [-1, 1], a TorchRL ``Bounded`` spec
- ``reward``: float32 ``[num_envs, 1]``
- ``terminated`` (the task failed or succeeded), ``truncated`` (time limit),
  ``done = terminated | truncated``: bool ``[num_envs, 1]``

A ``_reset`` mask resets only the marked copies. All randomness comes from one
``numpy.random.Generator`` seeded by ``set_seed``: same seed, same rollouts.

Seed blocks: with a list of seeds (``seed=[3, 4, 5]``) the copies form equal
blocks, one per seed, in order, each with a generator of its own, so each
block's copies start their episodes exactly as an env of ``num_envs / len(seeds)``
copies with that one seed would (several runs' envs in one physics batch).

A copy whose physics diverges during a step (MuJoCo found it unstable: see
``robots.physics``) ends its episode there as truncated (``terminated`` false,
``done`` true) with reward 0 and, as next observation, its observation before
the step; ``step_and_maybe_reset`` then resets that copy only. ``divergences``
counts these events since construction, and each is logged once (logger
``tasks.env``, WARNING).

``ended_info`` holds, per copy, the task's ``episode_info`` as it was when that
copy's episode last ended, taken just before a partial reset starts the next
one (``step_and_maybe_reset`` resets ended copies in the same call, so this is
where a trainer reads what an episode achieved).

``step_and_maybe_reset`` keeps TorchRL's contract (``step``, ``step_mdp``, then a
partial reset of the ended copies): the returned transition holds each copy's
true next observation in ``("next", "observation")``, terminal ones included,
and the second tensordict, the next step's input, holds the new episodes' first
observations. It does all of it in one pass (numpy masks, the very random draws
a partial ``_reset`` makes, in the same order) instead of ``EnvBase``'s generic
reset machinery, whose cost did not shrink with the physics: some copy ends on
nearly every call of a large batch. ``step`` alone never resets (this is not a
TorchRL "auto-reset" env, whose ``next`` observations would be the reset ones).
"""

from __future__ import annotations

import atexit
import logging
import weakref
from collections.abc import Mapping, Sequence

import mujoco
import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase, is_non_tensor, is_tensor_collection
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from params.private_api import get_entry, has_names, new_tensordict, set_entry
from robots.physics import BatchedPhysics
from tasks.base import Task, check_action_form, check_task

_log = logging.getLogger(__name__)


def _zero_rows(value, rows: np.ndarray):
    """``value`` (a tensor or a tensordict of them) with the ``rows`` entries (bool
    ``(num_envs,)``) zeroed, out of place: what TorchRL's partial reset
    (``where(..., pad=0)``) leaves in the reset rows of entries the reset does not make."""
    if isinstance(value, torch.Tensor):
        if type(value) is torch.Tensor:
            try:  # numpy's copy and masked write: no dispatcher round trips on the hot path
                array = value.numpy().copy()
            except (TypeError, RuntimeError):  # not on the CPU, needs grad, a dtype numpy lacks
                pass
            else:
                array[rows] = 0
                return torch.from_numpy(array)
        mask = torch.from_numpy(rows.reshape(rows.shape + (1,) * (value.ndim - 1)))
        return value.masked_fill(mask.to(value.device), 0)
    if is_tensor_collection(value) and not is_non_tensor(value):
        return value.apply(lambda leaf: _zero_rows(leaf, rows))
    return value


def _seed_blocks(num_envs: int, seed: int | Sequence[int]) -> list[int]:
    """The seeds of ``seed`` (one, or one per block), checked against ``num_envs``."""
    if int(num_envs) < 1:
        raise ValueError(f"env.num_envs must be >= 1, got {num_envs}")
    seeds = [int(s) for s in seed] if isinstance(seed, Sequence) else [int(seed)]
    if not seeds or int(num_envs) % len(seeds):
        raise ValueError(f"env.num_envs ({num_envs}) must be a multiple of the number of seed "
                         f"blocks ({len(seeds)})")
    return seeds


def compile_model(arena) -> mujoco.MjModel:
    """Compiles a dm_control MJCF arena (with its attached robot) to an ``MjModel``."""
    return mujoco.MjModel.from_xml_string(arena.to_xml_string(), assets=arena.get_assets())


class RobotTaskEnv(EnvBase):
    """A batched TorchRL environment for any task and the robot it has."""

    def __init__(self, task: Task, num_envs: int = 1, seed: int | Sequence[int] = 0,
                 nthread: int | None = None, actions: str = "discrete"):
        seeds = _seed_blocks(num_envs, seed)
        check_task(task)
        check_action_form(task, actions)
        super().__init__(batch_size=torch.Size([int(num_envs)]), device="cpu")
        self.task = task
        self.num_envs = int(num_envs)
        self.model = compile_model(task.build_arena())
        self.physics = BatchedPhysics(self.model, self.num_envs, nthread=nthread)
        task.bind(self.physics)
        n = self.num_envs
        self.actions = actions
        self._make_specs(task, n, actions)
        self.elapsed_steps = np.zeros(n, dtype=np.int64)
        self.divergences = 0  # diverged steps (ended episodes) since construction
        self.ended_info: dict[str, np.ndarray] = {}  # episode_info at each copy's last episode end
        self.n_blocks = len(seeds)
        self.block_size = n // self.n_blocks
        self.block_divergences = np.zeros(self.n_blocks, dtype=np.int64)  # ``divergences`` by block
        self._set_seed(seeds if self.n_blocks > 1 else seeds[0])
        # What step_mdp drops of the root (it takes the observation and the flags from next).
        self._mdp_dropped = frozenset(("next", "reward", "_reset", "done", "terminated", "truncated"))
        self._renderer: mujoco.Renderer | None = None
        self._render_data: mujoco.MjData | None = None
        self.camera_names = [mujoco.mj_id2name(self.model, mujoco.mjtObj.mjOBJ_CAMERA, i)
                             for i in range(self.model.ncam)]

    def _make_specs(self, task: Task, n: int, actions: str) -> None:
        """The observation, action (``actions``' form), reward and done specs of ``n`` copies."""
        n_obs = len(task.observation_names)
        self.observation_spec = Composite(
            observation=Unbounded(shape=(n, n_obs), dtype=torch.float32), shape=(n,)
        )
        if actions == "continuous":
            self.action_shape: tuple[int, ...] = (n, task.action_range.dims)
            self.action_spec = Bounded(-1.0, 1.0, shape=self.action_shape, dtype=torch.float32)
        else:
            self.action_shape = (n,)
            self.action_spec = Categorical(task.n_actions, shape=(n,), dtype=torch.int64)
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float32)
        self.done_spec = Composite(
            done=Categorical(2, shape=(n, 1), dtype=torch.bool),
            terminated=Categorical(2, shape=(n, 1), dtype=torch.bool),
            truncated=Categorical(2, shape=(n, 1), dtype=torch.bool),
            shape=(n,),
        )

    # -- EnvBase -----------------------------------------------------------------
    def _set_seed(self, seed: int | Sequence[int] | None) -> None:
        """One generator (``_rng``), or with a list of seeds one per block (``_rngs``)."""
        if isinstance(seed, Sequence):
            if len(seed) != self.n_blocks:
                raise ValueError(f"this env has {self.n_blocks} seed blocks; got {len(seed)} seeds")
            self._rngs = [np.random.default_rng(int(s)) for s in seed]
        else:
            self._rngs = [np.random.default_rng(seed)]
        self._rng = self._rngs[0]

    def set_seed(self, seed: int | Sequence[int] | None = None, static_seed: bool = False):
        """Seeds the env (a list: one seed per block) and returns the seed (TorchRL's next
        seed for a single one)."""
        if isinstance(seed, Sequence):
            self._set_seed(seed)
            return seed
        return super().set_seed(seed, static_seed)

    def block(self, b: int) -> slice:
        """The copies of seed block ``b``."""
        return slice(b * self.block_size, (b + 1) * self.block_size)

    def block_mask(self, b: int, within: np.ndarray | None = None) -> np.ndarray:
        """Bool ``(num_envs,)``: the copies of seed block ``b`` (that ``within`` marks, if given)."""
        mask = np.zeros(self.num_envs, dtype=bool)
        mask[self.block(b)] = True if within is None else within[self.block(b)]
        return mask

    def renew_block(self, b: int, seed: int) -> torch.Tensor:
        """Seed block ``b`` started anew as seed ``seed`` (a batch's freed member given another
        trial x seed): its generator, its copies' first episodes, step counters and divergence
        count as an env of ``block_size`` copies with that seed starts them; its copies step
        again (:meth:`~robots.physics.BatchedPhysics.release`). The other blocks are left as
        they are. Returns the block's first observations (float32 ``[block_size, n_obs]``)."""
        if not 0 <= b < self.n_blocks:
            raise ValueError(f"this env has {self.n_blocks} seed blocks; got block {b}")
        self._rngs[b] = np.random.default_rng(int(seed))
        self._rng = self._rngs[0]
        mask = self.block_mask(b)
        self.physics.release(mask)
        for value in self.ended_info.values():  # as a new env's: none ended yet
            value[mask] = 0.0
        self.divergences -= int(self.block_divergences[b])
        self.block_divergences[b] = 0
        obs = self._start_episodes(mask, keep_ended_info=False)
        return torch.from_numpy(obs[self.block(b)].astype(np.float32))

    def seed_block(self, b: int) -> SeedBlock:
        """Seed block ``b`` seen as an env of its own (see :class:`SeedBlock`)."""
        return SeedBlock(self, b)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        mask, partial = np.ones(self.num_envs, dtype=bool), False
        if tensordict is not None and "_reset" in tensordict.keys():
            mask = tensordict.get("_reset").reshape(self.num_envs).cpu().numpy().astype(bool)
            partial = True
        obs = self._start_episodes(mask, keep_ended_info=partial)
        false = np.zeros((self.num_envs, 1), dtype=bool)
        return self._tensordict(None, {"observation": torch.from_numpy(obs.astype(np.float32)),
                                       "done": torch.from_numpy(false),
                                       "terminated": torch.from_numpy(false.copy()),
                                       "truncated": torch.from_numpy(false.copy())})

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        return self.step_actions(tensordict.get("action"))

    def step_actions(self, action: torch.Tensor) -> TensorDictBase:
        """``step``'s ``next`` tensordict for every copy's ``action``, made without an input
        tensordict: the same tensors, less ``EnvBase.step``'s handling of a tensordict this
        env made itself (a greedy evaluation's steps: ~0.2 ms a step less)."""
        return self._advance(action.reshape(self.action_shape).cpu().numpy(), device=None)[0]

    def _step_and_maybe_reset(self, tensordict: TensorDictBase
                              ) -> tuple[TensorDictBase, TensorDictBase]:
        """``step``, ``step_mdp`` and the partial reset of the ended copies, as
        ``EnvBase`` does them, in one pass without its generic reset machinery.

        ``tensordict`` gets ``("next", ...)``, the step's true outcome (a copy that
        ended keeps its terminal observation there), as ``step`` gives it. The second
        tensordict is the next step's input, made as ``step_mdp`` makes it; the ended
        copies restart in place (the very draws ``_reset`` makes, in the same order)
        and their rows of it read the new episode's observation, done flags false and,
        in every other entry (``action``, a policy's), zeros, as TorchRL's partial reset
        (``_update_during_reset``) pads them (unless every copy restarts: then, as
        there, those entries stay as they were; with seed blocks, every copy of a block:
        :meth:`_padded`). Inputs this path does not cover (a partial ``_step``, a preset
        ``next``, lazy stacks, named dims, another batch size, transforms' hooks) take
        ``EnvBase``'s generic path, which gives the same results."""
        if tensordict.device != self.device:
            tensordict = tensordict.to(self.device)
        action = self._one_pass_action(tensordict)
        if action is None:
            return super()._step_and_maybe_reset(tensordict)
        next_td, entries, obs32, done = self._advance(action, device=self.device)
        if self.run_type_checks:
            next_td = self._step_proc_data(next_td)
        # Made here with the batch's shape and device: TensorDict's checks are skipped.
        set_entry(tensordict, "next", next_td)
        if not done.any():
            return tensordict, self._next_input(tensordict, entries, None)
        reset_obs = self._start_episodes(done, keep_ended_info=True)
        obs = obs32.copy()
        np.copyto(obs, reset_obs, where=done[:, None])  # float64 -> float32 as astype rounds
        false = np.zeros((3, self.num_envs, 1), dtype=bool)  # three flags, apart
        restarted = {"observation": torch.from_numpy(obs), "done": torch.from_numpy(false[0]),
                     "terminated": torch.from_numpy(false[1]),
                     "truncated": torch.from_numpy(false[2])}
        return tensordict, self._next_input(tensordict, restarted, self._padded(done))

    def _padded(self, done: np.ndarray) -> np.ndarray | None:
        """The restarted rows whose other entries are zeroed (None: none). TorchRL pads them
        with zeros only in a partial reset; when every copy restarts, it leaves them as they
        are. Per seed block, as that block's env alone would: a block whose copies all
        restarted keeps its rows."""
        whole = done.reshape(self.n_blocks, self.block_size).all(axis=1)
        padded = done & ~np.repeat(whole, self.block_size)
        return padded if padded.any() else None

    # -- the step and the restart of ended copies ---------------------------------
    def _one_pass_action(self, tensordict: TensorDictBase) -> np.ndarray | None:
        """The actions as a numpy array if ``_step_and_maybe_reset``'s one-pass path
        applies to ``tensordict`` (on this env's device), else None."""
        if (type(tensordict) is not TensorDict or tensordict.batch_size != self.batch_size
                or self._post_step_mdp_hooks is not None or has_names(tensordict)
                or self.__dict__.get("_torchrl_native_autoreset", False)):
            return None  # EnvBase's path handles it (or raises, as for a wrong batch size)
        action = get_entry(tensordict, "action")
        if (action is None or get_entry(tensordict, "next") is not None
                or get_entry(tensordict, "_step") is not None or get_entry(tensordict, "_reset") is not None):
            return None
        return action.numpy().reshape(self.action_shape)

    def _advance(self, action: np.ndarray, device: torch.device | None
                 ) -> tuple[TensorDictBase, dict, np.ndarray, np.ndarray]:
        """One step of every copy: the ``next`` tensordict (on ``device``) and its
        entries, its float32 observation array and the copies' ``done`` (bool
        ``(num_envs,)``). Every array and tensor is new (callers stack the steps')."""
        physics, task, n = self.physics, self.task, self.num_envs
        task.apply_action(physics, action)
        physics.step(task.n_substeps)
        self.elapsed_steps += 1
        obs = task.observation(physics)
        terminated = np.array(task.terminated(physics, obs), dtype=bool)
        diverged = physics.diverged
        any_diverged = diverged.any()
        if any_diverged:
            terminated &= ~diverged
        truncated = self.elapsed_steps >= task.max_episode_steps
        truncated &= ~terminated
        reward = task.reward(physics, obs, terminated)
        if any_diverged:
            truncated |= diverged
            reward = np.where(diverged, 0.0, reward)
            self._report_divergences(diverged)
        done = terminated | truncated
        obs32 = obs.astype(np.float32)
        entries = {"observation": torch.from_numpy(obs32),
                   "reward": torch.from_numpy(np.array(reward, dtype=np.float32).reshape(n, 1)),
                   "done": torch.from_numpy(done.reshape(n, 1)),
                   "terminated": torch.from_numpy(terminated.reshape(n, 1)),
                   "truncated": torch.from_numpy(truncated.reshape(n, 1))}
        return self._tensordict(device, entries), entries, obs32, done

    def _start_episodes(self, mask: np.ndarray, keep_ended_info: bool) -> np.ndarray:
        """Starts new episodes in the ``mask`` copies (keeping their ``episode_info`` in
        ``ended_info`` first if asked); returns every copy's observation."""
        if keep_ended_info:
            self._keep_ended_info(mask)
        self.physics.reset(mask)
        if len(self._rngs) == 1:
            self.task.initialize_episode(self.physics, mask, self._rng)
        else:  # each block draws from its own generator, as alone
            for b, rng in enumerate(self._rngs):
                block_mask = self.block_mask(b, within=mask)
                if block_mask.any():
                    self.task.initialize_episode(self.physics, block_mask, rng)
        self.physics.forward(mask)
        self.elapsed_steps[mask] = 0
        return self.task.observation(self.physics)

    def _next_input(self, tensordict: TensorDictBase, carried: dict,
                    reset_rows: np.ndarray | None) -> TensorDictBase:
        """``step_mdp(tensordict)`` for this env's keys: the root entries but ``next``,
        the reward, the done flags and ``_reset``, with the observation and done flags
        taken from ``carried`` (the step's ``next`` or, after a restart, new tensors);
        entries ``carried`` does not hold get their ``reset_rows`` zeroed (out of place)."""
        entries = {}
        for key, value in tensordict.items():
            if key in self._mdp_dropped:
                continue
            if key == "observation":
                value = carried[key]
            elif reset_rows is not None:
                value = _zero_rows(value, reset_rows)
            elif not isinstance(value, torch.Tensor) and is_tensor_collection(value):
                value = value.copy()
            entries[key] = value
        if "observation" not in entries:
            entries["observation"] = carried["observation"]
        for key in ("done", "terminated", "truncated"):
            entries[key] = carried[key]
        return self._tensordict(tensordict.device, entries)

    def _tensordict(self, device: torch.device | None, entries: dict) -> TensorDictBase:
        """A batch-sized tensordict of ``entries`` on ``device``, built without
        TensorDict's checks (every entry is made here, on the CPU, with the batch's
        shape). ``reset`` and ``step`` get no device, as ever (they place the result)."""
        return new_tensordict(entries, self.batch_size, device)

    def _keep_ended_info(self, mask: np.ndarray) -> None:
        """Copies the task's ``episode_info`` of the ``mask`` copies into ``ended_info``."""
        for key, value in self.task.episode_info(self.physics).items():
            self.ended_info.setdefault(key, np.zeros(self.num_envs))[mask] = np.asarray(value)[mask]

    def _report_divergences(self, diverged: np.ndarray) -> None:
        for i in np.flatnonzero(diverged):
            self.divergences += 1
            self.block_divergences[i // self.block_size] += 1
            _log.warning(
                "physics diverged in env copy %d at step %d of its episode; episode "
                "truncated (%d divergences so far)",
                i, self.elapsed_steps[i], self.divergences,
            )

    # -- extras -----------------------------------------------------------------
    def check_camera(self, camera: str | int | None = None) -> str | int:
        """``camera`` if the model has it (a name of ``camera_names``, or an index, -1 being
        MuJoCo's free camera), else a ``ValueError`` listing the cameras; ``None`` is
        the task's first camera (the free one if it has none)."""
        names, n = self.camera_names, len(self.camera_names)
        if camera is None:
            return 0 if n else -1
        if camera in names or (isinstance(camera, (int, np.integer)) and not isinstance(camera, bool)
                               and -1 <= camera < n):
            return camera
        raise ValueError(f"camera {camera!r} is not a camera of this model; its cameras: "
                         f"{', '.join(names) or 'none'} (or an index in [-1, {n - 1}], "
                         f"-1 MuJoCo's free camera)")

    def check_frame_size(self, width: int, height: int) -> None:
        """A ``ValueError`` unless a ``width`` x ``height`` frame fits the model's offscreen
        buffer (the arenas make it 1920 x 1080)."""
        most = (self.model.vis.global_.offwidth, self.model.vis.global_.offheight)
        if not (1 <= width <= most[0] and 1 <= height <= most[1]):
            raise ValueError(f"frame size must be from 1x1 to {most[0]}x{most[1]} (the model's "
                             f"offscreen buffer); got {width}x{height}")

    def load_state_of(self, other: "RobotTaskEnv") -> None:
        """Takes ``other``'s whole state: every copy's physics, the step counters, the
        randomness, the task's and the robot's state. ``other`` must be built from the
        same config (same model and number of copies)."""
        if (other.num_envs, other.physics.nstate) != (self.num_envs, self.physics.nstate):
            raise ValueError(f"cannot take the state of an env of {other.num_envs} copies of "
                             f"{other.physics.nstate} state values: this one has {self.num_envs} "
                             f"of {self.physics.nstate}")
        for name in ("state", "ctrl", "sensordata"):  # in place: qpos and qvel view the state
            getattr(self.physics, name)[:] = getattr(other.physics, name)
        self.elapsed_steps[:] = other.elapsed_steps
        self.divergences = other.divergences
        self.ended_info = {k: v.copy() for k, v in other.ended_info.items()}
        for mine, theirs in zip(self._rngs, other._rngs, strict=True):
            mine.bit_generator.state = theirs.bit_generator.state
        self.block_divergences[:] = other.block_divergences
        self.task.load_state_dict(other.task.state_dict())
        self.task.robot.load_state_dict(other.task.robot.state_dict())

    def render(self, width: int = 480, height: int = 360, camera: str | int = -1,
               index: int = 0) -> np.ndarray:
        """An RGB frame (``height x width x 3``, uint8) of copy ``index`` seen by ``camera``
        (see :meth:`check_camera`)."""
        self.check_camera(camera)
        self.check_frame_size(width, height)
        if self._renderer is None or (self._renderer.width, self._renderer.height) != (width, height):
            if self._renderer is not None:
                self._renderer.close()
            self._renderer = mujoco.Renderer(self.model, height=height, width=width)
            _RENDERERS.add(self._renderer)
            # After MuJoCo's own exit hook (it ends the EGL display, registered with the first
            # GL context): the last registered runs first, so renderers close while they can.
            atexit.unregister(_close_renderers)
            atexit.register(_close_renderers)
            self._render_data = mujoco.MjData(self.model)
        self.physics.load_into(self._render_data, index)
        self._renderer.update_scene(self._render_data, camera=camera)
        return self._renderer.render()

    def close(self, *, raise_if_closed: bool = True) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None
        self.physics.close()
        super().close(raise_if_closed=raise_if_closed)


# Renderers not closed by their env's close(): closed at exit before the GL display under
# them ends (else an env left open prints two EGLError tracebacks at exit).
_RENDERERS: weakref.WeakSet = weakref.WeakSet()


def _close_renderers() -> None:
    for renderer in list(_RENDERERS):
        try:
            renderer.close()
        except Exception:  # noqa: BLE001 - at exit, a renderer that cannot close is left to the OS
            pass


class _Rows:
    """Attribute access that slices every array attribute of ``inner`` to ``rows``."""

    def __init__(self, inner, rows: slice) -> None:
        self._inner, self._rows = inner, rows

    def __getattr__(self, name: str):
        value = getattr(self._inner, name)
        return value[self._rows] if isinstance(value, np.ndarray) else value

    def state_dict(self) -> dict[str, np.ndarray]:
        return {k: v[self._rows] for k, v in self._inner.state_dict().items()}

    def load_state_dict(self, state: Mapping[str, np.ndarray]) -> None:
        """Restores these rows of ``inner``'s per-copy state (the other rows as they are)."""
        full = self._inner.state_dict()
        for key, value in state.items():
            if key in full:
                full[key][self._rows] = value
        self._inner.load_state_dict({**full, **{k: v for k, v in state.items() if k not in full}})


class SeedBlock:
    """One seed block of a :class:`RobotTaskEnv`, read as an env of ``block_size`` copies:
    what a run books and checkpoints (``num_envs``, ``divergences``, ``ended_info``, the
    block's physics arrays, step counters, generator and per-copy task state). It does not
    step: the whole env steps every block at once."""

    def __init__(self, env: RobotTaskEnv, b: int) -> None:
        self.env, self.index, self.rows = env, b, env.block(b)
        self.num_envs = env.block_size
        self.physics = _Rows(env.physics, self.rows)
        self.task = _Rows(env.task, self.rows)
        self.task.robot = _Rows(env.task.robot, self.rows)

    @property
    def divergences(self) -> int:
        return int(self.env.block_divergences[self.index])

    @divergences.setter
    def divergences(self, count: int) -> None:  # a resumed seed's count, from its checkpoint
        self.env.divergences += int(count) - int(self.env.block_divergences[self.index])
        self.env.block_divergences[self.index] = int(count)

    @property
    def ended_info(self) -> dict[str, np.ndarray]:
        return {k: v[self.rows] for k, v in self.env.ended_info.items()}

    @property
    def elapsed_steps(self) -> np.ndarray:
        return self.env.elapsed_steps[self.rows]

    @property
    def _rng(self) -> np.random.Generator:
        return self.env._rngs[self.index]
