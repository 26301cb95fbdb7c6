"""Executors: where the independent work items of collection, rendering, suite generation and
benchmark runs execute.

Two backends share one shape, :meth:`Executor.imap_unordered`, which yields ``(item, result)``
as results finish so the calling (driver) process can write them as they come, alone:

* :class:`LocalExecutor` (``--executor local``, the default): ``spawn``-ed worker processes on
  this machine (``local.py``); with ``on_lost="yield"`` a pool that survives dead workers
  and charges a death to the item that caused it.
* :class:`RayExecutor` (``--executor ray --address auto|HOST:PORT``): Ray actors, each holding
  its own per-process state (a simulator, a model replica) built by a per-actor initialiser,
  with declared resources (``num_cpus`` / ``num_gpus`` per actor). An item whose actor or node
  died is re-run on another actor a bounded number of times (``ray_actors.py``).

A result must depend only on its item (its seed), never on which worker ran it; then both
backends give identical results. See docs/scale-out.md.
"""

from __future__ import annotations

from vp2.utils.executors.base import EXECUTORS, Executor, LiveQueue, WorkerLost
from vp2.utils.executors.local import LocalExecutor, default_workers, spawn_manager, spawn_pool
from vp2.utils.executors.ray_actors import RayExecutor


def make_executor(
    kind: str = "local",
    workers: int | None = None,
    address: str | None = None,
    num_cpus_per_worker: float = 1.0,
    num_gpus_per_worker: float = 0.0,
) -> LocalExecutor | RayExecutor:
    """The executor named by the command line's ``--executor`` and its options."""
    if kind == "local":
        if address is not None:
            raise ValueError("--address is for --executor ray")
        return LocalExecutor(workers)
    if kind == "ray":
        return RayExecutor(
            address=address, workers=workers, num_cpus=num_cpus_per_worker,
            num_gpus=num_gpus_per_worker,
        )
    raise ValueError(f"executor must be one of {EXECUTORS}, got {kind!r}")


__all__ = [
    "EXECUTORS",
    "Executor",
    "LiveQueue",
    "LocalExecutor",
    "RayExecutor",
    "WorkerLost",
    "default_workers",
    "make_executor",
    "spawn_manager",
    "spawn_pool",
]
