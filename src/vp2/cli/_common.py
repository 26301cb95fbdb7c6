"""Flags and helpers shared by several ``vp2`` commands."""

from __future__ import annotations

import argparse

from vp2.cli._fields import Flag, add_flags
from vp2.utils.executors.base import EXECUTORS


def make_executor_from_args(args: argparse.Namespace):
    """The executor of a data command's ``--executor``/``--address``/... flags."""
    from vp2.utils.executors import make_executor

    return make_executor(args.executor, workers=args.workers, address=args.address,
                         num_cpus_per_worker=args.num_cpus_per_worker,
                         num_gpus_per_worker=args.num_gpus_per_worker)


def executor_flags(*, cli_only: bool = False, gpus_default: float = 0.0) -> dict[str, Flag]:
    """The flags of where work runs: fields of a config (``vp2 run``'s RunConfig; defaults from
    its fields) or, ``cli_only``, a data command's own flags (these defaults)."""

    def own(default: object, kind: type | None = None) -> dict[str, object]:
        return {"default": default, "type": kind, "cli_only": True} if cli_only else {}

    return {
        "executor": Flag(
            choices=EXECUTORS,
            help="where work runs: local worker processes, or a Ray cluster (docs/scale-out.md)",
            **own("local"),
        ),
        "address": Flag(
            help="with --executor ray: 'auto' or the head's HOST:PORT (default: a private Ray "
            "instance on this machine, on loopback)",
            **own(None),
        ),
        "num_cpus_per_worker": Flag(
            help="with --executor ray: CPUs each actor reserves", **own(1.0, float)
        ),
        "num_gpus_per_worker": Flag(
            help="with --executor ray: GPUs each actor reserves (fractions allowed)",
            **own(gpus_default, float),
        ),
    }


def add_executor_flags(p: argparse.ArgumentParser, gpus_default: float = 0.0) -> None:
    """Adds the executor flags of a data command (:func:`executor_flags`, its own flags)."""
    add_flags(p, None, executor_flags(cli_only=True, gpus_default=gpus_default))
