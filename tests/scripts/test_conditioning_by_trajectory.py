"""The interval over trajectories of benchmarks/studies/conditioning_by_trajectory.py."""

from __future__ import annotations

import numpy as np
import pytest
from benchmarks.studies.conditioning_by_trajectory import trajectory_interval


def test_equal_trajectories_give_a_point_and_unequal_ones_a_wider_interval_than_clips():
    trajectory = np.repeat(np.arange(4), 5)  # 4 trajectories of 5 clips each
    true = np.ones(20)
    assert trajectory_interval(true, 1.2 * true, trajectory) == pytest.approx((1.2, 1.2))
    # Each trajectory has its own ratio (1.0, 1.1, 1.3, 1.6), identical across its clips: the
    # interval spans whole trajectories' ratios, not the 20 clips' average behaviour.
    shuffled = np.repeat([1.0, 1.1, 1.3, 1.6], 5)
    low, high = trajectory_interval(true, shuffled, trajectory)
    assert 1.0 <= low < 1.25 < high <= 1.6
    assert high - low > 0.3
    # A single trajectory resamples to itself.
    assert trajectory_interval(true[:5], shuffled[:5], trajectory[:5]) == pytest.approx((1.0, 1.0))
