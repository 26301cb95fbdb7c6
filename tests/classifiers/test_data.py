"""Labelled frames of a collected dataset: the success flags of the dataset's own split."""

from __future__ import annotations

import numpy as np
import pytest

from tests.classifiers import STEPS
from vp2.classifiers.data import load_frames
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
