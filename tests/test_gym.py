"""Gymnasium registration: every robot's default task makes, passes check_env, seeds, steps;
the ids work in subprocess workers; actions, copies and observation bounds as clients use them."""

import copy
import os
import subprocess
import sys
import textwrap
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hydra import compose, initialize_config_dir
from hydra.core.global_hydra import GlobalHydra
from omegaconf import OmegaConf

import adapters.register_gym  # noqa: F401  (registers the MujocoRL ids)
from tasks import catalog
from adapters.gym_env import MujocoRLEnv, default_tasks, env_id, register_envs

ROOT = Path(__file__).resolve().parents[1]
BIG = np.finfo(np.float32).max  # the bound of an entry the task knows no bound for


def _expected() -> dict[str, tuple[str, int, int, int]]:
    """id -> (robot, observation size, actions, time limit), found in the config tree: every
    conf/robot/*.yaml with the task its ``defaults`` name, that task built for its sizes and
    its YAML's ``max_episode_steps`` (no list of robots to keep up to date)."""
    out = {}
    for path in sorted((ROOT / "conf" / "robot").glob("*.yaml")):
        robot = path.stem
        task = next(e["/task"] for e in OmegaConf.load(path).defaults if "/task" in e)
        steps = OmegaConf.load(ROOT / "conf" / "task" / f"{task}.yaml").max_episode_steps
        built = catalog.built(robot, task)
        out[env_id(robot, task)] = (robot, len(built.observation_names), built.n_actions, steps)
    return out


EXPECTED = _expected()


@pytest.fixture
def make():
    envs = []

    def _make(env_name: str, **kwargs):
        env = gym.make(env_name, **kwargs)
        envs.append(env)
        return env

    yield _make
    for env in envs:
        env.close()


def test_every_robot_is_registered_with_its_default_task():
    ids = register_envs()
    assert sorted(ids) == sorted(EXPECTED)
    assert register_envs() == ids  # idempotent
    robots = sorted(p.stem for p in (ROOT / "conf" / "robot").glob("*.yaml"))
    assert sorted(default_tasks()) == robots
    for name in ids:
        assert name in gym.registry and gym.spec(name).namespace == "MujocoRL"
        assert gym.spec(name).max_episode_steps == EXPECTED[name][3]
    assert env_id("cartpole", "stay_up") == "MujocoRL/CartPoleStayUp-v0"
    assert {"MujocoRL/CartPoleStayUp-v0", "MujocoRL/AcrobotSwingup-v0",
            "MujocoRL/DoublePendulumBalance-v0"} <= set(ids)


def test_importing_the_packages_registers_nothing():
    """Only an explicit call (``register_envs``, or importing ``adapters.register_gym``)
    registers the ids: importing ``tasks``, ``runs`` or ``learners`` does not."""
    code = ("import gymnasium as gym, tasks, adapters.gym_env, runs.run, learners.dqn\n"
            "print(sorted(k for k in gym.registry if k.startswith('MujocoRL/')))\n"
            "adapters.gym_env.register_envs()\n"
            "print(len([k for k in gym.registry if k.startswith('MujocoRL/')]))\n")
    assert run_python(["-c", code])[-2:] == ["[]", str(len(EXPECTED))]


def test_registration_reads_what_a_composition_gives():
    """The ids are registered from the YAML files without composing: the same default task
    and time limit as the composed config of every robot without a learner's tuned file (the
    cube's set 300 steps for training; its id keeps the task's 1000)."""
    from adapters.gym_env import _plain_default

    for robot in catalog.robot_names():
        cfg = catalog.compose(robot, overrides=["~tuned"])
        assert _plain_default(robot) == (catalog.default_task(robot), int(cfg.task.max_episode_steps))


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_make_and_check_env(make, name):
    robot, n_obs, n_actions, _ = EXPECTED[name]
    env = make(name, render_mode="rgb_array", width=64, height=48)
    assert env.unwrapped.config.robot._target_ == catalog.compose(robot).robot._target_
    assert env.observation_space.shape == (n_obs,) and env.observation_space.dtype == np.float32
    assert env.action_space == gym.spaces.Discrete(n_actions)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no warning at all, about bounds or anything else
        check_env(env.unwrapped)
    obs, info = env.reset(seed=0)
    assert obs.dtype == np.float32 and obs.shape == (n_obs,) and isinstance(info, dict)
    frame = env.render()
    assert frame.shape == (48, 64, 3) and frame.dtype == np.uint8 and frame.std() > 0


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_the_continuous_form_is_a_box_that_check_env_passes(make, name):
    """``actions="continuous"``: a ``Box(-1, 1)`` of the task's continuous actions (SB3's SAC and
    PPO take it); an action of the wrong size or not finite is one clear error."""
    env = make(name, actions="continuous")
    dims = env.unwrapped.task.action_range.dims
    assert env.action_space == gym.spaces.Box(-1.0, 1.0, (dims,), dtype=np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped)
    env.reset(seed=0)
    obs, reward, *_ = env.step(np.full(dims, 0.5, dtype=np.float32))
    assert np.isfinite(obs).all() and np.isfinite(reward)
    for bad in (np.zeros(dims + 1), [float("nan")] * dims):
        with pytest.raises(ValueError, match=rf"action must be {dims} finite number\(s\) in \[-1, 1\]"):
            env.step(bad)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_seeded_reset_reproduces_trajectories(make, name):
    env = make(name)

    def rollout(seed):
        obs, _ = env.reset(seed=seed)
        start = env.unwrapped.torchrl_env.physics.qpos[0].copy()  # observations may be rounded
        out = [obs]
        rng = np.random.default_rng(0)
        for _ in range(5):
            obs, reward, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
            assert obs in env.observation_space and isinstance(reward, float)
            assert isinstance(terminated, bool) and isinstance(truncated, bool)
            out.append(obs)
            if terminated or truncated:
                break
        return start, np.stack(out)

    (s1, a), (s2, b), (s3, c) = rollout(11), rollout(11), rollout(12)
    assert np.array_equal(s1, s2) and np.array_equal(a, b)
    assert not np.array_equal(s1, s3)


def test_cartpole_steps_follow_the_task(make):
    env = make("MujocoRL/CartPoleStayUp-v0", max_episode_steps=400)
    env.reset(seed=0)
    for t in range(1, 401):  # always push right: the pole or the cart leaves its range
        obs, reward, terminated, truncated, _ = env.step(1)
        assert reward == 1.0
        if terminated:
            break
    assert terminated and not truncated and t < 100
    assert abs(obs[0]) >= 1.0 or abs(obs[2]) >= 0.7
    with pytest.raises(ValueError, match="action"):
        env.step(2)


def test_time_limit_and_episode_info(make):
    env = make("MujocoRL/MovingCubeOneDiskWalk-v0", max_episode_steps=3)
    env.reset(seed=0)
    steps = [env.step(2)[2:] for _ in range(3)]  # action 2: wheel stopped, the cube rests
    assert [s[:2] for s in steps] == [(False, False), (False, False), (False, True)]
    assert all(set(info) == {"y_displacement", "distance_walked"} for *_, info in steps)
    direct = MujocoRLEnv("cube", max_episode_steps=2)  # no make(): the task's own limit
    try:
        direct.reset(seed=0)
        assert [direct.step(2)[2:4] for _ in range(2)] == [(False, False), (False, True)]
    finally:
        direct.close()


def test_make_kwargs_override_task_and_robot_parameters(make):
    env = make("MujocoRL/CartPoleStayUp-v0", pos_step=0.5, n_actions=4,
               robot_params={"velocity_gain": 500.0})
    assert env.unwrapped.task.pos_step == 0.5 and env.action_space.n == 4
    assert env.unwrapped.config.robot.velocity_gain == 500.0
    with pytest.raises(TypeError, match="pos_stepp"):
        gym.make("MujocoRL/CartPoleStayUp-v0", pos_stepp=0.5)


def test_composing_inside_a_running_hydra_app_keeps_its_state():
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        app = GlobalHydra.instance().hydra
        cfg = catalog.compose("cube")
        assert cfg.task._target_ == "tasks.one_disk_walk.OneDiskWalk"
        assert GlobalHydra.instance().hydra is app
        assert compose(config_name="config").robot._target_ == "robots.cartpole.CartPole"


def run_python(args: list[str], cwd: Path | str = "/", timeout: int = 300) -> list[str]:
    """Runs this Python on ``args`` with the project on the path; its stdout lines."""
    env = {**os.environ, "PYTHONPATH": str(ROOT), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    proc = subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=timeout)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc.stdout.strip().splitlines()


def run_script(tmp_path: Path, source: str) -> list[str]:
    """Runs ``source`` as a client's script file (workers import it again: see adapters.gym_env)."""
    script = tmp_path / "client.py"
    script.write_text(textwrap.dedent(source))
    return run_python([str(script)], cwd=tmp_path)


def test_plain_gymnasium_user_makes_it_after_the_import_or_with_the_prefix():
    """No script file (``python -c``): a spawned worker has nothing to import again, so it
    takes the prefixed id, which imports adapters.register_gym there too."""
    code = textwrap.dedent("""
        import gymnasium as gym
        env = gym.make("adapters.register_gym:MujocoRL/TurtleBot2Maze-v0")  # imports adapters.register_gym first
        obs, _ = env.reset(seed=1)
        print(env.spec.id, obs.shape, obs in env.observation_space)
        import adapters.register_gym
        print(gym.make("MujocoRL/CartPoleStayUp-v0").spec.id)
        envs = gym.vector.AsyncVectorEnv([lambda: gym.make("adapters.register_gym:MujocoRL/CartPoleStayUp-v0")])
        print(envs.reset(seed=0)[0].shape)
        envs.close()
        """)
    assert run_python(["-c", code])[-3:] == ["MujocoRL/TurtleBot2Maze-v0 (6,) True",
                                              "MujocoRL/CartPoleStayUp-v0", "(1, 4)"]


def test_sb3_dqn_trains_on_the_bare_id_in_subprocess_workers(tmp_path):
    pytest.importorskip("stable_baselines3")  # the test extra: pip install -e ".[test]"
    out = run_script(tmp_path, """
        import os
        import torch
        torch.set_num_threads(1)
        import adapters.register_gym  # registers the MujocoRL ids: here, and in each worker importing this file
        from stable_baselines3 import DQN
        from stable_baselines3.common.env_util import make_vec_env
        from stable_baselines3.common.vec_env import SubprocVecEnv

        if __name__ == "__main__":
            venv = make_vec_env("MujocoRL/CartPoleStayUp-v0", n_envs=1, seed=0,
                                vec_env_cls=SubprocVecEnv)  # one worker proves it (each costs its imports)
            model = DQN("MlpPolicy", venv, learning_starts=200, seed=0, device="cpu")
            model.learn(800)  # 600 steps of updates: it trains there, which is what is asked
            workers = {type(p).__name__ for p in venv.processes if p.pid != os.getpid()}
            print(model.num_timesteps, len(venv.processes), *workers)
            print(*sorted({spec.id for spec in venv.get_attr("spec")}))
            venv.close()
        """)
    assert out[-2].split() == ["800", "1", "ForkServerProcess"]  # SB3's default: no fork
    assert out[-1] == "MujocoRL/CartPoleStayUp-v0"


def test_async_vector_env_makes_the_bare_id_in_spawned_workers(tmp_path):
    out = run_script(tmp_path, """
        import multiprocessing
        import gymnasium as gym
        import adapters.register_gym  # registers the MujocoRL ids: here, and in each worker importing this file

        def make():
            return gym.make("MujocoRL/TurtleBot2Maze-v0")

        if __name__ == "__main__":
            envs = gym.vector.AsyncVectorEnv([make])  # one spawned worker proves it (each costs its imports)
            obs, _ = envs.reset(seed=0)
            for _ in range(3):
                obs, *_ = envs.step(envs.action_space.sample())
            print(multiprocessing.get_start_method(), obs.shape, obs in envs.observation_space)
            envs.close()
        """)
    assert out[-1] == "spawn (1, 6) True"  # TorchRL makes spawn the default


@pytest.mark.parametrize("action", [1, np.int64(1), np.uint8(1), np.array(1), np.array([1]),
                                    np.array([1], dtype=np.int32), 1.0, np.float32(1.0)])
def test_step_takes_an_integer_in_any_common_form(make, action):
    env = make("MujocoRL/CartPoleStayUp-v0")
    env.reset(seed=0)
    obs = env.step(action)[0]
    twin = make("MujocoRL/CartPoleStayUp-v0")
    twin.reset(seed=0)
    assert np.array_equal(obs, twin.step(1)[0])


@pytest.mark.parametrize("action", [2, -1, 0.5, np.nan, True, np.array([0, 1]), np.array([[1]]),
                                    np.zeros((0,), int), "1", None, [1, 0]])
def test_a_bad_action_is_one_clear_error(make, action):
    env = make("MujocoRL/CartPoleStayUp-v0")
    env.reset(seed=0)
    with pytest.raises(ValueError) as err:
        env.step(action)
    message = str(err.value)
    assert message.startswith("action must be an integer in [0, 1] (an int, a numpy integer, or an "
                              "array of shape () or (1,) holding one); got ")
    assert "\n" not in message


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_deepcopy_is_an_independent_env_in_the_same_state(make, name):
    env = make(name, render_mode="rgb_array", width=32, height=24)
    env.reset(seed=3)
    for _ in range(3):
        env.step(0)
    twin = copy.deepcopy(env)
    assert twin.unwrapped is not env.unwrapped and twin.spec.id == name
    assert twin.unwrapped.torchrl_env is not env.unwrapped.torchrl_env
    assert np.array_equal(twin.render(), env.render())
    rng = np.random.default_rng(0)
    for action in rng.integers(env.action_space.n, size=6):
        a, b = env.step(action), twin.step(action)
        assert np.array_equal(a[0], b[0]) and a[1:] == b[1:]
        if a[2] or a[3]:
            break
    assert np.array_equal(env.reset()[0], twin.reset()[0])  # the same randomness too
    before = env.unwrapped.torchrl_env.physics.state.copy()
    twin.step(1)
    twin.close()
    assert np.array_equal(env.unwrapped.torchrl_env.physics.state, before)
    env.step(1)  # the original still works after its copy is closed


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_observations_stay_in_the_declared_bounds(make, name):
    env = make(name, max_episode_steps=60)
    space = env.observation_space
    assert np.isfinite(space.low).all() and np.isfinite(space.high).all()
    rng = np.random.default_rng(1)
    for episode in range(4):
        obs, _ = env.reset(seed=episode)
        done = False
        while not done:
            assert obs in space, (obs, space)
            obs, _, terminated, truncated, _ = env.step(int(rng.integers(env.action_space.n)))
            done = terminated or truncated
        assert obs in space, (obs, space)


def test_bounds_are_the_tasks_true_ones_and_only_those():
    maze = gym.make("MujocoRL/TurtleBot2Maze-v0").observation_space  # laser sectors: 0 .. range
    assert np.array_equal(maze.low, np.zeros(6)) and np.array_equal(maze.high, np.full(6, 6.0))
    cube = gym.make("MujocoRL/MovingCubeOneDiskWalk-v0").observation_space
    # wheel_speed, y_distance, roll, pitch, y_speed, yaw: angles known, the rest not
    np.testing.assert_allclose(cube.high, [BIG, BIG, 3.1, 1.6, BIG, 3.1], rtol=1e-6)
    assert np.array_equal(cube.low, -cube.high)
    cartpole = gym.make("MujocoRL/CartPoleStayUp-v0").observation_space  # soft joint limits
    assert np.array_equal(cartpole.high, np.full(4, BIG)) and np.array_equal(cartpole.low, -cartpole.high)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_torchrls_own_gym_env_opens_every_id_and_passes_check_env_specs(name):
    """``torchrl.envs.GymEnv("MujocoRL/...")`` (TorchRL passes ``frameskip=`` to the maker and,
    told it is an unexpected keyword, repeats actions itself), beside the native EnvBase."""
    from torchrl.envs import GymEnv
    from torchrl.envs.utils import check_env_specs

    robot, n_obs, n_actions, _ = EXPECTED[name]
    env = GymEnv(name)
    try:
        check_env_specs(env)
        assert env.observation_spec["observation"].shape == (n_obs,)
        assert env.action_spec.shape == (n_actions,)  # one-hot, TorchRL's default for Discrete
        assert env.rollout(4)["next", "reward"].shape == (4, 1)
    finally:
        env.close()


def test_torchrls_gym_env_takes_task_parameters_and_its_own_frame_skip():
    from torchrl.envs import GymEnv

    env = GymEnv("MujocoRL/CartPoleStayUp-v0", frame_skip=2, pos_step=0.5)
    try:
        assert env._env.unwrapped.task.pos_step == 0.5
        rewards = env.rollout(3)["next", "reward"].flatten().tolist()
        assert rewards == [2.0, 2.0, 2.0]  # two task steps of +1 per action
    finally:
        env.close()
    with pytest.raises(TypeError, match="unexpected keyword argument 'pos_stepp'"):
        GymEnv("MujocoRL/CartPoleStayUp-v0", pos_stepp=0.5)


def test_make_without_a_time_limit_is_refused():
    """``max_episode_steps=-1`` drops Gymnasium's TimeLimit; the task's own limit is lifted
    under ``gymnasium.make``, so its episodes could run for ever: refused in one line."""
    register_envs()
    with pytest.raises(ValueError) as err:
        gym.make("MujocoRL/CartPoleStayUp-v0", max_episode_steps=-1)
    assert str(err.value).startswith("max_episode_steps=-1 is refused") and "allowed: a positive integer" in str(err.value)
    env = gym.make("MujocoRL/CartPoleStayUp-v0", max_episode_steps=3)
    env.reset(seed=0)
    assert env.spec.max_episode_steps == 3
    env.close()


def test_an_env_left_open_after_rendering_exits_without_gl_errors():
    """The Gymnasium snippet of docs/gymnasium.md without env.close(): the renderer is closed at exit
    before the EGL display is ended, so nothing is printed at interpreter exit."""
    import subprocess
    import sys

    code = ("import gymnasium as gym\nfrom adapters.gym_env import register_envs\nregister_envs()\n"
            "env = gym.make('MujocoRL/CartPoleStayUp-v0', render_mode='rgb_array')\n"
            "env.reset(seed=0)\nprint(env.render().shape)\n")
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env=env)
    assert proc.returncode == 0 and proc.stdout.strip() == "(360, 480, 3)", proc.stderr[-2000:]
    assert "Exception ignored" not in proc.stderr and "Error" not in proc.stderr, proc.stderr[-2000:]
