"""The tuning sweep: Optuna asks for trials, each runs as one job per seed, the study is told
the mean over the seeds of its objective (``hydra/sweeper=optuna``; Hydra's plugin class is
the thin shell :class:`hydra_plugins.rl_optuna_sweeper.optuna_sweeper.OptunaSweeper`, which
imports this module only when a tuning sweep starts).

Trials train on a plain run's (and the benchmark's) terms: each seed stops when its verdict
says solved, or at the study's budget of env steps, with the config's own greedy
evaluations. A job is valued by :func:`runs.summary.success_and_speed` (the study's metric
name, ``success_and_speed``), which orders runs as the benchmark does: the task's measure
at the end over its threshold, capped at 1 (1: a success), plus the fraction of the budget
left when a success was judged solved. A study that ranked trials by the final measure
after training past "solved" picked settings whose policies had drifted off a good one by
the budget's end, and valued a hand pick that solves quickly as a failure."""

from __future__ import annotations

import itertools
import statistics
import warnings
from pathlib import Path
from typing import Any, Sequence

from hydra.core.plugins import Plugins
from hydra.types import HydraContext, TaskFunction
from omegaconf import DictConfig, OmegaConf, open_dict

from params import ConfigError
from tasks.catalog import GROUPS, TASK_TUNED, conf_dir, default_task, tuned_name, with_tuned_layers
from runs.settings import check_run_config
from runs.summary import SUCCESS_AND_SPEED, final_measure, success_and_speed, summarize_run
from sweeps.resume import continuable, resume_runs
from sweeps.tuning import (KEPT, OWN_VALUES, Plan, abandoned, batch_size, check_space, check_sweeper_settings, claim,
                           current_trial, job_folders_of, kept_text, load_space, make_pruner, names_study, now_utc,
                           open_storage, override_value, replace_tuned, searched_values, settings_of, shown_url,
                           tuned_text)
from tasks.base import Success
from tasks.factory import build_task

# Settings the sweeper itself gives every job: the command line may not.
OWN = ("seed", "trial", "max_env_steps", "max_episodes", "stop_when_solved")


def continued_seed(sampler_seed: int, held: int) -> int:
    """The sampler's seed for a study continued with ``held`` trials: ``sampler_seed`` mixed
    with ``held`` (numpy's ``SeedSequence``), so a continued study never draws the values its
    first sweep drew from ``sampler_seed``, and the same continuation draws the same values."""
    import numpy as np

    return int(np.random.SeedSequence([int(sampler_seed), int(held)]).generate_state(1)[0])


class TuningSweep:
    """Asks Optuna for trials, launches each as one job per seed, tells it the mean of their objective."""

    def __init__(self, study: str, storage: str, n_trials: int = 12, trials_per_batch: int = 1,
                 seeds: Sequence[int] = (0, 1), search: str | None = None, budget_steps: int = 50_000,
                 report_every: int = 5000, pruner: str | dict | None = None, pruners: dict | None = None,
                 startup_trials: int = 5,
                 sampler_seed: int | None = None, write_tuned: bool = False, start_from_current: bool = True,
                 value_defaults: bool = False, refill: bool = False) -> None:
        # As given: :meth:`_check_settings` checks each and keeps it in its type (1.5 trials is
        # refused, not rounded; ``write_tuned=maybe`` is refused, not taken as true).
        self.settings = dict(study=study, storage=storage, n_trials=n_trials, trials_per_batch=trials_per_batch,
                             seeds=seeds, search=search, budget_steps=budget_steps, report_every=report_every,
                             pruner=pruner, pruners=pruners, startup_trials=startup_trials, sampler_seed=sampler_seed,
                             write_tuned=write_tuned, start_from_current=start_from_current,
                             value_defaults=value_defaults, refill=refill)
        self.study_name, self.storage_url = str(study), str(storage)
        self.search, self.pruner, self.sampler_seed = search, pruner, sampler_seed
        self.config: DictConfig | None = None
        self.launcher = None
        self.hydra_context: HydraContext | None = None

    def setup(self, *, hydra_context: HydraContext, task_function: TaskFunction, config: DictConfig) -> None:
        self.hydra_context, self.config = hydra_context, config
        self.launcher = Plugins.instance().instantiate_launcher(
            hydra_context=hydra_context, task_function=task_function, config=config)

    # -- checks before any trial ------------------------------------------------
    def _check_settings(self) -> None:
        """Checks every sweeper setting (one line naming it, its value and what is allowed)
        and keeps each in its type."""
        checked = check_sweeper_settings(self.settings)
        self.study_name, self.storage_url, self.search = checked["study"], checked["storage"], checked["search"]
        self.n_trials, self.trials_per_batch = checked["n_trials"], checked["trials_per_batch"]
        self.seeds, self.budget_steps = checked["seeds"], checked["budget_steps"]
        self.report_every, self.pruner = checked["report_every"], checked["pruner"]
        self.startup_trials, self.sampler_seed = checked["startup_trials"], checked["sampler_seed"]
        self.write_tuned, self.start_from_current = checked["write_tuned"], checked["start_from_current"]
        self.value_defaults, self.refill = checked["value_defaults"], checked["refill"]

    def _fixed(self, arguments: list[str]) -> list[str]:
        """The command line's overrides, given to every job; sweeps and the sweeper's own keys refused."""
        parser = _parser()
        for override in parser.parse_overrides(arguments):
            key = override.get_key_element()
            if override.is_sweep_override():
                raise ConfigError(f"{override.input_line}: the study picks the values; put ranges in the search "
                                  "space (conf/search/<learner>.yaml or hydra.sweeper.search) and seeds in "
                                  "hydra.sweeper.seeds=[0,1]")
            if key in OWN:
                raise ConfigError(f"{override.input_line}: the sweeper sets {key} for each job "
                                  "(hydra.sweeper.seeds, hydra.sweeper.budget_steps)")
        return list(arguments)

    def _compose(self, overrides: list[str]) -> DictConfig:
        assert self.hydra_context is not None and self.config is not None
        cfg = self.hydra_context.config_loader.load_sweep_config(self.config, list(overrides))
        with open_dict(cfg):
            del cfg["hydra"]
        return cfg

    def _hydra_overrides(self) -> list[str]:
        """The command line's ``hydra...`` overrides (the sweeper's settings among them)."""
        assert self.config is not None
        return [str(o) for o in self.config.hydra.overrides.hydra
                if not str(o).startswith(("hydra.sweep.dir=", "hydra.mode="))]

    def _budget(self) -> list[str]:
        return [f"max_env_steps={self.budget_steps}", "max_episodes=0", "stop_when_solved=true"]

    def _trial_defaults(self, fixed: list[str]) -> list[str]:
        """What trial jobs get unless the command line says otherwise: ``quiet=true`` (banner
        and verdict per job; the sweeper prints one line per trial). Greedy evaluations are
        the config's own, as a plain run's: they may solve it."""
        given = {a.split("=", 1)[0] for a in fixed}
        return [f"{k}={v}" for k, v in (("quiet", "true"),) if k not in given]

    def _plan(self, arguments: list[str]) -> Plan:
        """What every trial shares, checked before the first one: one line for bad input."""
        assert self.config is not None
        self._check_settings()
        given = self._fixed(arguments)
        fixed = [*self._trial_defaults(given), *given, *self._budget()]
        choices = self.config.hydra.runtime.choices
        robot, task, learner = (str(choices.get(k)) for k in GROUPS)
        space_file = Path(self.search) if self.search else search_file(robot, learner, task)
        params = load_space(space_file)
        base = self._compose(fixed)
        check_run_config(base)
        success = _check_builds(base)
        episode = base.task.get("max_episode_steps")
        if episode is not None and self.budget_steps < int(episode):
            raise ConfigError(f"hydra.sweeper.budget_steps must be at least one episode of {robot}/{task} "
                              f"(task.max_episode_steps = {int(episode)} env steps); got {self.budget_steps}")
        check_space(params, base, str(space_file), check_run_config)
        defaults, why = None, ""
        if self.value_defaults:  # the learner's own values, where the tuned files change them
            own = searched_values(params, self._compose(with_tuned_layers([*fixed, "~tuned"])))
            defaults = own if own is not None and own != searched_values(params, base) else None
            why = ("its config lacks a searched setting" if own is None else
                   "they are the settings the study began with" if defaults is None else "")
        return Plan(robot, task, learner, given, fixed, space_file, params, success.measure,
                    SUCCESS_AND_SPEED, current_trial(params, base), defaults, why)

    # -- the study ----------------------------------------------------------------
    def sweep(self, arguments: list[str]) -> Any:
        import optuna

        assert self.config is not None and self.launcher is not None
        optuna.logging.set_verbosity(optuna.logging.WARNING)
        plan = self._plan(arguments)
        if self.refill and not hasattr(self.launcher, "launch_fed"):
            raise ConfigError("hydra.sweeper.refill=true trains a study's trials as members of one batch: it needs "
                              f"hydra/launcher=seeds (the default); got {type(self.launcher).__name__}")
        study = self._open_study(plan)
        sweep_dir = Path(str(self.config.hydra.sweep.dir))
        sweep_dir.mkdir(parents=True, exist_ok=True)
        OmegaConf.save(self.config, sweep_dir / "multirun.yaml")
        print(f"tuning {plan.learner} on {plan.robot}/{plan.task}: study {self.study_name} in {shown_url(self.storage_url)}\n"
              f"  {self.n_trials} trials x seeds {self.seeds}, {self.budget_steps} env steps each, objective: "
              f"{plan.objective} (mean over the seeds), pruning: {self.pruner or 'off'}, space: {plan.space_file}",
              flush=True)
        if not study.trials:  # the tuned file its trials run with: the study's final file builds on it
            ran_file = self._ran_with(plan)[1]
            study.set_user_attr("tuned_file_text", ran_file.read_text() if ran_file else "")
        if self.start_from_current and not study.trials:
            if plan.current is not None:  # the study's first trial: what a plain run does now
                # skip_if_exists: a sweep started beside this one on the same new study may have queued it
                study.enqueue_trial(plan.current, skip_if_exists=True)
                print("  trial 0 is the current configuration (start_from_current)", flush=True)
            else:
                print("  the current configuration lies outside the space: every trial is sampled, and it is "
                      "valued beside the first round", flush=True)
        told = _told(study)
        to_ask = self.n_trials + self._take_over(study, plan)  # trials asked again are not new ones
        # Configurations valued apart from the trials (the current one where no trial is it,
        # the learner's own values) go beside the first round (their jobs members of that
        # batch), not in a batch of their own after the last.
        apart = self._apart_jobs(study, plan)
        extra = [job for _, jobs in apart for job in jobs]
        results, done, launched = [], 0, 0
        while done < to_ask and not (sweep_dir / ".stop").exists():
            size = batch_size(self.trials_per_batch, to_ask - done, _finished(study), self.startup_trials)
            batch = [self._ask(study, plan) for _ in range(size)]
            if self.refill:
                returns, asked = self._run_fed(study, batch, plan, launched, extra, to_ask - done - size, sweep_dir)
                results.append(returns)
                launched += len(returns)
                done += asked
            else:
                results.append(self._run_batch(study, batch, plan, first_job=launched, extra=extra))
                launched += len(batch) * len(self.seeds) + len(extra)
                done += len(batch)
            if extra:
                self._value_apart(study, plan, apart, results[-1][-len(extra):])
                apart, extra = [], []
        if extra and not (sweep_dir / ".stop").exists():  # no round ran (a study already at its count)
            self._value_apart(study, plan, apart, self.launcher.launch(extra, initial_job_idx=launched))
        self._finish(study, plan, sweep_dir, told=_told(study) != told)
        return results

    def _apart_jobs(self, study, plan: Plan) -> list[tuple[str, list[list[str]]]]:
        """The configurations the study values apart from its trials, once each, and their
        jobs (one per seed, on the study's budget): the current one where the space does not
        hold it (``current_value``), and with ``value_defaults`` the learner's own values of
        the searched settings where the tuned files change them (``defaults_value``)."""
        apart = []
        if self.start_from_current and plan.current is None and "current_value" not in study.user_attrs:
            apart.append(("current_value", [[*plan.fixed, f"seed={seed}"] for seed in self.seeds]))
        if self.value_defaults and "defaults_value" not in study.user_attrs:
            if plan.defaults is None:  # nothing to value apart
                study.set_user_attr("defaults_value", None)
                print(f"  {OWN_VALUES}: not valued apart ({plan.why_no_defaults})", flush=True)
            else:
                own = [f"{k}={override_value(v)}" for k, v in plan.defaults.items()]
                apart.append(("defaults_value", [[*plan.fixed, *own, f"seed={seed}"] for seed in self.seeds]))
        return apart

    def _value_apart(self, study, plan: Plan, apart: list[tuple[str, list[list[str]]]], returns: list) -> None:
        """Each configuration valued apart (:meth:`_apart_jobs`): its value, the mean over its
        jobs' ``returns`` of the objective, kept in the study's ``user_attrs`` under its name.
        The tuned file takes the best trial's values only where they beat it."""
        shown = {"current_value": "current configuration (outside the space)", "defaults_value": OWN_VALUES}
        for name, jobs in apart:
            mine, returns = returns[:len(jobs)], returns[len(jobs):]
            summaries = _summaries([_run_dir(r) for r in mine])
            values = [success_and_speed(s, self.budget_steps) for s in summaries]
            if any(s.get("status") != "ok" for s in summaries) or any(v is None for v in values):
                print(f"the {shown[name]} has no value: its jobs did not all finish", flush=True)
                continue
            value = statistics.fmean(float(v) for v in values)
            if name == "defaults_value":  # what was valued, as later sweeps cannot tell it from the files
                study.set_user_attr("defaults", plan.defaults)
            study.set_user_attr(name, value)
            print(f"{shown[name]}: {plan.objective} {value:.4g} "
                  f"(seeds {', '.join(f'{float(v):.4g}' for v in values)})", flush=True)

    def _run_batch(self, study, batch: list, plan: Plan, first_job: int, extra: list | None = None) -> list:
        """Launches ``batch``'s trials, one job per seed each, and ``extra`` jobs after them (in
        the same launch: side by side where they fit one batch), and tells the study the
        trials' values; every job's return, the trials' first."""
        assert self.launcher is not None
        values = [self._values(t, plan) for t in batch]
        jobs = [job for t, vals in zip(batch, values) for job in self._jobs(t, vals, plan)]
        returns = self.launcher.launch(jobs + list(extra or []), initial_job_idx=first_job)
        n = len(self.seeds)
        for i, (trial, vals) in enumerate(zip(batch, values)):
            self._tell(study, trial.number, plan, vals, [_run_dir(r) for r in returns[i * n:(i + 1) * n]])
        return returns

    def _ask(self, study, plan: Plan):
        """A new trial of the space, claimed by this sweep (its seeds, its lease)."""
        trial = study.ask({k: p.distribution for k, p in plan.params.items()})
        claim(self._storage, self._trial_id(study, trial.number), self.seeds)
        return trial

    def _may_ask(self, study) -> bool:
        """Whether a trial may be asked now: one the sampler draws at random (the study holds
        fewer than ``startup_trials``), or one it guides once that many have finished (as
        :func:`sweeps.tuning.batch_size` keeps rounds: never a guided trial asked blind)."""
        return len(study.get_trials(deepcopy=False)) < self.startup_trials or _finished(study) >= self.startup_trials

    @staticmethod
    def _values(trial, plan: Plan) -> dict:
        """The trial's values of the searched settings, as a run takes them."""
        return {k: p.value(trial.params[k]) for k, p in plan.params.items()}

    def _jobs(self, trial, values: dict, plan: Plan) -> list[list[str]]:
        """The overrides of the trial's jobs (with its ``values``), one per seed."""
        return [[*plan.fixed, *(f"{k}={override_value(v)}" for k, v in values.items()), f"seed={seed}",
                 f"trial={trial.number}"] for seed in self.seeds]

    def _run_fed(self, study, batch: list, plan: Plan, first_job: int, extra: list, left: int,
                 sweep_dir: Path) -> tuple[list, int]:
        """``refill``: ``batch``'s trials (and ``extra`` jobs after them) launched as one batch
        whose members, as a trial's jobs all end, take the study's next trials (up to
        ``left`` more), each asked then, knowing every trial told so far (a guided one not
        before the random ones have finished: :meth:`_may_ask`); each trial told as its last
        job ends. Every job's return (the first batch's, the extra ones, then
        the later trials'), and how many trials were asked."""
        n, trial_of, values, ended, told = len(self.seeds), {}, {}, {}, set()
        index = itertools.count(first_job)

        def add(trial) -> list[tuple[int, list[str]]]:
            values[trial.number] = self._values(trial, plan)
            jobs = [(next(index), job) for job in self._jobs(trial, values[trial.number], plan)]
            trial_of.update({idx: trial.number for idx, _ in jobs})
            return jobs

        def more(done: Sequence[tuple[int, Path]], room: int) -> list[tuple[int, list[str]]]:
            nonlocal left
            for idx, folder in done:
                if idx in trial_of:
                    number = trial_of[idx]
                    ended.setdefault(number, {})[idx] = folder
                    if len(ended[number]) == n:
                        folders = [ended[number][i] for i in sorted(ended[number])]
                        self._tell(study, number, plan, values[number], folders)
                        told.add(number)
            jobs = []
            while left > 0 and room >= n and not (sweep_dir / ".stop").exists() and self._may_ask(study):
                jobs += add(self._ask(study, plan))
                left, room = left - 1, room - n
            return jobs

        first = [job for trial in batch for job in add(trial)]
        extras = [(next(index), list(job)) for job in extra]
        returns = self.launcher.launch_fed(first + extras, more)
        for number in set(trial_of.values()) - told:  # a job that never trained (its checks failed)
            self._tell(study, number, plan, values[number],
                       [_run_dir(returns[idx]) for idx in sorted(i for i in trial_of if trial_of[i] == number)])
        # (a trial's jobs are numbered in the order asked; the extra ones between the first trials and the later)
        return [returns[idx] for idx in sorted(trial_of) if idx in returns] + [returns[idx] for idx, _ in extras], \
            len(set(trial_of.values()))

    def _ran_with(self, plan: Plan) -> tuple[str | None, Path | None]:
        """The tuned file the trials compose and the study's file replaces: its name (the
        choice; None where it names none) and its path where it exists. A task's file goes on
        top of the robot's, which stays as it is."""
        choices = self.config.hydra.runtime.choices
        ran_with = choices.get(TASK_TUNED if _per_task(plan.robot, plan.task, choices.get(TASK_TUNED)) else "tuned")
        ran_file = conf_dir() / "tuned" / f"{ran_with}.yaml"
        return ran_with, ran_file if ran_with and ran_file.is_file() else None

    def _trial_id(self, study, number: int) -> int:
        """The storage's id of trial ``number`` of ``study``."""
        study_id = self._storage.get_study_id_from_name(study.study_name)
        return self._storage.get_trial_id_from_study_id_trial_number(study_id, number)

    def _take_over(self, study, plan: Plan) -> int:
        """Finishes the trials of this study that a stopped sweep left running
        (:func:`sweeps.tuning.abandoned`): a trial whose every job has a folder to continue
        from resumes there (each job from its checkpoint, as it would have run on) and is
        told its value; any other is told failed and asked again with its values (among the
        first trials this sweep asks, besides its ``n_trials``). Returns how many are asked
        again."""
        import optuna

        again = 0
        running = study.get_trials(deepcopy=False, states=(optuna.trial.TrialState.RUNNING,))
        for trial in [t for t in running if abandoned(t)]:
            seeds = trial.user_attrs.get("seeds", [])
            claim(self._storage, self._trial_id(study, trial.number), seeds)
            folders = job_folders_of(trial)
            values = {k: p.value(trial.params[k]) for k, p in plan.params.items() if k in trial.params}
            if seeds and len(folders) == len(seeds) and all(continuable(f) for f in folders):
                print(f"trial {trial.number} was left running by a sweep that stopped: resuming its jobs "
                      f"{', '.join(str(f) for f in folders)}", flush=True)
                summaries = resume_runs(folders)
                stopped = [s for s in summaries if s.get("interrupted")]
                if stopped:
                    raise SystemExit(128 + int(stopped[0].get("signal", 2)))
                self._tell(study, trial.number, plan, values, folders)
            else:
                study.tell(trial.number, state=optuna.trial.TrialState.FAIL)
                study.enqueue_trial(trial.params, user_attrs={"retry_of": trial.number})
                again += 1
                print(f"trial {trial.number} was left running by a sweep that stopped before all its jobs "
                      "could continue: told failed, and asked again as a new trial", flush=True)
        return again

    def _open_study(self, plan: Plan):
        """The study (made, or loaded), its objective named ``plan.objective`` (Optuna's metric
        name); a study of another measure or objective is refused in one line."""
        import optuna

        storage = self._storage = open_storage(self.storage_url)
        with warnings.catch_warnings():  # constant_liar is "experimental" in Optuna 5
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            # Trials asked together (trials_per_batch) or by sweeps sharing the study: each
            # running trial counts as a poor result, so those asked at once spread out.
            sampler = optuna.samplers.TPESampler(n_startup_trials=self.startup_trials, seed=self.sampler_seed,
                                                 constant_liar=True)
        study = optuna.create_study(study_name=self.study_name, storage=storage, sampler=sampler,
                                    pruner=make_pruner(self.pruner), direction="maximize", load_if_exists=True)
        held = len(study.get_trials(deepcopy=False))
        if held and self.sampler_seed is not None:  # continued: not the first sweep's draws again
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                study.sampler = optuna.samplers.TPESampler(
                    n_startup_trials=self.startup_trials, seed=continued_seed(self.sampler_seed, held),
                    constant_liar=True)
        known = study.user_attrs.get("measure")  # a study of an earlier version names only its measure
        names = study.metric_names
        if known not in (None, plan.measure) or names not in (None, [plan.objective]):
            theirs = names[0] if names else known
            raise ConfigError(f"study {self.study_name} in {shown_url(self.storage_url)} maximizes {theirs}, this "
                              f"run's objective is {plan.objective}: name another study (hydra.sweeper.study=...)")
        if known is None:
            study.set_user_attr("measure", plan.measure)
        if names is None:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                study.set_metric_names([plan.objective])
        return study

    def _tell(self, study, number: int, plan: Plan, values: dict, run_dirs: list) -> None:
        """Trial ``number``'s value: the mean over its seeds' job folders ``run_dirs`` of
        ``plan.objective`` (pruned if any job was pruned)."""
        import optuna

        jobs = _summaries(run_dirs)
        failed = [j for j in jobs if j.get("status") != "ok"]
        pruned = [j for j in jobs if j.get("pruned_at") is not None]
        shown = " ".join(f"{k}={override_value(v)}" for k, v in values.items())
        if failed:
            study.tell(number, state=optuna.trial.TrialState.FAIL)
            print(f"trial {number} failed: {failed[0].get('error') or failed[0].get('status')} ({shown})",
                  flush=True)
            return
        objective = [success_and_speed(j, self.budget_steps) for j in jobs]
        if pruned:
            study.tell(number, state=optuna.trial.TrialState.PRUNED)
            print(f"trial {number} pruned at episode {pruned[0]['pruned_at']} ({shown})", flush=True)
            return
        value = statistics.fmean(float(v) for v in objective if v is not None) if any(
            v is not None for v in objective) else float("nan")
        study.tell(number, value)
        per_seed = ", ".join(_seed_text(v, j) for v, j in zip(objective, jobs))
        print(f"trial {number}: {plan.objective} {value:.4g} (seeds {per_seed}) {shown}", flush=True)

    def _finish(self, study, plan: Plan, sweep_dir: Path, told: bool = True) -> None:
        """The study's counts, its best trial, and the tuned file (``told``: whether this
        sweep told the study any trial; a sweep that did not leaves a file that is already
        the study's, with the same settings, as it is)."""
        import optuna

        robot, learner, params = plan.robot, plan.learner, plan.params
        state = optuna.trial.TrialState
        states = [t.state for t in study.trials]
        complete, pruned, failed = (states.count(s) for s in (state.COMPLETE, state.PRUNED, state.FAIL))
        print(f"study {self.study_name}: {len(states)} trials ({complete} complete, {pruned} pruned, {failed} failed)")
        if not complete:
            print("no trial completed: no tuned file written")
            return
        best = study.best_trial
        values = {k: p.value(best.params[k]) for k, p in params.items() if k in best.params}
        current = study.user_attrs.get("current_value")
        mine, mine_values = study.user_attrs.get("defaults_value"), study.user_attrs.get("defaults")
        # The learner's own values win only above the best trial and the settings the study began with.
        mine_won = mine is not None and bool(mine_values) and mine > best.value and (current is None or mine > current)
        own = plan.current is not None and best.params == plan.current  # the best trial is the file's settings
        kept = not mine_won and (own or (current is not None and current >= best.value))  # the hand pick
        header = [
            f"Tuned by Optuna ({now_utc()}): study {self.study_name} in {shown_url(self.storage_url)}",
            f"best trial {best.number}: {plan.objective} {best.value:.4g} (mean over seeds {self.seeds}), of "
            f"{len(states)} trials ({complete} complete, {pruned} pruned, {failed} failed)",
            f"budget per trial and seed: {self.budget_steps} env steps, stopping when solved; "
            f"pruner: {self.pruner or 'none'}; search space: {plan.space_file.name}",
            f"command: python train.py -m {' '.join(map(shown_url, self._hydra_overrides() + plan.given))}",
        ]
        choices = self.config.hydra.runtime.choices
        per_task = _per_task(robot, plan.task, choices.get(TASK_TUNED))
        name = f"{tuned_name(robot, learner, plan.task if per_task else None)}.yaml"
        base_file = conf_dir() / "tuned" / name
        ran_with, ran_file = self._ran_with(plan)
        # As it was when the study began (its trials ran with that), not as it may be now.
        ran_text = study.user_attrs.get("tuned_file_text")
        if ran_text is None and ran_file:
            ran_text = ran_file.read_text()
        base_values = OmegaConf.to_container(OmegaConf.create(ran_text)) if ran_text else None
        if per_task:
            header.append(f"for task {plan.task} only: applied on top of {tuned_name(robot, learner)}.yaml "
                          "(where there is one), which the trials ran with too")
        if base_values:
            header.append(f"settings not searched are {ran_with}.yaml's, which the trials ran with")
        began_with = current  # the value of the settings the file held: valued apart, or a trial's
        if began_with is None and plan.current is not None:
            began_with = next((t.value for t in study.trials
                               if t.state == state.COMPLETE and t.params == plan.current), None)
        if mine_won:
            header.append(f"written instead: {OWN_VALUES}, {plan.objective} {mine:.4g} on the same seeds and "
                          "budget, above every trial")
        if began_with is not None and not kept:
            header.append(f"replacing the settings the study began with: {plan.objective} {began_with:.4g} on the "
                          "same seeds and budget")
        print(f"best trial {best.number}: {plan.objective} {best.value:.4g} " + " ".join(
            f"{k}={override_value(v)}" for k, v in values.items()))
        if mine_won:
            values = dict(mine_values)
            print(f"{OWN_VALUES} ({plan.objective} {mine:.4g}) beat every trial: the tuned file takes them")
        # The budget its pair is judged with: a run with the file is a trial's run (issue 65).
        text = tuned_text({**values, "max_env_steps": self.budget_steps, "max_episodes": 0}, base_values, header)
        out = sweep_dir / f"tuned_{name}"
        out.write_text(text)
        print(f"tuned file: {out}")
        # As the study began with it (its trials ran with that), not as it may be now.
        began = ran_text if ran_file is not None and ran_file.resolve() == base_file.resolve() else None
        kept = kept and bool(began or base_file.is_file())  # without a file, the best trial's values are written
        if not told and self.write_tuned and base_file.is_file():  # nothing new: the study's file stays
            on_disk = base_file.read_text(errors="replace")  # (edits made since included)
            news = mine_won and settings_of(on_disk) != settings_of(text)  # the learner's own values won
            if names_study(on_disk, self.study_name) and not news:
                print(f"this sweep told no trial and {base_file.name} is already the study's: it stays as it is")
                return
        study.set_user_attr("tuned_kept", kept)
        why = None
        if kept:
            why = (f"the best trial is the current configuration (trial {best.number})" if own else
                   f"the current configuration ({plan.objective} {current:.4g} on the same seeds and budget) is at "
                   "least as good as the best trial")
        self._write_tuned(base_file, out, text, header, why, began,
                          f"robot={robot}{f' task={plan.task}' if per_task else ''} learner={learner}")

    def _write_tuned(self, base_file: Path, out: Path, text: str, header: list[str], why: str | None,
                     began: str | None, picks: str) -> None:
        """The pair's tuned file: kept (``why`` says why; with ``write_tuned`` the study's header
        put on the file as the study ``began`` with it), replaced by ``text`` (written to ``out``
        in the sweep folder; with ``write_tuned`` to the pair's file too), or left for the user
        to copy."""
        if why is not None:
            print(f"{why}: {base_file.name} stays as it is")
            if self.write_tuned:
                mine = [f"{KEPT} ({now_utc()}): study {self.study_name} in {shown_url(self.storage_url)}: {why}",
                        *header[1:4]]
                base_file.write_text(kept_text(began or base_file.read_text(), mine))
                print(f"{base_file}: the study's header added, its settings and notes as the study began with them")
        elif self.write_tuned:
            print(replace_tuned(base_file, text, out.parent))
            print(f"the next `python train.py {picks}` uses it")
        else:
            print(f"to use it: cp {out} {base_file} (or tune with hydra.sweeper.write_tuned=true)")


def _told(study) -> int:
    """The study's trials told a state (complete, pruned or failed)."""
    return sum(t.state.is_finished() for t in study.get_trials(deepcopy=False))


def _finished(study) -> int:
    """The study's trials the sampler learns from (complete or pruned)."""
    import optuna

    state = optuna.trial.TrialState
    return len(study.get_trials(deepcopy=False, states=(state.COMPLETE, state.PRUNED)))


def _summaries(run_dirs: list) -> list[dict]:
    """Each job folder's summary (a failed one for a job that made no folder)."""
    return [summarize_run(d) if d else {"status": "failed", "error": "no run folder"} for d in run_dirs]


def _check_builds(cfg: DictConfig) -> Success:
    """The robot and its task build (a task that does not fit the robot is refused here, in
    one line, not in every trial's jobs); returns the task's rule."""
    from hydra.errors import InstantiationException

    try:
        return build_task(cfg).success
    except InstantiationException as err:
        cause = err.__cause__ or err
        raise ConfigError((str(cause).strip().splitlines() or [type(cause).__name__])[0]) from None


def search_file(robot: str, learner: str, task: str | None = None) -> Path:
    """``conf/search/<robot>_<task>_<learner>.yaml`` where there is one (a space for one
    task), else ``conf/search/<robot>_<learner>.yaml`` where there is one (settings only that
    robot's configs have, e.g. bins per state entry), else ``conf/search/<learner>.yaml``."""
    for name in ([tuned_name(robot, learner, task)] if task else []) + [tuned_name(robot, learner)]:
        if (conf_dir() / "search" / f"{name}.yaml").is_file():
            return conf_dir() / "search" / f"{name}.yaml"
    return conf_dir() / "search" / f"{learner}.yaml"


def _per_task(robot: str, task: str, task_file: str | None) -> bool:
    """Whether a study of ``robot`` / ``task`` writes the task's tuned file
    (``<robot>_<task>_<learner>``) rather than the robot's: for a task other than the robot's
    default, or where a task's file (``task_file``, the per-task pick) applied already (the
    robot's file would stay under it, its values overridden)."""
    return task != default_task(robot) or bool(task_file and (conf_dir() / "tuned" / f"{task_file}.yaml").is_file())


def _parser():
    from hydra.core.override_parser.overrides_parser import OverridesParser

    return OverridesParser.create()


def _run_dir(ret) -> Path | None:
    try:
        return Path(str(ret.hydra_cfg.hydra.runtime.output_dir))
    except Exception:  # noqa: BLE001 - a job that never composed has no config
        return None


def _seed_text(value: float | None, job: dict) -> str:
    """One seed's part of a trial's console line: its value, its measure at the end, and
    the env steps it was solved at."""
    if value is None:
        return "-"
    measure, steps = final_measure(job), job.get("steps_to_solve")
    return (f"{value:.4g} ({job.get('measure')} {measure:.4g}"
            + (f", solved at {steps} env steps)" if job.get("solved") and steps is not None else ")"))
