"""What every executor shares: the interface, the lost-worker error and the live item queue."""

from __future__ import annotations

import abc
import collections
from collections.abc import Callable, Iterable, Iterator
from typing import Any, Generic, TypeVar

T = TypeVar("T")
R = TypeVar("R")

EXECUTORS: tuple[str, ...] = ("local", "ray")


class WorkerLost(RuntimeError):
    """An item's worker (a process, a Ray actor or its node) died every time the item ran."""

    def __init__(self, item: Any, attempts: int, cause: BaseException | None = None) -> None:
        super().__init__(
            f"the worker running an item died {attempts} time(s) (killed, node lost, segfault "
            f"or out of memory){f': {cause}' if cause else ''}"
        )
        self.item = item
        self.attempts = attempts


class Executor(abc.ABC):
    """Runs ``fn`` over independent items in workers and streams the results back.

    Executors are context managers; :meth:`close` releases their workers.
    """

    #: ``"local"`` or ``"ray"``.
    name: str

    @abc.abstractmethod
    def imap_unordered(
        self,
        fn: Callable[[T], R],
        items: Iterable[T],
        initializer: Callable[..., Any] | None = None,
        initargs: tuple[Any, ...] = (),
        on_lost: str = "raise",
    ) -> Iterator[tuple[T, Any]]:
        """Yields ``(item, fn(item))`` as results finish, in any order.

        ``initializer(*initargs)`` runs once in each worker before its first item (it sets
        up per-process state that ``fn`` uses). Exceptions raised by ``fn`` propagate. An
        item whose worker died: ``on_lost="raise"`` fails the map, ``on_lost="yield"`` yields
        ``(item, WorkerLost(...))`` and goes on (see the implementations for who is charged).
        """

    @abc.abstractmethod
    def close(self) -> None:
        """Releases the workers (idempotent)."""

    def __enter__(self) -> Executor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def check_on_lost(on_lost: str) -> None:
    if on_lost not in ("raise", "yield"):
        raise ValueError(f"on_lost must be 'raise' or 'yield', got {on_lost!r}")


class LiveQueue(Generic[T]):
    """Iterator over the items, then whatever the consumer puts into ``added`` while
    iterating (the benchmark runner's retries). An executor polls it again after every
    result, so it may run dry and fill up again."""

    def __init__(self, items: Iterable[T], added: collections.deque[T]) -> None:
        self.items = collections.deque(items)
        self.added = added

    def __iter__(self) -> LiveQueue[T]:
        return self

    def __next__(self) -> T:
        if self.added:
            self.items.extend(self.added)
            self.added.clear()
        if not self.items:
            raise StopIteration
        return self.items.popleft()
