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

The stages live in modules of their own; this one holds the command line and the split by
environment: :mod:`~benchmarks.comparison.model_comparison_settings` (what is compared, the
settings, ``log.jsonl``), ``model_comparison_train`` (a.), ``model_comparison_conditioning``
(b.: conditioning and diagnose), ``model_comparison_metrics`` (c.), ``model_comparison_runs``
(d.), ``model_comparison_publish`` (e.–g.), ``model_comparison_build`` (every stage in order)
and ``model_comparison_results`` with ``model_comparison_sections`` (the page's text).
"""

from __future__ import annotations

import argparse
import copy
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

import torch

from benchmarks import common
from benchmarks.comparison.model_comparison_build import (
    run_comparison,
    save_records,
    write_build_record,
    write_zoo_cards,
)
from benchmarks.comparison.model_comparison_conditioning import conditioning_stage, diagnose_stage
from benchmarks.comparison.model_comparison_metrics import metrics_stage, shared_fvd
from benchmarks.comparison.model_comparison_publish import publish, publish_found, screenshot
from benchmarks.comparison.model_comparison_results import combined_markdown, relative_link
from benchmarks.comparison.model_comparison_runs import run_config, runs_stage
from benchmarks.comparison.model_comparison_settings import (
    BASELINES,
    DEFAULT_DATA,
    FAMILIES,
    STEP_CAP,
    Settings,
    StageLog,
    TrainStage,
    dataset_env,
    device_name,
    done_record,
    extra_env,
    parse_extras,
    parse_seeds_for,
)
from benchmarks.comparison.model_comparison_train import (
    model_spec,
    train_config,
    train_family,
    train_stage,
)
from vp2.utils.io import atomic_path
from vp2.utils.tensors import resolve_device

#: The names this module has always offered (the stages' live in their modules now).
__all__ = [
    "BASELINES", "DEFAULT_DATA", "FAMILIES", "FULL", "SMOKE", "STEP_CAP", "Settings", "StageLog",
    "TrainStage", "conditioning_stage", "dataset_env", "device_name", "diagnose_stage",
    "done_record", "extra_env", "main", "metrics_stage", "model_spec", "parse_args",
    "parse_extras", "parse_seeds_for", "part_settings", "publish", "publish_found", "run_config",
    "run_comparison", "run_parts", "runs_stage", "save_records", "screenshot", "settings_from_args",
    "shared_fvd", "train_config", "train_family", "train_stage", "write_build_record",
    "write_parts_page", "write_zoo_cards",
]  # fmt: skip


#: The defaults of the flags that --smoke changes: the full comparison.
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
