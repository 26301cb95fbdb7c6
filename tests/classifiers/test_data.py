"""Labelled frames of a collected dataset: the success flags of the dataset's own split."""

from __future__ import annotations

import numpy as np
import pytest

from tests.classifiers import STEPS
from vp2.classifiers.data import load_frames, progress_targets, progress_threshold
from vp2.data import storage


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


def test_progress_targets_decay_before_the_first_positive_frame():
    got = progress_targets(np.array([0, 0, 0, 1, 0, 1], bool), decay=0.5)
    np.testing.assert_allclose(got, [0.125, 0.25, 0.5, 1.0, 1.0, 1.0])
    assert got.dtype == np.float32
    np.testing.assert_array_equal(progress_targets(np.zeros(4, bool)), np.zeros(4))
    np.testing.assert_allclose(progress_targets(np.array([1, 0], bool)), [1.0, 1.0])
    with pytest.raises(ValueError, match="decay"):
        progress_targets(np.ones(3, bool), decay=1.0)


def test_progress_label_scores_against_the_paper_label(dataset):
    root, trajectories = dataset
    frames = load_frames(root, "push_red", "train", label="progress")
    dense = load_frames(root, "push_red", "train", label="dense")
    np.testing.assert_array_equal(frames.labels, dense.labels)
    assert dense.targets is None and dense.threshold == 0.0
    expected = [
        progress_targets(t.dense_reward >= 30)
        for t in trajectories
        if t.task == "robodesk/push_red" and not storage.is_valid_index(t.index, 3)
    ]
    np.testing.assert_allclose(frames.targets, np.concatenate(expected))
    np.testing.assert_allclose(frames.training_targets(), frames.targets)
    np.testing.assert_array_equal(dense.training_targets(), dense.labels.astype(np.float32))
    # halfway between the targets of the first positive frame (1) and the one before (0.7)
    assert frames.threshold == pytest.approx(np.log(0.85 / 0.15)) == progress_threshold()
