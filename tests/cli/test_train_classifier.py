"""``vp2 train-classifier``: trains, saves, writes metrics; the result registers."""

from __future__ import annotations

import argparse
import json

import torch

from vp2.classifiers.checkpoint import load_classifier
from vp2.classifiers.data import load_frames
from vp2.classifiers.registry import (
    METRICS_FILE,
    ClassifierRegistry,
    register_shipped_classifiers,
)
from vp2.classifiers.train import evaluate
from vp2.cli.train_classifier import configure_parser, run_from_args


def test_command_trains_saves_and_registers(tmp_path, dataset):
    parser = configure_parser(argparse.ArgumentParser())
    args = parser.parse_args(
        [
            "--data",
            str(dataset[0]),
            "--tasks",
            "push_red",
            "--steps",
            "20",
            "--batch-size",
            "16",
            "--arch",
            "ours",
            "paper",
            "--paper-steps",
            "2",
            "--lr-schedule",
            "cosine",
            "--width",
            "2",
            "--out",
            str(tmp_path / "run"),
        ]
    )
    assert run_from_args(args) == 0
    metrics = json.loads((tmp_path / "run" / METRICS_FILE).read_text())
    assert set(metrics) == {"ours", "paper"} and set(metrics["ours"]) == {"push_red"}
    entry = metrics["ours"]["push_red"]
    assert (
        entry["training"]["steps"] == 20 and metrics["paper"]["push_red"]["training"]["steps"] == 2
    )
    assert "--paper-steps 2" in entry["command"] and "--lr-schedule cosine" in entry["command"]
    assert entry["training"]["lr_schedule"] == "cosine" and "--width 2" in entry["command"]
    assert entry["width"] == 2 and metrics["paper"]["push_red"]["width"] == 1
    loaded = load_classifier(tmp_path / "run" / "push_red.pt")
    valid = load_frames(dataset[0], "push_red", "valid")
    assert evaluate(loaded, valid) == entry["heldout"]
    registry = ClassifierRegistry()
    assert register_shipped_classifiers(registry, tmp_path / "run") == ["robodesk/push_red"]
    assert "robodesk/push_red" in registry and "robodesk/push_blue" not in registry
    assert registry.get("robodesk/push_red", torch.device("cpu")).meta["arch"] == "ours"
