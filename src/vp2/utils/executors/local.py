"""The local executor: ``spawn``-ed worker processes on this machine.

Every item's result must depend only on the item (its seed), never on which worker ran it;
results stream back to the calling process, which alone writes output files.
:func:`spawn_pool` is the one place the package starts a process pool, and
:func:`spawn_manager` the one place it starts a ``multiprocessing`` manager. Every process
either of them starts ends soon after its parent does, however the parent ended
(:func:`watch_parent`): a run killed by SIGKILL or the OOM killer leaves no orphaned workers
holding their models' memory.
"""

from __future__ import annotations

import collections
import multiprocessing as mp
import os
import sys
import threading
import time
from collections.abc import Callable, Hashable, Iterable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from concurrent.futures.process import BrokenProcessPool
from multiprocessing.managers import SyncManager
from typing import Any, TypeVar

from vp2.utils.executors.base import Executor, WorkerLost, check_on_lost

T = TypeVar("T")
R = TypeVar("R")


def default_workers() -> int:
    """Worker processes to use by default: the machine's cores (at least 1)."""
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1)


#: Seconds between a child's checks that its parent is still alive.
PARENT_CHECK_INTERVAL = 1.0


def watch_parent(parent_pid: int, interval: float = PARENT_CHECK_INTERVAL) -> None:
    """Ends this process within ``interval`` seconds of ``parent_pid`` ceasing to be its parent.

    A daemon thread compares ``os.getppid()`` with ``parent_pid`` (an orphan is re-parented,
    so the two differ once the parent is gone, also when it died before this call). Pool
    workers block forever on their task queue when their parent is killed, since they hold
    the queue's writing end themselves; this is what ends them.
    """

    def watch() -> None:
        while os.getppid() == parent_pid:
            time.sleep(interval)
        print(f"vp2: parent process {parent_pid} is gone; process {os.getpid()} exits",
              file=sys.stderr, flush=True)  # fmt: skip
        os._exit(1)

    threading.Thread(target=watch, name="vp2-watch-parent", daemon=True).start()


def _init_child(
    parent_pid: int, initializer: Callable[..., Any] | None, initargs: tuple[Any, ...]
) -> None:
    watch_parent(parent_pid)
    if initializer is not None:
        initializer(*initargs)


def spawn_pool(
    workers: int, initializer: Callable[..., Any] | None = None, initargs: tuple[Any, ...] = ()
) -> ProcessPoolExecutor:
    """A pool of ``workers`` ``spawn``-ed processes (fork is unsafe once a GL context or torch
    threads exist), each set up by ``initializer(*initargs)`` and ended when this process
    ends (:func:`watch_parent`)."""
    return ProcessPoolExecutor(
        max_workers=workers,
        mp_context=mp.get_context("spawn"),
        initializer=_init_child,
        initargs=(os.getpid(), initializer, initargs),
    )


def spawn_manager() -> SyncManager:
    """A started ``spawn``-ed :class:`~multiprocessing.managers.SyncManager` (use it as a
    context manager to shut it down) that ends when this process ends (:func:`watch_parent`)."""
    manager = SyncManager(ctx=mp.get_context("spawn"))
    manager.start(_init_child, (os.getpid(), None, ()))
    return manager


def imap_unordered(
    fn: Callable[[T], R],
    items: Iterable[T],
    workers: int,
    initializer: Callable[..., Any] | None = None,
    initargs: tuple[Any, ...] = (),
) -> Iterator[tuple[T, R]]:
    """Yields ``(item, fn(item))`` as results finish.

    ``workers <= 1`` runs in this process (no start-up cost, easy debugging); otherwise a
    pool of :func:`spawn_pool` processes. At most ``2 * workers`` items are in flight, so
    huge item lists cost no memory. Exceptions raised by ``fn`` propagate to the caller, and
    so does a dead worker (``BrokenProcessPool``).
    """
    if workers <= 1:
        if initializer is not None:
            initializer(*initargs)
        for item in items:
            yield item, fn(item)
        return
    with spawn_pool(workers, initializer, initargs) as pool:
        pending: dict[Future[R], T] = {}
        iterator = iter(items)
        exhausted = False
        while True:
            while not exhausted and len(pending) < 2 * workers:
                try:
                    item = next(iterator)
                except StopIteration:
                    exhausted = True
                    break
                pending[pool.submit(fn, item)] = item
            if not pending:
                return
            done, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in done:
                item = pending.pop(future)
                yield item, future.result()


def imap_isolating(
    fn: Callable[[T], R], items: Iterable[T], workers: int,
    initializer: Callable[..., Any] | None = None, initargs: tuple[Any, ...] = (),
    key: Callable[[T], Hashable] | None = None,
) -> Iterator[tuple[T, R | WorkerLost]]:
    """Like :func:`imap_unordered`, but survives dead workers; yields ``(item, WorkerLost)``
    for an item whose worker died while it ran alone (so the item is to blame).

    When a worker dies, every item in flight fails with it and the culprit is unknown: those
    items are re-run one at a time ("isolated") before the others continue, so an item that
    kills its worker is identified and charged, and its neighbours are not.

    ``items`` is read again at every step, so it may be a live queue that the consumer
    refills while iterating (:class:`~vp2.utils.executors.base.LiveQueue`); an item whose
    ``key`` (default: the item) killed a worker before runs isolated when it comes back.
    """
    key = key or (lambda item: item)
    iterator = iter(items)
    pending: collections.deque[T] = collections.deque()
    suspects: collections.deque[T] = collections.deque()
    killers: set[Hashable] = set()  # keys of items that killed their worker while alone
    pool = spawn_pool(workers, initializer, initargs)
    in_flight: dict[Future[R], tuple[T, bool]] = {}  # future -> (item, running alone)

    def submit(item: T, alone: bool) -> bool:
        # The pool may have broken since the last wait (a worker died in between): then
        # submit raises, and the item waits for the next pool.
        try:
            in_flight[pool.submit(fn, item)] = (item, alone)
        except BrokenProcessPool:
            return False
        return True

    try:
        while True:
            for item in iterator:  # new items (a live queue's refills); a known killer stays alone
                (suspects if key(item) in killers else pending).append(item)
            if not (pending or suspects or in_flight):
                return
            broken = False
            if suspects:
                if not in_flight:
                    item = suspects.popleft()
                    if not submit(item, alone=True):
                        suspects.appendleft(item)
                        broken = True
            else:
                while pending and len(in_flight) < workers:
                    item = pending.popleft()
                    if not submit(item, alone=False):
                        pending.appendleft(item)
                        broken = True
                        break
            if in_flight and not broken:
                done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                for future in done:
                    item, alone = in_flight.pop(future)
                    try:
                        result = future.result()
                    except BrokenProcessPool as exc:
                        broken = True
                        if alone:
                            killers.add(key(item))
                            yield item, WorkerLost(item, 1, exc)
                        else:
                            suspects.append(item)
                    else:
                        yield item, result
            if broken:
                # Every other item in flight failed with the pool (or finished just before).
                for future, (item, _) in list(in_flight.items()):
                    try:
                        result = future.result()
                    except BrokenProcessPool:
                        suspects.append(item)
                    else:
                        yield item, result
                in_flight.clear()
                pool.shutdown(wait=True, cancel_futures=True)
                pool = spawn_pool(workers, initializer, initargs)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


class LocalExecutor(Executor):
    """Worker processes on this machine (``workers <= 1``: this process).

    Args:
        workers: Worker processes; ``None``: one per core. Never more than the items.
    """

    name = "local"

    def __init__(self, workers: int | None = None) -> None:
        self.workers = default_workers() if workers is None else max(1, int(workers))

    def imap_unordered(
        self, fn: Callable[[T], R], items: Iterable[T],
        initializer: Callable[..., Any] | None = None, initargs: tuple[Any, ...] = (),
        on_lost: str = "raise", key: Callable[[T], Hashable] | None = None,
    ) -> Iterator[tuple[T, Any]]:
        """See :meth:`Executor.imap_unordered`.

        ``on_lost="raise"``: a dead worker fails the map (``BrokenProcessPool``), with at most
        ``2 * workers`` items in flight (:func:`imap_unordered`). ``on_lost="yield"``: items
        in flight when a worker died are re-run alone, and one that kills its worker alone is
        yielded with :class:`WorkerLost` (:func:`imap_isolating`, with ``key``); ``items`` is
        then polled again at every step, so it may be a live queue.
        """
        check_on_lost(on_lost)
        workers = self.workers
        if hasattr(items, "__len__"):
            workers = min(workers, max(1, len(items)))  # type: ignore[arg-type]
        if on_lost == "yield" and workers > 1:
            return imap_isolating(fn, items, workers, initializer, initargs, key)
        return imap_unordered(fn, items, workers, initializer=initializer, initargs=initargs)

    def close(self) -> None:
        pass
