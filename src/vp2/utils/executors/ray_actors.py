"""The Ray executor: Ray actors, each holding its own per-process state (a simulator, a model
replica) built by a per-actor initialiser, with declared resources (``num_cpus`` / ``num_gpus``
per actor). An item whose actor or node died is re-run on another actor a bounded number of
times. See docs/scale-out.md.
"""

from __future__ import annotations

import collections
import ipaddress
import logging
import math
import os
import sys
from collections.abc import Callable, Iterable, Iterator
from typing import Any, TypeVar

from vp2.utils.executors.base import Executor, WorkerLost, check_on_lost

log = logging.getLogger(__name__)

T = TypeVar("T")
R = TypeVar("R")

#: Ray reads this at import: ``0`` keeps a node's address (and so its ports) on loopback.
_RAY_LOOPBACK_ENV = "RAY_ENABLE_WINDOWS_OR_OSX_CLUSTER"


def _is_loopback(address: str | None) -> bool:
    """Whether ``address`` (``None``, ``"auto"``, ``HOST:PORT``) names this machine's
    loopback; ``"auto"`` is resolved like Ray does (``RAY_ADDRESS``, then the address the
    last ``ray start`` recorded)."""
    if address is None:
        return True
    if address == "auto":
        address = os.environ.get("RAY_ADDRESS")
        if not address:
            recorded = os.path.join(
                os.environ.get("RAY_TMPDIR", "/tmp"), "ray", "ray_current_cluster"
            )
            try:
                with open(recorded) as f:
                    address = f.read().strip()
            except OSError:
                return False
    host = address.split("://")[-1].rsplit(":", 1)[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _keep_ray_on_loopback() -> None:
    """Makes Ray keep ``127.0.0.1`` as this node's address instead of swapping in the
    machine's routable one, so a local instance's servers listen on loopback only and a
    driver can reach a cluster started on loopback.

    Ray decides this from an environment variable read at import (its off switch for
    multi-node clusters, which only the ``ray start --address`` of an extra node checks). A
    value the user set is left alone: that is how one asks for the routable address.
    """
    if _RAY_LOOPBACK_ENV in os.environ:
        return
    os.environ[_RAY_LOOPBACK_ENV] = "0"
    constants = sys.modules.get("ray._private.ray_constants")
    if constants is not None and hasattr(constants, "ENABLE_RAY_CLUSTER"):
        constants.ENABLE_RAY_CLUSTER = False


def _import_ray() -> Any:
    try:
        import ray
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ImportError(
            "--executor ray needs Ray: pip install 'vp2[ray]' (see docs/scale-out.md)"
        ) from exc
    return ray


class _ActorBody:
    """A Ray actor's body: runs the initialiser once, then items one at a time."""

    def __init__(self, initializer: Callable[..., Any] | None, initargs: tuple[Any, ...]) -> None:
        if initializer is not None:
            initializer(*initargs)

    def run(self, fn: Callable[[Any], Any], item: Any) -> Any:
        return fn(item)

    def ping(self) -> int:
        return os.getpid()


class RayExecutor(Executor):
    """Ray actors, one per worker, each with its own per-process state.

    Args:
        address: ``None``: start a private Ray instance on this machine, bound to loopback
            and without the dashboard; ``"auto"``: the cluster ``ray start`` started here (or
            ``RAY_ADDRESS``); ``"HOST:PORT"``: that cluster's head (GCS) address.
        workers: Actors; ``None``: as many as the cluster's CPUs (and GPUs, with
            ``num_gpus``) fit. With ``address=None`` also sizes the private instance.
        num_cpus: CPUs each actor reserves (its simulator's core).
        num_gpus: GPUs each actor reserves (its model replica's share, fractions allowed:
            ``0.25`` puts four replicas on one GPU). ``0``: CPU-only actors.
        max_lost_retries: How often an item whose actor or node died is re-run on another
            actor before it is given up (:class:`WorkerLost`).
        runtime_env_vars: Environment variables of the actors' processes; by default the
            driver's rendering settings (``MUJOCO_GL``, ``PYOPENGL_PLATFORM``), as a
            cluster's nodes may have been started without them.
    """

    name = "ray"

    def __init__(
        self,
        address: str | None = None,
        workers: int | None = None,
        num_cpus: float = 1.0,
        num_gpus: float = 0.0,
        max_lost_retries: int = 2,
        runtime_env_vars: dict[str, str] | None = None,
    ) -> None:
        if num_cpus < 0 or num_gpus < 0 or (num_cpus == 0 and num_gpus == 0):
            raise ValueError(
                f"each actor needs resources: num_cpus={num_cpus}, num_gpus={num_gpus}"
            )
        if workers is not None and workers < 1:
            raise ValueError(f"workers must be >= 1, got {workers}")
        if max_lost_retries < 0:
            raise ValueError(f"max_lost_retries must be >= 0, got {max_lost_retries}")
        self.address = address
        self.workers = workers
        self.num_cpus = float(num_cpus)
        self.num_gpus = float(num_gpus)
        self.max_lost_retries = max_lost_retries
        if runtime_env_vars is None:
            runtime_env_vars = {
                k: os.environ[k] for k in ("MUJOCO_GL", "PYOPENGL_PLATFORM") if k in os.environ
            }
        self.runtime_env_vars = dict(runtime_env_vars)
        self._ray: Any = None
        self._owns_ray = False
        self._actor_cls: Any = None
        self._actors: list[Any] = []
        self._init_key: tuple[Any, ...] | None = None
        self._target = 0

    # ---- connection --------------------------------------------------------------------
    def _connect(self) -> Any:
        if self._ray is not None:
            return self._ray
        if _is_loopback(self.address):
            _keep_ray_on_loopback()
        ray = _import_ray()
        if not ray.is_initialized():
            kwargs: dict[str, Any] = {"logging_level": logging.WARNING}
            if self.address is None:
                # A private instance: loopback only (see _keep_ray_on_loopback), no dashboard.
                kwargs.update(include_dashboard=False, dashboard_host="127.0.0.1")
                if self.workers is not None:
                    kwargs["num_cpus"] = max(1, math.ceil(self.workers * self.num_cpus))
                    if self.num_gpus:
                        kwargs["num_gpus"] = math.ceil(self.workers * self.num_gpus)
            else:
                kwargs["address"] = self.address
            ray.init(**kwargs)
            self._owns_ray = True
        self._ray = ray
        options: dict[str, Any] = {
            "num_cpus": self.num_cpus,
            "num_gpus": self.num_gpus,
            # Deaths are handled here (the item is re-run on another actor), not by Ray.
            "max_restarts": 0,
            "max_task_retries": 0,
        }
        if self.runtime_env_vars:
            options["runtime_env"] = {"env_vars": self.runtime_env_vars}
        self._actor_cls = ray.remote(_ActorBody).options(**options)
        return ray

    def _capacity(self) -> int:
        """Actors the cluster's total resources fit."""
        resources = self._ray.cluster_resources()
        fits = [int(resources.get("CPU", 0) // self.num_cpus)] if self.num_cpus else []
        if self.num_gpus:
            fits.append(int(resources.get("GPU", 0) // self.num_gpus))
        if min(fits) < 1:
            raise ValueError(
                f"no Ray actor with num_cpus={self.num_cpus:g}, num_gpus={self.num_gpus:g} fits "
                f"the cluster ({resources.get('CPU', 0):g} CPUs, {resources.get('GPU', 0):g} GPUs)"
            )
        return min(fits)

    def _free_slots(self) -> int:
        """Actors that fit into the resources available right now."""
        resources = self._ray.available_resources()
        fits = [int(resources.get("CPU", 0) // self.num_cpus)] if self.num_cpus else []
        if self.num_gpus:
            fits.append(int(resources.get("GPU", 0) // self.num_gpus))
        return max(0, min(fits))

    # ---- actors ------------------------------------------------------------------------
    def _pool(
        self, initializer: Callable[..., Any] | None, initargs: tuple[Any, ...], num_items: int | None
    ) -> list[Any]:
        """The actors for this initialiser, reused across calls with the same one."""
        key = (initializer, initargs)
        if self._init_key != key:
            self._kill(self._actors)
            self._actors = []
            self._init_key = key
            capacity = self._capacity()
            if self.workers and self.workers > capacity:
                # Actors beyond the cluster's resources would wait forever, and so would
                # the items handed to them.
                log.warning(
                    "%d Ray actors requested, the cluster fits %d (num_cpus=%g, num_gpus=%g "
                    "each): using %d", self.workers, capacity, self.num_cpus, self.num_gpus,
                    capacity,
                )
            target = min(self.workers or capacity, capacity)
            self._target = min(target, num_items) if num_items else target
        while len(self._actors) < self._target:
            self._actors.append(self._actor_cls.remote(initializer, initargs))
        return list(self._actors)

    def _kill(self, actors: Iterable[Any]) -> None:
        for actor in actors:
            try:
                self._ray.kill(actor, no_restart=True)
            except Exception:  # already dead, or the cluster is gone
                log.debug("could not kill actor %s", actor, exc_info=True)

    def _drop(self, actor: Any) -> None:
        if actor in self._actors:
            self._actors.remove(actor)
        self._kill([actor])

    # ---- the map -----------------------------------------------------------------------
    def imap_unordered(
        self, fn: Callable[[T], R], items: Iterable[T],
        initializer: Callable[..., Any] | None = None, initargs: tuple[Any, ...] = (),
        on_lost: str = "raise",
    ) -> Iterator[tuple[T, Any]]:
        """See :meth:`Executor.imap_unordered`.

        Each actor runs one item at a time, so an actor's death is charged to the item it
        ran. Such an item is re-run on another actor up to ``max_lost_retries`` times; after
        that ``on_lost="raise"`` raises :class:`WorkerLost` and ``on_lost="yield"`` yields
        ``(item, WorkerLost(...))`` and goes on. A dead actor is not replaced at once (its
        node may be gone); new actors are added when the cluster has room again.

        ``items`` is polled again after every result, so it may be a live queue that the
        consumer refills while iterating (the benchmark runner's retries).
        """
        check_on_lost(on_lost)
        ray = self._connect()
        from ray.exceptions import ObjectLostError, RayActorError, RayTaskError

        num_items = len(items) if hasattr(items, "__len__") else None  # type: ignore[arg-type]
        if num_items == 0:
            return
        idle = collections.deque(self._pool(initializer, initargs, num_items))
        iterator = iter(items)
        retries: collections.deque[tuple[T, int]] = collections.deque()
        in_flight: dict[Any, tuple[Any, T, int]] = {}  # ref -> (actor, item, deaths so far)
        try:
            while True:
                if len(self._actors) < self._target and self._free_slots() > 0:
                    actor = self._actor_cls.remote(initializer, initargs)
                    self._actors.append(actor)
                    idle.append(actor)
                if not self._actors and (retries or not in_flight):
                    # Every actor died: wait for one to be placed wherever the cluster can.
                    actor = self._actor_cls.remote(initializer, initargs)
                    self._actors.append(actor)
                    idle.append(actor)
                while idle:
                    if retries:
                        item, deaths = retries.popleft()
                    else:
                        try:
                            item, deaths = next(iterator), 0
                        except StopIteration:
                            break
                    actor = idle.popleft()
                    in_flight[actor.run.remote(fn, item)] = (actor, item, deaths)
                if not in_flight:
                    return
                [ref], _ = ray.wait(list(in_flight), num_returns=1)
                actor, item, deaths = in_flight.pop(ref)
                try:
                    result = ray.get(ref)
                except RayTaskError as exc:  # fn raised: the caller's error, not a lost worker
                    idle.append(actor)
                    cause = getattr(exc, "cause", None)
                    raise (cause if isinstance(cause, BaseException) else exc) from None
                except (RayActorError, ObjectLostError) as exc:
                    self._drop(actor)
                    deaths += 1
                    if deaths <= self.max_lost_retries:
                        log.warning(
                            "a Ray worker died (%s); re-running its item (%d/%d)",
                            type(exc).__name__, deaths, self.max_lost_retries,
                        )
                        retries.append((item, deaths))
                        continue
                    lost = WorkerLost(item, deaths, exc)
                    if on_lost == "raise":
                        raise lost from exc
                    yield item, lost
                    continue
                idle.append(actor)
                yield item, result
        finally:
            if in_flight:  # abandoned mid-way: stop the work still running
                for actor, _, _ in in_flight.values():
                    self._drop(actor)

    def close(self) -> None:
        if self._ray is None:
            return
        self._kill(self._actors)
        self._actors = []
        self._init_key = None
        if self._owns_ray:
            self._ray.shutdown()
        self._ray = None
        self._owns_ray = False
