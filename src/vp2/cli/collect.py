"""``vp2 collect``: scripted trajectories into a dataset (docs/data.md)."""

from __future__ import annotations

import argparse

from vp2.cli._common import add_executor_flags, make_executor_from_args
from vp2.data.collect import DEFAULT_TRAJECTORIES

NAME = "collect"
HELP = "collect scripted trajectories into a dataset"
DESCRIPTION = None


def run_from_args(args: argparse.Namespace) -> int:
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
    with make_executor_from_args(args) as executor:
        root = collect(config, out, workers=args.workers, executor=executor)
    print(f"dataset: {root} ({config.total} trajectories)")
    return 0


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 collect`` arguments to ``p``."""
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
    add_executor_flags(p)
    return p
