"""Policy videos: an MP4 that decodes to the right frames; the run-folder CLI."""

import os
import subprocess
import sys
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from hydra.utils import instantiate
from tasks import factory
from tasks import catalog
from runs import video
from runs.checkpoint import save_model

ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"


def config(*overrides: str):
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", overrides=list(overrides))
    OmegaConf.resolve(cfg)
    return cfg


def read_frames(path: Path) -> np.ndarray:
    reader = imageio.get_reader(path, format="FFMPEG")
    try:
        return np.stack(list(reader.iter_data()))
    finally:
        reader.close()


@pytest.fixture
def dqn_on_cartpole():
    cfg = config("robot=cartpole", "learner=dqn")
    learner = instantiate(cfg.learner, _convert_="all")
    env = factory.build_env(cfg, num_envs=1, seed=0)
    learner.build(env.task)
    yield cfg, learner.member(0), env
    env.close()


def test_record_video_decodes_to_the_frames_it_wrote(tmp_path, dqn_on_cartpole):
    _, learner, env = dqn_on_cartpole
    path = tmp_path / "sub" / "policy.mp4"
    with learner.greedy():
        n = video.record_video(env, learner.policy, path, n_steps=29, width=120, height=90)
    assert n == 30
    frames = read_frames(path)
    assert frames.shape == (30, 90, 120, 3) and frames.dtype == np.uint8
    assert all(frame.std() > 5 for frame in frames)  # a scene, not a blank
    motion = np.abs(np.diff(frames.astype(np.int16), axis=0)).mean(axis=(1, 2, 3))
    assert (motion > 0).sum() >= 10  # the cart-pole moves
    reader = imageio.get_reader(path, format="FFMPEG")
    meta = reader.get_meta_data()
    reader.close()
    assert meta["codec"] == "h264" and meta["fps"] == pytest.approx(25.0)  # 1 / running_step


def test_record_video_rejects_odd_sizes(tmp_path, dqn_on_cartpole):
    _, learner, env = dqn_on_cartpole
    with pytest.raises(ValueError, match="even"):
        video.record_video(env, learner.policy, tmp_path / "x.mp4", n_steps=1, width=121, height=90)


def save_run_folder(cfg, learner, run_dir: Path) -> Path:
    """The two files of a finished run that the video CLI reads."""
    run_dir.mkdir(parents=True)
    OmegaConf.save(cfg, run_dir / "config.yaml", resolve=True)
    save_model(run_dir / "model.pt", learner, meta={})
    return run_dir


@pytest.fixture
def run_folder(tmp_path, dqn_on_cartpole):
    cfg, learner, _ = dqn_on_cartpole
    return save_run_folder(cfg, learner, tmp_path / "run")


def test_cli_writes_policy_mp4_of_a_run_folder(run_folder, capsys):
    video.main([str(run_folder), "--steps", "4", "--width", "64", "--height", "48"])
    assert f"video in {run_folder / 'policy.mp4'}" in capsys.readouterr().out
    assert read_frames(run_folder / "policy.mp4").shape == (5, 48, 64, 3)


@pytest.mark.parametrize("camera", ["side", "0", "-1"])
def test_cli_camera_by_name_or_index(run_folder, camera):
    out = run_folder / f"cam{camera}.mp4"
    video.main([str(run_folder), "--steps", "1", "--width", "32", "--height", "24",
                "--camera", camera, "--out", str(out)])
    assert read_frames(out).shape == (2, 24, 32, 3)


def test_cli_frame_larger_than_the_offscreen_buffer_is_one_line(run_folder, capsys):
    with pytest.raises(SystemExit) as exit_:
        video.main([str(run_folder), "--steps", "1", "--width", "4000", "--height", "720"])
    assert exit_.value.code == 2
    assert capsys.readouterr().err == ("error: frame size must be from 1x1 to 1920x1080 (the "
                                       "model's offscreen buffer); got 4000x720\n")
    assert not (run_folder / "policy.mp4").exists()


@pytest.mark.parametrize("camera", ["top", "1", "-2"])
def test_cli_with_a_camera_the_model_lacks_lists_its_cameras(run_folder, capsys, camera):
    with pytest.raises(SystemExit) as exit_:
        video.main([str(run_folder), "--steps", "1", "--camera", camera])
    assert exit_.value.code == 2
    shown = repr(int(camera)) if camera.lstrip("-").isdigit() else repr(camera)
    assert capsys.readouterr().err == (
        f"error: camera {shown} is not a camera of this model; its cameras: side "
        f"(or an index in [-1, 0], -1 MuJoCo's free camera)\n")
    assert not (run_folder / "policy.mp4").exists()


def test_cli_on_a_folder_without_model_is_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        video.main([str(tmp_path)])
    assert exit_.value.code == 2
    err = capsys.readouterr().err.strip()
    assert err == f"error: {tmp_path} is not a run folder: it has no config.yaml"


@pytest.mark.skipif("video" not in OmegaConf.load(CONF / "config.yaml"),
                    reason="train.py has no video flag yet")
def test_train_with_video_flag_writes_policy_mp4(tmp_path):
    cmd = [sys.executable, "train.py", f"hydra.run.dir={tmp_path}", "quiet=true", "learner=dqn",
           "max_episodes=3", "eval_episodes=0", "video=true", "video_steps=9"]
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-1500:]
    assert proc.stdout.strip().splitlines()[-1].startswith("VERDICT ")
    assert read_frames(tmp_path / "policy.mp4").shape[0] == 10


@pytest.mark.parametrize("robot", catalog.robot_names())
def test_every_robot_renders_full_hd(robot):
    """The arena sizes MuJoCo's offscreen buffer for 1920 x 1080 (its default is 640 x 480)."""
    env = catalog.make_env(robot)
    env.reset()
    frame = env.render(1920, 1080)
    assert frame.shape == (1080, 1920, 3) and frame.std() > 5  # a picture, not a blank
    env.close()


@pytest.mark.parametrize("args, words", [
    (["--fps", "-5"], "--fps must be a number in (0, 1000] (default: real time); got -5"),
    (["--fps", "nan"], "--fps must be a number in (0, 1000]"),
    (["--steps", "-1"], "--steps must be an integer in [0, 100000]; got -1"),
    (["--steps", "x"], "argument --steps: invalid int value: 'x'"),
    (["--bogus"], "unrecognized arguments: --bogus"),
    (["--out", "{file}/x.mp4"], "lies below {file}, which is a file; allowed: a path in a folder"),
    (["--out", "{folder}"], "is a folder; allowed: the path of an .mp4 file"),
])
def test_cli_bad_arguments_are_one_line_before_anything_is_built(run_folder, tmp_path, capsys, args, words):
    (tmp_path / "notes.txt").write_text("x")
    where = {"file": tmp_path / "notes.txt", "folder": tmp_path}
    with pytest.raises(SystemExit) as exit_:
        video.main([str(run_folder), *(a.format(**where) for a in args)])
    err = capsys.readouterr().err.splitlines()
    assert exit_.value.code == 2 and len(err) == 1 and err[0].startswith("error: "), err
    assert words.format(**where) in err[0]
    assert not (run_folder / "policy.mp4").exists()


@pytest.mark.parametrize("text, words", [
    ("learner: [1, 2\n", "config.yaml does not parse"),
    ("- 1\n", "must hold a mapping of settings"),
    ("learner:\n  _target_: os.system\n", "learner._target_='os.system' is not allowed"),
    (None, "learner.gamma must be a finite number in [0, 1]; got -3"),
])
def test_cli_on_a_damaged_config_is_one_line(run_folder, capsys, text, words):
    config = run_folder / "config.yaml"
    config.write_text(text if text is not None else config.read_text().replace("gamma: ", "gamma: -3 #", 1))
    with pytest.raises(SystemExit) as exit_:
        video.main([str(run_folder), "--steps", "1"])
    err = capsys.readouterr().err.splitlines()
    assert exit_.value.code == 2 and len(err) == 1 and words in err[0], err
    assert not (run_folder / "policy.mp4").exists()


def test_python_m_runs_video_renders_headless_without_mujoco_gl_set(run_folder, tmp_path):
    """``python -m runs.video <run>`` as a user types it on a machine without a display and
    without ``MUJOCO_GL``: ``torchrl.envs.utils`` imports MuJoCo first, so ``runs`` sets the
    headless backend when it is imported (it crashed with ``gladLoadGL error``)."""
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM", "DISPLAY")}
    out = tmp_path / "headless.mp4"
    proc = subprocess.run([sys.executable, "-m", "runs.video", str(run_folder), "--out", str(out), "--steps", "5",
                           "--width", "64", "--height", "48"],
                          cwd=ROOT, capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-1500:]
    assert read_frames(out).shape[0] == 6
