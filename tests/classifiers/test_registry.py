"""The shipped classifiers: all seven load, are registered on import, and build the cost."""

from __future__ import annotations

import json

import torch

from vp2.classifiers.registry import ASSETS_DIR, CLASSIFIER_TASKS, CLASSIFIERS, METRICS_FILE
from vp2.planning.planner import build_cost


def _shipped() -> list[str]:
    return sorted(p.stem for p in ASSETS_DIR.glob("*.pt"))


def test_all_seven_shipped_classifiers_load_and_are_registered():
    assert _shipped() == sorted(t.split("/")[1] for t in CLASSIFIER_TASKS)
    metrics = json.loads((ASSETS_DIR / METRICS_FILE).read_text())
    frames = torch.rand(2, 10, 3, 64, 64)
    for task in CLASSIFIER_TASKS:
        assert task in CLASSIFIERS
        path = ASSETS_DIR / f"{task.split('/')[1]}.pt"
        assert path.stat().st_size < 1_000_000
        classifier = CLASSIFIERS.get(task, torch.device("cpu"))
        meta = classifier.meta
        assert meta["task"] == task and meta["arch"] == "ours" and meta["image_size"] == 64
        assert meta["heldout"] == metrics["ours"][task.split("/")[1]]["heldout"]
        logits = classifier(frames.flatten(0, 1))
        assert logits.shape == (20,) and torch.isfinite(logits).all()
        cost, kind = build_cost(task, torch.rand(3, 64, 64))
        assert kind == "pixel+classifier" and cost(frames).shape == (2,)


def test_the_shipped_classifiers_meet_the_benchmark_goals():
    """Issue goals for the shipped files: >= 500 collected trajectories per task (train and
    held-out together), >= 97% held-out accuracy, the paper's label (SPEC §6)."""
    metrics = json.loads((ASSETS_DIR / METRICS_FILE).read_text())["ours"]
    assert sorted(metrics) == _shipped()
    for task, entry in metrics.items():
        data = entry["data"]
        assert data["train"]["trajectories"] + data["valid"]["trajectories"] >= 500, task
        assert entry["training"]["label"] == "dense", task
        assert entry["heldout"]["accuracy"] >= 0.97, (task, entry["heldout"]["accuracy"])
        assert entry["heldout"]["frames"] >= 1800, task
