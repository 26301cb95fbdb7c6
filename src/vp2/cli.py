"""The ``vp2`` command line. Thin: it parses arguments and calls library functions.

Run ``vp2 --help`` or ``vp2 <command> --help``.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence
from pathlib import Path

DEFAULT_TRAJECTORIES = {"robodesk": 20, "tabletop": 100}


def _cmd_main(args: argparse.Namespace) -> int:
    from vp2.envs.gallery import render_gallery

    png, previews = render_gallery(args.out, seed=args.seed)
    for p in previews:
        print(p.summary())
    print(f"\ncontact sheet: {png}\nsummary:       {Path(args.out) / 'tasks.txt'}")
    return 0


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
    )
    out = args.out or f"data/{args.env}-{n}x-{args.image_size}px"
    root = collect(config, out, workers=args.workers)
    print(f"dataset: {root} ({config.total} trajectories)")
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    from vp2.data.render import rerender

    out = args.out or f"{str(args.dataset).rstrip('/')}-{args.size}px"
    print(f"dataset: {rerender(args.dataset, out, args.size, workers=args.workers)}")
    return 0


def _cmd_tasks(args: argparse.Namespace) -> int:
    from vp2.data import suite as suite_lib

    if args.tasks_command == "generate":
        counts = dict(suite_lib.SUITE_COUNTS)
        if args.tasks:
            counts = {t: counts[t] for t in args.tasks}
        if args.count:
            counts = dict.fromkeys(counts, args.count)
        suite = suite_lib.generate_suite(counts, seed=args.seed, workers=args.workers)
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="vp2", description=__doc__.splitlines()[0])
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("main", help="the README's main job on its embedded default")
    p.add_argument("--out", default="outputs/main", help="output directory")
    p.add_argument("--seed", type=int, default=0)
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
    p.add_argument("--workers", type=int, default=None, help="worker processes (default: cores)")
    p.set_defaults(fn=_cmd_collect)

    p = sub.add_parser("render", help="re-render a dataset at another resolution")
    p.add_argument("dataset", type=Path)
    p.add_argument("--size", type=int, required=True)
    p.add_argument("--out", help="output dataset (default: <dataset>-<size>px)")
    p.add_argument("--workers", type=int, default=None)
    p.set_defaults(fn=_cmd_render)

    p = sub.add_parser("tasks", help="the task suite: generate, list, show")
    tsub = p.add_subparsers(dest="tasks_command", required=True)
    g = tsub.add_parser("generate", help="generate a task suite with fixed seeds")
    g.add_argument("--out", default="task_suite.npz")
    g.add_argument("--seed", type=int, default=2023)
    g.add_argument("--tasks", nargs="+", help="only these task categories")
    g.add_argument("--count", type=int, help="instances per category (default: SPEC §2)")
    g.add_argument("--workers", type=int, default=None)
    lst = tsub.add_parser("list", help="instances per task category")
    lst.add_argument("--suite", help="suite file (default: the shipped suite)")
    show = tsub.add_parser("show", help="contact sheet of start and goal images")
    show.add_argument("task", help="task category, e.g. robodesk/push_red")
    show.add_argument("--suite", help="suite file (default: the shipped suite)")
    show.add_argument("--out", default=None, help="PNG path (default: outputs/tasks/<task>.png)")
    show.add_argument("--max", type=int, default=12, help="instances to show")
    p.set_defaults(fn=_cmd_tasks)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return args.fn(args)
    except (ValueError, FileExistsError, FileNotFoundError) as exc:
        print(f"vp2 {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
