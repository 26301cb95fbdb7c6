"""benchmarks/studies/block_classifier_negatives.py: rollouts labelled as the dataset labels its
frames, and mining that refuses the reported instances."""

from __future__ import annotations

import json

import numpy as np
import pytest
from benchmarks.studies.block_classifier_negatives import concat, mined, rollout

from vp2.data.suite import TaskSuite

TASK = "robodesk/flat_block_off_table"


def test_the_scripted_push_is_labelled_positive_only_after_the_block_falls():
    inst = TaskSuite.load().get(TASK, 1)
    push = rollout(inst, np.concatenate([np.zeros((1, 5)), inst.actions, np.zeros((2, 5))]))
    assert push["images"].shape == (len(inst.actions) + 4, 64, 64, 3)
    # instance #1's push drops the block at its 10th action; the paper's label (the dense
    # reward over the step) holds from that frame on, and never while the block is on the desk
    np.testing.assert_array_equal(push["on_desk"], np.arange(len(push["on_desk"])) < 10)
    np.testing.assert_array_equal(push["positive"], ~push["on_desk"])
    still = rollout(inst, np.zeros((4, 5)))
    assert still["on_desk"].all() and not still["positive"].any()


def _write(tmp_path, instance):
    run = tmp_path / f"run{instance}"
    run.mkdir()
    row = {"task": TASK, "instance": instance, "success": False, "actions": [[0.0] * 5] * 3}
    (run / "trials.jsonl").write_text(json.dumps(row) + "\n")
    return run


def test_mining_refuses_a_reported_instance(tmp_path):
    with pytest.raises(SystemExit, match="#4 is a reported one"):
        mined(TASK, [_write(tmp_path, 4)], repeat=2)


def test_mined_frames_are_repeated_and_labelled_negative(tmp_path):
    frames = mined(TASK, [_write(tmp_path, 12)], repeat=3)
    assert len(frames) == 3 * 4  # the initial frame and three steps, three times
    assert not frames.labels.any() and not frames.training_targets().any()
    both = concat(frames, frames)
    assert len(both) == 24 and both.threshold == frames.threshold
