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


def test_get_or_make_builds_once_per_key_and_evicts_like_get():
    made = []

    def make(name):
        def build():
            made.append(_FakeEnv(name, {}))
            return made[-1]

        return build

    cache = EnvCache(2)
    a = cache.get_or_make(("push_red", 64), make("a"))
    assert cache.get_or_make(("push_red", 64), make("again")) is a and len(made) == 1
    b = cache.get_or_make(("push_red", None), make("b"))
    cache.get_or_make(("push_red", 64), make("again"))  # a is the most recently used
    cache.get_or_make("c", make("c"))
    assert b.closed and not a.closed and [e.meta for e in made] == ["a", "b", "c"]


def test_the_data_stages_release_their_environments(tmp_path):
    # Suite generation, collection and rendering keep environments per process while they run
    # and close them at the end: a long-lived process (tests, a notebook) must not hold one
    # environment per task it ever touched (each reserves hundreds of MB).
    from vp2.data import collect as collect_module
    from vp2.data import suite as suite_module
    from vp2.data.collect import CollectionConfig, collect

    suite_module.generate_suite({"robodesk/open_slide": 1}, workers=1, progress=False)
    assert len(suite_module._ENVS) == 0
    config = CollectionConfig(
        env="robodesk", trajectories_per_stream=1, streams=("robodesk/push_red",), horizon=3, image_size=16
    )
    collect(config, tmp_path / "data", workers=1, progress=False)
    assert len(collect_module._WORKER_ENVS) == 0
