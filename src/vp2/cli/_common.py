"""Flags and helpers shared by several ``vp2`` commands."""

from __future__ import annotations

import argparse


def make_executor_from_args(args: argparse.Namespace):
    """The executor of a data command's ``--executor``/``--address``/... flags."""
    from vp2.utils.executors import make_executor

    return make_executor(args.executor, workers=args.workers, address=args.address,
                         num_cpus_per_worker=args.num_cpus_per_worker,
                         num_gpus_per_worker=args.num_gpus_per_worker)


def add_executor_flags(p: argparse.ArgumentParser, gpus_default: float = 0.0) -> None:
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
