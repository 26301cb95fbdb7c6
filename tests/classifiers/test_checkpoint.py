"""Classifier checkpoints: identical logits after a round trip, clear errors."""

from __future__ import annotations

import hashlib

import pytest
import torch

from tests.classifiers import SIDE
from vp2.classifiers.checkpoint import (
    load_classifier,
    read_classifier_checkpoint,
    save_classifier,
)
from vp2.classifiers.networks import build_classifier


@pytest.mark.parametrize("arch", ["ours", "paper"])
def test_save_load_round_trip_gives_identical_logits(tmp_path, arch):
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        net = build_classifier(arch, SIDE if arch == "ours" else 8).eval()
    size = net.image_size
    meta = {
        "arch": arch,
        "task": "robodesk/push_red",
        "image_size": size,
        "heldout": {"accuracy": 1},
    }
    path = save_classifier(tmp_path / "c.pt", net, meta)
    loaded = load_classifier(path)
    x = torch.rand(7, 3, size, size)
    with torch.no_grad():
        torch.testing.assert_close(loaded(x), net(x), atol=0, rtol=0)
    digest = hashlib.sha256(path.read_bytes()).hexdigest()
    assert loaded.meta == {**meta, "sha256": digest} and not any(p.requires_grad for p in loaded.parameters())
    assert read_classifier_checkpoint(path)["meta"] == meta
    assert not list(tmp_path.glob(".*.tmp"))


def test_checkpoint_errors_are_clear(tmp_path):
    with pytest.raises(ValueError, match="needs 'image_size'"):
        save_classifier(tmp_path / "c.pt", build_classifier("ours"), {"arch": "ours", "task": "t"})
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="junk.pt: not a readable classifier checkpoint"):
        load_classifier(tmp_path / "junk.pt")


def test_a_wider_network_round_trips_and_the_paper_net_has_one_size(tmp_path):
    wide = build_classifier("ours", width=2).eval()
    assert sum(p.numel() for p in wide.parameters()) > 3 * sum(
        p.numel() for p in build_classifier("ours").parameters())
    meta = {"arch": "ours", "task": "robodesk/push_red", "image_size": 64, "width": 2}
    loaded = load_classifier(save_classifier(tmp_path / "w.pt", wide, meta))
    x = torch.rand(3, 3, 64, 64)
    with torch.no_grad():
        torch.testing.assert_close(loaded(x), wide(x), atol=0, rtol=0)
    with pytest.raises(ValueError, match="width applies to the 'ours' network only"):
        build_classifier("paper", width=2)
    with pytest.raises(ValueError, match="width must be a positive integer"):
        build_classifier("ours", width=0)
