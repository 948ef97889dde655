"""What the loggers get: episode, eval, train and run scalars against env steps, and the
resolved config as hyperparameters. Runs are short and in-process (no subprocess imports)."""

import csv
from pathlib import Path

import pytest
import torch
from hydra.utils import instantiate
from omegaconf import OmegaConf

from learners.member import UpdateStats, track
from runs.loggers import csv_sizes, flat_config, log_hparams, make_logger, run_scalar_names
from tests.inprocess import train_in_process
from runs.run import Hooks, Run
from runs.training_state import seed_everything
from tasks.factory import build_env
from tasks.catalog import compose

TUNED_DQN = OmegaConf.to_container(compose(robot="cartpole", learner="dqn"))  # with its tuned file
TUNED_DQN_LR = TUNED_DQN["learner"]["lr"]
DQN_SHORT = ["max_episodes=24", "learner.learning_starts=32", "learner.batch_size=32",
             "eval_every=10"]


def train(run_dir: Path, learner: str, logger: str, overrides: list[str]):
    """A run of ``learner`` logging to ``logger`` through ``train.py``; the trained learner
    as its ``model.pt`` holds it (its logs under ``logs/<run_dir.name>``)."""
    return train_in_process(run_dir, f"learner={learner}", f"logger={logger}", "eval_episodes=2", "quiet=true",
                            *overrides).learner


def events(run_dir: Path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    files = list((run_dir / "logs").rglob("events.out.tfevents.*"))
    assert len(files) == 1  # hparams too go to the run's own event file
    acc = EventAccumulator(str(files[0].parent))
    acc.Reload()
    return acc


def test_dqn_logs_train_scalars_and_hparams_to_tensorboard_against_env_steps(tmp_path):
    pytest.importorskip("tensorboard")
    train(tmp_path, "dqn", "tensorboard", DQN_SHORT)
    acc = events(tmp_path)
    rows = list(csv.DictReader(open(tmp_path / "metrics.csv")))
    env_steps = [int(r["env_steps"]) for r in rows]
    lengths = acc.Scalars("episode/length")
    assert [e.step for e in lengths] == env_steps  # episodes against env steps
    assert [e.value for e in acc.Scalars("episode/index")] == list(range(1, len(rows) + 1))
    for name in ("loss", "q_mean", "td_error", "grad_norm", "epsilon", "lr", "updates",
                 "updates_per_s"):
        points = acc.Scalars(f"train/{name}")
        steps = [e.step for e in points]
        assert len(points) >= 3 and steps == sorted(set(steps)), name  # increasing env steps
        assert set(steps) <= set(env_steps), name  # logged when episodes ended (and at the end)
        assert all(e.value == e.value for e in points), name  # no NaN
    updates = [e.value for e in acc.Scalars("train/updates")]
    assert updates == sorted(updates) and updates[-1] > 0
    assert all(e.value > 0 for e in acc.Scalars("train/loss"))
    evals = list(csv.DictReader(open(tmp_path / "evals.csv")))
    assert [e.step for e in acc.Scalars("eval/length")] == [int(r["env_steps"]) for r in evals]
    for name in run_scalar_names("length", 100):  # the summary's numbers by their summary.json names
        assert [e.step for e in acc.Scalars(name)] == [env_steps[-1]], name
    assert acc.Scalars("run/train_return_mean")[0].value == pytest.approx(
        sum(float(r["reward"]) for r in rows) / len(rows), rel=1e-6)
    assert not [tag for tag in acc.Tags()["scalars"] if "score" in tag]
    from tensorboard.plugins.hparams import plugin_data_pb2

    content = acc.PluginTagToContent("hparams")
    # The run's session only: an experiment per run would make TensorBoard show every run of
    # a folder with the first one's settings (a sweep writes its own, next test).
    assert "_hparams_/session_start_info" in content and "_hparams_/experiment" not in content
    start = plugin_data_pb2.HParamsPluginData.FromString(
        content["_hparams_/session_start_info"]).session_start_info
    assert start.hparams["learner.lr"].number_value == pytest.approx(TUNED_DQN_LR)  # conf/tuned/cartpole_dqn.yaml's
    assert start.hparams["learner._target_"].string_value == "learners.dqn.DQN"
    assert start.hparams["learner.hidden"].string_value == str(TUNED_DQN["learner"]["hidden"])  # a list as text


def hparams_tab(logdir: Path) -> tuple[set, dict]:
    """What TensorBoard's HParams tab shows for ``logdir`` (its own backend): the settings'
    names, and per run (session) its ``learner._target_`` and final ``run/train_return_mean``."""
    from tensorboard import context
    from tensorboard.backend.event_processing.data_provider import MultiplexerDataProvider
    from tensorboard.backend.event_processing.plugin_event_multiplexer import EventMultiplexer
    from tensorboard.plugins import base_plugin
    from tensorboard.plugins.hparams import api_pb2, backend_context, list_session_groups

    mux = EventMultiplexer()
    mux.AddRunsFromDirectory(str(logdir))
    mux.Reload()
    tb = base_plugin.TBContext(logdir=str(logdir), multiplexer=mux,
                               data_provider=MultiplexerDataProvider(mux, str(logdir)))
    backend, rc = backend_context.Context(tb), context.RequestContext()
    experiment = backend.experiment_from_metadata(rc, "", True, backend.hparams_metadata(rc, ""),
                                                  backend.hparams_from_data_provider(rc, "", 0))
    statuses = [api_pb2.STATUS_UNKNOWN, api_pb2.STATUS_SUCCESS, api_pb2.STATUS_RUNNING, api_pb2.STATUS_FAILURE]
    request = api_pb2.ListSessionGroupsRequest(
        start_index=0, slice_size=100, allowed_statuses=statuses,
        col_params=[api_pb2.ColParams(hparam="learner._target_"),
                    api_pb2.ColParams(metric=api_pb2.MetricName(tag="run/train_return_mean"))])
    groups = list_session_groups.Handler(rc, backend, "", request).run().session_groups
    runs = {g.name.split("/")[0]: (g.hparams["learner._target_"].string_value,
                                   {m.name.tag: m.value for m in g.metric_values}.get("run/train_return_mean"))
            for g in groups}
    return {h.name for h in experiment.hparam_infos}, runs


def test_a_sweeps_hparams_tab_shows_every_jobs_settings_and_final_measures(tmp_path):
    """Two jobs of different learners logged to TensorBoard, then the sweep's comparison: the
    HParams tab of the sweep folder lists the settings of both (qlearn's alpha, dqn's lr) and
    each job's final numbers by their summary.json names."""
    pytest.importorskip("tensorboard")
    import json

    from runs.loggers import finish_log
    from sweeps.comparison import hparams_for_tensorboard

    returns = {"0_qlearn": ("qlearn", 7.5), "1_dqn": ("dqn", 12.25)}
    names = [n.split("/", 1)[1] for n in run_scalar_names("length", 100)]
    for job, (learner, mean_return) in returns.items():
        cfg = compose(learner=learner, overrides=["logger=tensorboard"])
        (tmp_path / job).mkdir()
        OmegaConf.save(cfg, tmp_path / job / "config.yaml", resolve=True)
        (tmp_path / job / "success.json").write_text(json.dumps({"measure": "length", "window": 100}))
        logger = make_logger("tensorboard", tmp_path / job, exp_name=job)
        log_hparams(logger, cfg, run_scalar_names("length", 100))
        finish_log(logger, {**dict.fromkeys(names, 1.0), "measure": "length", "window": 100,
                            "train_return_mean": mean_return, "env_steps": 100, "episodes": 5, "solved": False})
    names, runs = hparams_tab(tmp_path)
    assert "learner.alpha" in names and "learner.lr" in names  # without the sweep's own: still both
    hparams_for_tensorboard(tmp_path)
    assert (tmp_path / "hparams").is_dir()
    names, runs = hparams_tab(tmp_path)
    assert {"learner.alpha", "learner.lr", "learner.epsilon.steps", "seed"} <= names
    assert runs == {"0_qlearn": ("learners.qlearn.QLearn", 7.5), "1_dqn": ("learners.dqn.DQN", 12.25)}


def test_logging_changes_no_training_result(tmp_path):
    """Stats collection draws no random numbers and reorders nothing: a run with a logger
    writes the same metrics.csv and ends with the same network as one without."""
    quiet = train(tmp_path / "none", "dqn", "none", DQN_SHORT)
    logged = train(tmp_path / "csv", "dqn", "csv", DQN_SHORT)
    for name in ("metrics.csv", "evals.csv"):
        assert (tmp_path / "none" / name).read_bytes() == (tmp_path / "csv" / name).read_bytes()
    assert torch.equal(quiet.params, logged.params)
    assert logged.steps == quiet.steps and quiet.steps[0] > 0
    scalars = tmp_path / "csv" / "logs" / "csv" / "scalars"
    assert (scalars / "train" / "loss.csv").read_text().strip()
    hparams = (tmp_path / "csv" / "logs" / "csv" / "texts" / "hparams0.txt").read_text()
    assert f"learner.lr: {TUNED_DQN_LR}" in hparams.splitlines()


def test_qlearn_logs_the_visited_fraction_of_its_table(tmp_path):
    train(tmp_path, "qlearn", "csv", ["max_episodes=15", "eval_episodes=0"])
    scalars = tmp_path / "logs" / tmp_path.name / "scalars" / "train"
    rows = [line.split(",") for line in (scalars / "visited_fraction.csv").read_text().split()]
    steps, values = [int(s) for s, _ in rows], [float(v) for _, v in rows]
    assert len(rows) >= 3 and steps == sorted(set(steps))
    assert all(0 < v <= 1 for v in values) and values == sorted(values)
    assert (scalars / "epsilon.csv").exists()


def test_update_stats_average_each_interval_without_per_update_syncs():
    stats = UpdateStats()
    stats.FOLD = 2  # reduce in the middle of the interval too
    q = [torch.tensor([[1.0], [3.0]]), torch.tensor([[5.0], [7.0]]), torch.tensor([[0.0], [0.0]])]
    target = [x + 1 for x in q[:2]] + [torch.tensor([[-2.0], [2.0]])]
    for i in range(3):  # a round of one member: its loss [1], values [1, 2, 1], norm [1]
        track([stats], [0], torch.tensor([float(i)]), q[i][None], target[i][None], torch.tensor([float(i + 1)]), [True])
    peek = stats.read(updates=3, reset=False)
    assert peek["loss"] == 1.0 and peek["q_mean"] == 16 / 6 and peek["td_error"] == 8 / 6
    assert peek["grad_norm"] == 2.0 and peek["updates"] == 3.0
    first = stats.read(updates=3)  # the same interval, now closed
    assert {k: first[k] for k in peek if k != "updates_per_s"} == \
        {k: peek[k] for k in peek if k != "updates_per_s"}
    again = stats.read(updates=3)  # no update since: the latest means, no rate
    assert again["loss"] == 1.0 and again["updates_per_s"] == 0.0


def test_dqn_train_stats_without_clipping_measure_the_latest_gradient():
    from learners.dqn import DQN
    from learners.schedules import LinearEpsilon
    from robots.cartpole import CartPole
    from tasks.env import RobotTaskEnv
    from tasks.stay_up import StayUp

    learner = DQN(epsilon=LinearEpsilon(1.0, 0.1, 100), grad_clip=0.0, batch_size=8)
    learner.build(StayUp(CartPole()))
    assert set(learner.train_stats(0)) == {"epsilon", "lr", "updates", "updates_per_s"}
    env = RobotTaskEnv(StayUp(CartPole()), num_envs=4, seed=0)
    td = env.reset()
    for _ in range(4):
        td, nxt = env.step_and_maybe_reset(learner.act(td))
        learner.store(td)
        td = nxt
    env.close()
    learner.optimize(3)
    stats = learner.train_stats(0)
    assert stats["grad_norm"] == pytest.approx(float(torch.linalg.vector_norm(learner.grads[0])))
    assert learner.grads[0].abs().sum() > 0
    assert stats["updates"] == 3 and stats["loss"] > 0


def test_the_csv_logger_writes_torchrls_lines_through_a_buffer_a_checkpoint_flushes(tmp_path):
    """The CSV logger's files hold TorchRL's CSVLogger's lines for the same calls (``step,value``,
    a step counted where none is given), nothing of them kept in memory; the sizes a
    checkpoint records (``csv_sizes`` with the run's logger) count every value logged so far."""
    from torchrl.record.loggers.csv import CSVLogger

    calls = [("episode/reward", 1.5, 10), ("episode/reward", -2.0, 20), ("train/loss", 0.25, None),
             ("train/loss", 1e-9, None), ("episode/length", 12, 20)]
    ours, theirs = make_logger("csv", tmp_path / "ours", exp_name="run"), CSVLogger("run", str(tmp_path / "theirs"))
    for name, value, step in calls:
        ours.log_scalar(name, value, step)
        theirs.log_scalar(name, value, step)
    sizes = csv_sizes(tmp_path / "ours", ours)
    assert sizes == {f"logs/run/scalars/{name}.csv": (tmp_path / "theirs" / "run" / "scalars" / f"{name}.csv").stat().st_size
                     for name in ("episode/length", "episode/reward", "train/loss")}
    assert len(ours.experiment.scalars["train/loss"]) == 2 and not hasattr(ours.experiment.scalars["train/loss"], "pop")
    ours.close()
    for name in ("episode/reward", "train/loss", "episode/length"):
        mine = (tmp_path / "ours" / "logs" / "run" / "scalars" / f"{name}.csv").read_text()
        assert mine == (tmp_path / "theirs" / "run" / "scalars" / f"{name}.csv").read_text()
    assert (tmp_path / "ours" / "logs" / "run" / "scalars" / "train" / "loss.csv").read_text() == "0,0.25\n1,1e-09\n"


def test_flat_config_joins_keys_and_keeps_scalars():
    flat = flat_config({"a": {"b": 1, "c": [1, 2], "d": None}, "e": "x", "f": True})
    assert flat == {"a.b": 1, "a.c": "[1, 2]", "e": "x", "f": True}


def test_mlflow_gets_the_config_as_params_and_the_train_metrics(tmp_path):
    mlflow = pytest.importorskip("mlflow")  # extra: pip install -e ".[mlflow]"
    train(tmp_path, "qlearn", "mlflow", ["max_episodes=10", "eval_episodes=0"])
    mlflow.set_tracking_uri(f"sqlite:///{tmp_path / 'logs' / 'mlflow.db'}")
    run_id = mlflow.search_runs(search_all_experiments=True).run_id[0]
    client = mlflow.MlflowClient()
    assert client.get_run(run_id).data.params["learner._target_"] == "learners.qlearn.QLearn"
    history = client.get_metric_history(run_id, "train/visited_fraction")
    assert len(history) >= 3 and all(0 < m.value <= 1 for m in history)
    rows = list(csv.DictReader(open(tmp_path / "metrics.csv")))
    steps = [m.step for m in client.get_metric_history(run_id, "episode/length")]
    assert steps == [int(r["env_steps"]) for r in rows]


def _sweep_jobs(tmp_path: Path, n: int = 2) -> list[Path]:
    """Job folders of a sweep folder (Hydra's multirun.yaml beside them)."""
    sweep = tmp_path / "my_sweep"
    sweep.mkdir()
    (sweep / "multirun.yaml").write_text("{}\n")
    jobs = [sweep / f"{i}_cartpole_dqn_seed{i}" for i in range(n)]
    for job in jobs:
        job.mkdir()
    return jobs


def test_a_sweeps_jobs_log_to_one_mlflow_experiment_from_one_process(tmp_path):
    """The seeds of a batch are runs of one process: each its own MLflow run (TorchRL's
    fluent-API logger refuses a second active run), all in the sweep's store and experiment,
    and a resumed job goes on in its own MLflow run."""
    mlflow = pytest.importorskip("mlflow")  # extra: pip install -e ".[mlflow]"
    jobs = _sweep_jobs(tmp_path)
    loggers = [make_logger("mlflow", job, exp_name=job.name, tags={"seed": i, "learner": "dqn"})
               for i, job in enumerate(jobs)]
    for step in (10, 20):
        for i, logger in enumerate(loggers):
            logger.log_metrics({"episode/length": float(step + i)}, step=step)
    log_hparams(loggers[0], {"learner": {"lr": 0.001}})
    for logger in loggers:
        logger.close()
    again = make_logger("mlflow", jobs[1], exp_name=jobs[1].name)  # resumed: the same MLflow run
    again.log_metrics({"episode/length": 99.0}, step=30)
    again.close()
    client = mlflow.MlflowClient(tracking_uri=f"sqlite:///{tmp_path / 'my_sweep' / 'mlflow.db'}")
    experiment = client.get_experiment_by_name("my_sweep")
    runs = {r.info.run_name: r for r in client.search_runs([experiment.experiment_id])}
    assert set(runs) == {job.name for job in jobs}
    for i, job in enumerate(jobs):
        history = [(m.step, m.value) for m in client.get_metric_history(runs[job.name].info.run_id, "episode/length")]
        assert history == [(10, 10.0 + i), (20, 20.0 + i)] + ([(30, 99.0)] if i else [])
        assert runs[job.name].data.tags["seed"] == str(i) and runs[job.name].info.status == "FINISHED"
    assert runs[jobs[0].name].data.params == {"learner.lr": "0.001"}


def test_a_sweeps_jobs_are_one_wandb_group_and_runs_of_one_process(tmp_path):
    pytest.importorskip("wandb")  # extra: pip install -e ".[wandb]"
    jobs = _sweep_jobs(tmp_path)
    loggers = [make_logger("wandb", job, exp_name=job.name) for job in jobs]
    for logger in loggers:  # both still live: W&B's default would have finished the first
        logger.log_metrics({"episode/length": 5.0}, step=10)
    assert [lg.experiment.group for lg in loggers] == ["my_sweep", "my_sweep"]
    assert [lg.experiment.name for lg in loggers] == [job.name for job in jobs]
    for logger in loggers:
        logger.close()
    single = make_logger("wandb", tmp_path / "one_run", exp_name="one_run")  # not a sweep's job: no group
    assert not single.experiment.group
    single.close()
