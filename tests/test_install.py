"""``pip install .`` (not editable) works on its own: the installed packages carry their
configs and MJCF models, so Gymnasium ids make and the video CLI renders away from the
source tree."""

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import imageio.v2 as imageio
import pytest

ROOT = Path(__file__).resolve().parents[1]
CLIENT = """
    import runpy
    import sys
    from pathlib import Path

    import gymnasium as gym
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    import learners
    from runs.checkpoint import save_model
    from tasks import factory
    from tasks import catalog

    site = Path(sys.argv[1])
    for module in (factory, learners):
        assert Path(module.__file__).is_relative_to(site), module.__file__  # not the source tree
    env = gym.make("adapters.register_gym:MujocoRL/CartPoleStayUp-v0")
    env.reset(seed=0)
    obs, reward, *_ = env.step(1)
    print(env.spec.id, obs.shape, reward)
    import conf  # docs/getting-started.md: where an installed user finds the shipped configs and models
    shipped = Path(conf.__file__).parent
    print("conf", shipped.is_relative_to(site), (shipped / "models" / "acrobot" / "acrobot.xml").is_file(),
          (shipped / "robot" / "cartpole.yaml").is_file())
    acro = gym.make("adapters.register_gym:MujocoRL/AcrobotSwingup-v0")  # its model ships in conf/models
    print(acro.spec.id, acro.reset(seed=0)[0].shape, Path(acro.unwrapped.config.robot.model).is_relative_to(site))
    cfg = catalog.compose("cartpole", learner="dqn")  # a run folder: its config and model
    learner = instantiate(cfg.learner, _convert_="all")
    learner.build(factory.build_task(cfg))
    Path("run").mkdir()
    OmegaConf.save(cfg, "run/config.yaml", resolve=True)
    save_model(Path("run/model.pt"), learner.member(0), meta={})
    sys.argv = ["runs.video", "run", "--steps", "3", "--width", "1280", "--height", "720"]
    runpy.run_module("runs.video", run_name="__main__", alter_sys=True)  # python -m
"""


def clean_clone_ignore():
    """A ``copytree`` ignore that leaves out what a clean clone lacks: ``.git`` and what
    .gitignore names (runs, studies' folders), its ``/``-anchored names at the top only
    (``/benchmark/`` is not ``docs/assets/benchmark``)."""
    lines = [line.strip() for line in (ROOT / ".gitignore").read_text().splitlines()
             if line.strip() and not line.startswith("#")]
    anywhere = shutil.ignore_patterns(".git", *(line.strip("/") for line in lines if not line.startswith("/")))
    at_top = {line.strip("/") for line in lines if line.startswith("/")}

    def ignore(folder: str, names: list[str]) -> set[str]:
        return set(anywhere(folder, names)) | (at_top & set(names) if Path(folder) == ROOT else set())
    return ignore


def test_a_plain_install_makes_gym_ids_and_full_hd_videos(tmp_path):
    pytest.importorskip("pip")
    src, site, work = tmp_path / "src", tmp_path / "site", tmp_path / "work"
    shutil.copytree(ROOT, src, ignore=clean_clone_ignore())
    # No build isolation: the build uses this environment's setuptools (no download).
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--no-build-isolation",
                    "--no-cache-dir", "--quiet", "--target", str(site), str(src)],
                   check=True, capture_output=True, timeout=300)
    work.mkdir()
    (work / "client.py").write_text(textwrap.dedent(CLIENT))
    env = {**os.environ, "PYTHONPATH": str(site), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    proc = subprocess.run([sys.executable, "client.py", str(site)], cwd=work, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = proc.stdout.strip().splitlines()
    assert lines[-4:] == ["MujocoRL/CartPoleStayUp-v0 (4,) 1.0", "conf True True True",
                          "MujocoRL/AcrobotSwingup-v0 (6,) True", "video in run/policy.mp4"]
    reader = imageio.get_reader(work / "run" / "policy.mp4", format="FFMPEG")
    try:
        frames = [frame.shape for frame in reader.iter_data()]
    finally:
        reader.close()
    assert frames == [(720, 1280, 3)] * 4
    # The installed command trains, evaluates and resumes from any folder, on the package's configs.
    script = site / "bin" / "mujoco-rl-train"
    assert script.is_file(), sorted(p.name for p in (site / "bin").iterdir())
    for args in (["max_episodes=3", "eval_episodes=0", "hydra.run.dir=trained"],
                 ["mode=eval", "checkpoint=trained", "eval_episodes=2", "hydra.run.dir=evaluated"]):
        proc = subprocess.run([sys.executable, str(script), "quiet=true", *args], cwd=work, env=env,
                              capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, (args, proc.stderr[-3000:])
    assert (work / "trained" / "model.pt").is_file() and "greedy evaluation over 2 episodes" in proc.stdout
    proc = subprocess.run([sys.executable, "-m", "train", "resume=trained"], cwd=work, env=env,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "it is finished" in proc.stderr, proc.stderr[-3000:]
