"""The ``vp2`` command line. Thin: it parses arguments and calls library functions.

Run ``vp2 --help`` or ``vp2 <command> --help``.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

from vp2.data.collect import DEFAULT_TRAJECTORIES

RUN_OPTIMIZERS = ["mppi", "cem", "cem_gd", "lbfgs"]


def _cmd_main(args: argparse.Namespace) -> int:
    from vp2.benchmark.main_job import MainJobConfig, run_main_job

    config = MainJobConfig(out=args.out, num_instances=args.num_instances,
                           seeds=tuple(args.seeds), tasks=tuple(args.tasks or ()),
                           model_samples=args.model_samples or None, workers=args.workers,
                           agents=tuple(args.agents), resume=not args.fresh)
    if args.fresh and Path(args.out).exists():
        raise FileExistsError(f"{args.out} exists; remove it or drop --fresh to resume it")
    table, path = run_main_job(config)
    print(f"\n{table}\n\nresults: {path}  (run directories next to it; "
          f"contact sheet of the tasks: {Path(args.out) / 'tasks.png'})")
    return 0


def _executor(args: argparse.Namespace):
    """The executor of a data command's ``--executor``/``--address``/... flags."""
    from vp2.utils.executors import make_executor

    return make_executor(args.executor, workers=args.workers, address=args.address,
                         num_cpus_per_worker=args.num_cpus_per_worker,
                         num_gpus_per_worker=args.num_gpus_per_worker)


def _add_executor_flags(p: argparse.ArgumentParser, gpus_default: float = 0.0) -> None:
    p.add_argument("--executor", choices=["local", "ray"], default="local",
                   help="where work runs: local worker processes, or a Ray cluster "
                        "(docs/scale-out.md)")
    p.add_argument("--address", default=None,
                   help="with --executor ray: 'auto' or the head's HOST:PORT (default: a "
                        "private Ray instance on this machine, on loopback)")
    p.add_argument("--num-cpus-per-worker", type=float, default=1.0,
                   help="with --executor ray: CPUs each actor reserves")
    p.add_argument("--num-gpus-per-worker", type=float, default=gpus_default,
                   help="with --executor ray: GPUs each actor reserves (fractions allowed)")


def _cmd_collect(args: argparse.Namespace) -> int:
    from vp2.data.collect import CollectionConfig, collect

    n = args.num_trajectories or DEFAULT_TRAJECTORIES[args.env]
    config = CollectionConfig(
        env=args.env,
        trajectories_per_stream=n,
        streams=tuple(args.streams) if args.streams else None,
        image_size=args.image_size,
        seed=args.seed,
        chunk_size=args.chunk_size,
        render=not args.states_only,
    )
    out = args.out or f"data/{args.env}-{n}x-" + ("states" if args.states_only else f"{args.image_size}px")
    with _executor(args) as executor:
        root = collect(config, out, workers=args.workers, executor=executor)
    print(f"dataset: {root} ({config.total} trajectories)")
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    from vp2.data.render import rerender

    out = args.out or f"{str(args.dataset).rstrip('/')}-{args.size}px"
    with _executor(args) as executor:
        root = rerender(args.dataset, out, args.size, workers=args.workers, executor=executor)
    print(f"dataset: {root}")
    return 0


def _cmd_tasks(args: argparse.Namespace) -> int:
    from vp2.data import suite as suite_lib

    if args.tasks_command == "generate":
        counts = dict(suite_lib.SUITE_COUNTS)
        if args.tasks:
            counts = {t: counts[t] for t in args.tasks}
        if args.count:
            counts = dict.fromkeys(counts, args.count)
        with _executor(args) as executor:
            suite = suite_lib.generate_suite(counts, seed=args.seed, workers=args.workers,
                                             executor=executor)
        out = Path(args.out)
        suite.save(out)
        print(f"task suite: {out} ({len(suite)} instances)")
        return 0
    suite = suite_lib.TaskSuite.load(args.suite)
    if args.tasks_command == "list":
        for task in suite.tasks:
            insts = suite.for_task(task)
            steps = [len(i.actions) for i in insts]
            print(f"{task:34s} {len(insts):3d} instances  scripted steps to goal: "
                  f"min {min(steps)} / mean {sum(steps) / len(steps):.1f} / max {max(steps)}")
        print(f"total: {len(suite)} instances")
        return 0
    # show
    from vp2.data.suite_view import suite_contact_sheet

    png = suite_contact_sheet(suite, args.task, args.out, max_instances=args.max)
    print(f"contact sheet: {png}")
    return 0


def run_config_from_args(args: argparse.Namespace):
    """The :class:`vp2.benchmark.RunConfig` of parsed ``vp2 run`` arguments."""
    from vp2.benchmark.runner import RunConfig, parse_model_args

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


def _cmd_run(args: argparse.Namespace) -> int:
    from vp2.benchmark.runner import run_benchmark

    result = run_benchmark(run_config_from_args(args))
    print(result.table)
    print(f"\nrun directory: {result.run_dir}  ({result.num_run} trials run, "
          f"{result.num_skipped} already done, {result.num_errors} errors)")
    return 1 if result.num_errors else 0


def _add_run_parser(sub: argparse._SubParsersAction) -> None:
    # Literal defaults and choices (importing the runner here would import torch for every
    # command); tests/test_cli.py checks them against RunConfig, AGENTS and OPTIMIZERS.
    p = sub.add_parser(
        "run", help="evaluate a model by planning with it on the task suite (docs/benchmark.md)",
        description="Evaluate a video prediction model by planning with it on the task suite. "
                    "One flag per vp2.benchmark.RunConfig field (docs/benchmark.md).")
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
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--optimizer", choices=RUN_OPTIMIZERS, default="mppi")
    p.add_argument("--num-samples", type=int, help="planner samples (default: SPEC, 200/800)")
    p.add_argument("--gamma", type=float, default=0.05, help="MPPI inverse temperature")
    p.add_argument("--num-iterations", type=int, help="planner iterations per step")
    p.add_argument("--cost", choices=["auto", "spec", "pixel_only"], default="auto")
    p.add_argument("--num-steps", type=int, default=15, help="control steps per trial")
    p.add_argument("--stop-on-success", action="store_true")
    p.add_argument("--workers", type=int, default=1, help="trial processes (Ray: actors)")
    _add_executor_flags(p)
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
    p.set_defaults(fn=_cmd_run)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="vp2", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("main", help="the README's main job: a small evaluation on the defaults",
                       description="Evaluates the shipped small model and the trivial baselines "
                                   "on the first instance of every task category "
                                   "(vp2.benchmark.main_job). Re-running resumes.")
    p.add_argument("--out", default="outputs/main", help="output directory")
    p.add_argument("--num-instances", type=int, default=1, help="instances per task category")
    p.add_argument("--seeds", type=int, nargs="+", default=[0], help="control-run seeds")
    p.add_argument("--tasks", nargs="+", help="task categories or env names (default: all)")
    p.add_argument("--model-samples", type=int, default=50,
                   help="planner samples for the learned model (0: SPEC, 200/800)")
    p.add_argument("--workers", type=int, default=2, help="trial processes")
    p.add_argument("--agents", nargs="+", default=["model", "repeat_last_frame", "random"],
                   choices=["model", "repeat_last_frame", "random"])
    p.add_argument("--fresh", action="store_true", help="refuse an existing output directory")
    p.set_defaults(fn=_cmd_main)

    p = sub.add_parser("collect", help="collect scripted trajectories into a dataset")
    p.add_argument("env", choices=sorted(DEFAULT_TRAJECTORIES), help="environment")
    p.add_argument("-n", "--num-trajectories", type=int, default=None,
                   help="trajectories per data stream (default: robodesk 20 per task, tabletop 100; "
                        "paper scale: robodesk 5000, tabletop 50000)")
    p.add_argument("--streams", nargs="+", help="data streams (default: all of the env's)")
    p.add_argument("--out", help="dataset directory (default: data/<env>-<n>x-<size>px)")
    p.add_argument("--image-size", type=int, default=64)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--chunk-size", type=int, default=10, help="trajectories per shard")
    p.add_argument("--states-only", action="store_true",
                   help="store states, actions and labels but no images (physics only; add "
                        "the images later with `vp2 render DATASET --size 64`)")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes (default: cores; Ray: as many actors as fit)")
    _add_executor_flags(p)
    p.set_defaults(fn=_cmd_collect)

    p = sub.add_parser("render", help="re-render a dataset at another resolution")
    p.add_argument("dataset", type=Path)
    p.add_argument("--size", type=int, required=True)
    p.add_argument("--out", help="output dataset (default: <dataset>-<size>px)")
    p.add_argument("--workers", type=int, default=None)
    _add_executor_flags(p)
    p.set_defaults(fn=_cmd_render)

    p = sub.add_parser("tasks", help="the task suite: generate, list, show")
    tsub = p.add_subparsers(dest="tasks_command", required=True)
    g = tsub.add_parser("generate", help="generate a task suite with fixed seeds")
    g.add_argument("--out", default="task_suite.npz")
    g.add_argument("--seed", type=int, default=2023)
    g.add_argument("--tasks", nargs="+", help="only these task categories")
    g.add_argument("--count", type=int, help="instances per category (default: SPEC §2)")
    g.add_argument("--workers", type=int, default=None)
    _add_executor_flags(g)
    lst = tsub.add_parser("list", help="instances per task category")
    lst.add_argument("--suite", help="suite file (default: the shipped suite)")
    show = tsub.add_parser("show", help="contact sheet of start and goal images")
    show.add_argument("task", help="task category, e.g. robodesk/push_red")
    show.add_argument("--suite", help="suite file (default: the shipped suite)")
    show.add_argument("--out", default=None, help="PNG path (default: outputs/tasks/<task>.png)")
    show.add_argument("--max", type=int, default=12, help="instances to show")
    p.set_defaults(fn=_cmd_tasks)

    _add_run_parser(sub)

    from vp2.benchmark import classifiers, report, shipped_oracle, study
    from vp2.metrics import evaluate as metrics_command
    from vp2.training import command as train_command

    _add_module_command(
        sub, "train", train_command,
        "train a video prediction model on a collected dataset",
        "Train a video prediction model on a collected dataset (docs/models.md). Continue a "
        "run with the same command and --resume.")
    _add_module_command(
        sub, "train-classifier", classifiers,
        "train RoboDesk success classifiers",
        "Train the per-task RoboDesk success classifiers of the planning cost on a collected "
        "dataset (docs/benchmark.md).")
    _add_module_command(
        sub, "metrics", metrics_command,
        "perceptual metrics of a model on held-out clips",
        "MSE, PSNR, SSIM, LPIPS and FVD of a model's predictions on a fixed, seeded set of "
        "held-out clips (docs/metrics.md).")
    _add_module_command(
        sub, "report", report,
        "self-contained HTML report of one or more runs",
        "Writes one self-contained HTML page: success per task and model, normalised scores, "
        "the study when metrics exist, trial videos (docs/report.md).")
    _add_module_command(
        sub, "ship-oracle", shipped_oracle,
        "build the shipped oracle (the default normaliser) from simulator-oracle runs",
        "Reads finished simulator-oracle run directories and writes the per-task success "
        "rates that vp2 run, main and report normalise scores by when no --oracle is given "
        "(docs/benchmark.md, 'The shipped oracle').")
    _add_module_command(
        sub, "study", study,
        "perceptual metrics versus control success",
        "Table 1 of the paper and rank correlations between each metric and success over "
        "several models (docs/report.md).")
    return parser


def _add_module_command(sub, name: str, module, help: str, description: str) -> None:
    """A sub-command whose module brings its own ``configure_parser`` and ``run_from_args``."""
    p = sub.add_parser(name, help=help, description=description)
    module.configure_parser(p)
    p.set_defaults(fn=module.run_from_args)


def main(argv: Sequence[str] | None = None) -> int:
    from vp2.data.storage import DatasetError

    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    logging.getLogger("OpenGL").setLevel(logging.WARNING)
    try:
        return args.fn(args)
    except (ValueError, FileExistsError, FileNotFoundError, DatasetError) as exc:
        print(f"vp2 {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except RuntimeError as exc:
        from vp2.benchmark.runner import ModelFailure

        if not isinstance(exc, ModelFailure):
            raise
        print(f"vp2 {args.command}: error: {exc}", file=sys.stderr)
        return 3


if __name__ == "__main__":
    sys.exit(main())
