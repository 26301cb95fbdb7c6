"""The per-process environment cache: one environment per metadata and keywords, LRU eviction."""

from __future__ import annotations

import pytest

from vp2.envs import cache as cache_module
from vp2.envs.cache import EnvCache


class _FakeEnv:
    def __init__(self, meta, kwargs):
        self.meta, self.kwargs, self.closed = meta, kwargs, False

    def close(self):
        self.closed = True


@pytest.fixture
def built(monkeypatch):
    envs = []

    def make(meta, **kwargs):
        envs.append(_FakeEnv(meta, kwargs))
        return envs[-1]

    monkeypatch.setattr(cache_module, "make_env_from_metadata", make)
    return envs


def test_same_metadata_and_keywords_give_the_same_env(built):
    cache = EnvCache(2)
    a = cache.get({"name": "x", "kwargs": {"seed": 1}}, observation_size=None)
    assert cache.get({"kwargs": {"seed": 1}, "name": "x"}, observation_size=None) is a
    assert a.kwargs == {"observation_size": None}
    other = cache.get({"name": "x", "kwargs": {"seed": 1}})  # other keywords: another env
    assert other is not a and len(built) == 2 and len(cache) == 2


def test_least_recently_used_is_closed_and_close_closes_all(built):
    cache = EnvCache(2)
    a, b = cache.get({"name": "a"}), cache.get({"name": "b"})
    assert cache.get({"name": "a"}) is a  # a is now the most recently used
    c = cache.get({"name": "c"})
    assert b.closed and not a.closed and not c.closed and len(cache) == 2
    cache.close()
    assert a.closed and c.closed and len(cache) == 0
    with pytest.raises(ValueError, match="size must be >= 1"):
        EnvCache(0)
