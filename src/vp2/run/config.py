"""The configuration of a benchmark run: :class:`RunConfig`, one field per ``vp2 run`` flag.

The planner's settings are one nested :class:`~vp2.planning.config.PlannerConfig`
(``RunConfig.planner``), and ``config.yaml`` stores them nested (``planner:``). A run
directory written before the nesting is converted to this form as it is read
(:func:`vp2.run.run_dir.nest_legacy_config`).

Making a ``RunConfig`` and reading a run directory's config does not load torch
(:class:`~vp2.planning.config.PlannerConfig` is plain data); validating one builds the
planner's optimizers, which does.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

from vp2 import spec
from vp2.envs import ENV_TASKS, split_name
from vp2.planning.config import PlannerConfig
from vp2.run.model_spec import ENSEMBLE_PREFIX
from vp2.utils.executors.base import EXECUTORS
from vp2.utils.seeds import check_seed

AGENTS: tuple[str, ...] = ("planning", "random")
#: Fields of :class:`RunConfig` that change what a trial does (``planner``: every field of it).
#: A resumed run must keep them; the others (which trials, how many processes, where) may
#: change between sessions.
PROTOCOL_FIELDS: tuple[str, ...] = (
    "model",
    "model_args",
    "agent",
    "suite",
    "planner",
    "cost",
    "num_steps",
)


def flat_settings(data: Mapping[str, Any]) -> dict[str, Any]:
    """A ``config`` mapping of ``config.yaml`` shown with the planner's fields beside the
    others (``{"model": ..., "optimizer": ..., "num_samples": ...}``), e.g. to show a run's
    settings or to look one up by its field name."""
    out = {k: v for k, v in data.items() if k != "planner"}
    planner = data.get("planner")
    if isinstance(planner, Mapping):
        out.update(planner)
    return out


def planner_of(data: Mapping[str, Any]) -> PlannerConfig:
    """The planner of a ``config`` mapping, nested or shown flat (:func:`flat_settings`);
    fields it lacks take their defaults, keys that are no planner field are ignored."""
    names = {f.name for f in dataclasses.fields(PlannerConfig)}
    values = {k: v for k, v in flat_settings(data).items() if k in names}
    if values.get("sigma") is not None:
        values["sigma"] = tuple(values["sigma"])
    return PlannerConfig(**values)


@dataclasses.dataclass(frozen=True)
class RunConfig:
    """Everything a benchmark run needs; one field per ``vp2 run`` flag.

    Attributes:
        model: Model spec (``--model``): ``simulator``, ``repeat_last_frame``,
            ``NAME:CHECKPOINT``, ``zoo:NAME``, ``package.module:factory``, a YAML file or
            ``ensemble(SPEC,SPEC,...)`` (:mod:`vp2.run.model_spec`). Ignored by
            ``agent="random"``.
        out: Run directory (``--out``).
        model_args: Keyword arguments of the model factory (``--model-arg KEY=VALUE``,
            repeatable; values parsed as YAML, see
            :func:`~vp2.run.model_spec.parse_model_args`).
        agent: ``"planning"`` (visual foresight with the model) or ``"random"`` (uniform
            random actions, no model) (``--agent``).
        suite: Task suite file (``--suite``); ``None``: the suite shipped with vp2.
        tasks: Task categories or environment names to run (``--tasks``); empty: every task
            of the suite.
        num_instances: First ``k`` instances of each task (``--num-instances``); ``None``:
            all. A task with fewer runs all it has, and the run says so.
        seeds: Control-run seeds (``--seeds``); SPEC §4 asks for at least 3.
        planner: The planning agents' optimizer settings
            (:class:`~vp2.planning.config.PlannerConfig`): ``optimizer`` (``--optimizer``:
            ``mppi`` (SPEC), ``cem``, ``cem_gd``, ``lbfgs``), ``num_samples`` (planner
            samples per step, ``--num-samples``; ``None``: SPEC, 200, 800 for
            open_slide/open_drawer; other values are for tests and ablations), ``gamma``
            (MPPI inverse temperature, ``--gamma``), ``num_iterations`` (iterations per step,
            ``--num-iterations``; ``None``: the optimizer's default), the settings only some
            optimizers read (``num_elites``, ``num_samples_first``, ``num_refined``, ``lr``,
            ``grad_steps``: ``--num-elites`` ...; ``None``: the optimizer's default; one its
            optimizer does not read is refused); ``sigma`` and ``options`` have no flag.
        cost: ``auto`` | ``spec`` | ``pixel_only`` (``--cost``), see
            :data:`vp2.planning.planner.CostMode`.
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
        max_retries: Extra attempts of a crashed trial (``--max-retries``); a trial past
            ``trial_timeout`` is not retried at once.
        trial_timeout: Wall-clock seconds of a trial attempt (``--trial-timeout``); ``None``:
            no limit. A trial past it stops and is recorded as an error (``TrialTimeout``,
            naming the limit) and the run goes on; ``--resume --retry-errors`` runs it again.
            Building the model and the simulator is not counted, the trial's first render is
            (a fresh worker creates its GL context then). Not a protocol field: a resumed
            run may change it.
        resume: Continue an existing run directory, running only missing trials
            (``--resume``).
        retry_errors: With ``resume``, also re-run trials recorded as errors
            (``--retry-errors``).
        save_gifs: Write a GIF per trial: execution next to the goal (``--no-gifs`` off).
        save_predictions: Also a GIF of the chosen plan's predicted frames per planning step
            (``--save-predictions``; one extra model call per step).
        oracle: Run directory (or ``trials.jsonl``) of a simulator-oracle run, to normalise
            the scores (``--oracle``); ``None``: the shipped oracle's table of the run's planner samples
            (:mod:`vp2.oracle.shipped`), if there is one.
        progress: Show a progress bar with ETA (``--no-progress`` off).
        precheck: Before the first trial of a learned model, measure on a few held-out clips
            of the environment's default dataset whether its predictions depend on the
            actions, and warn when they do not (``--no-precheck`` off;
            :func:`vp2.diagnose.model.precheck_model`). Not a protocol field.
    """

    model: str
    out: str
    model_args: dict[str, Any] = dataclasses.field(default_factory=dict)
    agent: str = "planning"
    suite: str | None = None
    tasks: tuple[str, ...] = ()
    num_instances: int | None = None
    seeds: tuple[int, ...] = tuple(range(spec.MIN_SEEDS))
    planner: PlannerConfig = dataclasses.field(default_factory=PlannerConfig)
    cost: str = "auto"
    num_steps: int = spec.NUM_CONTROL_STEPS
    stop_on_success: bool = False
    workers: int = 1
    executor: str = "local"
    address: str | None = None
    num_cpus_per_worker: float = 1.0
    num_gpus_per_worker: float = 0.0
    device: str | None = None
    max_retries: int = 1
    trial_timeout: float | None = None
    resume: bool = False
    retry_errors: bool = False
    save_gifs: bool = True
    save_predictions: bool = False
    oracle: str | None = None
    progress: bool = True
    precheck: bool = True

    def validate(self) -> None:
        """Raises ``ValueError`` naming the first invalid field."""
        from vp2.planning.optimizers import OPTIMIZERS
        from vp2.planning.planner import COST_MODES

        if self.agent not in AGENTS:
            raise ValueError(f"agent must be one of {AGENTS}, got {self.agent!r}")
        if not isinstance(self.planner, PlannerConfig):
            raise ValueError(f"planner must be a PlannerConfig, got {self.planner!r}")
        if self.planner.optimizer not in OPTIMIZERS:
            raise ValueError(
                f"optimizer must be one of {tuple(OPTIMIZERS)}, got {self.planner.optimizer!r}"
            )
        if self.cost not in COST_MODES:
            raise ValueError(f"cost must be one of {COST_MODES}, got {self.cost!r}")
        if not self.seeds or len(set(self.seeds)) != len(self.seeds):
            raise ValueError(f"seeds must be distinct and non-empty, got {self.seeds}")
        for seed in self.seeds:
            check_seed(seed, "every seed")
        if self.num_steps < 2:
            raise ValueError(f"num_steps must be >= 2, got {self.num_steps}")
        if self.num_instances is not None and self.num_instances < 1:
            raise ValueError(f"num_instances must be >= 1, got {self.num_instances}")
        if self.workers < 1 or self.max_retries < 0:
            raise ValueError("workers must be >= 1 and max_retries >= 0")
        timeout = self.trial_timeout
        if timeout is not None and not (
            isinstance(timeout, (int, float)) and not isinstance(timeout, bool)
            and 0 < timeout < math.inf
        ):
            raise ValueError(
                f"trial_timeout must be a positive number of seconds (or None: no limit), "
                f"got {timeout!r}"
            )
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
        if self.agent == "planning":
            # The optimizer validates its own settings (num_samples, gamma, ...): build one per
            # environment now, so that a bad value stops the run before any trial starts.
            from vp2.planning.planner import build_optimizer

            for env, env_tasks in ENV_TASKS.items():
                build_optimizer(f"{env}/{env_tasks[0]}", self.planner)

    def to_dict(self) -> dict[str, Any]:
        """Plain data (tuples as lists, ``planner`` a nested mapping), as written to
        ``config.yaml``."""
        d = _lists(dataclasses.asdict(self))
        d["planner"] = _lists(d["planner"])
        return d

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> RunConfig:
        """Inverse of :meth:`to_dict` (the planner nested, as ``config.yaml`` stores it; a
        run directory's old flat form is converted first, by
        :func:`vp2.run.run_dir.nest_legacy_config`). Unknown keys are an error."""
        names = {f.name for f in dataclasses.fields(cls)}
        planner_names = {f.name for f in dataclasses.fields(PlannerConfig)}
        data = dict(data)
        nested = data.pop("planner", None) or {}
        if isinstance(nested, PlannerConfig):
            nested = dataclasses.asdict(nested)
        if not isinstance(nested, Mapping):
            raise ValueError(f"planner must be a mapping of PlannerConfig fields, got {nested!r}")
        unknown = set(data) - names
        if unknown:
            raise ValueError(f"unknown RunConfig field(s) {sorted(unknown)}")
        unknown = set(nested) - planner_names
        if unknown:
            raise ValueError(f"unknown PlannerConfig field(s) {sorted(unknown)}")
        planner = dict(nested)
        if planner.get("sigma") is not None:
            planner["sigma"] = tuple(planner["sigma"])
        for key in ("tasks", "seeds"):
            if key in data:
                data[key] = tuple(data[key])
        return cls(**data, planner=PlannerConfig(**planner))

    def protocol(self) -> dict[str, Any]:
        """The settings a resumed run must keep (:data:`PROTOCOL_FIELDS`), the planner's
        field by field (``{"model": ..., "optimizer": ..., "num_samples": ..., ...}``)."""
        out: dict[str, Any] = {}
        for name in PROTOCOL_FIELDS:
            value = getattr(self, name)
            if dataclasses.is_dataclass(value):
                out.update((f.name, getattr(value, f.name)) for f in dataclasses.fields(value))
            else:
                out[name] = value
        return out

    def deviations(self) -> list[str]:
        """How this run departs from the SPEC protocol (shown with the results)."""
        out = []
        planner = self.planner
        if self.num_steps != spec.NUM_CONTROL_STEPS:
            out.append(f"num_steps={self.num_steps} (SPEC: {spec.NUM_CONTROL_STEPS})")
        if planner.num_samples is not None:
            out.append(
                f"num_samples={planner.num_samples} (SPEC: {spec.NUM_SAMPLES}, "
                f"{spec.LARGE_NUM_SAMPLES} for open_slide/open_drawer)"
            )
        if self.agent == "planning":
            if planner.optimizer != "mppi":
                out.append(f"optimizer={planner.optimizer} (SPEC: mppi)")
            if planner.gamma != spec.GAMMA and planner.optimizer == "mppi":
                out.append(f"gamma={planner.gamma} (SPEC: {spec.GAMMA})")
            if planner.num_iterations is not None:
                out.append(
                    f"num_iterations={planner.num_iterations} (SPEC: {spec.NUM_ITERATIONS})"
                )
            for name, value in planner.optimizer_fields().items():
                out.append(f"{name}={value} (SPEC: none, {planner.optimizer}'s default)")
            if planner.sigma is not None:
                out.append(f"sigma={list(planner.sigma)} (SPEC: the environment's, vp2.spec.SIGMA)")
            if planner.options:
                out.append(f"optimizer options {planner.options} (SPEC: none)")
            if self.model.startswith(ENSEMBLE_PREFIX):
                out.append(
                    f"model {self.model} is an ensemble, planned with the ensemble cost (a random "
                    f"member's score - {spec.ENSEMBLE_DISAGREEMENT_WEIGHT} x the members' "
                    "disagreement; SPEC: one model)"
                )
            if self.cost == "pixel_only":
                out.append("cost=pixel_only (SPEC: RoboDesk uses its success classifier)")
        if len(self.seeds) < spec.MIN_SEEDS:
            out.append(
                f"{len(self.seeds)} seed(s) (SPEC: at least {spec.MIN_SEEDS} control runs)"
            )
        return out


def _lists(data: dict[str, Any]) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in data.items()}
