"""``vp2 collect``: scripted trajectories into a dataset (docs/data.md)."""

from __future__ import annotations

import argparse

from vp2.cli._common import executor_flags, make_executor_from_args
from vp2.cli._fields import NOT_A_FLAG, Flag, add_flags, build
from vp2.data.collect import DEFAULT_TRAJECTORIES, CollectionConfig

NAME = "collect"
HELP = "collect scripted trajectories into a dataset"
DESCRIPTION = None


#: One entry per :class:`~vp2.data.collect.CollectionConfig` field (and the command's own
#: flags), in the order of ``vp2 collect --help``.
FLAGS: dict[str, Flag | None] = {
    "env": Flag("env", choices=sorted(DEFAULT_TRAJECTORIES), help="environment"),
    "trajectories_per_stream": Flag(
        "--num-trajectories",
        short="-n",
        help="trajectories per data stream (default: robodesk 20 per task, tabletop 100; "
        "paper scale: robodesk 5000, tabletop 50000)",
    ),
    "streams": Flag(help="data streams (default: all of the env's)"),
    "out": Flag(cli_only=True, help="dataset directory (default: data/<env>-<n>x-<size>px)"),
    "image_size": Flag(),
    "seed": Flag(),
    "horizon": NOT_A_FLAG,
    "chunk_size": Flag(help="trajectories per shard"),
    "valid_every": Flag(
        help="hold out every Nth trajectory of the dataset for validation (0: none); must be "
        "coprime with the number of streams, so that every stream has held-out trajectories"
    ),
    "render": Flag(
        "--states-only",
        negate=True,
        help="store states, actions and labels but no images (physics only; add the images "
        "later with `vp2 render DATASET --size 64`)",
    ),
    "workers": Flag(
        cli_only=True,
        type=int,
        default=None,
        help="worker processes (default: cores; Ray: as many actors as fit)",
    ),
    **executor_flags(cli_only=True),
}


def run_from_args(args: argparse.Namespace) -> int:
    from vp2.data.collect import collect

    n = DEFAULT_TRAJECTORIES[args.env] if args.num_trajectories is None else args.num_trajectories
    config = build(CollectionConfig, args, FLAGS, trajectories_per_stream=n)
    out = args.out or f"data/{args.env}-{n}x-" + ("states" if args.states_only else f"{args.image_size}px")
    with make_executor_from_args(args) as executor:
        root = collect(config, out, workers=args.workers, executor=executor)
    print(f"dataset: {root} ({config.total} trajectories)")
    return 0


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 collect`` arguments to ``p`` (one per :data:`FLAGS` entry)."""
    add_flags(p, CollectionConfig, FLAGS)
    return p
