"""Tuning a learner with Optuna: search spaces, the trial jobs' link to their study, and
the tuned file a study ends with.

A search space (``conf/search/<learner>.yaml``) maps a setting to a range in Hydra's
sweep grammar, the same as ``hydra-optuna-sweeper``'s ``params``::

    learner.lr: tag(log, interval(1e-4, 1e-2))   # float, sampled on a log scale
    learner.batch_size: choice(32, 64, 128)      # categorical
    learner.number_splits: int(interval(4, 12))  # integer
    learner.hidden: choice([64, 64], [128, 128]) # categorical of lists

The sweeper (``hydra_plugins/rl_optuna_sweeper``) asks the study for a trial, runs it
as one job per seed and tells the study the mean over them of its objective, the task's
own measure as its judge sees it (``greedy_<measure>`` or
``train_<measure>_last<window>``, :meth:`runs.summary.MeasureKeys.headline`; the study's
metric name). Each job reports its
rolling measure to the study every ``report_every`` env steps (:class:`TrialLink`); the
mean over the trial's seeds is its intermediate value, and every seed's job stops when
the pruner says the trial is hopeless.

A trial the sweeper asked is its own (:func:`claim`: ``sweeper`` = host and process,
``alive_at`` renewed by its jobs' reports, every :data:`RENEW_S` seconds at most) until
told. A trial left running by a sweeper that is gone (:func:`abandoned`: its process
ended on this machine, or no word from it for :data:`LEASE_S` seconds) is taken over by
the next sweep of its study.
"""

from __future__ import annotations

import datetime as _dt
import math
import os
import re
import socket
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Iterable, Mapping

from omegaconf import OmegaConf

from params import ConfigError, did_you_mean, dotted
from params.declare import is_integer
from params.private_api import apply_value_overrides
from runs.settings import moved, moved_to

@dataclass
class Plan:
    """What every trial of a sweep shares: the picks, the command line's overrides
    (``given``) and all a job gets besides its trial's values (``fixed``), the space."""

    robot: str
    task: str
    learner: str
    given: list[str]
    fixed: list[str]
    space_file: Path
    params: dict
    measure: str
    objective: str  # the number each job is valued by, as summary.json names it (the study's metric)
    current: dict | None = None  # the run's own values as a trial, where the space holds them
    # The learner's own values of the searched settings (its config without tuned files:
    # the published ones), where they differ from the run's own (``value_defaults``).
    defaults: dict | None = None
    why_no_defaults: str = ""  # why ``defaults`` is None with ``value_defaults`` on


LEASE_S = 600  # seconds without word from another machine's trial before it counts as abandoned
RENEW_S = 30  # a trial's jobs renew its lease at a report this long after the last renewal


def claim(storage: Any, trial_id: int, seeds: Iterable[int]) -> None:
    """Marks a trial as this process's (``sweeper``: host and process id; ``alive_at``: now;
    ``seeds``: the seeds its jobs run)."""
    storage.set_trial_user_attr(trial_id, "sweeper", f"{socket.gethostname()}:{os.getpid()}")
    storage.set_trial_user_attr(trial_id, "alive_at", time.time())
    storage.set_trial_user_attr(trial_id, "seeds", [int(s) for s in seeds])


def abandoned(trial: Any, now: float | None = None) -> bool:
    """Whether a running trial's sweeper is gone: its process has ended on this machine, or
    (on another) neither it nor the trial's jobs have said anything for :data:`LEASE_S`
    seconds. A trial with no ``sweeper`` (asked by an older version) is left alone."""
    owner = trial.user_attrs.get("sweeper")
    if not isinstance(owner, str) or ":" not in owner:
        return False
    host, pid = owner.rsplit(":", 1)
    if host == socket.gethostname():
        try:
            os.kill(int(pid), 0)
        except ProcessLookupError:
            return True
        except (PermissionError, ValueError):
            return False
        return False
    return (time.time() if now is None else now) - float(trial.user_attrs.get("alive_at", 0)) > LEASE_S


def job_folders_of(trial: Any) -> list[Path]:
    """The job folders a trial's jobs reported from (``run_dir_seed<s>``), in its seeds' order;
    fewer than its seeds where a job never reported."""
    attrs = trial.user_attrs
    return [Path(attrs[f"run_dir_seed{s}"]) for s in attrs.get("seeds", []) if f"run_dir_seed{s}" in attrs]


# The sweeper's whole numbers: (least, most). Bounds keep a typo (1e308) from running for ever.
SWEEPER_INTS = {"n_trials": (0, 10**6), "trials_per_batch": (1, 10**4), "budget_steps": (1, 10**12),
                "report_every": (1, 10**8), "startup_trials": (0, 10**6)}
SEED_LIMIT = 2**32  # numpy's (and so Optuna's samplers') seeds; a run's own seeds are checked by the run
# Optuna's pruners by ``hydra.sweeper.pruner`` (steps are env steps): their class and settings.
PRUNERS = {
    "median": ("MedianPruner", ("n_startup_trials", "n_warmup_steps", "interval_steps", "n_min_trials")),
    "successive_halving": ("SuccessiveHalvingPruner", ("min_resource", "reduction_factor",
                                                       "min_early_stopping_rate", "bootstrap_count")),
    "hyperband": ("HyperbandPruner", ("min_resource", "max_resource", "reduction_factor", "bootstrap_count")),
}
AUTO = ("min_resource", "max_resource")  # settings Optuna also takes as "auto"


def check_sweeper_settings(settings: Mapping[str, Any]) -> dict[str, Any]:
    """``hydra.sweeper``'s settings checked and in their types; :class:`ConfigError`
    ``hydra.sweeper.<name> must be <allowed>; got <value>`` for the first bad one."""
    out = dict(settings)

    def refuse(name: str, allowed: str) -> ConfigError:
        return ConfigError(f"hydra.sweeper.{name} must be {allowed}; got {_plain(settings[name])!r}")

    for name, (low, high) in SWEEPER_INTS.items():
        if not (is_integer(settings[name]) and low <= settings[name] <= high):
            raise refuse(name, f"an integer >= {low} and <= {high:.0e}" if high >= 10**6 else
                         f"an integer >= {low} and <= {high}")
        out[name] = int(settings[name])
    for name in ("write_tuned", "start_from_current", "value_defaults", "refill"):
        if not isinstance(settings[name], bool):
            raise refuse(name, "true or false")
    for name in ("study", "storage"):
        if not isinstance(settings[name], str) or not settings[name].strip():
            raise refuse(name, "a non-empty name" if name == "study" else "a non-empty database URL (sqlite:///file.db)")
    if settings["search"] is not None and not (isinstance(settings["search"], str) and settings["search"].strip()):
        raise refuse("search", "null (conf/search/) or the path of a search space file")
    seeds = _plain(settings["seeds"])
    seeds = list(seeds) if isinstance(seeds, tuple) else seeds
    if not (isinstance(seeds, list) and seeds and all(is_integer(s) and 0 <= s < 2**63 for s in seeds)
            and len(set(seeds)) == len(seeds)):
        raise refuse("seeds", "distinct seeds, at least one, each an integer from 0 to 2^63-1 (a list: [0,1])")
    out["seeds"] = [int(s) for s in seeds]
    sampler_seed = settings["sampler_seed"]
    if sampler_seed is not None and not (is_integer(sampler_seed) and 0 <= sampler_seed < SEED_LIMIT):
        raise refuse("sampler_seed", "null or an integer from 0 to 2^32-1")
    out["sampler_seed"] = None if sampler_seed is None else int(sampler_seed)
    out["pruner"] = pruner_settings(settings["pruner"], settings.get("pruners"), refuse)
    return out


def batch_size(per_batch: int, left: int, finished: int, startup: int) -> int:
    """How many trials to ask together next: ``per_batch`` (at most the ``left`` to ask), but
    while fewer than ``startup`` trials have finished (complete or pruned: the TPE sampler
    draws at random until then), only the random ones still due. A trial the sampler could
    guide is not asked before the random trials it would learn from have run, so a batched
    study samples as many trials at random as one asked one at a time, not all of them."""
    size = min(per_batch, left)
    return min(size, startup - finished) if finished < startup else size


def pruner_settings(pruner: Any, pruners: Any = None,
                    refuse: Callable[[str, str], ConfigError] | None = None) -> dict | None:
    """The pruner a sweep uses, ``{"kind": ..., <settings>}`` or None: ``pruner`` names a kind
    (:data:`PRUNERS`) whose settings are ``pruners[kind]`` (``hydra.sweeper.pruners``), or is
    itself a mapping of ``kind`` (median by default) and settings, or null for none."""
    pruner, pruners = _plain(pruner), _plain(pruners) or {}
    if refuse is None:
        def refuse(name: str, allowed: str) -> ConfigError:
            return ConfigError(f"hydra.sweeper.{name} must be {allowed}; got {pruner!r}")
    if isinstance(pruner, str):
        if pruner not in PRUNERS:
            raise ConfigError(f"hydra.sweeper.pruner must be null or one of {', '.join(PRUNERS)}; got {pruner!r}")
        own = pruners.get(pruner) or {}
        if not isinstance(own, dict):
            raise ConfigError(f"hydra.sweeper.pruners.{pruner} must be a mapping of its settings; got {own!r}")
        return _checked_pruner({**own, "kind": pruner}, refuse, f"hydra.sweeper.pruners.{pruner}.")
    return _checked_pruner(pruner, refuse)


def _checked_pruner(pruner: Any, refuse: Callable[[str, str], ConfigError],
                    where: str = "hydra.sweeper.pruner.") -> dict | None:
    """The pruner's ``kind`` (median by default; :data:`PRUNERS`) and settings (null or {}
    for none), each a whole number >= 0 (``min_resource``/``max_resource`` also ``auto``)."""
    if pruner is None or pruner == {}:
        return None
    if not isinstance(pruner, dict):
        raise refuse("pruner", f"null, one of {', '.join(PRUNERS)}, or a mapping: kind and its settings")
    kind = pruner.get("kind", "median")
    if kind not in PRUNERS:
        raise ConfigError(f"hydra.sweeper.pruner.kind must be one of {', '.join(PRUNERS)}; got {kind!r}")
    keys = PRUNERS[kind][1]
    out: dict[str, Any] = {"kind": kind}
    for key, value in pruner.items():
        if key == "kind":
            continue
        if key not in keys:
            hint = did_you_mean(str(key), keys, where)
            raise ConfigError(f"{where}{key} is not a setting of the {kind} pruner; {hint}"
                              f"allowed: kind, {', '.join(keys)}")
        if key in AUTO and value == "auto":
            out[key] = value
            continue
        least = 2 if key == "reduction_factor" else 1 if key in AUTO else 0
        if not (is_integer(value) and least <= value <= 10**9):
            more = " or auto" if key in AUTO else ""
            raise ConfigError(f"{where}{key} must be an integer >= {least} and <= 1e+09{more}; "
                              f"got {value!r}")
        out[key] = int(value)
    return out


def _plain(value: Any) -> Any:
    """A setting as plain Python (Hydra hands lists and mappings over as OmegaConf nodes)."""
    return OmegaConf.to_container(value, resolve=True) if OmegaConf.is_config(value) else value


SAMPLED = "choice(...), interval(...), int(interval(...)), tag(log, interval(...)) or range(...)"


@dataclass
class Param:
    """One searched setting: its key, Optuna distribution and, for a categorical, the
    value behind each label (Optuna's choices must be plain scalars)."""

    key: str
    distribution: Any
    labels: dict[str, Any] | None = None

    def value(self, sampled: Any) -> Any:
        """The setting's value for Optuna's sample ``sampled``."""
        if self.labels is not None:
            return self.labels[sampled]
        return float(f"{sampled:.4g}") if isinstance(sampled, float) else sampled

    def sample_of(self, value: Any) -> Any:
        """Optuna's sample for the setting's ``value``, or None where the space cannot give it."""
        if self.labels is not None:
            label = override_value(value)
            return label if label in self.labels else None
        d = self.distribution
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not d.low <= value <= d.high:
            return None
        if isinstance(d.low, int) and not float(value).is_integer():
            return None
        return int(value) if isinstance(d.low, int) else float(value)

    def extremes(self) -> list[Any]:
        """The values the space can give that bound it (every choice of a categorical)."""
        if self.labels is not None:
            return list(self.labels.values())
        return [self.distribution.low, self.distribution.high]


def override_value(value: Any) -> str:
    """``value`` as Hydra's command line reads it back."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, (list, tuple)):
        return "[" + ",".join(override_value(v) for v in value) + "]"
    if value is None:
        return "null"
    return str(value)


def parse_space(space: Mapping[str, Any], where: str) -> dict[str, Param]:
    """The search space ``space`` (key -> Hydra sweep expression) as :class:`Param`s;
    ``where`` names it in errors."""
    import optuna.distributions as od
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.core.override_parser.types import ChoiceSweep, IntervalSweep, RangeSweep

    parser = OverridesParser.create()
    params: dict[str, Param] = {}
    for key, expr in space.items():
        text = f"{key}: {expr}"
        try:
            value = parser.parse_override(f"{key}={expr}").value()
        except Exception as err:  # noqa: BLE001 - the grammar's errors come in several types
            raise ConfigError(f"{where}: {text} does not parse ({str(err).splitlines()[0]}); "
                              f"use {SAMPLED}") from None
        log = "log" in getattr(value, "tags", set())
        if isinstance(value, ChoiceSweep):
            labels = {override_value(v): v for v in value.list}
            params[key] = Param(key, od.CategoricalDistribution(list(labels)), labels)
        elif isinstance(value, IntervalSweep):
            low, high = value.start, value.end
            if not low < high:
                raise ConfigError(f"{where}: {text} is an empty range (its low end must be below its high end)")
            if log and low <= 0:
                raise ConfigError(f"{where}: {text} samples on a log scale: its low end must be > 0")
            ints = isinstance(low, int) and isinstance(high, int)
            dist = (od.IntDistribution(low, high, log=log) if ints
                    else od.FloatDistribution(float(low), float(high), log=log))
            params[key] = Param(key, dist)
        elif isinstance(value, RangeSweep):
            values = list(_range_values(value))
            if not values:
                raise ConfigError(f"{where}: {text} is an empty range")
            if not all(isinstance(v, int) for v in (value.start, value.stop, value.step)):
                labels = {override_value(v): v for v in values}
                params[key] = Param(key, od.CategoricalDistribution(list(labels)), labels)
            else:
                params[key] = Param(key, od.IntDistribution(values[0], values[-1], step=abs(value.step)))
        else:
            raise ConfigError(f"{where}: {text} is one value, not a range; use {SAMPLED} "
                              "(a fixed value goes on the command line)")
    if not params:
        raise ConfigError(f"{where} has no setting to search")
    return params


def _range_values(r) -> Iterable[Any]:
    value = r.start
    while (r.step > 0 and value < r.stop) or (r.step < 0 and value > r.stop):
        yield value
        value += r.step


def load_space(path: Path, override: str | None = None) -> dict[str, Param]:
    """The search space in ``path`` (a YAML mapping)."""
    try:
        raw = OmegaConf.to_container(OmegaConf.load(path), resolve=False)
    except FileNotFoundError:
        raise ConfigError(f"no search space {path}: write one (see conf/search/) or point "
                          "hydra.sweeper.search at one") from None
    except Exception as err:  # noqa: BLE001 - yaml and OmegaConf raise many types
        raise ConfigError(f"{path} does not parse ({type(err).__name__})") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{path} must map settings to ranges (key: interval(...)); got a {type(raw).__name__}")
    return parse_space(dotted(raw), str(path))  # {learner: {lr: ..}} and {learner.lr: ..} alike


def check_space(params: Mapping[str, Param], config: Any, where: str, check: Callable[[Any], None]) -> None:
    """Every searched key must be a setting of ``config`` (the composed run config), and
    every value the space can give must pass ``check`` (the run's own validation) on a copy of
    ``config`` given that value by Hydra's own override step, as composing with ``key=value``
    gives it (a composition each cost ~0.35 s): a bad range is refused before any trial runs."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parser = OverridesParser.create()
    for key, param in params.items():
        parent, _, leaf = key.rpartition(".")
        node = OmegaConf.select(config, parent) if parent else config
        if moved_to(key):
            raise ConfigError(f"{where}: {moved(key, '...')}")
        if node is None or not OmegaConf.is_dict(node) or leaf not in node:
            names = sorted(str(k) for k in node) if OmegaConf.is_dict(node) else []
            hint = did_you_mean(leaf, names, prefix=f"{parent}." if parent else "")
            raise ConfigError(f"{where}: {key} is not a setting of this run; {hint}"
                              f"allowed{' in ' + parent if parent else ''}: {', '.join(names)}")
        for value in param.extremes():
            given = config.copy()
            apply_value_overrides(parser.parse_overrides([f"{key}={override_value(value)}"]), given)
            try:
                check(given)
            except ConfigError as err:
                raise ConfigError(f"{where}: {key} can be {override_value(value)}, which the run "
                                  f"refuses: {err}") from None


def searched_values(params: Mapping[str, Param], config: Any) -> dict[str, Any] | None:
    """The values ``config`` has for the searched keys of ``params`` (plain Python; null is
    a value, e.g. the dqn's ``done_episode_reward``), or None where it lacks a key."""
    out, missing = {}, object()
    for key in params:
        value = OmegaConf.select(config, key, default=missing)
        if value is missing:
            return None
        out[key] = OmegaConf.to_container(value) if OmegaConf.is_config(value) else value
    return out


def current_trial(params: Mapping[str, Param], config: Any) -> dict[str, Any] | None:
    """Optuna's params for the values ``config`` already has, if the space holds them all."""
    values = searched_values(params, config)
    if values is None:
        return None
    samples = {key: param.sample_of(values[key]) for key, param in params.items()}
    return samples if all(s is not None for s in samples.values()) else None


def make_pruner(settings: Mapping[str, Any] | None):
    """Optuna's pruner of ``settings``' ``kind`` (median by default; :data:`PRUNERS`) with
    its other settings (steps are env steps), or none for ``None``/``{}``. The median pruner
    compares a trial with finished ones only; successive halving and Hyperband with every
    trial that reached its rung, running ones too (trials trained side by side)."""
    import optuna

    if not settings:
        return optuna.pruners.NopPruner()
    settings = dict(settings)
    name = PRUNERS[settings.pop("kind", "median")][0]
    return getattr(optuna.pruners, name)(**settings)


JOURNAL = "journal://"  # journal:///shared/fs/studies.log: Optuna's journal file storage


def shown_url(url: str) -> str:
    """``url`` with its password replaced by ``***`` (for the console and the tuned file)."""
    return re.sub(r"(://[^:/@]+:)[^@/]*@", r"\1***@", str(url))


def open_storage(url: str, attempts: int = 3):
    """Optuna's storage at ``url``: any SQLAlchemy URL (``sqlite:///file.db``,
    ``postgresql://user:pw@host/db``) or ``journal:///path/studies.log`` (a journal file, for a
    shared file system); refused in one line when it cannot be opened (unreachable, login
    refused, no driver). Several sweeps opening one new database at once may race creating
    its tables: the loser tries again."""
    import optuna

    for attempt in range(attempts):
        try:
            return _storage(url)
        except ImportError as err:
            raise ConfigError(f"hydra.sweeper.storage={shown_url(url)} needs its database driver "
                              f"({err}); for PostgreSQL: pip install -e '.[postgresql]'") from None
        except Exception as err:  # noqa: BLE001 - SQLAlchemy and drivers raise many types
            reason = shown_url(" ".join(str(err).split()) or type(err).__name__)
            if attempt + 1 < attempts and re.search(r"already exists|duplicate key", reason):
                time.sleep(0.5 * (attempt + 1))
                continue
            raise ConfigError(f"hydra.sweeper.storage={shown_url(url)} cannot be opened: {reason[:200]}") from None
    raise AssertionError("unreachable")


def _storage(url: str):
    import optuna

    if url.startswith(JOURNAL):
        from optuna.storages.journal import JournalFileBackend

        path = Path(url[len(JOURNAL):])
        path.parent.mkdir(parents=True, exist_ok=True)
        return optuna.storages.JournalStorage(JournalFileBackend(str(path)))
    if url.startswith("sqlite:///"):
        Path(url[len("sqlite:///"):]).parent.mkdir(parents=True, exist_ok=True)
    return optuna.storages.RDBStorage(url, engine_kwargs=_engine_kwargs(url))


def _engine_kwargs(url: str) -> dict:
    # Several processes write one SQLite file: wait for its lock instead of failing.
    if url.startswith("sqlite"):
        return {"connect_args": {"timeout": 60}}
    # A server that cannot be reached is refused in seconds, not after the OS's TCP timeout.
    if url.startswith("postgresql"):
        return {"connect_args": {"connect_timeout": 10}, "pool_pre_ping": True}
    return {}


class TrialLink:
    """A trial job's line to its study: reports the rolling measure and asks the pruner
    whether to stop. Every seed's job reports its value at a step (``step<s>_seed<seed>``);
    once all the trial's seeds have, their mean is the trial's intermediate value at that
    step (a trial of one seed: its value). A study it cannot reach is one warning, and the
    run goes on unpruned.

    A trial pruned by one seed's report stops its other seeds' runs in this process at
    their next step (:attr:`pruned`), and elsewhere at their next report."""

    # Trials this process has seen pruned, (storage, study, number): shared by the links of
    # one trial's seeds that train side by side.
    _pruned: set[tuple[str, str, int]] = set()
    # The storages this process opened, by URL: the jobs of a batch share one (a journal
    # file is then read once per report, not once per job).
    _storages: dict[str, Any] = {}

    def __init__(self, storage: str, study: str, number: int, lead: bool,
                 pruner: Mapping[str, Any] | None, every: int, run_dir: Path, seed: int = 0) -> None:
        import optuna

        self.every, self.lead, self.number, self.seed = int(every), lead, number, int(seed)
        self._key = (storage, study, number)
        if storage not in TrialLink._storages:
            TrialLink._storages[storage] = open_storage(storage)
        self._storage = TrialLink._storages[storage]
        self._study = optuna.load_study(study_name=study, storage=self._storage, pruner=make_pruner(pruner))
        study_id = self._storage.get_study_id_from_name(study)
        self._trial_id = self._storage.get_trial_id_from_study_id_trial_number(study_id, number)
        self._pruner = self._study.pruner
        self._never_prunes = isinstance(self._pruner, optuna.pruners.NopPruner)
        self._renewed = -math.inf  # when this job last renewed the trial's lease
        where = f"{socket.gethostname()}:{os.getpid()}"
        key = "worker" if lead else f"worker_{os.getpid()}"
        self._storage.set_trial_user_attr(self._trial_id, key, where)
        if lead:
            self._storage.set_trial_user_attr(self._trial_id, "run_dir", str(run_dir))
        # Where each seed's job runs: a sweep that takes the trial over resumes it there.
        self._storage.set_trial_user_attr(self._trial_id, f"run_dir_seed{seed}", str(Path(run_dir).resolve()))

    @property
    def pruned(self) -> bool:
        """Whether this process has seen the trial pruned (by any of its seeds' reports)."""
        return self._key in TrialLink._pruned

    def __call__(self, step: int, value: float) -> bool:
        """Reports ``value`` at ``step`` env steps; True when the study prunes the trial."""
        import optuna

        try:
            frozen = self._storage.get_trial(self._trial_id)
            if frozen.state != optuna.trial.TrialState.RUNNING:
                return False  # told already (e.g. a resumed job): nothing to report to
            if frozen.user_attrs.get("pruned_at_step") is not None:
                TrialLink._pruned.add(self._key)  # another seed's report pruned it
                return True
            if time.time() - self._renewed >= RENEW_S:  # the trial's lease
                self._renewed = time.time()
                self._storage.set_trial_user_attr(self._trial_id, "alive_at", self._renewed)
            if not (math.isfinite(value) and self._report(step, float(value), frozen)):
                return False  # no new intermediate value: nothing new for the pruner to judge
            if self._never_prunes:
                return False  # (the trial's new state need not be read back for it)
            frozen = self._storage.get_trial(self._trial_id)
            if self._pruner.prune(self._study, frozen):
                self._storage.set_trial_user_attr(self._trial_id, "pruned_at_step", step)
                TrialLink._pruned.add(self._key)
                return True
            return False
        except Exception as err:  # noqa: BLE001 - the study is a remote database too
            print(f"warning: trial {self.number}: cannot reach the study ({type(err).__name__}: "
                  f"{str(err).splitlines()[0] if str(err) else ''}); the run goes on unpruned")
            self.every = 0
            return False

    def _report(self, step: int, value: float, frozen: Any) -> bool:
        """This seed's value at ``step``; the trial's intermediate value there once every seed's
        is in (the first seed's alone for a trial asked without its seeds). True when it
        wrote an intermediate value."""
        seeds = frozen.user_attrs.get("seeds")
        if not seeds:
            if self.lead:
                self._storage.set_trial_intermediate_value(self._trial_id, step, value)
            return self.lead
        self._storage.set_trial_user_attr(self._trial_id, f"step{step}_seed{self.seed}", value)
        return bool(self._complete_steps(frozen, {f"step{step}_seed{self.seed}": value}, [step]))

    def solved(self, step: int, value: float) -> None:
        """This seed stopped solved at ``step`` env steps with ``value``: it counts with that
        value at every later step the trial's other seeds report (a solved seed must not
        leave its trial without intermediate values, nor out of the pruner's later rungs)."""
        try:
            frozen = self._storage.get_trial(self._trial_id)
            if not frozen.user_attrs.get("seeds") or not math.isfinite(value):
                return
            self._storage.set_trial_user_attr(self._trial_id, f"solved_seed{self.seed}", [int(step), float(value)])
            reported = (re.fullmatch(r"step(\d+)_seed\d+", k) for k in frozen.user_attrs)
            later = sorted({int(m.group(1)) for m in reported if m and int(m.group(1)) > step})
            self._complete_steps(frozen, {f"solved_seed{self.seed}": [int(step), float(value)]}, later)
        except Exception as err:  # noqa: BLE001 - as __call__: the run's result does not depend on it
            print(f"warning: trial {self.number}: cannot reach the study ({type(err).__name__})")

    def _complete_steps(self, frozen: Any, new: dict, steps: list[int]) -> list[int]:
        """The trial's intermediate value at each of ``steps`` where every seed's is now in
        (``new``: attributes just written): a seed solved before a step counts its solved
        value. Returns the steps it wrote."""
        values, written = {**frozen.user_attrs, **new}, []
        for step in steps:
            reported = []
            for s in frozen.user_attrs["seeds"]:
                held = values.get(f"solved_seed{s}")
                reported.append(values.get(f"step{step}_seed{s}", held[1] if held and held[0] < step else None))
            if all(v is not None for v in reported) and step not in frozen.intermediate_values:
                self._storage.set_trial_intermediate_value(self._trial_id, step, sum(reported) / len(reported))
                written.append(step)
        return written


def tuned_text(values: Mapping[str, Any], base: Mapping[str, Any] | None, header: list[str]) -> str:
    """A ``conf/tuned/<robot>_<learner>.yaml`` (or a task's ``<robot>_<task>_<learner>.yaml``):
    ``base`` (the tuned file the study ran with, if any) with the best trial's ``values``
    (dotted keys) set, under ``header``."""
    conf = OmegaConf.create(dict(base or {}))
    for key, value in values.items():
        OmegaConf.update(conf, key, value, force_add=True)
    lines = ["# @package _global_", *(f"# {line}".rstrip() for line in header)]
    return "\n".join(lines) + "\n" + OmegaConf.to_yaml(conf)


def names_study(text: str, study: str) -> bool:
    """Whether a tuned file's ``text`` is study ``study``'s (its header names it)."""
    return f"study {study} in" in text


OWN_VALUES = "the learner's own values of the searched settings"  # in the header of a file they won
KEPT = "Kept by Optuna"  # the first header line of a file a study kept ...
KEPT_END = "end of the study's header; the file's own notes follow"  # ... and its last


def kept_text(text: str, header: list[str]) -> str:
    """A tuned file a study kept (its own settings, or at least as good as the best trial):
    ``text`` as it is, its notes included, with ``header`` (the study's, first line
    :data:`KEPT`) after ``# @package _global_`` in place of an earlier study's."""
    lines = text.splitlines()
    head = lines[:1] if lines and lines[0].startswith("# @package") else []
    rest = lines[len(head):]
    if rest and rest[0].startswith(f"# {KEPT}"):  # an earlier study's header: replaced
        end = next((i for i, line in enumerate(rest) if line == f"# {KEPT_END}"), 0)
        rest = rest[end + 1:]
    ours = [f"# {line}".rstrip() for line in [*header, KEPT_END]]
    return "\n".join([*head, *ours, *rest]) + "\n"


def replace_tuned(path: Path, text: str, keep_in: Path) -> str:
    """Writes the tuned file ``text`` to ``path`` (``hydra.sweeper.write_tuned=true``), the
    previous file first copied to ``keep_in/previous_<name>``; returns one line saying what
    changed (``key old -> new``, keys only one of them has with ``(none)``)."""
    old_text = path.read_text(errors="replace") if path.is_file() else None
    kept = ""
    if old_text is not None:
        backup = keep_in / f"previous_{path.name}"
        backup.write_text(old_text)
        kept = f" (the previous one kept as {backup})"
    path.write_text(text)
    before, after = (settings_of(t) for t in (old_text, text))
    changes = [f"{k} {before.get(k, '(none)')} -> {after.get(k, '(none)')}"
               for k in sorted(set(before) | set(after)) if before.get(k, "(none)") != after.get(k, "(none)")]
    return f"wrote {path}{kept}: " + ("; ".join(changes) if changes else "no setting changed")


def settings_of(text: str | None) -> dict[str, Any]:
    """A tuned file's settings by dotted key (none for no file, or one that does not parse)."""
    if text is None:
        return {}
    try:
        conf = OmegaConf.to_container(OmegaConf.create(text), resolve=False)
    except Exception:  # noqa: BLE001 - a damaged old file: everything counts as changed
        return {}
    return {k: override_value(v) for k, v in dotted(conf).items()} if isinstance(conf, dict) else {}


def now_utc() -> str:
    return _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")


def trial_link(cfg: Any, run_dir: Path, sweeper: Any) -> TrialLink | None:
    """The Optuna study a ``trial=N`` job reports to (its ``sweeper``'s storage and study;
    ``sweeper`` is the job's ``hydra.sweeper`` node); None for any other job."""
    if cfg.get("trial") is None or cfg.mode != "train":
        return None
    if "rl_optuna_sweeper" not in str(sweeper.get("_target_", "")):
        raise ConfigError(f"trial={cfg.trial} is set by hydra/sweeper=optuna for its own jobs; "
                          "tune with: python train.py -m hydra/sweeper=optuna ...")
    try:
        return TrialLink(str(sweeper.storage), str(sweeper.study), int(cfg.trial),
                         lead=int(cfg.seed) == int(sweeper.seeds[0]),
                         pruner=pruner_settings(sweeper.pruner, sweeper.get("pruners")),
                         every=int(sweeper.report_every), run_dir=run_dir, seed=int(cfg.seed))
    except ConfigError:
        raise
    except Exception as err:  # noqa: BLE001 - a missing study or trial, a database error
        first = (str(err).strip().splitlines() or [""])[0]
        raise ConfigError(f"trial={cfg.trial}: study {sweeper.study} in {shown_url(sweeper.storage)} has no such "
                          f"trial to report to ({type(err).__name__}: {first})") from None
