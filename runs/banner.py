"""The lines a run prints before its first step: what was chosen and where it goes.

    cartpole / stay_up / qlearn, seed 0, 8 copies, up to 4000 episodes
    tuned: conf/tuned/cartpole_qlearn.yaml changed num_envs 1 -> 8, learner.alpha 0.1 -> 0.2, ...
    (or, with a task's file on top: tuned: conf/tuned/turtlebot_qlearn.yaml + conf/tuned/turtlebot_wall_qlearn.yaml changed ...)
    solved when: mean steps balanced of the last 100 training episodes >= 250 steps ... and the greedy policy's too
    run folder: outputs/2026-11-23/14-27-16_cartpole_qlearn_4242 (full log: train.log)
"""

from __future__ import annotations

from pathlib import Path
from typing import Mapping, Sequence

from omegaconf import DictConfig, OmegaConf

from params import dotted
from tasks.base import Success
from runs.catalog import GROUPS, TASK_TUNED, TUNED_PICKS, compose

PICKS = (*GROUPS, "tuned", TASK_TUNED)  # the config groups' keys, not values
SHOWN_CHANGES = 5  # values a tuned file changed, named on its line (the rest counted)


def tuned_changes(cfg: DictConfig, choices: Mapping[str, str | None],
                  overrides: Sequence[str]) -> list[str] | None:
    """``key before -> after`` for each value the tuned files (the robot's and the task's)
    changed in ``cfg`` (the same command composed with ``~tuned``, which leaves out both);
    ``[]`` when no tuned file applies, ``None`` when the command does not compose without
    them (an override of a key only they add)."""
    if not tuned_files(choices):
        return []
    kept = [o for o in overrides if o.split("=", 1)[0].lstrip("+~") not in PICKS]
    try:
        plain = compose(choices.get("robot"), choices.get("task"), choices.get("learner"),
                        [*kept, "~tuned"])
    except Exception:  # noqa: BLE001 - the banner still names the file
        return None
    before = dotted(OmegaConf.to_container(plain, resolve=True))
    after = dotted(OmegaConf.to_container(cfg, resolve=True))
    return [f"{key} {before.get(key)} -> {value}" for key, value in after.items()
            if before.get(key) != value]


def tuned_files(choices: Mapping[str, str | None]) -> list[str]:
    """The tuned files a run applied, ``conf/tuned/<name>.yaml``, the robot's first."""
    return [f"conf/tuned/{choices[key]}.yaml" for key in TUNED_PICKS if choices.get(key)]


def solved_when(success: Success) -> str:
    """``mean <description> of the last N training episodes >= T <unit>`` or the greedy form."""
    unit = f" {success.unit}" if success.unit else ""
    if success.judge == "greedy":
        return (f"the greedy policy's mean {success.description} >= {success.threshold:g}{unit} "
                f"(evaluated every eval_every episodes)")
    return (f"mean {success.description} of the last {success.window} training episodes "
            f">= {success.threshold:g}{unit} (after >= {success.min_episodes} episodes), and the "
            f"greedy policy's too")


def banner_lines(cfg: DictConfig, choices: Mapping[str, str | None], changes: Sequence[str] | None,
                 success: Success, run_dir: Path, episodes: int) -> list[str]:
    """The start banner: robot / task / learner and the run's scale, the tuned file and what
    it changed (``changes``; ``None``: not worked out, e.g. a resumed run), what "solved" means
    here, the run folder."""
    copies = int(cfg.num_envs)
    what = "evaluate " if cfg.mode == "eval" else ""
    lines = [f"{what}{choices.get('robot')} / {choices.get('task')} / {choices.get('learner')}, "
             f"seed {cfg.seed}, {copies} cop{'y' if copies == 1 else 'ies'}"
             + (f", up to {episodes} episodes" if cfg.mode == "train" else "")
             + (f" or {int(cfg.max_env_steps)} env steps" if cfg.mode == "train" and cfg.get("max_env_steps") else "")
             + (", training past 'solved'" if cfg.mode == "train" and not cfg.get("stop_when_solved", True) else "")
             + (f", Optuna trial {cfg.trial}" if cfg.get("trial") is not None else "")]
    files = tuned_files(choices)
    if files:
        if changes is None:
            what = "applied"
        else:
            more = f" and {len(changes) - SHOWN_CHANGES} more" if len(changes) > SHOWN_CHANGES else ""
            what = "changed " + (", ".join(changes[:SHOWN_CHANGES]) + more
                                 or "nothing (overridden on the command line)")
        lines.append(f"tuned: {' + '.join(files)} {what} ('~tuned' leaves {'them' if len(files) > 1 else 'it'} out)")
    lines.append(f"solved when: {solved_when(success)}")
    lines.append(f"run folder: {run_dir} (full log: train.log)")
    return lines
