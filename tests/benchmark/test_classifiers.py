"""RoboDesk success classifiers: networks, frame data, training, checkpoints, shipped files."""

from __future__ import annotations

import argparse
import json

import numpy as np
import pytest
import torch

from vp2.benchmark import CLASSIFIERS, build_cost
from vp2.benchmark.agent import ClassifierRegistry
from vp2.benchmark.classifiers import (
    ASSETS_DIR,
    CLASSIFIER_TASKS,
    METRICS_FILE,
    FrameClassifierModule,
    FrameSet,
    PaperClassifier,
    SuccessClassifier,
    TrainConfig,
    build_classifier,
    classification_metrics,
    configure_parser,
    evaluate,
    load_classifier,
    load_frames,
    multiply_adds,
    read_checkpoint,
    register_shipped_classifiers,
    run_from_args,
    save_classifier,
    train_classifier,
)
from vp2.data import storage
from vp2.utils.io import write_json_atomic

SIDE = 16  # tiny frames keep training in the tests fast
STEPS = 6  # frames per trajectory


def _frame(success: bool, rng: np.random.Generator) -> np.ndarray:
    """A noisy frame; success frames carry a bright square in the top-left corner."""
    image = rng.integers(0, 90, (SIDE, SIDE, 3), dtype=np.uint8)
    if success:
        image[2:7, 2:7] = 230
    return image


def _write_dataset(root, num_per_task: int = 6, valid_every: int = 3, seed: int = 0):
    """A hand-made dataset in the vp2 layout: push_red and open_drawer trajectories whose
    success flags switch on at a per-trajectory step (never, for some)."""
    rng = np.random.default_rng(seed)
    streams = ("robodesk/push_red", "robodesk/open_drawer")
    trajectories = []
    for index in range(num_per_task * len(streams)):
        onset = int(rng.integers(1, STEPS + 2))  # > STEPS - 1: never successful
        success = np.arange(STEPS) >= onset
        trajectories.append(
            storage.Trajectory(
                task=streams[index % len(streams)],
                index=index,
                seed=index,
                actions=np.zeros((STEPS - 1, 5), np.float32),
                states=np.zeros((STEPS, 3)),
                images=np.stack([_frame(s, rng) for s in success]),
                success=success,
                env_meta={"env": "robodesk"},
            )
        )
    chunks = []
    for c, start in enumerate(range(0, len(trajectories), 5)):
        part = trajectories[start : start + 5]
        storage.write_shard(storage.shard_path(root, c), part, {"env": "robodesk"}, valid_every)
        chunks.append({"chunk": c, "first": start, "count": len(part)})
    write_json_atomic(
        root / storage.MANIFEST,
        {
            "format": storage.FORMAT,
            "config": {"env": "robodesk", "image_size": SIDE, "valid_every": valid_every},
            "chunks": chunks,
            "complete": True,
        },
    )
    return root, trajectories


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    return _write_dataset(tmp_path_factory.mktemp("classifier_data") / "ds")


# --------------------------------------------------------------------------- networks


@pytest.mark.parametrize("arch, cls", [("ours", SuccessClassifier), ("paper", PaperClassifier)])
def test_networks_map_frames_to_one_logit_each(arch, cls):
    net = build_classifier(arch, image_size=64)
    assert isinstance(net, cls)
    out = net(torch.rand(5, 3, 64, 64))
    assert out.shape == (5,) and out.dtype == torch.float32


def test_paper_network_is_the_papers_size_and_ours_is_80x_cheaper():
    paper, ours = build_classifier("paper"), build_classifier("ours")
    assert paper.head[1].in_features == 12288 and paper.head[1].out_features == 1024
    convs = [m for m in paper.modules() if isinstance(m, torch.nn.Conv2d)]
    assert len(convs) == 8 and all(c.stride == (1, 1) and c.kernel_size == (3, 3) for c in convs)
    assert sum(p.numel() for p in paper.parameters()) == 12_642_212
    # 3->32 and 32->3 at 64x64 plus six 32->32, plus the dense head.
    expected = 4096 * (32 * 27 + 6 * 32 * 288 + 3 * 288) + 12288 * 1024 + 1024
    assert multiply_adds(paper) == expected
    assert multiply_adds(paper) / multiply_adds(ours) > 70
    assert sum(p.numel() for p in ours.parameters()) < 100_000


def test_other_image_sizes_are_resized_for_the_network():
    module = FrameClassifierModule(build_classifier("ours", 64).eval(), "robodesk/push_red", {})
    x = torch.rand(2, 3, 64, 64)
    big = torch.nn.functional.interpolate(x, size=(128, 128), mode="nearest")
    torch.testing.assert_close(module(big), module(x), atol=1e-5, rtol=1e-5)
    with pytest.raises(ValueError, match="push_red classifier: images must have shape"):
        module(torch.rand(2, 64, 64))


# --------------------------------------------------------------------------- data


def test_frame_labels_are_the_success_flags_of_the_split(dataset):
    root, trajectories = dataset
    for split in ("train", "valid"):
        frames = load_frames(root, "push_red", split)
        expected = [
            t
            for t in trajectories
            if t.task == "robodesk/push_red"
            and storage.is_valid_index(t.index, 3) == (split == "valid")
        ]
        assert frames.num_trajectories == len(expected) > 0
        np.testing.assert_array_equal(frames.labels, np.concatenate([t.success for t in expected]))
        np.testing.assert_array_equal(frames.images, np.concatenate([t.images for t in expected]))
        np.testing.assert_array_equal(frames.steps, np.tile(np.arange(STEPS), len(expected)))
        assert frames.images.dtype == np.uint8 and frames.labels.dtype == bool
    train = load_frames(root, "robodesk/push_red", "train")
    valid = load_frames(root, "push_red", "valid")
    assert not set(train.trajectories) & set(valid.trajectories)
    with pytest.raises(ValueError, match="RoboDesk tasks only"):
        load_frames(root, "tabletop/push_sphere", "train")


def test_frame_set_counts(dataset):
    frames = load_frames(dataset[0], "open_drawer", "train")
    d = frames.describe()
    assert d["frames"] == len(frames) == d["trajectories"] * STEPS
    assert d["positives"] == int(frames.labels.sum())
    assert d["positive_trajectories"] == len(np.unique(frames.trajectories[frames.labels]))


# --------------------------------------------------------------------------- training


def test_metrics_on_hand_made_logits():
    m = classification_metrics(
        np.array([2.0, -1.0, 0.5, -3.0, 1.0]), np.array([1, 1, 0, 0, 1], bool)
    )
    assert (m["tp"], m["fp"], m["fn"], m["tn"]) == (2, 1, 1, 1)
    assert m["accuracy"] == pytest.approx(3 / 5)
    assert m["precision"] == pytest.approx(2 / 3) and m["recall"] == pytest.approx(2 / 3)
    none = classification_metrics(np.array([-1.0, -2.0]), np.array([False, False]))
    assert none["accuracy"] == 1.0 and none["precision"] is None and none["recall"] is None


def _separable(n: int, seed: int) -> FrameSet:
    rng = np.random.default_rng(seed)
    labels = rng.random(n) < 0.4
    return FrameSet(
        images=np.stack([_frame(bool(s), rng) for s in labels]),
        labels=labels,
        trajectories=np.arange(n),
        steps=np.zeros(n, np.int64),
    )


def test_training_learns_a_separable_problem_reproducibly():
    train, held_out = _separable(256, 0), _separable(128, 1)
    config = TrainConfig(arch="ours", steps=150, batch_size=32, seed=3)
    state = torch.random.get_rng_state()
    model = train_classifier(train, config, log_every=1000)
    assert torch.equal(torch.random.get_rng_state(), state)  # global random state untouched
    m = evaluate(model, held_out)
    assert m["accuracy"] >= 0.95 and m["recall"] >= 0.9 and m["precision"] >= 0.9
    again = train_classifier(train, config, log_every=1000)
    for a, b in zip(model.state_dict().values(), again.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b, atol=0, rtol=0)


def test_balanced_pos_weight_is_negatives_over_positives():
    frames = _separable(50, 0)
    negatives = len(frames) - frames.positives
    assert TrainConfig(pos_weight="balanced").resolved_pos_weight(frames) == pytest.approx(
        negatives / frames.positives
    )
    assert TrainConfig().resolved_pos_weight(frames) is None


# --------------------------------------------------------------------------- checkpoints


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
    assert loaded.meta == meta and not any(p.requires_grad for p in loaded.parameters())
    assert read_checkpoint(path)["meta"] == meta
    assert not list(tmp_path.glob(".*.tmp"))


def test_checkpoint_errors_are_clear(tmp_path):
    with pytest.raises(ValueError, match="needs 'image_size'"):
        save_classifier(tmp_path / "c.pt", build_classifier("ours"), {"arch": "ours", "task": "t"})
    (tmp_path / "junk.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="junk.pt: not a readable classifier checkpoint"):
        load_classifier(tmp_path / "junk.pt")


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
    assert "--paper-steps 2" in entry["command"]
    loaded = load_classifier(tmp_path / "run" / "push_red.pt")
    valid = load_frames(dataset[0], "push_red", "valid")
    assert evaluate(loaded, valid) == entry["heldout"]
    registry = ClassifierRegistry()
    assert register_shipped_classifiers(registry, tmp_path / "run") == ["robodesk/push_red"]
    assert "robodesk/push_red" in registry and "robodesk/push_blue" not in registry
    assert registry.get("robodesk/push_red", torch.device("cpu")).meta["arch"] == "ours"


# --------------------------------------------------------------------------- shipped files


def _shipped() -> list[str]:
    return sorted(p.stem for p in ASSETS_DIR.glob("*.pt"))


def test_all_seven_shipped_classifiers_load_and_are_registered():
    assert _shipped() == sorted(t.split("/")[1] for t in CLASSIFIER_TASKS)
    metrics = json.loads((ASSETS_DIR / METRICS_FILE).read_text())
    frames = torch.rand(2, 10, 3, 64, 64)
    for task in CLASSIFIER_TASKS:
        assert task in CLASSIFIERS
        path = ASSETS_DIR / f"{task.split('/')[1]}.pt"
        assert path.stat().st_size < 500_000
        classifier = CLASSIFIERS.get(task, torch.device("cpu"))
        meta = classifier.meta
        assert meta["task"] == task and meta["arch"] == "ours" and meta["image_size"] == 64
        assert meta["heldout"] == metrics["ours"][task.split("/")[1]]["heldout"]
        logits = classifier(frames.flatten(0, 1))
        assert logits.shape == (20,) and torch.isfinite(logits).all()
        cost, kind = build_cost(task, torch.rand(3, 64, 64))
        assert kind == "pixel+classifier" and cost(frames).shape == (2,)
