"""rl-baselines3-zoo on our ids: the hyperparameter file the project ships (conf/zoo/dqn.yml)
is SB3 DQN settings for registered ids, and ``python -m adapters.zoo <script>`` registers the
ids before it runs the zoo's script (the zoo itself is not a dependency: a stand-in
``rl_zoo3`` package here records what the real one would be given)."""

import ast
import importlib.util
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import gymnasium as gym
import pytest
import yaml

import adapters.register_gym  # noqa: F401  (registers the MujocoRL ids)
from tasks.catalog import conf_dir

ROOT = Path(__file__).resolve().parents[1]
ZOO_ONLY = ("n_timesteps", "policy", "normalize", "n_envs", "frame_stack", "env_wrapper", "callback")


def zoo_settings() -> dict:
    return yaml.safe_load((conf_dir() / "zoo" / "dqn.yml").read_text())


def test_the_zoo_file_is_sb3_dqn_settings_for_our_registered_ids():
    from stable_baselines3 import DQN
    from stable_baselines3.common.env_checker import check_env

    settings = zoo_settings()
    assert "MujocoRL/CartPoleStayUp-v0" in settings
    for env_id, hyper in settings.items():
        env = gym.make(env_id)
        check_env(env.unwrapped)  # SB3's own checker
        kwargs = {k: v for k, v in hyper.items() if k not in ZOO_ONLY}
        if "policy_kwargs" in kwargs:  # the zoo evaluates this string
            kwargs["policy_kwargs"] = eval(kwargs["policy_kwargs"], {"dict": dict})  # noqa: S307
        model = DQN(hyper["policy"], env, seed=0, **kwargs)  # every key is DQN's
        model.learn(total_timesteps=200)
        assert model.num_timesteps >= 200 and hyper["n_timesteps"] >= 10_000
        env.close()


def fake_zoo(folder: Path) -> Path:
    """A stand-in ``rl_zoo3`` whose ``record_video`` writes what it was given and whether
    our ids were registered when it ran."""
    package = folder / "rl_zoo3"
    package.mkdir(parents=True)
    (package / "__init__.py").write_text("")
    (package / "record_video.py").write_text(textwrap.dedent("""
        import sys
        import gymnasium as gym
        if __name__ == "__main__":
            print("ARGV", sys.argv)
            print("REGISTERED", "MujocoRL/CartPoleStayUp-v0" in gym.envs.registry)
    """))
    return folder


def zoo_cli(*args: str, path: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"), "PYTHONPATH": f"{path}{os.pathsep}{ROOT}"}
    return subprocess.run([sys.executable, "-m", "adapters.zoo", *args], cwd=ROOT, capture_output=True,
                          text=True, timeout=300, env=env)


def test_runs_zoo_registers_the_ids_then_runs_the_zoo_script(tmp_path):
    proc = zoo_cli("record_video", "--algo", "dqn", "--env", "MujocoRL/CartPoleStayUp-v0", "-n", "10",
                   path=fake_zoo(tmp_path))
    assert proc.returncode == 0, proc.stderr[-2000:]
    lines = dict(line.split(" ", 1) for line in proc.stdout.splitlines() if line.startswith(("ARGV", "REGISTERED")))
    argv = ast.literal_eval(lines["ARGV"])  # as ``python -m rl_zoo3.record_video ...`` gives it
    assert argv[0].endswith("record_video.py")
    assert argv[1:] == ["--algo", "dqn", "--env", "MujocoRL/CartPoleStayUp-v0", "-n", "10"]
    assert lines["REGISTERED"] == "True"


def test_runs_zoo_refuses_an_unknown_script_and_names_a_missing_zoo(monkeypatch, capsys):
    from adapters import zoo

    with pytest.raises(SystemExit) as stop:
        zoo.main(["fly"])
    assert stop.value.code == 2
    assert capsys.readouterr().err.startswith("usage: python -m adapters.zoo {train,enjoy,record_video")
    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "rl_zoo3" else real(name, *a))
    with pytest.raises(SystemExit) as stop:
        zoo.main(["enjoy", "--algo", "dqn"])
    assert stop.value.code == 2
    assert capsys.readouterr().err.strip() == "error: adapters.zoo needs rl-baselines3-zoo: pip install rl_zoo3"
