"""A per-process cache of environments rebuilt from their metadata.

Building an environment is slow (a MuJoCo model, textures, a renderer), and a process that plans
or runs trials uses the same few environments again and again: the simulator oracle's worker
processes (:mod:`vp2.models.simulator`) and the benchmark's trial workers each keep one
:class:`EnvCache`, and so do suite generation, collection and re-rendering (closed when they
end). The cache is bounded because an environment is heavy: a tabletop one holds about 0.65 GB
resident once rendered (its 19 textures, 13 of them cube maps, uploaded to the software
renderer), a RoboDesk one reserves a 208 MB solver arena per ``MjData``.

Metadata that differ only in the generator's ``seed`` (every task instance has its own) or in
informational fields (a tabletop instance's texture names: the textures are part of the state)
share one environment, reseeded on every :meth:`EnvCache.get` to the seed asked for. Building
one per instance instead cost a process about 0.3-0.75 GB per instance it ever saw (memory the
renderer does not give back when an evicted environment is closed): a 40-trial oracle run grew
past 13 GB.
"""

from __future__ import annotations

import collections
import json
from collections.abc import Callable, Hashable
from typing import Any

from vp2.envs.base import Env
from vp2.envs.factory import make_env_from_metadata


class EnvCache:
    """Environments rebuilt from :meth:`vp2.envs.base.Env.serialize` metadata, least recently
    used evicted (and closed) beyond ``size``.

    Two calls with equal metadata and equal keyword arguments get the same environment; the
    caller resets it to whatever state it needs.

    Args:
        size: Environments kept alive (>= 1).
    """

    def __init__(self, size: int) -> None:
        if size < 1:
            raise ValueError(f"size must be >= 1, got {size}")
        self.size = int(size)
        self._envs: collections.OrderedDict[Hashable, Env] = collections.OrderedDict()

    def get(self, env_meta: dict[str, Any], **make_kwargs: Any) -> Env:
        """The cached environment of ``env_meta``, built on first use, its generator reseeded
        with ``env_meta``'s seed (as a fresh build's); state and goal are what the last user left.

        Args:
            env_meta: The environment's :meth:`~vp2.envs.base.Env.serialize` output.
            **make_kwargs: Overrides for :func:`vp2.envs.make_env_from_metadata` (e.g.
                ``observation_size=None``); part of the cache key.
        """
        try:
            kwargs = dict(env_meta.get("kwargs", {}))
            name = env_meta["name"]
        except (AttributeError, KeyError, TypeError):  # make_env_from_metadata says what is wrong
            return make_env_from_metadata(env_meta, **make_kwargs)
        seed = kwargs.pop("seed", None)
        key = json.dumps([name, kwargs, make_kwargs], sort_keys=True)
        env = self.get_or_make(key, lambda: make_env_from_metadata(env_meta, **make_kwargs))
        env.reseed(seed)
        return env

    def get_or_make(self, key: Hashable, make: Callable[[], Env]) -> Env:
        """The cached environment under ``key``, built by ``make()`` on first use."""
        if key in self._envs:
            self._envs.move_to_end(key)
            return self._envs[key]
        env = make()
        self._envs[key] = env
        while len(self._envs) > self.size:
            _, old = self._envs.popitem(last=False)
            old.close()
        return env

    def __len__(self) -> int:
        return len(self._envs)

    def close(self) -> None:
        """Closes and forgets every cached environment (the cache stays usable)."""
        for env in self._envs.values():
            env.close()
        self._envs.clear()
