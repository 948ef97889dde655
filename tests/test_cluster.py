"""Sweeps on a cluster: the Slurm launcher config the project ships (hydra/launcher=slurm),
and a launcher the sweep cannot use refused in one line before any job starts, with
nothing written."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from hydra import compose, initialize_config_dir
from omegaconf import OmegaConf

from params import ConfigError
from tasks.catalog import conf_dir
from sweeps import launchers
from sweeps.launchers import check_launcher

ROOT = Path(__file__).resolve().parents[1]


def slurm_launcher(*overrides: str):
    with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
        cfg = compose("config", overrides=["hydra/launcher=slurm", *overrides], return_hydra_config=True)
    return cfg.hydra.launcher


def test_the_slurm_config_is_submitits_slurm_launcher_with_the_settings_a_user_edits():
    launcher = slurm_launcher("hydra.launcher.partition=cpu", "hydra.launcher.cpus_per_task=4")
    assert launcher._target_ == "hydra_plugins.hydra_submitit_launcher.submitit_launcher.SlurmLauncher"
    assert launcher.partition == "cpu" and launcher.cpus_per_task == 4
    assert launcher.timeout_min >= 1 and launcher.array_parallelism >= 1 and launcher.mem_gb >= 1
    text = (conf_dir() / "hydra" / "launcher" / "slurm.yaml").read_text()
    for key in ("partition", "timeout_min", "cpus_per_task", "array_parallelism", "setup"):
        assert f"\n{key}:" in text  # written out, with its meaning, for the user to edit


def test_the_seeds_slurm_config_is_one_slurm_job_per_batch_of_seeds():
    with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
        launcher = compose("config", overrides=["hydra/launcher=seeds_slurm", "hydra.launcher.partition=cpu"],
                           return_hydra_config=True).hydra.launcher
    assert launcher._target_ == "hydra_plugins.rl_seed_launcher.seed_launcher.SeedBatchSlurmLauncher"
    assert launcher.partition == "cpu" and launcher.max_seeds >= 1 and launcher.timeout_min >= 1
    text = (conf_dir() / "hydra" / "launcher" / "seeds_slurm.yaml").read_text()
    for key in ("max_seeds", "partition", "timeout_min", "cpus_per_task", "mem_gb", "setup"):
        assert f"\n{key}:" in text


def test_a_slurm_launcher_passes_where_slurm_is_and_is_refused_where_it_is_not(monkeypatch):
    launcher = OmegaConf.to_container(slurm_launcher())
    monkeypatch.setattr(launchers.shutil, "which", lambda tool: f"/usr/bin/{tool}")
    check_launcher(OmegaConf.create(launcher))
    monkeypatch.setattr(launchers.shutil, "which", lambda tool: None if tool == "srun" else f"/usr/bin/{tool}")
    with pytest.raises(ConfigError, match="needs Slurm's srun on PATH, not found here"):
        check_launcher(OmegaConf.create(launcher))
    check_launcher(OmegaConf.create({"_target_": "hydra_plugins.hydra_submitit_launcher.submitit_launcher."
                                                  "LocalLauncher", "cpus_per_task": 0}))  # not Slurm's


@pytest.mark.parametrize("args, line", [
    (["hydra/launcher=ray"], "error: hydra/launcher=ray is not installed; installed: basic, joblib, seeds, seeds_slurm, "
                             "seeds_submitit_local, seeds_submitit_slurm, slurm, submitit_local, submitit_slurm "
                             "(a Hydra launcher plugin is a pip package"),
    (["hydra/launcher=slurm", "hydra.launcher.timeout_min=abc"],
     "error: hydra.launcher.timeout_min must be an integer; got 'abc'"),
    (["hydra/launcher=slurm", "hydra.launcher.partition=[a,b]"],
     "error: hydra.launcher.partition must be a string; got a list: [a,b]"),
    (["hydra/launcher=slurm", "hydra.launcher.cpus_per_task=0"],
     "error: hydra.launcher.cpus_per_task must be an integer >= 1 (or null where Slurm has a default); got 0"),
    (["hydra/launcher=slurm"], "error: the Slurm launcher needs Slurm's sbatch and srun on PATH, not found here"),
    (["hydra/launcher=seeds_slurm"], "error: the Slurm launcher needs Slurm's sbatch and srun on PATH, not found here"),
    (["hydra/launcher=seeds_submitit_local", "hydra.launcher.max_seeds=0"],
     "error: hydra.launcher.max_seeds must be an integer >= 1; got 0"),
])
def test_a_launcher_the_sweep_cannot_use_is_one_line_before_any_job(tmp_path, args, line):
    if shutil.which("srun") or shutil.which("sbatch"):
        pytest.skip("this machine has Slurm: the launcher is not refused here")
    env = {**os.environ, "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    proc = subprocess.run([sys.executable, "train.py", "-m", *args, f"hydra.sweep.dir={tmp_path}/sweep",
                           "seed=0,1", "max_episodes=2"], cwd=ROOT, capture_output=True, text=True,
                          timeout=300, env=env)
    assert proc.returncode == 2, proc.stdout[-2000:] + proc.stderr[-2000:]
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(line), proc.stderr
    assert list(tmp_path.iterdir()) == []  # no sweep folder, no job
