"""Videos of a policy: MP4 files of copy 0 of a ``RobotTaskEnv``, rendered headless.

    python -m runs.video <run_dir> [--steps N]     # writes <run_dir>/policy.mp4
    python -m runs.video <run_dir> --camera top --width 1280 --height 720

The CLI rebuilds the run's task and learner from ``<run_dir>/config.yaml`` and
loads ``<run_dir>/model.pt``; the video shows the greedy policy. Frames are
encoded with imageio's FFMPEG plugin (H.264, yuv420p), whose ``imageio-ffmpeg``
wheel carries its own ffmpeg binary: no system ffmpeg needed.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Callable

import imageio.v2 as imageio
import torch
from omegaconf.errors import OmegaConfBaseException
from tensordict import TensorDictBase
from torchrl.envs.utils import step_mdp

from runs.checkpoint import load_model
from runs.console import OneLineParser
from runs.settings import check_targets
from runs.training_state import load_run_config
from runs.settings import check_run_config, upgraded
from tasks.factory import build_env


def record_video(
    env,
    policy: Callable[[TensorDictBase], TensorDictBase],
    path: Path | str,
    n_steps: int = 500,
    fps: float | None = None,
    camera: str | int | None = None,
    width: int = 480,
    height: int = 360,
    progress: Callable[[int], None] | None = None,
) -> int:
    """Writes an MP4 of ``policy`` acting in ``env`` (copy 0); returns the frame count.

    The video shows the reset state and then each of ``n_steps`` steps
    (``n_steps + 1`` frames); an episode's last state is shown before the copy
    resets. ``fps`` defaults to real time (one frame per ``task.running_step``),
    ``camera`` (a name or an index of the model's) to the task's first camera; a camera
    the model lacks is a ``ValueError`` listing its cameras. Width and height must be even.
    ``progress``: told after each step how many steps are done.
    """
    if n_steps < 0:
        raise ValueError(f"n_steps must be >= 0; got {n_steps}")
    if width % 2 or height % 2 or width < 2 or height < 2:
        raise ValueError(f"width and height must be even and >= 2 (H.264 yuv420p); got {width}x{height}")
    camera = env.check_camera(camera)  # before the file is opened
    env.check_frame_size(width, height)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fps = float(fps) if fps else 1.0 / float(env.task.running_step)
    frames = 0
    writer = imageio.get_writer(path, format="FFMPEG", mode="I", fps=fps, codec="libx264",
                                pixelformat="yuv420p", macro_block_size=2, ffmpeg_log_level="error")
    try:
        with torch.no_grad():
            td = env.reset()
            writer.append_data(env.render(width, height, camera, 0))
            frames += 1
            for i in range(n_steps):
                td = env.step(policy(td))
                writer.append_data(env.render(width, height, camera, 0))
                frames += 1
                if progress is not None:
                    progress(i + 1)
                td = env.maybe_reset(step_mdp(td))
    finally:
        writer.close()
    return frames


def video_of_run(run_dir: Path | str, n_steps: int = 500, out: Path | str | None = None,
                 **kwargs) -> Path:
    """Rebuilds a finished run's env (one copy, seed ``seed + 20000``) and learner from
    its folder and writes the greedy policy's video (default ``<run_dir>/policy.mp4``);
    ``kwargs`` go to :func:`record_video`. Returns the path. A folder that is not a run's,
    a damaged config.yaml or model.pt, or a config naming classes outside the project
    is a ``ValueError`` (one line)."""
    from hydra.errors import InstantiationException
    from hydra.utils import instantiate

    run_dir = Path(run_dir)
    for name in ("config.yaml", "model.pt"):
        if not (run_dir / name).is_file():
            raise FileNotFoundError(f"{run_dir} is not a run folder: it has no {name}")
    cfg = upgraded(load_run_config(run_dir))
    check_targets(cfg)  # config.yaml is data: it may build only the project's own classes
    try:
        check_run_config(cfg)
        env = build_env(cfg, 1, int(cfg.seed) + 20_000)
        learner = instantiate(cfg.learner, _convert_="all")
    except (InstantiationException, OmegaConfBaseException) as err:
        cause = err.__cause__ or err
        raise ValueError(f"{run_dir / 'config.yaml'} does not build its run: "
                         f"{(str(cause).strip().splitlines() or [type(cause).__name__])[0]}") from None
    try:
        learner.build(env.task)
        learner = learner.member(0)
        load_model(run_dir / "model.pt", learner)
        out = Path(out) if out else run_dir / "policy.mp4"
        with learner.greedy():
            from runs.console import Ticker

            kwargs.setdefault("progress", Ticker("recording the video", n_steps, "steps"))
            record_video(env, learner.policy, out, n_steps=n_steps, **kwargs)
    finally:
        env.close()
    return out


def check_arguments(args: argparse.Namespace) -> None:
    """The numbers and the output path, before anything is built (``ValueError``, one line)."""
    if not 0 <= args.steps <= 100_000:
        raise ValueError(f"--steps must be an integer in [0, 100000]; got {args.steps}")
    if args.fps is not None and not (math.isfinite(args.fps) and 0 < args.fps <= 1000):
        raise ValueError(f"--fps must be a number in (0, 1000] (default: real time); got {args.fps:g}")
    for name in ("width", "height"):
        value = getattr(args, name)
        if not (2 <= value <= 8192 and value % 2 == 0):
            raise ValueError(f"--{name} must be an even number of pixels in [2, 8192]; got {value}")
    if args.out is not None:
        out = Path(args.out)
        if out.is_dir():
            raise ValueError(f"--out={out} is a folder; allowed: the path of an .mp4 file")
        for parent in out.parents:
            if parent.exists() and not parent.is_dir():
                raise ValueError(f"--out={out} lies below {parent}, which is a file; allowed: a path in a folder")


def main(argv: list[str] | None = None) -> None:
    parser = OneLineParser(prog="python -m runs.video", description="Write <run_dir>/policy.mp4 of a trained run's greedy policy.")
    parser.add_argument("run_dir", type=Path)
    parser.add_argument("--steps", type=int, default=500, help="env steps to record (default 500)")
    parser.add_argument("--out", type=Path, default=None, help="default <run_dir>/policy.mp4")
    parser.add_argument("--width", type=int, default=480, help="pixels, even (default 480)")
    parser.add_argument("--height", type=int, default=360, help="pixels, even (default 360)")
    parser.add_argument("--camera", default=None,
                        help="camera name or index, -1 the free camera (default: the task's first)")
    parser.add_argument("--fps", type=float, default=None, help="default: real time")
    args = parser.parse_args(argv)
    camera = int(args.camera) if args.camera and args.camera.lstrip("-").isdigit() else args.camera
    try:
        check_arguments(args)
        out = video_of_run(args.run_dir, args.steps, args.out, width=args.width,
                           height=args.height, camera=camera, fps=args.fps)
    except (FileNotFoundError, ValueError) as err:  # CheckpointError, ConfigError are ValueErrors
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    except OSError as err:  # the video file: a folder it cannot create, a full disk
        print(f"error: cannot write the video: {err.filename or ''} {err.strerror or err}".replace("  ", " "),
              file=sys.stderr)
        sys.exit(2)
    print(f"video in {out}")


if __name__ == "__main__":
    main()
