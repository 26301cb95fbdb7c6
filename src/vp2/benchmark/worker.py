"""What runs in a trial worker: per-process state, one trial attempt, its record.

A worker is a process of the local executor's pool, a Ray actor, or (with one worker) the
driver process itself. :func:`init_worker` sets up its state once: the run config, one agent
per environment (the model built once per environment and checked against it) and a small
cache of simulators; :func:`run_job` then runs one trial and returns its record, however the
trial ends. Workers never write files: records stream back to the driver.

A trial attempt that runs past ``RunConfig.trial_timeout`` is stopped by a ``SIGALRM`` timer
(:func:`vp2.run.trial.time_limit`), which needs the main thread: pool workers and Ray
actors run trials there, and a driver that runs them itself (one worker) must be its
process's main thread. After a timeout the worker rebuilds the environment's model and its
simulators, which the interrupted trial may have left midway.

The one file a worker writes is its trial's progress (:mod:`vp2.run.partial`,
``<run>/partial/``), so that a run cut off mid-trial resumes at the step it reached; the
driver deletes it once the trial's record is written. (On Ray the file lives on the worker's
machine: a trial resumes mid-way where the run directory is shared.)
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import logging
import traceback
from collections.abc import Iterable, Iterator, Mapping, Sequence
from typing import Any

import torch

import vp2
from vp2.data.suite import TaskInstance
from vp2.envs import env_class, split_name
from vp2.envs.base import Env
from vp2.envs.cache import EnvCache
from vp2.envs.render_specs import render_fingerprint
from vp2.models.contract import gradient_problem, model_failure
from vp2.models.ensemble import EnsembleMismatch
from vp2.planning.agent import Agent, PlanningAgent, RandomActions
from vp2.planning.planner import GRADIENT_OPTIMIZERS
from vp2.run.config import RunConfig
from vp2.run.model_spec import MODEL_DOCS, model_identity, resolve_model
from vp2.run.partial import (
    PartialMismatch,
    PartialTrial,
    load_partial,
    save_partial,
)
from vp2.run.results import TrialKey
from vp2.run.run_dir import RunDir
from vp2.run.trial import ControlTrial, TrialResult, TrialTimeout, can_time_limit, time_limit
from vp2.utils.tensors import resolve_device

log = logging.getLogger(__name__)

#: Simulators a worker keeps built (trials of one environment reuse its simulator).
ENVS_PER_WORKER = 2


@dataclasses.dataclass
class Job:
    """One attempt of a trial, as the driver hands it to a worker."""

    key: TrialKey
    instance: TaskInstance
    attempt: int = 1
    errors: list[dict[str, Any]] = dataclasses.field(default_factory=list)


@dataclasses.dataclass
class Outcome:
    """What a worker returns for a :class:`Job`: the record, and the result for the GIFs."""

    key: TrialKey
    record: dict[str, Any]
    result: TrialResult | None = None
    fatal: bool = False  # the model could not be built: no trial can run


class WorkerState:
    """Per-process state: the run config, one agent per environment, reusable envs."""

    def __init__(self, config: RunConfig, in_pool: bool, envs: Sequence[str] = ()) -> None:
        self.config = config
        self.in_pool = in_pool
        #: Environments of the run: :meth:`prepare` builds their agents before any trial.
        self.envs_of_run = tuple(envs)
        self.device = resolve_device(config.device)
        self.agents: dict[str, tuple[Agent, dict[str, Any]]] = {}
        self.envs = EnvCache(ENVS_PER_WORKER)

    def prepare(self) -> None:
        """Builds (and checks) the agent of every environment of the run, so that a model
        that cannot run some task stops the run before any trial, not halfway."""
        for env_name in self.envs_of_run:
            self.agent(env_name, int(env_class(env_name).action_dim))

    def agent(self, env_name: str, action_dim: int) -> tuple[Agent, dict[str, Any]]:
        if env_name not in self.agents:
            self.agents[env_name] = self._build_agent(env_name, action_dim)
        return self.agents[env_name]

    def _build_agent(self, env_name: str, action_dim: int) -> tuple[Agent, dict[str, Any]]:
        cfg = self.config
        if cfg.agent == "random":
            return RandomActions(action_dim), {"spec": "random_actions", "name": "random_actions"}
        model = resolve_model(
            cfg.model, cfg.model_args, env=env_name, action_dim=action_dim, device=self.device
        )
        if self.in_pool and getattr(model, "num_workers", 1) > 1:
            # See vp2.benchmark.runner: trial processes never start model pools of their own.
            log.warning("running trials in parallel: %s uses 1 worker per trial", cfg.model)
            model.num_workers = 1
        identity = model_identity(cfg.model, cfg.model_args, model)
        check_model_fits(model, cfg, env_name, action_dim, self.device)
        agent = PlanningAgent(
            model,
            planner=cfg.planner,
            cost_mode=cfg.cost,  # type: ignore[arg-type]
            device=self.device,
            record_predictions=cfg.save_predictions,
        )
        return agent, identity

    def env(self, instance: TaskInstance) -> Env:
        """The simulator of ``instance`` (a trial resets it to the instance's state)."""
        return self.envs.get(instance.env_meta, observation_size=None)

    def drop_agent(self, env_name: str) -> None:
        """Forgets the agent (and model) of ``env_name``: the next trial builds a new one. The
        model is not closed, as its ``close`` may wait on the work that hung."""
        self.agents.pop(env_name, None)

    def close(self) -> None:
        self.envs.close()
        for agent, _ in self.agents.values():
            close = getattr(getattr(agent, "model", None), "close", None)
            if callable(close):
                close()
        self.agents.clear()


class ModelMismatch(ValueError):
    """A built model that cannot run the run's tasks (raised before any trial)."""


def check_model_fits(
    model: Any, cfg: RunConfig, env_name: str, action_dim: int, device: torch.device
) -> None:
    """Raises :class:`ModelMismatch` if ``model`` cannot plan the ``env_name`` tasks of the run:
    another action size, or no gradients for a gradient optimizer."""
    name = getattr(model, "name", type(model).__name__)
    if int(model.action_dim) != action_dim:
        raise ModelMismatch(
            f"model {name} has action_dim {model.action_dim}, but the {env_name} tasks have "
            f"{action_dim}-D actions; build it for the environment (a factory that declares an "
            f"`action_dim` parameter gets the environment's; {MODEL_DOCS})"
        )
    optimizer = cfg.planner.optimizer
    if optimizer in GRADIENT_OPTIMIZERS:
        problem = gradient_problem(model, device)
        if problem is not None:
            raise ModelMismatch(
                f"the {optimizer} optimizer needs gradients of the predictions with respect "
                f"to the actions, but model {name} {problem}; plan with --optimizer mppi or cem"
            )


_STATE: WorkerState | None = None


def init_worker(config: RunConfig, envs: Sequence[str] = ()) -> None:
    """Initialiser of trial worker processes (and Ray actors)."""
    global _STATE
    # Several trial processes share the machine's cores; one torch thread each avoids
    # oversubscription (and OpenMP stalls on shared cores, see docs/planning.md).
    torch.set_num_threads(1)
    _STATE = WorkerState(config, in_pool=True, envs=envs)


def run_in_process(
    jobs: Iterable[Job], config: RunConfig, envs: Sequence[str] = ()
) -> Iterator[tuple[Job, Outcome]]:
    """Runs the jobs in this process (one worker); ``jobs`` may be a live queue that the
    driver refills with retries while iterating."""
    global _STATE
    if config.trial_timeout is not None and not can_time_limit():
        raise ValueError(
            "trial_timeout needs the trials to run in a main thread (it uses SIGALRM), but "
            "run_benchmark runs them in this thread with workers=1: call it from the main "
            "thread, or run the trials in worker processes (workers >= 2)"
        )
    _STATE = WorkerState(config, in_pool=False, envs=envs)
    try:
        for job in jobs:
            yield job, run_job(job)
    finally:
        _STATE.close()
        _STATE = None


def envs_of(jobs: Sequence[Job]) -> tuple[str, ...]:
    """The environments of the jobs' tasks."""
    return tuple(sorted({split_name(job.key[0])[0] for job in jobs}))


def error_record(exc: BaseException, where: str) -> dict[str, Any]:
    """The ``error`` field of a record: what was raised, where, with the traceback."""
    error = {
        "type": type(exc).__name__,
        "message": str(exc),
        "where": where,
        "traceback": "".join(traceback.format_exception(exc)),
    }
    failure = model_failure(exc)
    if failure is not None:  # at the model boundary: what the driver's fail-fast compares
        error["model_failure"] = failure
    return error


def retried_at_once(error: Mapping[str, Any]) -> bool:
    """Whether the driver retries a trial that ended with ``error`` (an error record) at once,
    up to ``max_retries`` times: every error but a timeout (a model that hung is likely to
    hang again; ``--resume --retry-errors`` runs it again)."""
    return error.get("type") != TrialTimeout.__name__


def _base_record(job: Job, identity: dict[str, Any]) -> dict[str, Any]:
    task, index, seed = job.key
    return {
        "task": task,
        "instance": index,
        "instance_sha": job.instance.fingerprint,
        "render_fingerprint": render_fingerprint(split_name(task)[0]),
        "seed": seed,
        "model": identity,
        "vp2_version": vp2.__version__,
        "device": str(_STATE.device) if _STATE else None,
    }


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def worker_died(job: Job, config: RunConfig) -> Outcome:
    """The outcome of a job whose worker died with it running alone (so it is to blame)."""
    error = {
        "type": "WorkerDied",
        "message": "the trial's worker process died (killed, segfault or out of memory)",
        "where": "worker",
        "traceback": "",
    }
    record = {**_base_record(job, {"spec": config.model}), "success": None}
    return Outcome(job.key, {**record, "error": error, "finished_at": _now()})


def run_job(job: Job) -> Outcome:
    """Runs one trial in the current process (a worker, or the driver with one worker); its
    record is stamped ``finished_at`` when it ends, however it ends."""
    outcome = _attempt_trial(job)
    outcome.record["finished_at"] = _now()
    return outcome


def _attempt_trial(job: Job) -> Outcome:
    assert _STATE is not None, "worker state is not initialised"
    cfg = _STATE.config
    fallback_identity = {"spec": cfg.model, "args": dict(cfg.model_args)}
    try:
        _STATE.prepare()
    except Exception as exc:
        mismatch = isinstance(exc, (ModelMismatch, EnsembleMismatch))
        where = "model_check" if mismatch else "model_build"
        record = {**_base_record(job, fallback_identity), "success": None}
        return Outcome(job.key, {**record, "error": error_record(exc, where)}, fatal=True)
    try:
        env = _STATE.env(job.instance)
    except Exception as exc:  # a simulator that cannot even be built
        record = {**_base_record(job, fallback_identity), "success": None}
        return Outcome(job.key, {**record, "error": error_record(exc, "environment")})
    env_name = split_name(job.instance.task)[0]
    try:
        agent, identity = _STATE.agent(env_name, env.action_dim)
    except Exception as exc:
        record = {**_base_record(job, fallback_identity), "success": None}
        return Outcome(job.key, {**record, "error": error_record(exc, "model_build")}, fatal=True)
    record = _base_record(job, identity)
    partial_file = RunDir(cfg.out).partial_path(*job.key)
    trial_meta = {key: record[key] for key in ("model", "vp2_version", "render_fingerprint")}

    def make_trial(resume: PartialTrial | None) -> ControlTrial:
        return ControlTrial(
            job.instance,
            agent,
            seed=job.key[2],
            num_steps=cfg.num_steps,
            stop_on_success=cfg.stop_on_success,
            env=env,
            checkpoint=functools.partial(save_partial, partial_file),
            resume=resume,
            meta=trial_meta,
        )

    try:
        with time_limit(cfg.trial_timeout):
            trial = make_trial(load_partial(partial_file))
            try:
                result = trial.run()
            except PartialMismatch as exc:  # raised before any planning: start afresh
                log.warning("trial %s: %s; it starts from its first step", job.key, exc)
                partial_file.unlink(missing_ok=True)
                trial = make_trial(None)
                result = trial.run()
    except (Exception, TrialTimeout) as exc:
        # A simulator that raised may be broken beyond what reset_to repairs: rebuild it (the
        # cache is emptied; the next trials build the simulators they need again). A timeout
        # may have stopped the model anywhere: the next trial gets a new one too.
        _STATE.envs.close()
        if isinstance(exc, TrialTimeout):
            log.warning("trial %s: %s", job.key, exc)
            _STATE.drop_agent(env_name)
        record.update(
            success=None, cost=getattr(agent, "cost_kind", None), error=error_record(exc, "trial")
        )
        return Outcome(job.key, record)
    record.update(result.record())
    if trial.resumed_steps:
        record["resumed_at_step"] = trial.resumed_steps
    record["error"] = None
    return Outcome(job.key, record, result=result)
