"""benchmarks/studies/conditioning_by_trajectory.py: every valid clip, intervals over trajectories."""

from __future__ import annotations

import numpy as np
from benchmarks.studies.conditioning_by_trajectory import measure, valid_clips

from tests.models.synthetic import write_moving_square_dataset
from vp2.run.model_spec import resolve_model


def test_every_valid_clip_with_its_trajectory_and_both_intervals(tmp_path):
    # 6 trajectories of 16 frames, every 3rd held out: 2 valid trajectories of 5 clips each.
    data = write_moving_square_dataset(tmp_path / "squares", size=64, action_dim=4)
    frames, actions, trajectory = valid_clips(str(data), None)
    assert frames.shape == (10, 12, 3, 64, 64) and actions.shape == (10, 11, 4)
    assert np.bincount(trajectory).tolist() == [5, 5]
    model = resolve_model("tests.diagnose.test_model:ShiftModel", {}, env="tabletop",
                          action_dim=4, device="cpu")
    r = measure(model, frames, actions, trajectory, samples=1, batch=4)
    assert r["clips"] == 10 and r["trajectories"] == 2
    for low, high in (r["clip_interval"], r["trajectory_interval"]):
        assert 1.5 < low <= r["ratio"] <= high
