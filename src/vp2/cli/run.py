"""``vp2 run``: evaluate a model by planning with it on the task suite (docs/benchmark.md)."""

from __future__ import annotations

import argparse

from vp2.cli._common import add_executor_flags
from vp2.spec import GAMMA, MIN_SEEDS, NUM_CONTROL_STEPS

NAME = "run"
HELP = "evaluate a model by planning with it on the task suite (docs/benchmark.md)"
DESCRIPTION = (
    "Evaluate a video prediction model by planning with it on the task suite. One flag per "
    "vp2.benchmark.RunConfig field (docs/benchmark.md)."
)


RUN_OPTIMIZERS = ["mppi", "cem", "cem_gd", "lbfgs"]


def run_config_from_args(args: argparse.Namespace):
    """The :class:`vp2.benchmark.RunConfig` of parsed ``vp2 run`` arguments."""
    from vp2.benchmark.config import RunConfig
    from vp2.benchmark.model_spec import parse_model_args

    if args.model is None and args.agent == "planning":
        raise ValueError("--model is required with --agent planning (e.g. --model repeat_last_frame)")
    config = RunConfig(
        model=args.model or "none",
        out=args.out,
        model_args=parse_model_args(args.model_arg),
        agent=args.agent,
        suite=args.suite,
        tasks=tuple(args.tasks or ()),
        num_instances=args.num_instances,
        seeds=tuple(args.seeds),
        optimizer=args.optimizer,
        num_samples=args.num_samples,
        gamma=args.gamma,
        num_iterations=args.num_iterations,
        cost=args.cost,
        num_steps=args.num_steps,
        stop_on_success=args.stop_on_success,
        workers=args.workers,
        executor=args.executor,
        address=args.address,
        num_cpus_per_worker=args.num_cpus_per_worker,
        num_gpus_per_worker=args.num_gpus_per_worker,
        device=args.device,
        max_retries=args.max_retries,
        resume=args.resume,
        retry_errors=args.retry_errors,
        save_gifs=not args.no_gifs,
        save_predictions=args.save_predictions,
        oracle=args.oracle,
        progress=not args.no_progress,
    )
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
    """Adds the ``vp2 run`` arguments to ``p``."""
    p.add_argument("--model", help="model spec: simulator | repeat_last_frame | NAME:CHECKPOINT "
                   "| package.module:factory | file.yaml (with _target_); modules are also "
                   "looked up in the current directory (docs/benchmark.md, 'Plugins')")
    p.add_argument("--out", required=True, help="run directory")
    p.add_argument("--model-arg", action="append", default=[], metavar="KEY=VALUE",
                   help="model factory argument, repeatable; VALUE parsed as YAML (for a "
                   "checkpoint: an inference setting, e.g. sampling_steps=10)")
    p.add_argument("--agent", choices=["planning", "random"], default="planning")
    p.add_argument("--suite", help="task suite file (default: the shipped suite)")
    p.add_argument("--tasks", nargs="+", help="task names or env names (default: all)")
    p.add_argument("--num-instances", type=int, help="first K instances per task (default: all)")
    p.add_argument("--seeds", type=int, nargs="+", default=list(range(MIN_SEEDS)))
    p.add_argument("--optimizer", choices=RUN_OPTIMIZERS, default="mppi")
    p.add_argument("--num-samples", type=int, help="planner samples (default: SPEC, 200/800)")
    p.add_argument("--gamma", type=float, default=GAMMA, help="MPPI inverse temperature")
    p.add_argument("--num-iterations", type=int, help="planner iterations per step")
    p.add_argument("--cost", choices=["auto", "spec", "pixel_only"], default="auto")
    p.add_argument("--num-steps", type=int, default=NUM_CONTROL_STEPS, help="control steps per trial")
    p.add_argument("--stop-on-success", action="store_true")
    p.add_argument("--workers", type=int, default=1, help="trial processes (Ray: actors)")
    add_executor_flags(p)
    p.add_argument("--device", help="torch device (default: CUDA if available)")
    p.add_argument("--max-retries", type=int, default=1)
    p.add_argument("--resume", action="store_true", help="continue the run directory")
    p.add_argument("--retry-errors", action="store_true", help="with --resume: re-run errors")
    p.add_argument("--no-gifs", action="store_true", help="no per-trial GIFs")
    p.add_argument("--save-predictions", action="store_true",
                   help="also a GIF of the chosen plans' predictions")
    p.add_argument("--oracle", help="simulator-oracle run directory to normalise scores by "
                   "(default: the shipped oracle, vp2/assets/oracle.json or $VP2_ORACLE_ASSET)")
    p.add_argument("--no-progress", action="store_true")
    return p
