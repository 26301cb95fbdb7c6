"""The benchmark runner: model × tasks × instances × seeds, resumable, in parallel.

:func:`run_benchmark` takes a :class:`RunConfig` (one field per ``vp2 run`` flag) and

1. selects the task instances of the suite and the control-run seeds; every trial has the key
   ``(task, instance index, seed)`` and its randomness comes from that key alone;
2. creates the run directory with the resolved ``config.yaml`` (or, with ``resume=True``,
   checks that the protocol settings match the existing one);
3. runs the trials not yet in ``trials.jsonl`` in worker processes, each of which builds the
   model once per environment; results stream back to this (driver) process, which alone
   writes files: a GIF per trial, then one appended JSON line;
4. retries a crashed trial (model error, simulator error, dead worker) a bounded number of
   times and otherwise records it as an error, with its traceback, never as a success or a
   failure; but a model that fails at its boundary the same way twice in a row before any
   trial finished stops the run (:class:`ModelFailure`), and a model that does not fit the
   run (action size, gradients for ``cem_gd``/``lbfgs``) is refused before any trial;
5. writes and returns the summary table (per task: mean success over seeds with min/max,
   normalised by an oracle run if one is given, else by the shipped oracle,
   :mod:`vp2.benchmark.shipped_oracle`; an oracle run itself is not normalised).

Parallelism policy: trials are the unit of parallel work. With ``workers > 1`` every trial
process plans serially, and a model that runs its own process pool (the simulator oracle's
``num_workers``) is set to one worker, so processes never nest (``workers × num_workers``
processes would oversubscribe the cores). Model-level parallelism is for a single process:
``workers=1`` and e.g. ``model_args={"num_workers": 4}`` to make each of the oracle's
planning steps faster (lower latency per trial, the same throughput).

With ``executor="ray"`` the trials run on Ray actors instead (:mod:`vp2.utils.executors`,
docs/scale-out.md), one simulator and one model replica per actor, initialised like a pool
worker; results stream back to this process, which still alone writes files, so a run
resumes the same way under either executor.
"""

from __future__ import annotations

import collections
import dataclasses
import datetime
import json
import logging
import math
import multiprocessing as mp
import os
import traceback
from collections.abc import Iterator, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any

import numpy as np
import torch
import yaml
from tqdm.auto import tqdm

import vp2
from vp2.benchmark import plugins
from vp2.benchmark.agent import (
    COST_MODES,
    GRADIENT_OPTIMIZERS,
    Agent,
    PlannerConfig,
    PlanningAgent,
)
from vp2.benchmark.results import (
    TRIALS_FILE,
    Summary,
    TrialKey,
    TrialLog,
    format_summary,
    is_ok,
    read_trials,
    trial_key,
)
from vp2.benchmark.shipped_oracle import is_oracle_config, load_shipped_oracle, summarize_run
from vp2.benchmark.trial import NUM_CONTROL_STEPS, ControlTrial, TrialResult
from vp2.data.suite import TaskInstance, TaskSuite
from vp2.envs import ENV_TASKS, TASK_NAMES, env_class, split_name
from vp2.envs.base import Env
from vp2.models.base import gradient_problem, model_failure
from vp2.planning import OPTIMIZERS
from vp2.utils.executors import EXECUTORS, RayExecutor, WorkerLost
from vp2.utils.io import atomic_path, remove_stale_temporaries, write_json_atomic

log = logging.getLogger(__name__)

CONFIG_FILE = "config.yaml"
SUMMARY_FILE = "summary.md"
SUMMARY_JSON = "summary.json"
GIF_DIR = "gifs"
AGENTS: tuple[str, ...] = ("planning", "random")
#: Control runs per task the SPEC asks for (SPEC §4: ≥ 3 seeds).
MIN_SEEDS = 3
#: Identical model-boundary failures in a row, before any trial finished, that stop a run.
FAIL_FAST_AFTER = 2
#: Where the model interface is documented (named in the messages of model failures).
MODEL_DOCS = 'docs/benchmark.md, "Plugins"'


class ModelFailure(RuntimeError):
    """The run stopped because of the model: it does not fit the run (checked before any
    trial), or its first trials failed at the model boundary with the same error. Trials
    finished before stay in the run directory; fix the model and resume."""
#: Fields of :class:`RunConfig` that change what a trial does. A resumed run must keep them;
#: the others (which trials, how many processes, where) may change between sessions.
PROTOCOL_FIELDS: tuple[str, ...] = (
    "model",
    "model_args",
    "agent",
    "suite",
    "optimizer",
    "num_samples",
    "gamma",
    "num_iterations",
    "cost",
    "num_steps",
)


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Everything a benchmark run needs; one field per ``vp2 run`` flag.

    Attributes:
        model: Model spec (``--model``): ``simulator``, ``repeat_last_frame``,
            ``NAME:CHECKPOINT``, ``package.module:factory`` or a YAML file
            (:mod:`vp2.benchmark.plugins`). Ignored by ``agent="random"``.
        out: Run directory (``--out``).
        model_args: Keyword arguments of the model factory (``--model-arg KEY=VALUE``,
            repeatable; values parsed as YAML, see :func:`parse_model_args`).
        agent: ``"planning"`` (visual foresight with the model) or ``"random"`` (uniform
            random actions, no model) (``--agent``).
        suite: Task suite file (``--suite``); ``None``: the suite shipped with vp2.
        tasks: Task categories or environment names to run (``--tasks``); empty: every task
            of the suite.
        num_instances: First ``k`` instances of each task (``--num-instances``); ``None``:
            all.
        seeds: Control-run seeds (``--seeds``); SPEC §4 asks for at least 3.
        optimizer: ``mppi`` (SPEC), ``cem``, ``cem_gd``, ``lbfgs`` (``--optimizer``).
        num_samples: Planner samples per step (``--num-samples``); ``None``: SPEC (200,
            800 for open_slide/open_drawer). Other values are for tests and ablations.
        gamma: MPPI inverse temperature (``--gamma``).
        num_iterations: Planner iterations per step (``--num-iterations``); ``None``: the
            optimizer's default.
        cost: ``auto`` | ``spec`` | ``pixel_only`` (``--cost``), see
            :data:`vp2.benchmark.agent.CostMode`.
        num_steps: Control steps per trial (``--num-steps``); SPEC: 15. Fewer only for tests.
        stop_on_success: End a trial at its first success (``--stop-on-success``); the
            outcome is the same, later frames are not recorded.
        workers: Trial processes (``--workers``); 1 runs trials in this process. With
            ``executor="ray"``: actors, each with its own simulator and model replica.
        executor: Where trials run (``--executor``): ``"local"`` (worker processes on this
            machine) or ``"ray"`` (actors on a Ray cluster, docs/scale-out.md). Not a protocol
            field: a run may be resumed under another executor.
        address: Ray cluster to use (``--address``): ``"auto"``, ``HOST:PORT``, or ``None``
            for a private instance on this machine.
        num_cpus_per_worker: CPUs each Ray actor reserves (``--num-cpus-per-worker``).
        num_gpus_per_worker: GPUs each Ray actor reserves for its model replica, fractions
            allowed (``--num-gpus-per-worker``).
        device: Torch device of models and planning (``--device``); ``None``: CUDA if
            available, else CPU.
        max_retries: Extra attempts of a crashed trial (``--max-retries``).
        resume: Continue an existing run directory, running only missing trials
            (``--resume``).
        retry_errors: With ``resume``, also re-run trials recorded as errors
            (``--retry-errors``).
        save_gifs: Write a GIF per trial: execution next to the goal (``--no-gifs`` off).
        save_predictions: Also a GIF of the chosen plan's predicted frames per planning step
            (``--save-predictions``; one extra model call per step).
        oracle: Run directory (or ``trials.jsonl``) of a simulator-oracle run, to normalise
            the scores (``--oracle``); ``None``: the shipped oracle
            (:mod:`vp2.benchmark.shipped_oracle`), if there is one.
        progress: Show a progress bar with ETA (``--no-progress`` off).
    """

    model: str
    out: str
    model_args: dict[str, Any] = dataclasses.field(default_factory=dict)
    agent: str = "planning"
    suite: str | None = None
    tasks: tuple[str, ...] = ()
    num_instances: int | None = None
    seeds: tuple[int, ...] = (0, 1, 2)
    optimizer: str = "mppi"
    num_samples: int | None = None
    gamma: float = 0.05
    num_iterations: int | None = None
    cost: str = "auto"
    num_steps: int = NUM_CONTROL_STEPS
    stop_on_success: bool = False
    workers: int = 1
    executor: str = "local"
    address: str | None = None
    num_cpus_per_worker: float = 1.0
    num_gpus_per_worker: float = 0.0
    device: str | None = None
    max_retries: int = 1
    resume: bool = False
    retry_errors: bool = False
    save_gifs: bool = True
    save_predictions: bool = False
    oracle: str | None = None
    progress: bool = True

    def validate(self) -> None:
        """Raises ``ValueError`` naming the first invalid field."""
        if self.agent not in AGENTS:
            raise ValueError(f"agent must be one of {AGENTS}, got {self.agent!r}")
        if self.optimizer not in OPTIMIZERS:
            raise ValueError(
                f"optimizer must be one of {tuple(OPTIMIZERS)}, got {self.optimizer!r}"
            )
        if self.cost not in COST_MODES:
            raise ValueError(f"cost must be one of {COST_MODES}, got {self.cost!r}")
        if not self.seeds or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds must be distinct and non-empty, got {self.seeds}")
        if self.num_steps < 2:
            raise ValueError(f"num_steps must be >= 2, got {self.num_steps}")
        if self.num_instances is not None and self.num_instances < 1:
            raise ValueError(f"num_instances must be >= 1, got {self.num_instances}")
        if self.num_samples is not None and self.num_samples < 1:
            raise ValueError(f"num_samples must be >= 1, got {self.num_samples}")
        if self.workers < 1 or self.max_retries < 0:
            raise ValueError("workers must be >= 1 and max_retries >= 0")
        if self.executor not in EXECUTORS:
            raise ValueError(f"executor must be one of {EXECUTORS}, got {self.executor!r}")
        if self.address is not None and self.executor != "ray":
            raise ValueError("address is for executor='ray'")
        if self.num_cpus_per_worker < 0 or self.num_gpus_per_worker < 0:
            raise ValueError("num_cpus_per_worker and num_gpus_per_worker must be >= 0")
        if self.retry_errors and not self.resume:
            raise ValueError("retry_errors needs resume")
        for name in self.tasks:
            if name not in ENV_TASKS:
                split_name(name)

    def planner(self) -> PlannerConfig:
        return PlannerConfig(
            optimizer=self.optimizer,
            num_samples=self.num_samples,
            gamma=self.gamma,
            num_iterations=self.num_iterations,
        )

    def to_dict(self) -> dict[str, Any]:
        """Plain data (tuples as lists), as written to ``config.yaml``."""
        d = dataclasses.asdict(self)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> RunConfig:
        """Inverse of :meth:`to_dict`; unknown keys are an error."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = set(data) - names
        if unknown:
            raise ValueError(f"unknown RunConfig field(s) {sorted(unknown)}")
        data = dict(data)
        for key in ("tasks", "seeds"):
            if key in data:
                data[key] = tuple(data[key])
        return cls(**data)

    def deviations(self) -> list[str]:
        """How this run departs from the SPEC protocol (shown with the results)."""
        out = []
        if self.num_steps != NUM_CONTROL_STEPS:
            out.append(f"num_steps={self.num_steps} (SPEC: {NUM_CONTROL_STEPS})")
        if self.num_samples is not None:
            out.append(
                f"num_samples={self.num_samples} (SPEC: 200, 800 for open_slide/open_drawer)"
            )
        if self.agent == "planning":
            if self.optimizer != "mppi":
                out.append(f"optimizer={self.optimizer} (SPEC: mppi)")
            if self.gamma != 0.05 and self.optimizer == "mppi":
                out.append(f"gamma={self.gamma} (SPEC: 0.05)")
            if self.num_iterations is not None:
                out.append(f"num_iterations={self.num_iterations} (SPEC: 1)")
            if self.cost == "pixel_only":
                out.append("cost=pixel_only (SPEC: RoboDesk uses its success classifier)")
        if len(self.seeds) < MIN_SEEDS:
            out.append(f"{len(self.seeds)} seed(s) (SPEC: at least {MIN_SEEDS} control runs)")
        return out


def parse_model_args(items: Sequence[str]) -> dict[str, Any]:
    """``["num_workers=2", "name=foo"]`` -> ``{"num_workers": 2, "name": "foo"}``.

    Values are parsed as YAML scalars/lists (``2`` is an int, ``[1, 2]`` a list,
    ``true`` a bool); anything else stays a string.
    """
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"model argument {item!r}: expected KEY=VALUE")
        try:
            out[key.strip()] = yaml.safe_load(value)
        except yaml.YAMLError:
            out[key.strip()] = value
    return out


@dataclasses.dataclass
class RunResult:
    """What :func:`run_benchmark` returns.

    Attributes:
        run_dir: The run directory.
        config: The run's configuration.
        records: Every record in ``trials.jsonl`` (earlier sessions included).
        summary: Scores of those records.
        num_run: Trials finished in this call (errors included).
        num_skipped: Trials already in ``trials.jsonl`` (resume).
        num_errors: Error records among ``records``.
    """

    run_dir: Path
    config: RunConfig
    records: list[dict[str, Any]]
    summary: Summary
    num_run: int
    num_skipped: int
    num_errors: int

    @property
    def table(self) -> str:
        """The summary as Markdown."""
        return format_summary(self.summary)


# --------------------------------------------------------------------------- trial selection


def select_instances(suite: TaskSuite, config: RunConfig) -> list[TaskInstance]:
    """The suite's instances the run covers, in suite order."""
    wanted: list[str] = []
    for name in config.tasks or suite.tasks:
        wanted += [f"{name}/{t}" for t in ENV_TASKS[name]] if name in ENV_TASKS else [name]
    missing = [t for t in wanted if t not in suite.tasks]
    if config.tasks and missing == wanted:
        raise ValueError(
            f"the suite has none of the tasks {list(config.tasks)}; it has {suite.tasks}"
        )
    if missing and config.tasks and not all(t in ENV_TASKS for t in config.tasks):
        raise ValueError(f"tasks {missing} are not in the suite (it has {suite.tasks})")
    out = []
    for task in sorted((t for t in wanted if t in suite.tasks), key=TASK_NAMES.index):
        insts = sorted(suite.for_task(task), key=lambda i: i.index)
        out += insts[: config.num_instances] if config.num_instances else insts
    return out


def trial_keys(instances: Sequence[TaskInstance], seeds: Sequence[int]) -> list[TrialKey]:
    """Keys seed-major: an interrupted run has whole control runs finished first."""
    return [(inst.task, inst.index, seed) for seed in seeds for inst in instances]


# --------------------------------------------------------------------------- workers


@dataclasses.dataclass
class _Job:
    key: TrialKey
    instance: TaskInstance
    attempt: int = 1
    errors: list[dict[str, Any]] = dataclasses.field(default_factory=list)
    isolated: bool = False


@dataclasses.dataclass
class _Outcome:
    key: TrialKey
    record: dict[str, Any]
    result: TrialResult | None = None
    fatal: bool = False  # the model could not be built: no trial can run


class _WorkerState:
    """Per-process state: the run config, one agent per environment, reusable envs."""

    def __init__(self, config: RunConfig, in_pool: bool, envs: Sequence[str] = ()) -> None:
        self.config = config
        self.in_pool = in_pool
        #: Environments of the run: :meth:`prepare` builds their agents before any trial.
        self.envs_of_run = tuple(envs)
        self.device = torch.device(
            config.device or ("cuda" if torch.cuda.is_available() else "cpu")
        )
        self.agents: dict[str, tuple[Agent, dict[str, Any]]] = {}
        self.envs: collections.OrderedDict[str, Env] = collections.OrderedDict()

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
            from vp2.models.reference import RandomActions

            return RandomActions(action_dim), {"spec": "random_actions", "name": "random_actions"}
        model = plugins.build_model(
            cfg.model, cfg.model_args, env=env_name, action_dim=action_dim, device=self.device
        )
        if self.in_pool and getattr(model, "num_workers", 1) > 1:
            # See the module docstring: trial processes never start model pools of their own.
            log.warning("running trials in parallel: %s uses 1 worker per trial", cfg.model)
            model.num_workers = 1
        identity = plugins.model_identity(cfg.model, cfg.model_args, model)
        _check_model_fits(model, cfg, env_name, action_dim, self.device)
        agent = PlanningAgent(
            model,
            planner=cfg.planner(),
            cost_mode=cfg.cost,  # type: ignore[arg-type]
            device=self.device,
            record_predictions=cfg.save_predictions,
        )
        return agent, identity

    def env(self, instance: TaskInstance) -> Env:
        key = json.dumps(instance.env_meta, sort_keys=True)
        if key not in self.envs:
            self.envs[key] = instance.make_env(observation_size=None)
            while len(self.envs) > 2:
                self.envs.popitem(last=False)[1].close()
        self.envs.move_to_end(key)
        return self.envs[key]

    def close(self) -> None:
        for env in self.envs.values():
            env.close()
        self.envs.clear()
        for agent, _ in self.agents.values():
            close = getattr(getattr(agent, "model", None), "close", None)
            if callable(close):
                close()
        self.agents.clear()


class ModelMismatch(ValueError):
    """A built model that cannot run the run's tasks (raised before any trial)."""


def _check_model_fits(
    model: Any, cfg: RunConfig, env_name: str, action_dim: int, device: torch.device
) -> None:
    name = getattr(model, "name", type(model).__name__)
    if int(model.action_dim) != action_dim:
        raise ModelMismatch(
            f"model {name} has action_dim {model.action_dim}, but the {env_name} tasks have "
            f"{action_dim}-D actions; build it for the environment (a factory that declares an "
            f"`action_dim` parameter gets the environment's; {MODEL_DOCS})"
        )
    if cfg.optimizer in GRADIENT_OPTIMIZERS:
        problem = gradient_problem(model, device)
        if problem is not None:
            raise ModelMismatch(
                f"the {cfg.optimizer} optimizer needs gradients of the predictions with respect "
                f"to the actions, but model {name} {problem}; plan with --optimizer mppi or cem"
            )


_STATE: _WorkerState | None = None


def _init_worker(config: RunConfig, envs: Sequence[str] = ()) -> None:
    """Initialiser of trial worker processes."""
    global _STATE
    # Several trial processes share the machine's cores; one torch thread each avoids
    # oversubscription (and OpenMP stalls on shared cores, see docs/planning.md).
    torch.set_num_threads(1)
    _STATE = _WorkerState(config, in_pool=True, envs=envs)


def _envs_of(jobs: Sequence[_Job]) -> tuple[str, ...]:
    return tuple(sorted({split_name(job.key[0])[0] for job in jobs}))


def _error(exc: BaseException, where: str) -> dict[str, Any]:
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


def _base_record(job: _Job, identity: dict[str, Any]) -> dict[str, Any]:
    task, index, seed = job.key
    return {
        "task": task,
        "instance": index,
        "instance_sha": job.instance.fingerprint,
        "seed": seed,
        "model": identity,
        "vp2_version": vp2.__version__,
        "device": str(_STATE.device) if _STATE else None,
    }


def _now() -> str:
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def _run_job(job: _Job) -> _Outcome:
    """Runs one trial in the current process (a worker, or the driver with one worker); its
    record is stamped ``finished_at`` when it ends, however it ends."""
    outcome = _attempt_trial(job)
    outcome.record["finished_at"] = _now()
    return outcome


def _attempt_trial(job: _Job) -> _Outcome:
    assert _STATE is not None, "worker state is not initialised"
    cfg = _STATE.config
    fallback_identity = {"spec": cfg.model, "args": dict(cfg.model_args)}
    try:
        _STATE.prepare()
    except Exception as exc:
        where = "model_check" if isinstance(exc, ModelMismatch) else "model_build"
        record = {**_base_record(job, fallback_identity), "success": None}
        return _Outcome(job.key, {**record, "error": _error(exc, where)}, fatal=True)
    try:
        env = _STATE.env(job.instance)
    except Exception as exc:  # a simulator that cannot even be built
        record = {**_base_record(job, fallback_identity), "success": None}
        return _Outcome(job.key, {**record, "error": _error(exc, "environment")})
    env_name = split_name(job.instance.task)[0]
    try:
        agent, identity = _STATE.agent(env_name, env.action_dim)
    except Exception as exc:
        record = {**_base_record(job, fallback_identity), "success": None}
        return _Outcome(job.key, {**record, "error": _error(exc, "model_build")}, fatal=True)
    record = _base_record(job, identity)
    try:
        trial = ControlTrial(
            job.instance,
            agent,
            seed=job.key[2],
            num_steps=cfg.num_steps,
            stop_on_success=cfg.stop_on_success,
            env=env,
        )
        result = trial.run()
    except Exception as exc:
        # A simulator that raised may be broken beyond what reset_to repairs: rebuild it.
        broken = _STATE.envs.pop(json.dumps(job.instance.env_meta, sort_keys=True), None)
        if broken is not None:
            broken.close()
        record.update(
            success=None, cost=getattr(agent, "cost_kind", None), error=_error(exc, "trial")
        )
        return _Outcome(job.key, record)
    record.update(result.record())
    record["error"] = None
    return _Outcome(job.key, record, result=result)


# --------------------------------------------------------------------------- files


def _slug(task: str) -> str:
    return task.replace("/", "_")


def gif_path(run_dir: Path, key: TrialKey, suffix: str = "") -> Path:
    """Where the GIF of a trial goes."""
    task, index, seed = key
    return run_dir / GIF_DIR / _slug(task) / f"i{index:03d}_s{seed}{suffix}.gif"


def _upscale(frames: np.ndarray, factor: int) -> np.ndarray:
    return frames.repeat(factor, axis=-3).repeat(factor, axis=-2)


def execution_frames(result: TrialResult, scale: int = 2) -> np.ndarray:
    """``(num_steps + 1, s·H, 2·s·W, 3)``: each observation next to the goal image."""
    goal = np.broadcast_to(result.goal_image, result.frames.shape)
    return _upscale(np.concatenate([result.frames, goal], axis=2), scale)


def prediction_frames(result: TrialResult, scale: int = 2) -> np.ndarray | None:
    """``(num_planning_steps, s·H, s·(T+1)·W, 3)``: the chosen plan's predicted frames in a
    row, then the goal, one GIF frame per planning step."""
    if result.predicted_frames is None:
        return None
    pred = result.predicted_frames  # (P, T, H, W, 3)
    row = np.concatenate(list(pred.transpose(1, 0, 2, 3, 4)), axis=2)  # (P, H, T*W, 3)
    goal = np.broadcast_to(result.goal_image, (pred.shape[0], *result.goal_image.shape))
    return _upscale(np.concatenate([row, goal], axis=2), scale)


def write_gif(path: Path, frames: np.ndarray, duration_ms: int = 250) -> None:
    """Writes an animated GIF atomically."""
    import imageio.v3 as iio

    with atomic_path(path) as tmp:
        iio.imwrite(
            tmp, np.ascontiguousarray(frames), extension=".gif", duration=duration_ms, loop=0
        )


def _write_config(run_dir: Path, config: RunConfig) -> None:
    payload = {
        "vp2_version": vp2.__version__,
        "written_at": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "spec_deviations": config.deviations(),
        "config": config.to_dict(),
    }
    with atomic_path(run_dir / CONFIG_FILE) as tmp:
        tmp.write_text(yaml.safe_dump(payload, sort_keys=False))


def read_config(run_dir: str | os.PathLike[str]) -> RunConfig:
    """The configuration stored in a run directory."""
    data = yaml.safe_load((Path(run_dir) / CONFIG_FILE).read_text())
    return RunConfig.from_dict(data["config"])


def _prepare_run_dir(config: RunConfig) -> Path:
    run_dir = Path(config.out)
    existing = (run_dir / CONFIG_FILE).exists() or (run_dir / TRIALS_FILE).exists()
    if existing and not config.resume:
        raise FileExistsError(
            f"{run_dir} already holds a run; pass resume=True (--resume) to continue it, or "
            "choose another output directory"
        )
    if existing and (run_dir / CONFIG_FILE).exists():
        old = read_config(run_dir)
        changed = [
            f"{f}: {getattr(old, f)!r} -> {getattr(config, f)!r}"
            for f in PROTOCOL_FIELDS
            if getattr(old, f) != getattr(config, f)
        ]
        if changed:
            raise ValueError(
                f"cannot resume {run_dir} with different protocol settings ({'; '.join(changed)}); "
                "use a new output directory"
            )
    run_dir.mkdir(parents=True, exist_ok=True)
    # Temporaries of writes a killed run left behind (GIFs live one level down per task).
    for directory in [run_dir, *(run_dir / GIF_DIR).glob("*")]:
        if directory.is_dir():
            remove_stale_temporaries(directory)
    _write_config(run_dir, config)
    return run_dir


def _check_same_instances(
    run_dir: Path, records: list[dict[str, Any]], by_key: dict[tuple[str, int], TaskInstance]
) -> None:
    """Refuses to resume when finished trials ran on other task instances than the suite's now."""
    changed = sorted({
        by_key[key].key
        for r in records
        if (key := (r["task"], r["instance"])) in by_key
        and r.get("instance_sha") not in (None, by_key[key].fingerprint)
    })
    if changed:
        raise ValueError(
            f"cannot resume {run_dir}: finished trials ran on {len(changed)} task instance(s) that "
            f"differ from the task suite's now ({', '.join(changed[:5])}"
            f"{', ...' if len(changed) > 5 else ''}); the suite changed since (a new vp2 "
            "release or another --suite). Use a new output directory"
        )
    if any("instance_sha" not in r for r in records):
        log.warning(
            "%s: trials recorded before instance fingerprints existed; cannot check that they "
            "ran on the same task instances as the suite now", run_dir
        )


def _load_existing(run_dir: Path, retry_errors: bool) -> list[dict[str, Any]]:
    """Records already in the run, a partial last line cut off; error records dropped from
    the file (atomically) when they are to be re-run, so no key is ever written twice."""
    records = read_trials(run_dir, repair=True)
    if retry_errors and any(not is_ok(r) for r in records):
        records = [r for r in records if is_ok(r)]
        with atomic_path(run_dir / TRIALS_FILE) as tmp:
            tmp.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in records))
    return records


# --------------------------------------------------------------------------- execution


def _execute_in_pool(
    jobs: list[_Job], config: RunConfig, requeue: collections.deque[_Job]
) -> Iterator[tuple[_Job, _Outcome | None]]:
    """Runs jobs in worker processes; yields ``(job, outcome)``, outcome ``None`` if the job's
    worker died while it ran alone (so the job is to blame).

    When a worker dies, every trial in flight fails with it and the culprit is unknown: those
    trials are re-run one at a time ("isolated") before the others continue, so a trial that
    kills its worker is identified and charged, and its neighbours are not.
    """
    pending = collections.deque(jobs)
    suspects: collections.deque[_Job] = collections.deque()
    killers: set[TrialKey] = set()  # trials that killed their worker while running alone

    def new_pool() -> ProcessPoolExecutor:
        return ProcessPoolExecutor(
            max_workers=config.workers,
            mp_context=mp.get_context("spawn"),
            initializer=_init_worker,
            initargs=(config, _envs_of(jobs)),
        )

    pool = new_pool()
    in_flight: dict[Future[_Outcome], _Job] = {}

    def submit(job: _Job) -> bool:
        # The pool may have broken since the last wait (a worker died in between): then
        # submit raises, and the job waits for the next pool.
        try:
            in_flight[pool.submit(_run_job, job)] = job
        except BrokenProcessPool:
            return False
        return True

    try:
        while pending or suspects or in_flight or requeue:
            for job in requeue:  # retries from the driver; a known killer stays isolated
                (suspects if job.key in killers else pending).append(job)
            requeue.clear()
            broken = False
            if suspects:
                if not in_flight:
                    job = suspects.popleft()
                    job.isolated = True
                    if not submit(job):
                        suspects.appendleft(job)
                        broken = True
            else:
                while pending and len(in_flight) < config.workers:
                    job = pending.popleft()
                    if not submit(job):
                        pending.appendleft(job)
                        broken = True
                        break
            if in_flight and not broken:
                done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                for future in done:
                    job = in_flight.pop(future)
                    try:
                        outcome = future.result()
                    except BrokenProcessPool:
                        broken = True
                        if job.isolated:
                            killers.add(job.key)
                            yield job, None
                        else:
                            suspects.append(job)
                    else:
                        yield job, outcome
            if broken:
                # Every other trial in flight failed with the pool (or finished just before).
                for future, job in list(in_flight.items()):
                    try:
                        outcome = future.result()
                    except BrokenProcessPool:
                        suspects.append(job)
                    else:
                        yield job, outcome
                in_flight.clear()
                pool.shutdown(wait=True, cancel_futures=True)
                pool = new_pool()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


class _LiveQueue:
    """Iterator over the jobs, then whatever the driver puts into ``requeue`` later (a Ray
    executor polls it again after every result)."""

    def __init__(self, jobs: list[_Job], requeue: collections.deque[_Job]) -> None:
        self.jobs = collections.deque(jobs)
        self.requeue = requeue

    def __iter__(self) -> _LiveQueue:
        return self

    def __next__(self) -> _Job:
        if self.requeue:
            self.jobs.extend(self.requeue)
            self.requeue.clear()
        if not self.jobs:
            raise StopIteration
        return self.jobs.popleft()


def _execute_on_ray(
    jobs: list[_Job], config: RunConfig, requeue: collections.deque[_Job]
) -> Iterator[tuple[_Job, _Outcome | None]]:
    """Runs jobs on Ray actors, each initialised like a pool worker (one simulator and one
    model replica per actor); yields ``(job, outcome)``, outcome ``None`` if the job's actor
    (or its node) died every time it ran. Each actor runs one trial at a time, so a death is
    charged to the trial that ran, and a trial that lost an innocent worker (a node went
    away) is re-run elsewhere by the executor before it counts as an attempt here."""
    executor = RayExecutor(
        address=config.address,
        workers=config.workers,
        num_cpus=config.num_cpus_per_worker,
        num_gpus=config.num_gpus_per_worker,
    )
    if config.device is None and config.num_gpus_per_worker == 0:
        # An actor without a GPU share must not take a GPU its node has (Ray may leave it
        # visible): the model replicas of such a run belong on the CPU.
        config = dataclasses.replace(config, device="cpu")
    with executor:
        results = executor.imap_unordered(
            _run_job, _LiveQueue(jobs, requeue), _init_worker, (config, _envs_of(jobs)),
            on_lost="yield",
        )
        try:
            for job, outcome in results:
                yield job, None if isinstance(outcome, WorkerLost) else outcome
        finally:
            results.close()


def run_benchmark(config: RunConfig) -> RunResult:
    """Runs (or resumes) a benchmark run; see the module docstring.

    Args:
        config: The run's configuration.

    Returns:
        A :class:`RunResult` with the records and the summary (also written to
        ``summary.md`` / ``summary.json`` in the run directory).

    Raises:
        ValueError: an invalid config, a model spec that cannot be resolved, or a resume with
            different protocol settings.
        FileExistsError: the output directory holds a run and ``resume`` is off.
        RuntimeError: the model could not be built in a worker (nothing can run).
        ModelFailure: the model does not fit the run (action size; gradients for
            ``cem_gd``/``lbfgs``), or its first trials failed at the model boundary with the
            same error :data:`FAIL_FAST_AFTER` times in a row (finished trials are kept).
    """
    config.validate()
    if config.agent == "planning":
        plugins.check_spec(config.model)
    suite = TaskSuite.load(config.suite)
    instances = select_instances(suite, config)
    by_key = {(i.task, i.index): i for i in instances}
    keys = trial_keys(instances, config.seeds)
    run_dir = _prepare_run_dir(config)
    existing = _load_existing(run_dir, config.retry_errors)
    _check_same_instances(run_dir, existing, by_key)
    done = {trial_key(r) for r in existing}
    todo = [k for k in keys if k not in done]
    for message in config.deviations():
        log.warning("not the SPEC protocol: %s", message)

    jobs = [_Job(key=k, instance=by_key[k[:2]]) for k in todo]
    max_attempts = config.max_retries + 1
    requeue: collections.deque[_Job] = collections.deque()
    num_run = successes = finished = 0
    # Model-boundary failures in a row while no trial has finished in this session, and the
    # final error records among them, held back until the streak ends (if the run stops, those
    # trials are not finished: a resume runs them again).
    streak: list[dict[str, Any]] = []
    held: list[dict[str, Any]] = []
    bar = tqdm(total=len(jobs), unit="trial", desc="vp2 run", disable=not config.progress)
    if config.executor == "ray":
        stream = _execute_on_ray(jobs, config, requeue)
    elif config.workers > 1:
        stream = _execute_in_pool(jobs, config, requeue)
    else:
        stream = _retrying_in_process(jobs, config, requeue)
    try:
        with TrialLog(run_dir / TRIALS_FILE) as trial_log:
            for job, outcome in stream:
                if outcome is None:  # its worker died with it running alone
                    error = {
                        "type": "WorkerDied",
                        "message": "the trial's worker process died (killed, segfault or out of memory)",
                        "where": "worker",
                        "traceback": "",
                    }
                    record = {**_base_record(job, {"spec": config.model}), "success": None}
                    outcome = _Outcome(job.key, {**record, "error": error, "finished_at": _now()})
                if outcome.fatal:
                    err = outcome.record["error"]
                    if err["where"] == "model_check":
                        raise ModelFailure(
                            f"model {config.model!r} cannot run these tasks: {err['message']}"
                        )
                    raise RuntimeError(
                        f"could not build the model {config.model!r} "
                        f"({err['type']}: {err['message']}):\n{err['traceback']}"
                    )
                record = outcome.record
                failure = (record["error"] or {}).get("model_failure")
                if finished == 0 and failure is not None:
                    same = bool(streak) and _same(streak[-1], failure)
                    streak = [*streak, failure] if same else [failure]
                    if len(streak) >= FAIL_FAST_AFTER:
                        message = _fail_fast_message(config, run_dir, failure, len(streak))
                        raise ModelFailure(message)
                elif streak:
                    streak = []
                    for r in held:
                        trial_log.append(r)
                    held = []
                if record["error"] is not None and job.attempt < max_attempts:
                    log.warning(
                        "trial %s failed (attempt %d/%d): %s: %s",
                        job.key,
                        job.attempt,
                        max_attempts,
                        record["error"]["type"],
                        record["error"]["message"],
                    )
                    requeue.append(
                        _Job(job.key, job.instance, job.attempt + 1, [*job.errors, record["error"]])
                    )
                    continue
                record["attempts"] = job.attempt
                record["previous_errors"] = job.errors
                if outcome.result is not None and config.save_gifs:
                    _write_gifs(run_dir, outcome.result, record)
                if streak:
                    held.append(record)
                else:
                    trial_log.append(record)
                num_run += 1
                finished += record["error"] is None
                successes += bool(record.get("success"))
                bar.update(1)
                bar.set_postfix(success=f"{successes}/{finished}", errors=num_run - finished)
            for r in held:  # the run ended with a streak shorter than FAIL_FAST_AFTER
                trial_log.append(r)
    finally:
        bar.close()
        stream.close()

    records = read_trials(run_dir)
    is_oracle = is_oracle_config(config.to_dict())
    summary = summarize_run(
        records,
        is_oracle=is_oracle,
        oracle_run=config.oracle,
        shipped=None if is_oracle or config.oracle else load_shipped_oracle(),
    )
    summary.warnings += [f"not the SPEC protocol: {d}" for d in config.deviations()]
    write_json_atomic(run_dir / SUMMARY_JSON, _finite(summary.to_dict()))
    with atomic_path(run_dir / SUMMARY_FILE) as tmp:
        tmp.write_text(format_summary(summary, title=f"vp2 run {run_dir.name}") + "\n")
    try:  # the report is a view of the results above: its failure must never lose them
        from vp2.benchmark.report import REPORT_FILE, write_report

        write_report([run_dir], run_dir / REPORT_FILE)
    except Exception as exc:
        log.warning("could not write the HTML report of %s: %r", run_dir, exc)
    return RunResult(
        run_dir=run_dir,
        config=config,
        records=records,
        summary=summary,
        num_run=num_run,
        num_skipped=len(keys) - len(todo),
        num_errors=sum(not is_ok(r) for r in records),
    )


def _same(a: dict[str, Any], b: dict[str, Any]) -> bool:
    """The same model failure: model, field and what was expected (not the exact values)."""
    keys = ("model", "field", "expected")
    if a.get("expected") == "no exception":  # an exception from predict: its text too
        keys = (*keys, "got")
    return all(a.get(k) == b.get(k) for k in keys)


def _fail_fast_message(
    config: RunConfig, run_dir: Path, failure: dict[str, Any], count: int
) -> str:
    kept = len(read_trials(run_dir))
    return (
        f"stopped: model {failure['model']} ({config.model}) failed its first {count} trial "
        f"attempts the same way, at the model boundary: {failure['field']}: expected "
        f"{failure['expected']}, got {failure['got']}. See {MODEL_DOCS} for the interface. "
        f"{kept} finished trial(s) kept in {run_dir}; fix the model and continue with --resume"
    )


def _retrying_in_process(
    jobs: list[_Job], config: RunConfig, requeue: collections.deque[_Job]
) -> Iterator[tuple[_Job, _Outcome | None]]:
    """In-process execution that also drains the retry queue the driver fills."""
    global _STATE
    queue = collections.deque(jobs)
    _STATE = _WorkerState(config, in_pool=False, envs=_envs_of(jobs))
    try:
        while queue or requeue:
            queue.extend(requeue)
            requeue.clear()
            job = queue.popleft()
            yield job, _run_job(job)
    finally:
        _STATE.close()
        _STATE = None


def _write_gifs(run_dir: Path, result: TrialResult, record: dict[str, Any]) -> None:
    key = (result.task, result.instance, result.seed)
    path = gif_path(run_dir, key)
    write_gif(path, execution_frames(result))
    record["gif"] = str(path.relative_to(run_dir))
    predicted = prediction_frames(result)
    if predicted is not None:
        plan_path = gif_path(run_dir, key, "_plan")
        write_gif(plan_path, predicted, duration_ms=500)
        record["plan_gif"] = str(plan_path.relative_to(run_dir))


def _finite(obj: Any) -> Any:
    """NaN -> None, so that summary.json is strict JSON."""
    if isinstance(obj, float) and math.isnan(obj):
        return None
    if isinstance(obj, dict):
        return {str(k): _finite(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_finite(v) for v in obj]
    return obj
