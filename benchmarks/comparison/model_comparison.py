"""The five model families on one RoboDesk dataset at one compute budget, judged by control.

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.comparison.model_comparison \\
        --data data/robodesk-300x-64px --budget-minutes 60 --out outputs/comparison

One command builds everything, and the same command resumes it if interrupted (a stage that
completed is skipped, a half-done one continues). Stages:

a. **train** every family of :data:`FAMILIES` (SVG′, FitVid, Struct-VRNN, MCVD, MaskViT at
   their small or tiny presets; ``--families`` picks some) on ``--data`` for
   ``--budget-minutes`` of training wall time each (``vp2 train --max-minutes``: optimisation
   steps only, validation and checkpoints left out; MaskViT's budget is split 1/3 tokenizer,
   2/3 transformer). An interrupted training resumes from its newest checkpoint and counts the
   time its earlier sessions spent. ``--skip-train`` trains nothing and evaluates the newest
   checkpoint of each run directory (e.g. trained on another machine and copied here).
b. **conditioning**: each family's prediction error on held-out clips under the true and under
   shuffled actions (``benchmarks.studies.action_conditioning``'s functions): the ratio
   shuffled / true with its 95% bootstrap interval, on all pixels and on the pixels that change.
   Then **diagnose**: ``vp2 diagnose`` of each family, extra model and repeat-last-frame at its
   default measurements (those its predicted control score was fitted on) and the
   comparison's planner samples, so the page shows the diagnosis beside the control score.
c. **metrics**: ``vp2 metrics`` of each family and of repeat-last-frame on held-out clips
   (MSE, PSNR, SSIM; LPIPS and FVD where their weight files are on the machine, else skipped
   with a note).
``--extra LABEL=MODEL`` adds a model that is not trained here (a checkpoint from elsewhere, any
``vp2 run --model`` spec) to stages b.–g., labelled as outside the budget; a zoo model
(``zoo:NAME``) shows its card's training budget, steps and device instead. ``--families``
with no family compares extra models only (e.g. the zoo's).

**Both environments.** ``--data`` given once per environment (e.g. a RoboDesk and a tabletop
dataset) compares extra models only (``--families`` with no family): each model goes to the
environment its zoo card names, or the one after ``@`` in its label (``shipped@robodesk=...``);
each environment is a comparison of its own under ``--out/<env>`` (its tasks: those of
``--tasks`` in that environment, default all), run one after the other, and one page
(``--docs``) holds a part per environment.

d. **runs**: ``vp2 run`` of each family, repeat-last-frame and random actions on the RoboDesk
   tasks (the first ``--num-instances`` of each, ``--seeds``, ``--num-samples`` planner
   samples), resumed trial by trial. ``--seeds-for RUN=SEEDS`` gives one run a subset of the
   seeds (a model too slow to plan with all of them in the time there is; the page says so,
   and dropping the flag later resumes the missing seeds).
e. **study** (``vp2 study``: metrics versus control, rank correlations) and **report**
   (``vp2 report``), normalised by the shipped oracle.
f. **screenshot** of the report's top, if Chromium is on PATH.
g. **results.md** (``model_comparison_results.py``; ``--docs PATH`` also writes it there, e.g.
   ``docs/results.md``, with the screenshot beside it): the budget per family (minutes, steps
   reached, device, threads), success per task (mean with [min, max] over seeds) beside the
   shipped oracle and the two baselines, the oracle-normalised means, the action-conditioning
   ratios, the metrics, the study's correlations, the screenshot and the command; with
   ``--notes FILE``, a "Reading" section that links FILE (what the numbers say, written by
   hand, e.g. ``docs/findings/model-comparison.md``). Every number in it is read from the
   files the stages wrote. Study, report and page are rewritten after every run that planned
   trials (the baselines run first), so a build cut short publishes what it finished and
   names the runs still pending.

Layout of ``--out``::

    comparison.json              the settings and the command of the latest invocation
    log.jsonl                    one line per stage and invocation: found done, or ran
    train/<model>/, <model>.json a `vp2 train` run directory and its record once done
    conditioning/<family>.json   action conditioning
    diagnose/<name>.json         `vp2 diagnose`: its report and the settings it was made with
    zoo/<label>.json             the card of an extra model from the zoo (`zoo:NAME`)
    metrics/<name>/metrics.json  `vp2 metrics`
    runs/<name>/                 `vp2 run` directories (trials.jsonl, summary, GIFs, report)
    study/                       `vp2 study`: study.md, study.json, scatter plots
    report.html, report.png      `vp2 report` of every run, and its screenshot
    results.md                   the page

``--records DIR`` keeps the small outputs of each part (compact trial records, metrics,
diagnoses, conditioning) in ``DIR/<env>/`` (e.g. ``results/comparison``, committed) and
restores from there what ``--out`` lacks (:mod:`benchmarks.comparison.records`): a machine
that lost ``--out`` rebuilds the page and resumes the runs after their last recorded trial.

Every output is written atomically and records the settings it was made with; an invocation
with other settings for an existing output stops with a message (use another ``--out``)
rather than mixing results. Runs and metrics name a family's final checkpoint *file*, so a
retrained model cannot meet the trials of its predecessor. ``--smoke`` is a tiny
configuration for the end-to-end test (``tests/scripts/test_model_comparison.py``). On a CPU
shared with other work pass ``--threads 1`` (docs/models.md: two threads stalled each other).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import datetime
import json
import logging
import os
import shutil
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import torch

import vp2
from benchmarks import common
from benchmarks.comparison import records as evidence
from benchmarks.comparison.model_comparison_results import (
    combined_markdown,
    relative_link,
    results_markdown,
)
from vp2.benchmark.runner import RunResult, run_benchmark
from vp2.data.storage import DatasetError, load_manifest
from vp2.diagnose.model import DiagnoseConfig, diagnose_model, measure_conditioning
from vp2.envs import env_class
from vp2.metrics.evaluate import DEFAULT_BATCH_SIZE, evaluate_model, write_metrics
from vp2.metrics.fvd import FrechetVideoDistance
from vp2.planning.config import PlannerConfig
from vp2.report.page import write_report, write_run_report
from vp2.report.study import study
from vp2.report.study_output import write_study
from vp2.run.config import RunConfig
from vp2.run.model_spec import ModelSpec, resolve_model
from vp2.training.checkpoint import list_checkpoints
from vp2.training.config import TrainConfig
from vp2.training.perceptual import MissingWeightsError
from vp2.training.trainer import train
from vp2.utils.io import atomic_path, json_safe, write_json_atomic
from vp2.utils.tensors import resolve_device


@dataclasses.dataclass(frozen=True)
class TrainStage:
    """One model a family trains.

    Attributes:
        model: Registered model name.
        preset: Its size preset.
        overrides: Model config overrides (as ``vp2 train --model-arg``).
        share: Its share of the family's time budget.
        tokenizer: Whether it takes the previous stage's checkpoint as ``tokenizer_checkpoint``
            (MaskViT's transformer).
    """

    model: str
    preset: str
    overrides: tuple[tuple[str, Any], ...] = ()
    share: float = 1.0
    tokenizer: bool = False


#: The families compared and what each trains, in order; the last stage is the predictor
#: that is evaluated. SVG′ is shrunk as the shipped model is (M = K = 0.125, 1.65 M parameters).
FAMILIES: dict[str, tuple[TrainStage, ...]] = {
    "svg_prime": (TrainStage("svg_prime", "m0.25k0.25", (("m", 0.125), ("k", 0.125))),),
    "fitvid": (TrainStage("fitvid", "mini"),),
    "struct_vrnn": (TrainStage("struct_vrnn", "small"),),
    "mcvd": (TrainStage("mcvd", "tiny"),),
    "maskvit": (
        TrainStage("maskvit_tokenizer", "tiny", share=1 / 3),
        TrainStage("maskvit", "tiny", share=2 / 3, tokenizer=True),
    ),
}
#: The baselines run beside the families (label -> run settings); only repeat-last-frame
#: predicts frames, so only it has metrics.
BASELINES: dict[str, dict[str, Any]] = {
    "repeat_last_frame": {"model": "repeat_last_frame"},
    "random": {"model": "none", "agent": "random", "save_gifs": False},
}
#: Steps of a budgeted training run: far more than any budget buys, so the budget ends it.
STEP_CAP = 10_000_000


@dataclasses.dataclass(frozen=True)
class Settings:
    """The comparison's settings (from the command line, :func:`settings_from_args`; the flag
    of each field has its name, e.g. ``--num-samples``). ``device`` is resolved (``cpu``,
    ``cuda``), ``threads`` is torch's thread count, ``command`` rebuilds the comparison."""

    out: Path
    data: Path
    docs: Path | None  # where the page is also published (None: only under out)
    notes: Path | None  # Markdown file the page links in its "Reading" section
    publish_only: bool  # rebuild study, report and page from what is on disk; run nothing
    budget_minutes: float
    families: tuple[str, ...]
    extras: tuple[tuple[str, str], ...]  # (label, model spec): evaluated, not trained here
    tasks: tuple[str, ...]
    num_instances: int
    seeds: tuple[int, ...]
    seeds_for: tuple[tuple[str, tuple[int, ...]], ...]  # (run, seeds): fewer seeds for a run
    num_samples: int
    num_steps: int
    batch_size: int
    device: str  # resolved: "cpu", "cuda", "cuda:1", ...
    threads: int
    workers: int  # trial processes of `vp2 run`
    loader_workers: int  # DataLoader processes of `vp2 train`
    eval_interval: int
    eval_batches: int
    ckpt_interval: int
    log_interval: int
    metrics_clips: int
    lpips: tuple[str, ...]
    fvd: bool
    conditioning_clips: int
    conditioning_samples: int
    diagnose_clips: int | None  # None: vp2 diagnose's default (what its predictor was fitted on)
    diagnose_instances: int | None  # instances per task probed; None: vp2 diagnose's default
    skip_train: bool
    smoke: bool
    command: str
    records: Path | None = None  # this part's committed evidence (benchmarks.comparison.records)

    def seeds_of(self, name: str) -> tuple[int, ...]:
        """The control-run seeds of run ``name``: ``--seeds``, unless ``--seeds-for`` gives
        it fewer (a slow model's runs on a subset)."""
        return dict(self.seeds_for).get(name, self.seeds)

    def run_order(self) -> list[str]:
        """The order the runs go in: the baselines (minutes), the extra models, the families."""
        return [*BASELINES, *dict(self.extras), *self.families]

    def table_names(self) -> list[str]:
        """Every run, in the order of the page's columns and the report's runs."""
        return [*self.families, *dict(self.extras), *BASELINES]

    def predictor_names(self) -> list[str]:
        """What predicts frames, so has metrics: families, extra models, repeat-last-frame."""
        return [*self.families, *dict(self.extras), "repeat_last_frame"]


# --------------------------------------------------------------------------- bookkeeping


class StageLog:
    """``log.jsonl``: one line per stage and invocation (what was found done, what ran)."""

    def __init__(self, out: Path):
        self.path = out / "log.jsonl"
        self.invocation = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")

    def add(self, stage: str, name: str, status: str, **extra: Any) -> None:
        line = {"invocation": self.invocation, "stage": stage, "name": name, "status": status}
        line.update(extra)
        print(f"[{stage}] {name}: {status} {json.dumps(extra) if extra else ''}", flush=True)
        with self.path.open("a") as f:  # one short line per write: a kill loses at most it
            f.write(json.dumps(line) + "\n")


def done_record(path: Path, settings: dict[str, Any]) -> dict[str, Any] | None:
    """The record at ``path`` if a stage completed it with ``settings``; ``None`` if absent.

    Raises:
        ValueError: it was made with other settings (results would mix).
    """
    if not path.is_file():
        return None
    record = json.loads(path.read_text())
    saved = record.get("settings") or {}
    settings = json_safe(settings)
    if saved != settings:
        changed = sorted(k for k in {**saved, **settings} if saved.get(k) != settings.get(k))
        raise ValueError(
            f"{path} was made with other settings ({', '.join(changed)}: "
            f"{[saved.get(k) for k in changed]} vs now {[settings.get(k) for k in changed]}); "
            "use another --out or delete it"
        )
    return record


def device_name(device: str) -> str:
    """The device in words: the GPU's name, or the CPU's model and core count."""
    if device.startswith("cuda"):
        return f"{device} ({torch.cuda.get_device_name(torch.device(device))})"
    return f"cpu ({common.cpu_name()}, {os.cpu_count()} cores)"


# --------------------------------------------------------------------------- a. training


def train_config(s: Settings, stage: TrainStage, tokenizer: str | None) -> TrainConfig:
    """The ``vp2 train`` run of one stage of a family."""
    overrides = dict(stage.overrides)
    if stage.tokenizer:
        overrides["tokenizer_checkpoint"] = tokenizer
    return TrainConfig(
        model=stage.model,
        preset=stage.preset,
        model_overrides=overrides,
        dataset=str(s.data),
        out_dir=str(s.out / "train" / stage.model),
        steps=STEP_CAP,
        max_minutes=s.budget_minutes * stage.share,
        batch_size=s.batch_size,
        seed=0,
        eval_interval=s.eval_interval,
        eval_batches=s.eval_batches,
        ckpt_interval=s.ckpt_interval,
        log_interval=s.log_interval,
        workers=s.loader_workers,
        device=s.device,
        tensorboard=False,
        progress=sys.stderr.isatty(),
        resume=True,
    )


def _train_settings(config: TrainConfig) -> dict[str, Any]:
    """What makes a training record reusable: everything that changes the weights."""
    keys = ("model", "preset", "model_overrides", "dataset", "batch_size", "seed", "max_minutes")
    return {k: getattr(config, k) for k in keys}


def train_stage(s: Settings, config: TrainConfig, stage_log: StageLog) -> dict[str, Any]:
    """Trains (or resumes, or finds done) one model; returns its record."""
    path = Path(config.out_dir).with_suffix(".json")
    settings = _train_settings(config)
    record = done_record(path, settings)
    if record is not None and (record.get("complete") or s.skip_train):
        stage_log.add("train", config.model, "done earlier", step=record["step"])
        return record
    if s.skip_train:
        # Evaluate whatever the run directory holds (e.g. trained elsewhere and copied here).
        existing = list_checkpoints(config.out_dir)
        if not existing:
            raise FileNotFoundError(f"--skip-train: no checkpoint in {config.out_dir}")
        payload = torch.load(existing[-1], map_location="cpu", weights_only=True)
        found = _train_settings(TrainConfig.from_dict(payload["train_config"]))
        if json_safe(found) != json_safe(settings):
            raise ValueError(
                f"--skip-train: {existing[-1]} was trained with {found}, this comparison asks "
                f"for {settings}"
            )
        seconds = float(payload.get("train_seconds", 0.0))
        budget_reached = seconds >= 60 * config.max_minutes
        record = {
            "step": int(payload["step"]),
            "train_minutes": seconds / 60,
            "budget_reached": budget_reached,
            "checkpoint": str(existing[-1]),
            # An unfinished run taken as it is: a later invocation without --skip-train
            # continues its training.
            "complete": budget_reached,
            "note": "--skip-train: the newest checkpoint, as found",
        }
        stage_log.add("train", config.model, "skipped (--skip-train)", step=record["step"])
    else:
        resumed = bool(list_checkpoints(config.out_dir))
        result = train(config)
        record = {
            "step": result.step,
            "train_minutes": result.train_minutes,
            "budget_reached": result.budget_reached,
            "checkpoint": str(result.checkpoint),
            "complete": True,
        }
        stage_log.add("train", config.model, "resumed" if resumed else "trained", step=result.step)
    run_record = json.loads((Path(config.out_dir) / "config.json").read_text())
    record.update(
        settings=settings,
        budget_minutes=config.max_minutes,
        parameters=run_record.get("parameters"),
        # A run found as it is says only the torch device it trained on.
        device=f"{run_record['device']} (elsewhere)" if s.skip_train else device_name(s.device),
        threads=None if s.skip_train else torch.get_num_threads(),
    )
    write_json_atomic(path, json_safe(record))
    return record


def train_family(s: Settings, family: str, stage_log: StageLog) -> list[dict[str, Any]]:
    """Trains a family's stages in order; returns their records (the last is the predictor)."""
    records: list[dict[str, Any]] = []
    for stage in FAMILIES[family]:
        tokenizer = records[-1]["checkpoint"] if stage.tokenizer else None
        records.append(train_stage(s, train_config(s, stage, tokenizer), stage_log))
    return records


def model_spec(family: str, records: Sequence[dict[str, Any]]) -> str:
    """The family's ``NAME:CHECKPOINT`` spec: its final checkpoint *file*, so that runs and
    metrics made with another checkpoint of the same run directory are refused, not mixed."""
    return f"{FAMILIES[family][-1].model}:{records[-1]['checkpoint']}"


# --------------------------------------------------------------------------- b. conditioning


def conditioning_stage(s: Settings, family: str, spec: str, stage_log: StageLog) -> None:
    """True versus shuffled actions on held-out clips, measured as ``vp2 diagnose`` measures
    them (:func:`vp2.diagnose.model.measure_conditioning`, seed 0: the same clips and
    shuffle): ``conditioning/<family>.json``."""
    path = s.out / "conditioning" / f"{family}.json"
    settings = {
        "model": spec,
        "data": str(s.data),
        "clips": s.conditioning_clips,
        "samples": s.conditioning_samples,
        "measure": "vp2.diagnose.model.measure_conditioning",
    }
    if done_record(path, settings) is not None:
        stage_log.add("conditioning", family, "done earlier")
        return
    started = time.perf_counter()
    device = torch.device(s.device)
    env = load_manifest(s.data).get("config", {}).get("env", "robodesk")
    model = resolve_model(spec, {}, env=env, action_dim=int(env_class(env).action_dim),
                          device=device)
    result = measure_conditioning(model, s.data, s.conditioning_clips,
                                  s.conditioning_samples, 0, device)
    record = {"settings": settings, **result, "seconds": time.perf_counter() - started}
    write_json_atomic(path, json_safe(record))
    stage_log.add("conditioning", family, "ran", ratio=record["ratio"])


def write_zoo_cards(s: Settings) -> list[Path]:
    """The card of each extra model from the zoo (``zoo:NAME``, checked against its
    checkpoint), as ``zoo/<label>.json``: the page's budget row reads it. Returns the files."""
    written = []
    for label, spec in s.extras:
        parsed = ModelSpec.parse(spec)
        if parsed.kind == "zoo":
            parsed.check()
            path = s.out / "zoo" / f"{label}.json"
            write_json_atomic(path, json_safe(parsed.zoo.to_json()))
            written.append(path)
    return written


def diagnose_stage(s: Settings, name: str, spec: str, stage_log: StageLog) -> Path:
    """``vp2 diagnose`` of one model: ``diagnose/<name>.json`` holds ``settings`` and the
    diagnose ``report``. Clips and probed instances stay at diagnose's defaults unless the
    settings give them (``--smoke``), since its predicted score was fitted at those."""
    path = s.out / "diagnose" / f"{name}.json"
    env = load_manifest(s.data).get("config", {}).get("env", "robodesk")
    fields = {"clips": s.diagnose_clips, "instances_per_task": s.diagnose_instances}
    fields = {k: v for k, v in fields.items() if v is not None}
    config = DiagnoseConfig(
        model=spec, env=env, data=str(s.data), num_samples=s.num_samples, device=s.device,
        progress=sys.stderr.isatty(), **fields,
    )  # fmt: skip
    settings = {
        "model": spec, "data": str(s.data), "env": env, "num_samples": s.num_samples,
        "clips": config.clips, "instances_per_task": config.instances_per_task,
        "sampling_seeds": config.sampling_seeds, "seed": config.seed,
    }  # fmt: skip
    if done_record(path, settings) is not None:
        stage_log.add("diagnose", name, "done earlier")
        return path
    partial = path.with_name(f"{path.stem}.partial.json")  # a stopped diagnosis goes on from it
    report = diagnose_model(config, partial=partial)
    write_json_atomic(path, json_safe({"settings": settings, "report": report}))
    partial.unlink(missing_ok=True)
    stage_log.add(
        "diagnose", name, "ran", predicted=report.get("predicted_control_score"),
        seconds=report["timing"]["total_s"],
    )  # fmt: skip
    return path


# --------------------------------------------------------------------------- c. metrics


def shared_fvd(s: Settings) -> FrechetVideoDistance | None:
    """One FVD metric for every model's ``vp2 metrics``, so the held-out clips' I3D features
    are computed once (``FrechetVideoDistance.reference_features``); ``None`` when FVD is off
    or its weights are absent (each model's metrics then say why FVD was skipped)."""
    if not s.fvd:
        return None
    try:
        return FrechetVideoDistance(device=s.device, batch_size=DEFAULT_BATCH_SIZE)
    except MissingWeightsError:
        return None


def metrics_stage(
    s: Settings,
    name: str,
    spec: str,
    stage_log: StageLog,
    fvd_metric: FrechetVideoDistance | None = None,
) -> Path:
    """``vp2 metrics`` of one model: ``metrics/<name>/metrics.json`` (``fvd_metric``: one
    shared by the models, see :func:`shared_fvd`)."""
    path = s.out / "metrics" / name / "metrics.json"
    settings = {
        "model": spec,
        "data": str(s.data),
        "num_clips": s.metrics_clips,
        "seed": 0,
        "lpips": list(s.lpips),
        "fvd": s.fvd,
    }
    if path.is_file():
        done = json.loads(path.read_text())
        if done.get("comparison_settings") != settings:
            raise ValueError(f"{path} was made with other settings; use another --out or delete it")
        # FVD skipped for want of its weights, which are here now: measure again
        if not ("fvd" in done.get("skipped", {}) and fvd_metric is not None):
            stage_log.add("metrics", name, "done earlier")
            return path
    result = evaluate_model(
        spec,
        s.data,
        num_clips=s.metrics_clips,
        seed=0,
        batch_size=DEFAULT_BATCH_SIZE,
        lpips_nets=s.lpips,
        fvd=s.fvd,
        device=s.device,
        progress=sys.stderr.isatty(),
        fvd_metric=fvd_metric,
    )
    result["comparison_settings"] = settings
    write_metrics(path, result)
    stage_log.add(
        "metrics", name, "ran", mse=result["metrics"]["mse"], skipped=list(result["skipped"])
    )
    return path


# --------------------------------------------------------------------------- d. runs


def run_config(s: Settings, name: str, spec: str | None) -> RunConfig:
    """The ``vp2 run`` of a family (``spec``) or of a baseline (:data:`BASELINES`)."""
    shared: dict[str, Any] = dict(
        out=str(s.out / "runs" / name),
        tasks=s.tasks,
        num_instances=s.num_instances,
        seeds=s.seeds_of(name),
        planner=PlannerConfig(num_samples=s.num_samples),
        num_steps=s.num_steps,
        workers=s.workers,
        device=s.device,
        resume=True,  # a fresh directory starts, an existing one runs only its missing trials
        progress=sys.stderr.isatty(),
    )
    if spec is not None:
        return RunConfig(model=spec, **shared)
    baseline = dict(BASELINES[name])
    if baseline.get("agent") == "random":
        shared["planner"] = PlannerConfig()  # plans nothing: no planner setting departs from SPEC
    return RunConfig(**baseline, **shared)


def runs_stage(s: Settings, name: str, spec: str | None, stage_log: StageLog) -> RunResult:
    config = run_config(s, name, spec)
    result = run_benchmark(config, after_run=write_run_report)
    status = "ran" if result.num_run else "done earlier"
    stage_log.add(
        "run",
        name,
        status,
        num_run=result.num_run,
        num_skipped=result.num_skipped,
        trials=len(result.records),
        errors=result.num_errors,
    )
    return result


# --------------------------------------------------------------------------- e./f. study, report


def screenshot(html: Path, png: Path, width: int = 1200) -> str | None:
    """A PNG of the report down to its trial videos (headless Chromium over the DevTools pipe
    of ``tests/report/headless.py``); returns why not, or ``None`` when written."""
    try:
        from tests.report.headless import Browser, find_chromium
    except ImportError as exc:
        return f"no screenshot: tests/report/headless.py could not be imported ({exc})"
    executable = find_chromium()
    if executable is None:
        return "no screenshot: Chromium is not on PATH"
    try:
        with Browser(executable, width=width, height=1000) as browser:
            browser.open(html)
            # The page above the gallery: the runs, success chart and table, normalised
            # scores and the study (the GIF gallery below would make it megabytes).
            height = browser.evaluate(
                "(() => { const h = [...document.querySelectorAll('h2')]"
                ".find(e => e.textContent === 'Trial videos');"
                " return h ? h.getBoundingClientRect().top + window.scrollY"
                " : document.body.scrollHeight; })()"
            )
            image = browser.screenshot(
                {"x": 0, "y": 0, "width": width, "height": min(height, 12000)}
            )
    except (OSError, RuntimeError, TimeoutError) as exc:
        return f"no screenshot: Chromium failed ({exc!r})"
    with atomic_path(png) as tmp:
        tmp.write_bytes(image)
    return None


# --------------------------------------------------------------------------- the driver


def write_build_record(s: Settings) -> None:
    """``comparison.json``: what ``results.md`` reads besides the stages' files (the settings,
    and what was compared)."""
    record = {
        **dataclasses.asdict(s),
        "family_stages": {
            f: [
                {**dataclasses.asdict(stage), "budget_minutes": s.budget_minutes * stage.share}
                for stage in FAMILIES[f]
            ]
            for f in s.families
        },
        "extra_models": dict(s.extras),
        "run_names": s.table_names(),
        "metrics_names": s.predictor_names(),
        "vp2_version": vp2.__version__,
        "torch_version": torch.__version__,
    }
    write_json_atomic(s.out / "comparison.json", json_safe(record))


def run_comparison(s: Settings, after_publish: Callable[[], object] | None = None) -> Path:
    """Runs (or resumes) every stage; returns the path of ``results.md``. ``after_publish`` is
    called each time the page is rewritten (a comparison of several environments rewrites its
    combined page there, so a build that spans sessions shows what it finished)."""
    if s.publish_only:
        return publish_found(s)
    published = after_publish or (lambda: None)
    s.out.mkdir(parents=True, exist_ok=True)
    stage_log = StageLog(s.out)
    if s.records is not None:
        restored = evidence.restore(s.records, s.out)
        if any(restored.values()):
            stage_log.add("records", str(s.records), "restored", **restored)
    write_build_record(s)
    write_zoo_cards(s)
    train_records = {f: train_family(s, f, stage_log) for f in s.families}
    specs = {f: model_spec(f, records) for f, records in train_records.items()}
    specs.update(s.extras)
    for family, spec in specs.items():
        conditioning_stage(s, family, spec, stage_log)
    predictors = {**specs, "repeat_last_frame": "repeat_last_frame"}
    for name, spec in predictors.items():
        diagnose_stage(s, name, spec, stage_log)
    fvd_metric = shared_fvd(s)  # loading the I3D takes a second, even when all is done
    metrics_files = {
        name: metrics_stage(s, name, spec, stage_log, fvd_metric)
        for name, spec in predictors.items()
    }
    save_records(s)
    # The baselines first (minutes), then the extra models, then the families in the order
    # given: the page is rewritten after every run that planned trials, so a build cut short
    # (a session's end) still publishes what it finished, and says what is pending.
    order = s.run_order()
    run_dirs: dict[str, Path] = {}
    for name in order:
        result = runs_stage(s, name, specs.get(name), stage_log)
        run_dirs[name] = result.run_dir
        save_records(s)
        pending = [n for n in order if n not in run_dirs]
        if pending and result.num_run:
            publish(s, run_dirs, metrics_files, stage_log, pending)
            published()
    page = publish(s, run_dirs, metrics_files, stage_log, [])
    published()
    return page


def save_records(s: Settings) -> None:
    """Copies what the part measured so far into its records (``--records``), if any."""
    if s.records is not None:
        evidence.save(s.out, s.records)


def publish_found(s: Settings) -> Path:
    """``--publish-only``: the study, report and page of the runs finished under ``s.out``
    (those with a ``summary.json``), for the families and extra models the build recorded in
    ``comparison.json``; nothing is trained, measured or planned, and the recorded command
    stays the build's."""
    recorded = s.out / "comparison.json"
    if not recorded.is_file():
        raise ValueError(f"--publish-only: {recorded} does not exist; run the comparison first")
    if s.records is not None:
        evidence.restore(s.records, s.out)
    build = json.loads(recorded.read_text())
    s = dataclasses.replace(
        s,
        families=tuple(build["families"]),
        extras=tuple((k, v) for k, v in build.get("extra_models", {}).items()),
    )
    order = s.run_order()
    run_dirs = {n: s.out / "runs" / n for n in order}
    run_dirs = {n: d for n, d in run_dirs.items() if (d / "summary.json").is_file()}
    if not run_dirs:
        raise ValueError(f"--publish-only: no finished run under {s.out / 'runs'}")
    metrics_files = {n: s.out / "metrics" / n / "metrics.json" for n in s.predictor_names()}
    metrics_files = {n: p for n, p in metrics_files.items() if p.is_file()}
    pending = [n for n in order if n not in run_dirs]
    return publish(s, run_dirs, metrics_files, StageLog(s.out), pending)


def _notes_link(s: Settings, page: Path) -> str | None:
    """The link from ``page`` to the ``--notes`` file, ``None`` without one."""
    return None if s.notes is None else relative_link(s.notes, page)


def publish(
    s: Settings,
    run_dirs: dict[str, Path],
    metrics_files: dict[str, Path],
    stage_log: StageLog,
    pending: list[str],
) -> Path:
    """The study, the report (and its screenshot) and ``results.md`` of the runs finished so
    far (``run_dirs``); ``pending`` names the runs not yet finished. Returns ``results.md``."""
    study_dir = s.out / "study"
    entries = [(n, run_dirs[n], path) for n, path in metrics_files.items() if n in run_dirs]
    if entries:
        write_study(study(entries), study_dir)
        stage_log.add("study", "all", "written", entries=len(entries))
    else:  # runs finished beside a build still measuring metrics (--publish-only meanwhile)
        shutil.rmtree(study_dir, ignore_errors=True)
        stage_log.add("study", "all", "waits", why="no finished run has its metrics yet")
    labels = [n for n in s.table_names() if n in run_dirs]
    report = write_report(
        [run_dirs[n] for n in labels],
        s.out / "report.html",
        metrics={str(run_dirs[n]): path for n, path in metrics_files.items() if n in run_dirs},
        labels=labels,
        title="vp2 model comparison: " + ", ".join(labels),
    )
    shot_note = screenshot(report, s.out / "report.png")
    stage_log.add("report", "all", "written", screenshot=shot_note or "report.png")
    path = s.out / "results.md"
    written = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    with atomic_path(path) as tmp:
        tmp.write_text(results_markdown(s.out, shot_note, pending, notes=_notes_link(s, path),
                                        written=written))
    if s.docs is not None:  # the published copy, its screenshot beside it
        image = s.docs.with_name(s.docs.stem + "-report.png")
        if shot_note is None:
            with atomic_path(image) as tmp:
                tmp.write_bytes((s.out / "report.png").read_bytes())
        with atomic_path(s.docs) as tmp:
            notes = _notes_link(s, s.docs)
            tmp.write_text(results_markdown(s.out, shot_note, pending, image.name, notes,
                                            written))
    stage_log.add("results", "all", "written", pending=pending)
    return path


#: The defaults of the flags that --smoke changes: the comparison the issue asks for.
FULL = dict(
    budget_minutes=60.0, tasks=["robodesk"], num_instances=3, seeds=[0, 1], num_samples=50,
    num_steps=15, batch_size=32, eval_batches=4, eval_interval=1000, ckpt_interval=500,
    log_interval=50, metrics_clips=1000, lpips=["alex", "vgg"], fvd=True,
    conditioning_clips=128, conditioning_samples=3, loader_workers=2, diagnose_clips=None,
    diagnose_instances=None,
)  # fmt: skip
#: What ``--smoke`` sets (unless given on the command line): a run of minutes on a CPU.
SMOKE = dict(
    budget_minutes=0.1, tasks=["robodesk/push_red"], num_instances=1, seeds=[0], num_samples=8,
    num_steps=3, batch_size=4, eval_batches=1, eval_interval=0, ckpt_interval=0, log_interval=5,
    metrics_clips=8, lpips=[], fvd=False, conditioning_clips=8, conditioning_samples=1,
    loader_workers=0, diagnose_clips=4, diagnose_instances=0,
)  # fmt: skip


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog=common.prog(__spec__.name),
        description=__doc__.splitlines()[0],
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    # `None` defaults are filled by settings_from_args, from FULL (or SMOKE with --smoke).
    p.add_argument("--out", type=Path, default=Path("outputs/comparison"))
    p.add_argument(
        "--docs",
        type=Path,
        help="also write the page here (e.g. docs/results.md), its screenshot beside it",
    )
    p.add_argument(
        "--data",
        type=Path,
        action="append",
        help="dataset directory (default data/robodesk-300x-64px); once per environment to "
        "compare extra models on both (each dataset's environment from its manifest)",
    )
    p.add_argument("--budget-minutes", type=float, help="training minutes per family (default 60)")
    p.add_argument(
        "--families",
        nargs="*",
        choices=list(FAMILIES),
        default=list(FAMILIES),
        help="families to train and compare (default: all five; none: only --extra models)",
    )
    p.add_argument("--tasks", nargs="+", help="task categories or env (default: robodesk)")
    p.add_argument("--num-instances", type=int, help="first instances of each task (default 3)")
    p.add_argument("--seeds", type=int, nargs="+", help="control-run seeds (default: 0 1)")
    p.add_argument("--num-samples", type=int, help="planner samples (default 50)")
    p.add_argument("--num-steps", type=int, help="control steps per trial (default: SPEC 15)")
    p.add_argument("--batch-size", type=int, help="training batch (default 32)")
    p.add_argument("--device", default="auto", help="auto (CUDA if present), cpu, cuda, ...")
    p.add_argument("--threads", type=int, help="torch threads (default: torch's)")
    p.add_argument("--workers", type=int, default=1, help="trial processes of vp2 run")
    p.add_argument("--loader-workers", type=int, help="data loader processes (default 2)")
    p.add_argument("--eval-interval", type=int, help="validation every N steps (default 1000)")
    p.add_argument("--eval-batches", type=int, help="validation batches (default 4)")
    p.add_argument("--ckpt-interval", type=int, help="checkpoint every N steps (default 500)")
    p.add_argument("--log-interval", type=int, help="log every N steps (default 50)")
    p.add_argument("--metrics-clips", type=int, help="clips of vp2 metrics (default 1000)")
    p.add_argument("--lpips", nargs="*", help="LPIPS nets (default: alex vgg, if weights exist)")
    p.add_argument("--no-fvd", action="store_true", help="skip FVD")
    p.add_argument("--conditioning-clips", type=int, help="held-out clips (default 128)")
    p.add_argument("--conditioning-samples", type=int, help="sampling seeds (default 3)")
    p.add_argument(
        "--skip-train",
        action="store_true",
        help="train nothing: evaluate the newest checkpoint of each training run",
    )
    p.add_argument(
        "--notes",
        type=Path,
        help="a Markdown file the page links in its 'Reading' section (e.g. "
        "docs/findings/model-comparison.md: what the numbers say, kept apart from the "
        "generated page)",
    )
    p.add_argument(
        "--publish-only",
        action="store_true",
        help="train, measure and plan nothing: rebuild the study, report and page from the "
        "finished runs under --out (e.g. to add --notes)",
    )
    p.add_argument(
        "--extra",
        action="append",
        default=[],
        metavar="LABEL=MODEL",
        help="also evaluate this model (any --model spec of vp2 run, e.g. a checkpoint trained "
        "elsewhere) beside the families, outside the training budget; repeatable",
    )
    p.add_argument(
        "--seeds-for",
        action="append",
        default=[],
        metavar="RUN=SEEDS",
        help="control-run seeds of one run, a subset of --seeds, comma-separated (e.g. "
        "mcvd=0: a slow model planned with one seed); the page says so; repeatable",
    )
    p.add_argument(
        "--records",
        type=Path,
        help="keep the comparison's evidence here (e.g. results/comparison, committed): "
        "compact trial records, metrics, diagnoses, one folder per environment; a build "
        "restores from it what --out lacks (benchmarks/comparison/records.py)",
    )
    p.add_argument("--smoke", action="store_true", help="a tiny configuration (tests)")
    return p.parse_args(argv)


def parse_extras(items: Sequence[str], families: Sequence[str]) -> tuple[tuple[str, str], ...]:
    """``LABEL=MODEL`` items -> ``((label, model), ...)``.

    Raises:
        ValueError: an item without ``=``, an empty side, or a label that is already taken.
    """
    taken = {*families, *BASELINES}
    extras: list[tuple[str, str]] = []
    for item in items:
        label, sep, spec = item.partition("=")
        label, spec = label.strip(), spec.strip()
        if not sep or not label or not spec:
            raise ValueError(f"--extra {item!r}: expected LABEL=MODEL, e.g. shipped=svg_prime:model.pt")
        if label in taken:
            raise ValueError(f"--extra {item!r}: the label {label!r} is already used; pick another")
        taken.add(label)
        extras.append((label, spec))
    return tuple(extras)


def parse_seeds_for(
    items: Sequence[str], names: Sequence[str], seeds: Sequence[int]
) -> tuple[tuple[str, tuple[int, ...]], ...]:
    """``RUN=S[,S...]`` items -> ``((run, seeds), ...)``; ``names`` are the runs there are.

    Raises:
        ValueError: an item that is not ``RUN=SEEDS``, a run there is not, a run given twice,
            or seeds that are not integers of ``--seeds``.
    """
    out: dict[str, tuple[int, ...]] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        try:
            chosen = tuple(int(x) for x in value.split(",") if x.strip())
        except ValueError:
            chosen = ()
        if not sep or not name or not chosen:
            raise ValueError(f"--seeds-for {item!r}: expected RUN=SEEDS, e.g. mcvd=0 or mcvd=0,1")
        if name not in names:
            raise ValueError(
                f"--seeds-for {item!r}: no run {name!r} in this comparison; the runs are "
                f"{', '.join(names)}"
            )
        if name in out:
            raise ValueError(f"--seeds-for {item!r}: {name} is given seeds twice; give it once")
        outside = sorted(set(chosen) - set(seeds))
        if outside:
            raise ValueError(
                f"--seeds-for {item!r}: seed(s) {outside} are not among --seeds "
                f"{' '.join(map(str, seeds))}; a run may only drop seeds, so its column "
                "compares with the others on the seeds they share"
            )
        out[name] = tuple(sorted(set(chosen)))
    return tuple(out.items())


def settings_from_args(args: argparse.Namespace, argv: Sequence[str]) -> Settings:
    """The settings of a command line (``argv``, recorded as the command that rebuilds the
    results); sets torch's thread count if ``--threads`` is given."""
    defaults = SMOKE if args.smoke else FULL
    value = {k: getattr(args, k) if getattr(args, k, None) is not None else v
             for k, v in defaults.items()}  # fmt: skip
    if args.no_fvd:
        value["fvd"] = False
    if args.notes is not None and not args.notes.is_file():
        raise ValueError(f"--notes {args.notes}: no such file")
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    device = str(resolve_device(None if args.device == "auto" else args.device))
    command = common.command_line(__spec__.name, argv)
    extras = parse_extras(args.extra, args.families)
    names = [*args.families, *dict(extras), *BASELINES]
    seeds = tuple(value["seeds"])
    return Settings(
        out=args.out,
        data=args.data,
        docs=args.docs,
        notes=args.notes,
        publish_only=args.publish_only,
        budget_minutes=float(value["budget_minutes"]),
        families=tuple(args.families),
        extras=extras,
        tasks=tuple(value["tasks"]),
        num_instances=value["num_instances"],
        seeds=seeds,
        seeds_for=parse_seeds_for(args.seeds_for, names, seeds),
        num_samples=value["num_samples"],
        num_steps=value["num_steps"],
        batch_size=value["batch_size"],
        device=device,
        threads=torch.get_num_threads(),
        workers=args.workers,
        loader_workers=value["loader_workers"],
        eval_interval=value["eval_interval"],
        eval_batches=value["eval_batches"],
        ckpt_interval=value["ckpt_interval"],
        log_interval=value["log_interval"],
        metrics_clips=value["metrics_clips"],
        lpips=tuple(value["lpips"]),
        fvd=bool(value["fvd"]),
        conditioning_clips=value["conditioning_clips"],
        conditioning_samples=value["conditioning_samples"],
        diagnose_clips=value["diagnose_clips"],
        diagnose_instances=value["diagnose_instances"],
        skip_train=args.skip_train,
        smoke=args.smoke,
        command=command,
        records=None if args.records is None else args.records / dataset_env(args.data),
    )


#: The dataset of a comparison that names none.
DEFAULT_DATA = Path("data/robodesk-300x-64px")


def dataset_env(data: Path) -> str:
    """The environment a dataset was collected in (its manifest's), with a clear error."""
    try:
        manifest = load_manifest(data)
    except DatasetError as exc:
        raise ValueError(f"--data {data}: {exc}") from exc
    return str(manifest.get("config", {}).get("env", "robodesk"))


def extra_env(label: str, spec: str, envs: Sequence[str]) -> tuple[str, str]:
    """``(label without its @ENV, env)`` of an extra model in a comparison over ``envs``: the
    environment after ``@`` in its label, else its zoo card's.

    Raises:
        ValueError: neither says, or the environment has no dataset here.
    """
    label, _, env = label.partition("@")
    if not env:
        parsed = ModelSpec.parse(spec)
        if parsed.kind != "zoo":
            raise ValueError(
                f"--extra {label}={spec}: with a dataset per environment, say which "
                f"environment it plans in: --extra {label}@ENV={spec} (ENV: {', '.join(envs)})")
        env = parsed.zoo.env
    if env not in envs:
        raise ValueError(f"--extra {label}={spec}: it plans in {env}, and no --data is a {env} "
                         f"dataset (the datasets' environments: {', '.join(envs)})")
    return label, env


def part_settings(args: argparse.Namespace, argv: Sequence[str],
                  datasets: Sequence[Path]) -> list[Settings]:
    """One :class:`Settings` per ``--data`` (per environment): its extra models, its tasks of
    ``--tasks``, ``--out/<env>``; the page (``--docs``) is written by :func:`run_parts`.

    Raises:
        ValueError: families to train, two datasets of one environment, or an extra model or
            task of an environment with no dataset.
    """
    if args.families:
        raise ValueError(
            "several --data: this compares models trained elsewhere (--extra, e.g. the zoo's) "
            "on each environment; train families with one --data (add --families with no "
            "family)")
    envs = [dataset_env(d) for d in datasets]
    if len(set(envs)) < len(envs):
        raise ValueError(f"--data: two datasets of one environment ({', '.join(envs)}); give "
                         "one per environment")
    placed = [(*extra_env(*item.partition("=")[::2], envs), item) for item in args.extra]
    tasks = args.tasks or list(envs)
    stray = [t for t in tasks if t.split("/")[0] not in envs]
    if stray:
        raise ValueError(f"--tasks {' '.join(stray)}: no --data of that environment")
    parts = []
    for env, data in zip(envs, datasets, strict=True):
        part = copy.copy(args)
        part.data, part.docs, part.out = data, None, args.out / env
        part.extra = [f"{label}={item.partition('=')[2]}" for label, e, item in placed if e == env]
        part.tasks = [t for t in tasks if t.split("/")[0] == env]
        settings = settings_from_args(part, argv)
        if not settings.extras:
            raise ValueError(f"--data {data}: no --extra model plans in {env}; drop the dataset "
                             "or add a model")
        parts.append(settings)
    return parts


def run_parts(parts: Sequence[Settings], args: argparse.Namespace) -> Path:
    """Each environment's comparison in turn, and the page with a part per environment
    (``--docs``, else ``--out/results.md``), rewritten whenever a part rewrites its own: a
    build cut short (a session's end) leaves a page of what it finished. Returns the page."""
    for part in parts:
        run_comparison(part, after_publish=lambda: write_parts_page(parts, args))
    return write_parts_page(parts, args)


def write_parts_page(parts: Sequence[Settings], args: argparse.Namespace) -> Path:
    """The page of the parts that have started (their ``comparison.json`` exists), with each
    part's report screenshot beside it (copied next to ``--docs``). Returns the page."""
    page = args.docs or args.out / "results.md"
    parts = [p for p in parts if (p.out / "comparison.json").is_file()]
    outs = [p.out for p in parts]
    shots = {}
    for part in parts:
        shot = part.out / "report.png"
        if args.docs is not None and shot.is_file():
            image = page.with_name(f"{page.stem}-{part.out.name}-report.png")
            with atomic_path(image) as tmp:
                tmp.write_bytes(shot.read_bytes())
            shots[part.out] = image.name
        else:
            shots[part.out] = relative_link(shot, page) if shot.is_file() else None
    notes = None if args.notes is None else relative_link(args.notes, page)
    with atomic_path(page) as tmp:
        tmp.write_text(combined_markdown(outs, shots, notes))
    return page


def main(argv: Sequence[str] | None = None) -> None:
    argv = list(sys.argv[1:] if argv is None else argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        args = parse_args(argv)
        datasets = args.data or [DEFAULT_DATA]
        if len(datasets) == 1:
            args.data = datasets[0]
            parts = [settings_from_args(args, argv)]
        else:
            parts = part_settings(args, argv, datasets)
    except ValueError as exc:
        sys.exit(f"model_comparison.py: {exc}")
    for part in parts:
        print(f"model comparison -> {part.out} ({part.device}, {part.threads} threads)")
    try:
        path = run_comparison(parts[0]) if len(parts) == 1 else run_parts(parts, args)
    except ValueError as exc:  # settings that do not fit what is on disk, said plainly
        sys.exit(f"model_comparison.py: {exc}")
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
