"""The per-process environment cache: one environment per metadata and keywords, LRU eviction."""

from __future__ import annotations

import pytest

from vp2.envs import cache as cache_module
from vp2.envs.cache import EnvCache


class _FakeEnv:
    def __init__(self, meta, kwargs):
        self.meta, self.kwargs, self.closed = meta, kwargs, False
        self.seeds = [meta.get("kwargs", {}).get("seed")] if isinstance(meta, dict) else []

    def reseed(self, seed):
        self.seeds.append(seed)

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


def test_metadata_differing_in_seed_or_information_share_one_env_reseeded(built):
    cache = EnvCache(2)
    a = cache.get({"name": "x", "kwargs": {"seed": 1, "size": 2}, "textures": ["wood"]})
    b = cache.get({"name": "x", "kwargs": {"seed": 7, "size": 2}, "textures": ["clay"]})
    assert b is a and len(built) == 1 and a.seeds == [1, 1, 7]  # built with 1, reseeded per get
    assert cache.get({"name": "x", "kwargs": {"seed": 7, "size": 3}}) is not a  # other kwargs


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


def test_a_shared_env_plays_a_second_instance_as_a_fresh_build_would():
    # Two tabletop instances of one category share the cached env (their metadata differ in the
    # texture names, which the state carries): the second instance's rollout and its frames are
    # those of an env built from its own metadata.
    import numpy as np

    from vp2.data.suite import TaskSuite
    from vp2.envs import make_env_from_metadata

    first, second = TaskSuite.load().for_task("tabletop/push_sphere")[:2]
    assert first.env_meta != second.env_meta
    cache = EnvCache(1)
    shared = cache.get(first.env_meta, observation_size=None)
    shared.reset_to(first.init_state)
    shared.step(first.actions[0])
    assert cache.get(second.env_meta, observation_size=None) is shared and len(cache) == 1
    fresh = make_env_from_metadata(second.env_meta, observation_size=None)
    try:
        frames = []
        for env in (shared, fresh):
            env.reset_to(second.init_state)
            for action in second.actions[:2]:
                env.step(action)
            frames.append((env.get_state(), env.render(64)))
        assert shared.serialize() == fresh.serialize() == second.env_meta | {
            "kwargs": {**second.env_meta["kwargs"], "observation_size": None}}
        np.testing.assert_array_equal(frames[0][0], frames[1][0])
        np.testing.assert_array_equal(frames[0][1], frames[1][1])
        assert shared.is_success(second.goal_state) == fresh.is_success(second.goal_state)
    finally:
        fresh.close()
        cache.close()
    with pytest.raises(ValueError, match="must be a dict with 'name' and 'kwargs'"):
        cache.get({"kwargs": {}})
