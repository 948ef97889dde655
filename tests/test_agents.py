"""Trained agents shipped with the package (conf/agents/): each evaluates in seconds with
``mode=eval checkpoint=agent:<name>`` and passes its task's rule, as the README says; an
unknown name is one line listing the shipped ones."""

from __future__ import annotations

import json

import pytest

from inprocess import run_train
from tasks.catalog import conf_dir

AGENTS = sorted(p.name for p in (conf_dir() / "agents").iterdir() if (p / "model.pt").is_file())


def test_an_agent_ships_for_each_seed_task_with_qlearn_and_dqn():
    assert set(AGENTS) >= {f"{robot}_{learner}" for robot in ("cartpole", "cube", "turtlebot")
                           for learner in ("qlearn", "dqn")}


@pytest.mark.parametrize("name", AGENTS)
def test_a_shipped_agent_evaluates_and_passes_its_tasks_rule(name, tmp_path):
    run = tmp_path / "eval"
    done = run_train("mode=eval", f"checkpoint=agent:{name}", "eval_episodes=20", f"hydra.run.dir={run}",
                     "quiet=true")
    assert done.returncode == 0, done.stderr[-1500:]
    verdict = done.stdout.strip().splitlines()[-1]
    assert verdict.startswith("VERDICT mode=eval passed=true"), verdict
    assert json.loads((run / "run.json").read_text())["mode"] == "eval"


def test_an_unknown_agent_is_one_line_naming_the_shipped_ones(tmp_path):
    done = run_train("mode=eval", "checkpoint=agent:nobody", f"hydra.run.dir={tmp_path / 'x'}")
    assert done.returncode == 2
    assert "checkpoint=agent:nobody: no agent of that name is shipped; the shipped ones: agent:" in done.stderr
    assert len(done.stderr.strip().splitlines()) == 1 and not (tmp_path / "x").exists()
