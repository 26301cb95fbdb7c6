"""``vp2 diagnose``: whether a model can plan, in minutes instead of a control run's hours.

::

    vp2 diagnose --model svg_prime:runs/svg --env robodesk
    vp2 diagnose --model repeat_last_frame --env tabletop --clips 32 --instances-per-task 1

Python API (the command calls exactly this)::

    report = diagnose_model(DiagnoseConfig(model="repeat_last_frame", env="tabletop"))
    write_report("runs/diagnose/rlf/diagnose.json", report)

Four measurements (:mod:`vp2.diagnose.measures`), each with a verdict from fixed
thresholds (:mod:`vp2.diagnose.verdicts`; ``docs/diagnose.md``):

1. **action conditioning** on held-out clips of the environment's default dataset (the one
   ``vp2 collect ENV`` writes, as ``vp2 metrics`` reads it; where it is absent, its
   validation trajectories alone, collected once into the cache, :mod:`vp2.data.held_out`):
   mean error with the clips' true actions and with another clip's, their ratio shuffled /
   true and its 95% bootstrap interval;
2. at the first planning step of the first ``instances_per_task`` suite instances of every task
   (the candidates the trial of ``seed`` draws there, at ``num_samples``): the **scripted
   plan's rank** among the candidates under the model and the task's cost;
3. the **ranking's repeatability**: Spearman's ρ between two scorings of the same candidates
   with different model seeds (1 for a deterministic model);
4. **γ · spread** of the scores and the effective sample size of MPPI's weights
   ``softmax(γ · score)`` (``N``: every candidate weighs the same and MPPI executes their mean);
   and the **direction** the weights move the plan in: the mean cosine between instances of
   different tasks (near 1: the same direction whatever the goal);
5. the **agreement with the simulator**: the same candidates scored with the simulator's
   futures (the oracle), Spearman's ρ between its scores and the model's, and whether its
   best candidate is in the model's top tenth (the simulator's scores are cached on disk).

The report's ``predicted_control_score`` is the success fraction the shipped predictor
(:mod:`vp2.diagnose.score`, fitted on models whose control runs were measured)
gives these measurements, with ``predicted_control_score_reason`` saying what it rests on;
``None``, and why, where no predictor is fitted for the environment.

:func:`precheck_model` is the cheap part alone (action conditioning on
:data:`PRECHECK_CLIPS` clips), which :func:`vp2.benchmark.runner.run_benchmark` runs before the
first trial of a learned model and which warns when its predictions ignore the actions.

A diagnosis can keep what it has measured in a partial file (``partial=``; ``vp2 diagnose``
keeps one beside its report): the conditioning measure and every probed instance are saved
as they finish, and a re-run with the same settings and model skips them, so a diagnosis
stopped after an hour (a slow diffusion model) loses at most one instance.
"""

from __future__ import annotations

import dataclasses
import datetime
import functools
import logging
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vp2 import spec
from vp2.data.datasets import default_dataset
from vp2.data.storage import MANIFEST
from vp2.diagnose.measures import (
    conditioning_errors,
    held_out_clips,
    held_out_trajectories,
    oracle_cache_dir,
    probe_instance,
    ratio_statistics,
)
from vp2.diagnose.partial import PartialDiagnosis, partial_key
from vp2.diagnose.score import load_predictor, predicted_score
from vp2.diagnose.verdicts import (
    conditioning_verdict,
    format_report,
    summarize_planning,
    verdicts,
)
from vp2.envs import ENV_TASKS, env_class
from vp2.run.config import RunConfig
from vp2.run.model_spec import BUILTIN_MODELS, ModelSpec, model_identity, resolve_model
from vp2.run.run_dir import DIAGNOSIS_FILE
from vp2.utils.seeds import check_seed

log = logging.getLogger(__name__)

__all__ = [
    "FORMAT",
    "PRECHECK_CLIPS",
    "DiagnoseConfig",
    "checkpoint_env",
    "diagnose_env",
    "diagnose_model",
    "format_report",
    "measure_conditioning",
    "precheck_model",
    "report_path",
    "require_dataset",
    "verdicts",
    "write_report",
]

FORMAT = "vp2-diagnose/1"
#: Held-out clips of the run's pre-check (:func:`precheck_model`), one sampling seed.
PRECHECK_CLIPS = 16


@dataclasses.dataclass(frozen=True)
class DiagnoseConfig:
    """What ``vp2 diagnose`` measures; one field per flag.

    Attributes:
        model: Model spec, as ``vp2 run --model`` takes it.
        env: ``robodesk`` or ``tabletop``; ``None``: the environment the checkpoint was trained
            on where it says, else ``robodesk``.
        model_args: Keyword arguments of the model factory (``--model-arg``).
        data: Dataset of the held-out clips; ``None``: the environment's default dataset.
        suite: Task suite file; ``None``: the shipped suite.
        clips: Held-out clips of the conditioning measure (0: skip it).
        sampling_seeds: Model noise seeds per clip.
        instances_per_task: First instances of each task probed at their first planning step
            (0: skip the planning measures).
        num_samples: Planner samples (candidates) per planning step.
        seed: Control-run seed of the probed trials; also seeds the clip choice.
        oracle_agreement: Also score the probed candidates with the simulator (the oracle)
            and measure how the model's ranking agrees with it (cached on disk).
        device: Torch device (``None``: CUDA if available, else CPU).
        progress: Show a progress bar.
    """

    model: str
    env: str | None = None
    model_args: dict[str, Any] = dataclasses.field(default_factory=dict)
    data: str | None = None
    suite: str | None = None
    clips: int = 64
    sampling_seeds: int = 2
    instances_per_task: int = 2
    num_samples: int = spec.MAIN_JOB_NUM_SAMPLES
    seed: int = 0
    oracle_agreement: bool = True
    device: str | None = None
    progress: bool = True

    def validate(self) -> None:
        """Raises ``ValueError`` naming the first invalid field."""
        if self.env is not None and self.env not in ENV_TASKS:
            raise ValueError(f"env must be one of {tuple(ENV_TASKS)}, got {self.env!r}")
        if self.clips < 0 or self.clips == 1:
            raise ValueError(f"clips must be 0 (skip) or >= 2 (shuffling needs two), got {self.clips}")
        if self.sampling_seeds < 1 or self.instances_per_task < 0 or self.num_samples < 2:
            raise ValueError("sampling_seeds must be >= 1, instances_per_task >= 0, num_samples >= 2")
        check_seed(self.seed)


# --------------------------------------------------------------------------- inputs


def checkpoint_env(model: str | ModelSpec) -> str | None:
    """The environment a ``NAME:CHECKPOINT`` model was trained on, where its checkpoint says
    (``dataset.config.env``); ``None`` otherwise."""
    parsed = model if isinstance(model, ModelSpec) else ModelSpec.parse(model)
    if parsed.checkpoint is None:
        return None
    path = Path(parsed.checkpoint.path)
    try:
        stat = path.stat()
    except OSError:
        return None  # building the model reports the problem
    return _checkpoint_env(str(path.resolve()), stat.st_mtime_ns, stat.st_size)


@functools.lru_cache(maxsize=8)
def _checkpoint_env(path: str, mtime_ns: int, size: int) -> str | None:
    """:func:`checkpoint_env` of one version of a file (its path, mtime and size are the key):
    a diagnosis asks twice (its report path, then its run), and a checkpoint is read once."""
    from vp2.models.checkpoint import read_model_checkpoint

    del mtime_ns, size  # the cache key only
    try:
        payload = read_model_checkpoint(path)
    except (OSError, ValueError):
        return None  # building the model reports the problem
    env = ((payload.get("dataset") or {}).get("config") or {}).get("env")
    return env if env in ENV_TASKS else None


def needs_frames(parsed: ModelSpec) -> bool:
    """Whether a spec predicts from frames (not the simulator oracle, which needs a state)."""
    return not (parsed.kind == "builtin" and parsed.target == BUILTIN_MODELS["simulator"])


def require_dataset(data: str | Path | None, env: str) -> Path | None:
    """The dataset of the held-out clips: ``data``, or the environment's default one;
    ``None`` where no ``data`` is given and the default dataset is absent: the diagnosis then
    collects the default dataset's validation trajectories itself
    (:func:`vp2.data.held_out.held_out_dataset`).

    Raises:
        FileNotFoundError: no dataset at ``data``, naming how to make it.
    """
    if data is None:
        path = default_dataset(env)
        return path if (path / MANIFEST).is_file() else None
    path = Path(data)
    if not (path / MANIFEST).is_file():
        raise FileNotFoundError(
            f"no dataset at {path} ({MANIFEST} missing); create it with `vp2 collect {env} "
            f"--out {path}`, or leave out --data to use the default dataset (or --clips 0 to "
            "skip the action-conditioning measure)"
        )
    return path


def _check_clips_fit(model: Any, frames: Any, actions: Any, data: Path) -> None:
    size, action_dim = int(frames.shape[-1]), int(actions.shape[-1])
    if int(model.image_size) != size:
        raise ValueError(
            f"model {model.name} predicts {model.image_size}px frames but the clips of {data} are "
            f"{size}px; pass --data DIR with a dataset of its resolution"
        )
    if int(model.action_dim) != action_dim:
        raise ValueError(
            f"the clips of {data} have {action_dim}-D actions, the model {model.action_dim}-D: "
            "a dataset of another environment? pass --env or --data"
        )


def measure_conditioning(
    model: Any, data: Path, clips: int, sampling_seeds: int, seed: int, device: Any,
    on_call: Any = None,
) -> dict[str, Any]:
    """The action-conditioning measure of a built, checked model on ``data``'s held-out clips:
    :func:`~vp2.diagnose.measures.ratio_statistics` of all pixels (intervals over
    clips and over the clips' trajectories), with the changing pixels' under ``moving``."""
    frames, actions = held_out_clips(
        data, clips, seed, int(model.num_context), int(model.num_future)
    )
    _check_clips_fit(model, frames, actions, data)
    trajectory = held_out_trajectories(
        data, clips, seed, int(model.num_context), int(model.num_future)
    )
    errors = conditioning_errors(model, frames, actions, sampling_seeds, seed, device, on_call)
    result = ratio_statistics(errors["true"], errors["shuffled"], seed, trajectory)
    moving = ratio_statistics(errors["true_moving"], errors["shuffled_moving"], seed, trajectory)
    keep = ("ratio", "ci", "trajectory_ci", "mse_true", "mse_shuffled", "wins")
    return {
        **result,
        "moving": {k: moving[k] for k in keep},
        "sampling_seeds": sampling_seeds,
        "dataset": str(data),
    }


# --------------------------------------------------------------------------- the diagnosis


def diagnose_model(config: DiagnoseConfig, partial: str | Path | None = None) -> dict[str, Any]:
    """Measures a model (module docstring) and returns the report. Writes nothing but
    ``partial`` (if given): the measurements as they finish, reused by a diagnosis of the same
    settings and model (the module docstring); the caller deletes it once the report is kept.

    Raises:
        ValueError: an invalid config, a spec that cannot be resolved, or clips that do not fit
            the model.
        FileNotFoundError: no dataset at ``config.data`` (see :func:`require_dataset`).
        vp2.data.storage.DatasetError: the default dataset is absent and its held-out
            trajectories cannot be collected here (no rendering).
    """
    import torch
    from tqdm.auto import tqdm

    from vp2.data.suite import TaskSuite
    from vp2.utils.tensors import resolve_device

    start = time.perf_counter()
    config.validate()
    parsed = ModelSpec.parse(config.model)
    parsed.check()
    env, env_source = diagnose_env(config)
    wants_clips = bool(config.clips) and needs_frames(parsed)
    data = require_dataset(config.data, env) if wants_clips else None
    instances = []
    if config.instances_per_task:
        instances = TaskSuite.load(config.suite).select([env], config.instances_per_task)
    device = resolve_device(config.device)
    model = resolve_model(
        parsed, config.model_args, env=env, action_dim=int(env_class(env).action_dim),
        device=device,
    )
    identity = model_identity(parsed, config.model_args, model)
    checkpoint = parsed.checkpoint.path if parsed.checkpoint is not None else None
    saved = PartialDiagnosis(
        partial, partial_key(dataclasses.asdict(config), env, identity, checkpoint)
    )
    state_model = bool(getattr(model, "needs_simulator_state", False))
    simulator = None
    if instances and config.oracle_agreement and not state_model:
        simulator = resolve_model(
            "simulator", {}, env=env, action_dim=int(env_class(env).action_dim), device=device
        )
    timing: dict[str, float] = {"model_s": round(time.perf_counter() - start, 2)}
    bar = None
    try:
        if wants_clips and data is None and not state_model and saved.conditioning is None:
            from vp2.data.held_out import held_out_dataset

            t0 = time.perf_counter()
            data = held_out_dataset(env, progress=config.progress)
            timing["held_out_s"] = round(time.perf_counter() - t0, 2)
        calls = 2 * config.sampling_seeds if wants_clips and not state_model else 0
        bar = tqdm(total=calls + len(instances), unit="step", desc="vp2 diagnose",
                   disable=not config.progress)
        t0 = time.perf_counter()
        if not config.clips:
            conditioning: dict[str, Any] = {"skipped": "--clips 0"}
        elif state_model:
            conditioning = {"skipped": "the model predicts from the simulator state, not from "
                            "frames: held-out clips do not apply"}
        elif saved.conditioning is not None:
            conditioning = saved.conditioning
            bar.update(calls)
        else:
            assert data is not None
            conditioning = measure_conditioning(
                model, data, config.clips, config.sampling_seeds, config.seed, device,
                on_call=lambda: bar.update(1),
            )
            conditioning = saved.set_conditioning(conditioning)
        timing["conditioning_s"] = round(time.perf_counter() - t0, 2)
        t0 = time.perf_counter()
        rows = []
        for instance in instances:
            bar.set_postfix(instance=instance.key)
            row = saved.row(instance.key)
            if row is None:
                row = probe_instance(model, instance, config.num_samples, config.seed, device,
                                     simulator=simulator, cache=oracle_cache_dir())  # fmt: skip
                row = saved.add_row(instance.key, row)
            rows.append(row)
            bar.update(1)
        timing["planning_s"] = round(time.perf_counter() - t0, 2)
        timing["oracle_s"] = round(sum(r["oracle_seconds"] for r in rows), 2)
        if saved.resumed:
            timing["resumed"] = saved.resumed
    finally:
        if bar is not None:
            bar.close()
        for used in (model, simulator):
            close = getattr(used, "close", None)
            if callable(close):
                close()
    del model, simulator
    if device.type == "cuda":
        torch.cuda.empty_cache()
    report: dict[str, Any] = {
        "format": FORMAT,
        "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "model": identity,
        "env": env,
        "env_source": env_source,
        "settings": {**dataclasses.asdict(config), "device": str(device)},
        "action_conditioning": conditioning,
        "planning": {"instances": rows, **summarize_planning(rows, config.num_samples)},
    }
    score, reason = predicted_score(report, load_predictor())
    report["predicted_control_score"], report["predicted_control_score_reason"] = score, reason
    report["verdicts"] = verdicts(report)
    timing["total_s"] = round(time.perf_counter() - start, 2)
    report["timing"] = timing
    return report


def write_report(path: str | Path, report: dict[str, Any]) -> Path:
    """Writes the report as JSON, atomically; a directory gets
    :data:`~vp2.run.run_dir.DIAGNOSIS_FILE` in it."""
    from vp2.utils.io import json_safe, write_json_atomic

    path = report_path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, json_safe(report))
    return path


def report_path(path: str | Path) -> Path:
    """The file :func:`write_report` writes for ``path`` (a directory gets
    :data:`~vp2.run.run_dir.DIAGNOSIS_FILE`)."""
    path = Path(path)
    return path / DIAGNOSIS_FILE if path.is_dir() or not path.suffix else path


def diagnose_env(config: DiagnoseConfig) -> tuple[str, str]:
    """The environment a diagnosis probes and where it came from: ``flag`` (``config.env``),
    ``checkpoint`` (the environment a checkpoint was trained on) or ``default`` (robodesk)."""
    from_checkpoint = checkpoint_env(config.model) if config.env is None else None
    env = config.env or from_checkpoint or "robodesk"
    return env, "flag" if config.env else "checkpoint" if from_checkpoint else "default"


# --------------------------------------------------------------------------- the run's pre-check


def precheck_model(config: RunConfig, envs: Sequence[str]) -> list[dict[str, Any]]:
    """The action-conditioning measure on :data:`PRECHECK_CLIPS` held-out clips of each
    environment's default dataset, before a run's first trial; logs a warning when the
    interval holds 1 (the model ignores its actions) and returns the measures.

    Skipped (a debug log) for the random agent, the built-in models, models that plan from the
    simulator state, environments without a default dataset, and anything that fails here (the
    run reports a model's errors itself).
    """
    from vp2.utils.tensors import resolve_device

    if config.agent != "planning" or ModelSpec.parse(config.model).kind == "builtin":
        return []
    out = []
    for env in envs:
        data = default_dataset(env)
        if not (data / MANIFEST).is_file():
            log.debug("pre-check of %s skipped: no dataset at %s", config.model, data)
            continue
        start = time.perf_counter()
        try:
            result = _precheck_env(config, env, data, resolve_device(config.device))
        except Exception as exc:  # noqa: BLE001  (the run reports model errors itself)
            log.debug("pre-check of %s on %s skipped: %s", config.model, env, exc)
            continue
        if result is None:
            continue
        verdict = conditioning_verdict(result)
        figure = (
            f"shuffled/true error ratio {result['ratio']:.2f}, 95% CI {result['ci'][0]:.2f}-"
            f"{result['ci'][1]:.2f} on {result['clips']} held-out clips of {data}"
        )
        if verdict["status"] == "blind":
            log.warning(
                "model %s: predictions do not measurably depend on the actions (%s): it will "
                "plan like repeat-last-frame; see `vp2 diagnose`", config.model, figure,
            )
        elif verdict["status"] == "inconclusive":
            log.warning("model %s: the pre-check cannot tell whether the predictions depend on "
                        "the actions (%s); see `vp2 diagnose`", config.model, figure)
        elif verdict["status"] == "inverted":
            log.warning("model %s: %s (%s); see `vp2 diagnose`", config.model, verdict["text"], figure)
        else:
            log.info("pre-check: model %s: %s (%s)", config.model, verdict["text"], figure)
        log.debug("pre-check took %.1f s", time.perf_counter() - start)
        out.append({"env": env, **result, "verdict": verdict})
    return out


def _precheck_env(config: RunConfig, env: str, data: Path, device: Any) -> dict[str, Any] | None:
    model = resolve_model(
        config.model, config.model_args, env=env, action_dim=int(env_class(env).action_dim),
        device=device,
    )
    try:
        if getattr(model, "needs_simulator_state", False):
            return None
        return measure_conditioning(model, data, PRECHECK_CLIPS, 1, 0, device)
    finally:
        close = getattr(model, "close", None)
        if callable(close):
            close()
