"""``vp2 run``: evaluate a model by planning with it on the task suite (docs/evaluation.md)."""

from __future__ import annotations

import argparse

from vp2.cli._common import executor_flags
from vp2.cli._fields import NOT_A_FLAG, Flag, add_flags, build
from vp2.run.config import AGENTS, RunConfig
from vp2.run.model_spec import parse_model_args

NAME = "run"
HELP = "evaluate a model by planning with it on the task suite (docs/evaluation.md)"
DESCRIPTION = (
    "Evaluate a video prediction model by planning with it on the task suite. One flag per "
    "vp2.benchmark.RunConfig field (docs/evaluation.md)."
)


RUN_OPTIMIZERS = ["mppi", "cem", "cem_gd", "lbfgs"]
#: The argument group of the settings only some optimizers read (a run that sets one its
#: optimizer does not read is refused, ``vp2.planning.planner.check_optimizer_fields``).
PLANNER_GROUP = "settings of cem, cem_gd and lbfgs (default: the optimizer's own)"

#: One entry per :class:`~vp2.run.config.RunConfig` field (the planner's nested ones as
#: ``planner.*``), in the order of ``vp2 run --help``. Literal choices: listing the
#: optimizers and cost modes from the planner would import torch.
FLAGS: dict[str, Flag | None] = {
    "model": Flag(
        help="model spec: simulator | repeat_last_frame | NAME:CHECKPOINT | zoo:NAME (vp2 zoo "
        "list) | package.module:factory | file.yaml (with _target_) | 'ensemble(SPEC,SPEC,...)' "
        "(two or more of these, planned with the SPEC's ensemble cost; quote it in a shell); "
        "modules are also looked up in the current directory (docs/evaluation.md, 'Plugins')"
    ),
    "out": Flag(required=True, help="run directory"),
    "model_args": Flag(
        "--model-arg",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="model factory argument, repeatable; VALUE parsed as YAML (for a checkpoint: an "
        "inference setting, e.g. sampling_steps=10)",
        convert=parse_model_args,
    ),
    "agent": Flag(choices=list(AGENTS)),
    "suite": Flag(help="task suite file (default: the shipped suite)"),
    "tasks": Flag(help="task names or env names (default: all)"),
    "num_instances": Flag(help="first K instances per task (default: all)"),
    "seeds": Flag(),
    "planner.optimizer": Flag(choices=RUN_OPTIMIZERS),
    "planner.num_samples": Flag(help="planner samples (default: SPEC, 200/800)"),
    "planner.gamma": Flag(help="MPPI inverse temperature"),
    "planner.num_iterations": Flag(
        help="planner iterations per step (default: the optimizer's: mppi 1, cem and cem_gd 3)"
    ),
    **{f"planner.{field}": Flag(group=PLANNER_GROUP, help=text) for field, text in {
        "num_elites": "cem, cem_gd: samples the distribution is refitted to (default 10)",
        "num_samples_first": "cem_gd: samples per CEM iteration on a trial's first planning step "
                             "(default 500; --num-samples sets the later steps', default 50)",
        "num_refined": "cem_gd: best CEM samples refined by gradient steps (default 1)",
        "lr": "cem_gd: Adam step size of the refinement (default 0.01); lbfgs: step length "
              "(default 0.05; the paper tuned 0.001, 0.01, 0.05, 0.07)",
        "grad_steps": "cem_gd: most accepted gradient steps per refined sequence (default 15); "
                      "lbfgs: LBFGS.step calls per planning step (default 100)",
    }.items()},
    "planner.sigma": NOT_A_FLAG,
    "planner.options": NOT_A_FLAG,
    "cost": Flag(choices=["auto", "spec", "pixel_only"]),
    "num_steps": Flag(help="control steps per trial"),
    "stop_on_success": Flag(),
    "workers": Flag(help="trial processes (Ray: actors)"),
    **executor_flags(),
    "device": Flag(help="torch device (default: CUDA if available)"),
    "max_retries": Flag(help="extra attempts of a trial that ended in an error (not of a "
                         "timeout)"),
    "trial_timeout": Flag(
        metavar="SECONDS",
        help="wall-clock limit of a trial attempt (default: none); a trial past it is recorded "
        "as an error naming the limit and the run goes on; not retried at once: "
        "--resume --retry-errors runs it again",
    ),
    "resume": Flag(help="continue the run directory"),
    "retry_errors": Flag(help="with --resume: re-run errors"),
    "save_gifs": Flag("--no-gifs", negate=True, help="no per-trial GIFs"),
    "save_predictions": Flag(help="also a GIF of the chosen plans' predictions"),
    "oracle": Flag(
        help="simulator-oracle run directory to normalise scores by (default: the shipped "
        "oracle's table of the run's planner samples, vp2/assets/oracle.json or $VP2_ORACLE_ASSET)"
    ),
    "progress": Flag("--no-progress", negate=True),
    "precheck": Flag(
        "--no-precheck",
        negate=True,
        help="skip the check, before the first trial of a learned model, that its predictions "
        "depend on the actions (a few held-out clips of the default dataset; see vp2 diagnose)",
    ),
}


def run_config_from_args(args: argparse.Namespace) -> RunConfig:
    """The :class:`vp2.benchmark.RunConfig` of parsed ``vp2 run`` arguments (validated)."""
    if args.model is None and args.agent == "planning":
        raise ValueError("--model is required with --agent planning (e.g. --model repeat_last_frame)")
    config = build(RunConfig, args, FLAGS, model=args.model or "none")
    config.validate()
    return config


def run_from_args(args: argparse.Namespace) -> int:
    from vp2.benchmark.runner import run_benchmark
    from vp2.report.page import write_run_report

    result = run_benchmark(run_config_from_args(args), after_run=write_run_report)
    print(result.table)
    print(f"\nrun directory: {result.run_dir}  ({result.num_run} trials run, "
          f"{result.num_skipped} already done, {result.num_errors} errors)")
    return 1 if result.num_errors else 0


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 run`` arguments to ``p`` (one per :data:`FLAGS` entry)."""
    add_flags(p, RunConfig, FLAGS)
    return p
