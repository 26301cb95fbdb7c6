"""A collection's chosen trajectories alone (``collect(indices=...)``) and the default
datasets' validation trajectories (:mod:`vp2.data.held_out`)."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from tests.data.conftest import TINY
from vp2 import cli
from vp2.cli import collect as collect_cmd
from vp2.cli._fields import build
from vp2.data import storage
from vp2.data.collect import DEFAULT_TRAJECTORIES, CollectionConfig, collect
from vp2.data.held_out import (
    default_collection,
    held_out_dir,
    rendering_problem,
    validation_indices,
)
from vp2.data.loader import ClipDataset


def test_the_default_collections_and_their_validation_trajectories():
    for env in ("robodesk", "tabletop"):
        args = cli.build_parser().parse_args(["collect", env])
        # What `vp2 collect ENV` collects with no other flag.
        cli_config = build(CollectionConfig, args, collect_cmd.FLAGS,
                           trajectories_per_stream=DEFAULT_TRAJECTORIES[env])
        assert default_collection(env) == cli_config
    # 7 streams x 20 (every 10th held out), 1 stream x 100.
    assert validation_indices(default_collection("robodesk")) == list(range(9, 140, 10))
    assert validation_indices(default_collection("tabletop")) == list(range(9, 100, 10))
    assert validation_indices(TINY) == [2, 5]
    with pytest.raises(ValueError, match="unknown environment 'kitchen'"):
        default_collection("kitchen")


def test_the_cache_directory_is_keyed_by_the_collection(tmp_path, monkeypatch):
    monkeypatch.setenv("VP2_CACHE_DIR", str(tmp_path))
    robodesk, tabletop = held_out_dir("robodesk"), held_out_dir("tabletop")
    assert robodesk.parent == tmp_path / "held-out"
    assert re.fullmatch(r"robodesk-20x-64px-valid-[0-9a-f]{12}", robodesk.name)
    assert re.fullmatch(r"tabletop-100x-64px-valid-[0-9a-f]{12}", tabletop.name)
    assert held_out_dir("robodesk") == robodesk
    monkeypatch.setitem(DEFAULT_TRAJECTORIES, "robodesk", 30)
    assert held_out_dir("robodesk").name.startswith("robodesk-30x-64px-valid-")
    assert held_out_dir("robodesk").name[-12:] != robodesk.name[-12:]


def test_rendering_works_here():
    assert rendering_problem() is None


def test_chosen_trajectories_alone_equal_the_whole_collections(tiny_dataset, tmp_path):
    subset = collect(TINY, tmp_path / "valid", workers=1, progress=False, indices=[5, 2])
    manifest = storage.load_manifest(subset)
    assert manifest["indices"] == [2, 5] and manifest["complete"]
    assert [c["chunk"] for c in manifest["chunks"]] == [2, 5]
    records = storage.dataset_index(subset)
    assert [(r.name, r.split) for r in records] == [("demo_2", "valid"), ("demo_5", "valid")]
    # Every stored array equals the whole collection's, bit for bit.
    whole = {t.index: t for c in range(3) for t in storage.read_trajectories(
        storage.shard_path(tiny_dataset, c))}
    for c in (2, 5):
        (alone,) = storage.read_trajectories(storage.shard_path(subset, c))
        assert (alone.task, alone.seed) == (whole[c].task, whole[c].seed)
        for field in ("actions", "states", "images", "success", "dense_reward"):
            np.testing.assert_array_equal(getattr(alone, field), getattr(whole[c], field))
    # So do the validation clips, in the loader's order.
    a, b = ClipDataset(subset, "valid"), ClipDataset(tiny_dataset, "valid")
    assert len(a) == len(b) == 2 * 25
    for i in (0, 24, 25, 49):
        assert torch.equal(a[i]["frames"], b[i]["frames"])
        assert torch.equal(a[i]["actions"], b[i]["actions"])
        assert a[i]["index"] == b[i]["index"] and a.trajectory(i) == b.trajectory(i)
    a.close()
    b.close()
    # Re-running is a no-op; other trajectories or the whole collection are refused there.
    before = {p.name: p.stat().st_mtime_ns for p in (subset / "shards").iterdir()}
    collect(TINY, subset, workers=1, progress=False, indices=[2, 5])
    assert before == {p.name: p.stat().st_mtime_ns for p in (subset / "shards").iterdir()}
    with pytest.raises(FileExistsError, match="holds a subset of trajectories"):
        collect(TINY, subset, workers=1, progress=False, indices=[2])
    with pytest.raises(FileExistsError, match="holds a subset of trajectories"):
        collect(TINY, subset, workers=1, progress=False)
    with pytest.raises(FileExistsError, match="holds all trajectories"):
        collect(TINY, tiny_dataset, workers=1, progress=False, indices=[2])
    with pytest.raises(ValueError, match="indices must name trajectories 0..5"):
        collect(TINY, tmp_path / "bad", workers=1, progress=False, indices=[6])
