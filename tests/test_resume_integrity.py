"""Resume refuses what is not this run's own, intact state, in one line and before any file
is touched: another run's checkpoint, a damaged one, one whose parts do not load, a
config.yaml that names code outside the project, a damaged run.json."""

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from omegaconf import OmegaConf

from inprocess import run_train
from runs.checkpoint import CheckpointError, content_checksum, load_checkpoint, save_checkpoint
from runs.settings import check_targets
from runs.training_state import new_run_identity, read_run_json, run_identity
from params import ConfigError

ROOT = Path(__file__).resolve().parents[1]
# Without the tuned file: its episodes are short (~8 steps untrained), so the resumed run ends soon.
QLEARN = ["learner=qlearn", "~tuned", "num_envs=1", "max_episodes=300", "checkpoint_every=20"]


def resume(run_dir: Path) -> subprocess.CompletedProcess:
    return run_train(f"resume={run_dir}")


@pytest.fixture(scope="module")
def killed(tmp_path_factory) -> Path:
    """A qlearn run killed mid-run: checkpoint.pt holds fewer episodes than metrics.csv."""
    run_dir = tmp_path_factory.mktemp("killed") / "run"
    proc = subprocess.Popen([sys.executable, "train.py", "quiet=true", "eval_episodes=0", "seed=3",
                             f"hydra.run.dir={run_dir}", *QLEARN],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 300
    metrics = run_dir / "metrics.csv"
    while True:  # killed where metrics.csv is ahead of the checkpoint (not just after one): a cut shows
        if proc.poll() is not None or time.time() > deadline:
            proc.kill()
            pytest.fail(f"the run to kill ended or never got going: {proc.stderr.read()[-1500:]}")
        if metrics.is_file() and len(metrics.read_text().splitlines()) > 50:
            proc.send_signal(signal.SIGSTOP)  # frozen while its files are read (a checkpoint is renamed into place whole)
            saved = torch.load(run_dir / "checkpoint.pt", weights_only=True)["run"]["n_episodes"]
            if 0 < saved < len(metrics.read_text().splitlines()) - 1:
                break
            proc.send_signal(signal.SIGCONT)
        time.sleep(0.02)
    proc.kill()
    proc.communicate()
    return run_dir


def clone(src: Path, dst: Path, run_id: str | None = None) -> Path:
    """A copy of run folder ``src``; with ``run_id``, as a run created with that id (run.json
    holds it, and so does its checkpoint, as every checkpoint of such a run does); with
    ``run_id=""``, as a run folder from before run ids (none in run.json)."""
    dst.mkdir(parents=True)
    for path in src.iterdir():
        if path.is_file():
            shutil.copy2(path, dst / path.name)
    if run_id is not None:
        names = json.loads((dst / "run.json").read_text())
        names = {**names, "run_id": run_id} if run_id else {k: v for k, v in names.items() if k != "run_id"}
        (dst / "run.json").write_text(json.dumps(names, indent=1))
        state = torch.load(dst / "checkpoint.pt", weights_only=True)
        save_checkpoint(dst / "checkpoint.pt", {**state, "identity": run_identity(dst)})
    return dst


def files(run_dir: Path) -> dict[str, bytes]:
    """Every file of the run folder and its bytes, Hydra's own aside: .hydra-resume/ (written
    before train.py runs) and train.log (Hydra's job log, where libraries log as they load);
    and .lock, which holds the pid of the last process that held the folder."""
    return {str(p.relative_to(run_dir)): p.read_bytes() for p in sorted(run_dir.rglob("*"))
            if p.is_file() and ".hydra-resume" not in p.parts and p.name not in ("train.log", ".lock")}


def assert_refused(run_dir: Path, expected: str) -> str:
    """Resuming ``run_dir`` fails with one ``error:`` line holding ``expected``, leaving every file."""
    before = files(run_dir)
    done = resume(run_dir)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2, done.stderr[-1500:]
    assert len(lines) == 1 and lines[0].startswith("error:") and expected in lines[0], done.stderr[-1500:]
    assert "resuming" not in done.stdout
    assert files(run_dir) == before
    return lines[0]


# -- the run's identity ------------------------------------------------------------
def test_a_checkpoint_of_the_run_itself_resumes(tmp_path, killed):
    """Control for the refusals below: a run with a run_id resumes from its own checkpoint,
    and the checkpoints it writes carry that id."""
    run_dir = clone(killed, tmp_path / "own", run_id=new_run_identity()["run_id"])
    done = resume(run_dir)
    assert done.returncode == 0, done.stderr[-1500:]
    assert "resuming" in done.stdout
    assert torch.load(run_dir / "checkpoint.pt", weights_only=True)["identity"] == run_identity(run_dir)


@pytest.mark.parametrize("with_run_id", [True, False], ids=["run_id", "older-run-folder"])
def test_a_checkpoint_of_another_run_is_refused(tmp_path, killed, with_run_id):
    """Same config, same shapes, a consistent file: only the run id tells it apart."""
    source = clone(killed, tmp_path / "source", run_id=new_run_identity()["run_id"])
    target = clone(killed, tmp_path / "target", run_id=new_run_identity()["run_id"] if with_run_id else "")
    assert (source / "config.yaml").read_bytes() == (target / "config.yaml").read_bytes()
    shutil.copy2(source / "checkpoint.pt", target / "checkpoint.pt")
    assert_refused(target, "belongs to another run")


def test_a_checkpoint_saved_under_another_config_is_refused(tmp_path, killed):
    run_dir = clone(killed, tmp_path / "run", run_id=new_run_identity()["run_id"])
    cfg = OmegaConf.load(run_dir / "config.yaml")
    cfg.learner.alpha = 0.5  # edited by hand after the checkpoint was written
    OmegaConf.save(cfg, run_dir / "config.yaml")
    assert_refused(run_dir, "was saved under another config")


def test_new_run_identities_differ_and_older_runs_fall_back_to_the_config(tmp_path, killed):
    ids = {new_run_identity()["run_id"] for _ in range(3)}
    assert len(ids) == 3 and all(re.fullmatch("[0-9a-f]{32}", i) for i in ids)
    assert re.fullmatch("[0-9a-f]{32}", json.loads((killed / "run.json").read_text())["run_id"])
    assert run_identity(killed) == load_checkpoint(killed / "checkpoint.pt", "training_state")["identity"]
    older = clone(killed, tmp_path / "older", run_id="")  # a run folder from before run ids
    assert run_identity(older)["run_id"].startswith("config-")


# -- integrity ---------------------------------------------------------------------
def test_flipped_bytes_in_the_data_are_refused_by_the_checksum(tmp_path, killed):
    run_dir = clone(killed, tmp_path / "run")
    data = bytearray((run_dir / "checkpoint.pt").read_bytes())
    table = torch.load(run_dir / "checkpoint.pt", weights_only=True)["learner"]["table"]
    at = data.find(table.numpy().tobytes())
    assert at > 0
    data[at + table.numel() * 2] ^= 0x10  # one bit of a Q-value, mid-table
    (run_dir / "checkpoint.pt").write_bytes(bytes(data))
    torch.load(run_dir / "checkpoint.pt", weights_only=True)  # torch reads it without a word
    assert_refused(run_dir, "is damaged: its contents do not match its checksum")


def test_damaged_structure_is_refused(tmp_path, killed):
    run_dir = clone(killed, tmp_path / "run")
    data = bytearray((run_dir / "checkpoint.pt").read_bytes())
    for i in range(100, len(data), 997):
        data[i] ^= 0xFF
    (run_dir / "checkpoint.pt").write_bytes(bytes(data))
    line = assert_refused(run_dir, f"checkpoint {run_dir / 'checkpoint.pt'}")
    assert "cannot be read" in line or "is damaged" in line or "not a checkpoint" in line


@pytest.mark.parametrize("part", ["torch", "numpy", "python"])
def test_a_part_that_does_not_load_is_refused_before_metrics_are_cut(tmp_path, killed, part):
    """An intact file (valid checksum, this run's) whose global RNG state does not load: the
    refusal comes before metrics.csv and timing.csv are cut back to the checkpoint."""
    run_dir = clone(killed, tmp_path / "run")
    state = torch.load(run_dir / "checkpoint.pt", weights_only=True)
    rng = state["rng"]
    if part == "torch":
        rng["torch"] = rng["torch"][:100]
    elif part == "numpy":
        rng["numpy"][1] = rng["numpy"][1][:5]
    else:
        rng["python"][1] = rng["python"][1][:5]
    save_checkpoint(run_dir / "checkpoint.pt", state)
    assert_refused(run_dir, "does not fit this run")


def every_file(run_dir: Path) -> dict[str, bytes]:
    """Every file of the run folder and its bytes, none aside."""
    return {str(p.relative_to(run_dir)): p.read_bytes() for p in sorted(run_dir.rglob("*")) if p.is_file()}


@pytest.mark.parametrize("change, says", [
    (lambda s: s["learner"].update(table=s["learner"]["table"].reshape(-1, 1)), "table is torch.float64 ["),
    (lambda s: s["learner"].pop("table"), "it lacks table"),
], ids=["reshaped", "removed"])
def test_a_learner_tensor_that_does_not_fit_is_refused_before_anything_is_written(tmp_path, killed, change, says):
    """A checkpoint of this run, intact by its checksum, whose learner's table was reshaped or
    removed: refused in one line with the folder byte for byte as it was (no banner, no
    ``logs/``, ``train.log``, ``.lock`` and Hydra's records untouched)."""
    run_dir = clone(killed, tmp_path / "run")
    state = torch.load(run_dir / "checkpoint.pt", weights_only=True)
    change(state)
    save_checkpoint(run_dir / "checkpoint.pt", state)
    before = every_file(run_dir)
    done = resume(run_dir)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2, done.stderr[-1500:]
    assert len(lines) == 1 and "does not fit this run" in lines[0] and says in lines[0], done.stderr[-1500:]
    assert done.stdout == ""
    assert every_file(run_dir) == before
    assert sorted(p.name for p in run_dir.iterdir()) == sorted(Path(k).parts[0] for k in before)


def test_a_leftover_temporary_file_stays_when_the_checkpoint_is_refused(tmp_path, killed):
    run_dir = clone(killed, tmp_path / "run", run_id=new_run_identity()["run_id"])
    (run_dir / "checkpoint.pt.k1ll3d.tmp").write_bytes(b"half a checkp")
    (run_dir / "run.json").write_text(json.dumps({**json.loads((run_dir / "run.json").read_text()),
                                                  "run_id": "someone-else"}))
    assert_refused(run_dir, "belongs to another run")


def test_checksums_round_trip_and_catch_changes(tmp_path):
    payload = {"kind": "x", "t": torch.arange(6.0).reshape(2, 3)[:, 1:], "size": torch.Size([2, 3]),
               "values": [1, 2.5, float("nan"), None, True, "s", (1, 2)], "big": 2**100,
               "empty": torch.zeros(0), "scalar": torch.tensor(7), "gen": torch.Generator().get_state()}
    save_checkpoint(tmp_path / "c.pt", payload)
    loaded = load_checkpoint(tmp_path / "c.pt", "x")
    assert loaded["checksum"] == content_checksum(payload) == content_checksum(loaded)
    for change in ({"big": 2**100 + 1}, {"values": [1, 2.5, float("nan"), None, 1, "s", (1, 2)]},
                   {"values": [1, 2.5, float("nan"), None, True, "s", [1, 2]]},
                   {"t": payload["t"].double()}, {"t": payload["t"].reshape(-1)}):
        assert content_checksum({**payload, **change}) != content_checksum(payload), change
    loaded["t"][0, 0] += 1
    torch.save(loaded, tmp_path / "c.pt")
    with pytest.raises(CheckpointError, match="is damaged"):
        load_checkpoint(tmp_path / "c.pt", "x")


def test_save_fsyncs_the_file_before_the_rename_and_the_folder_after(tmp_path, monkeypatch):
    events = []
    fsync, replace = os.fsync, os.replace

    def spy_fsync(fd):
        events.append(("fsync-folder" if os.path.isdir(f"/proc/self/fd/{fd}") else "fsync-file"))
        fsync(fd)

    def spy_replace(a, b):
        events.append("rename")
        replace(a, b)

    monkeypatch.setattr(os, "fsync", spy_fsync)
    monkeypatch.setattr(os, "replace", spy_replace)
    save_checkpoint(tmp_path / "c.pt", {"kind": "x"})
    assert events == ["fsync-file", "rename", "fsync-folder"]


# -- config.yaml's targets -----------------------------------------------------------
@pytest.mark.parametrize("node,target", [
    ("learner", "os.system"),
    ("robot", "builtins.eval"),
    ("learner", "runs.checkpoint.os.system"),  # a project module's import of os
])
def test_a_target_outside_the_project_is_refused_and_nothing_runs(tmp_path, killed, node, target):
    run_dir = clone(killed, tmp_path / "run")
    marker = tmp_path / "executed"
    cfg = OmegaConf.load(run_dir / "config.yaml")
    if target.endswith("eval"):
        cfg[node] = {"_target_": target, "_args_": [f"__import__('pathlib').Path({str(marker)!r}).touch()"]}
    else:
        cfg[node] = {"_target_": target, "command": f"touch {marker}"}
    OmegaConf.save(cfg, run_dir / "config.yaml")
    line = assert_refused(run_dir, f"{node}._target_={target!r} is not allowed")
    assert "robots., tasks., learners." in line
    assert not marker.exists()


def test_check_targets_allows_the_project_classes_only():
    check_targets(OmegaConf.create({
        "robot": {"_target_": "robots.cartpole.CartPole"}, "task": {"_target_": "tasks.stay_up.StayUp"},
        "learner": {"_target_": "learners.dqn.DQN",
                    "epsilon": {"_target_": "learners.schedules.LinearEpsilon"}}}))
    for target in ("subprocess.Popen", "runs.checkpoint.torch.load",
                   "runs.checkpoint.save_checkpoint",
                   "runs.training_state.importlib.import_module", "robots", "learners..qlearn.QLearn",
                   "learners.nothing.Here", "${oc.env:HOME}", 3, None):
        for cfg in ({"learner": {"_target_": target}}, {"a": [{"b": {"_target_": target}}]}):
            with pytest.raises(ConfigError, match="is not allowed"):
                check_targets(OmegaConf.create(cfg))


# -- run.json ----------------------------------------------------------------------
@pytest.mark.parametrize("text,expected", [
    ('{"robot": "cartpole", "se', "run.json is not readable JSON"),
    ("[1, 2]", "run.json must hold a JSON object"),
    ('{"run_id": 7}', "run_id must be a non-empty string"),
])
def test_a_damaged_run_json_is_refused_at_the_start(tmp_path, killed, text, expected):
    run_dir = clone(killed, tmp_path / "run")
    (run_dir / "run.json").write_text(text)
    with pytest.raises(CheckpointError, match=expected):
        read_run_json(run_dir)
    if expected.startswith("run.json is not"):  # end to end once: refused before training
        assert_refused(run_dir, expected)


# -- a checkpoint's content, not only its checksum, must fit the run (issue 36) -----------------
def _member(learner: str):
    from hydra.utils import instantiate

    from runs.training_state import seed_everything
    from tasks.catalog import compose
    from tasks.factory import build_task

    cfg = compose("cartpole", learner=learner)
    made = instantiate(cfg.learner, _convert_="all")
    made.build(build_task(cfg), [seed_everything(0)])
    return made.member(0)


def _tampered(path: Path, change) -> Path:
    payload = torch.load(path, weights_only=True)
    change(payload)
    save_checkpoint(path, payload)  # a valid checksum over the changed content
    return path


def _drop(payload: dict, *keys: str) -> None:
    for key in keys[:-1]:
        payload = payload[key]
    del payload[keys[-1]]


@pytest.mark.parametrize("learner, change, says", [
    ("qlearn", lambda p: _drop(p, "table"), "it lacks table"),
    ("qlearn", lambda p: p.update(table=p["table"][:-1]), "table is torch.float64 ["),
    ("qlearn", lambda p: p.update(visited=p["visited"].float()), "visited is torch.float32"),
    ("dqn", lambda p: _drop(p, "actor", "module.0.module.0.weight"), "it lacks actor.module.0.module.0.weight"),
    ("dqn", lambda p: p["actor"].update({"module.0.module.0.bias": torch.zeros(3)}), "bias is torch.float32 [3]"),
    ("dqn", lambda p: _drop(p, "optimizer"), "it lacks optimizer"),
])
def test_a_checkpoint_that_does_not_fit_is_one_line_before_anything_loads(tmp_path, learner, change, says):
    from runs.checkpoint import load_model, save_model

    member = _member(learner)
    before = {k: v.clone() if isinstance(v, torch.Tensor) else v for k, v in member.model_state().items()}
    path = tmp_path / "model.pt"
    save_model(path, member, meta={})
    _tampered(path, change)
    with pytest.raises(CheckpointError) as err:
        load_model(path, member)
    message = str(err.value)
    assert says in message and "does not fit this run" in message and "\n" not in message, message
    after = member.model_state()
    assert all(torch.equal(after[k], v) for k, v in before.items() if isinstance(v, torch.Tensor))
