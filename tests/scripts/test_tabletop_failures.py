"""benchmarks/studies/tabletop_failures.py: the classes of a failed tabletop trial, and one
committed oracle record replayed to its recorded outcome."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from benchmarks.studies.tabletop_failures import classify, distances

RECORDS = Path(__file__).resolve().parents[2] / "results" / "oracle" / "samples-50" / "trials.jsonl"


def _dist(pushed_path, others=0.0):
    """Distances of 4 objects over the steps: the pushed one (index 0) along ``pushed_path``."""
    d = np.full((len(pushed_path), 4), others)
    d[:, 0] = pushed_path
    return d


FLAT = np.full((4, 4), 0.8)


@pytest.mark.parametrize(("pushed", "others", "height", "label"), [
    ([0.2, 0.1, 0.04, 0.04], 0.0, FLAT, "solved"),
    ([0.2, 0.2, 0.198, 0.2], 0.0, FLAT, "untouched"),
    ([0.2, 0.2, 0.3, 0.8], 0.0, np.array([[0.8] * 4, [0.8] * 4, [0.8] * 4, [0.0] + [0.8] * 3]),
     "pushed off"),
    ([0.2, 0.1, 0.04, 0.09], 0.0, FLAT, "solved"),  # success at any step counts
    ([0.2, 0.1, 0.04, 0.04], 0.06, FLAT, "neighbour disturbed"),
    ([0.2, 0.1, 0.08, 0.08], 0.0, FLAT, "short"),
])
def test_a_trial_is_classed_by_its_objects_distances(pushed, others, height, label):
    assert classify(_dist(pushed, others), height, 0) == label


def test_a_committed_tabletop_record_replays_to_its_outcome():
    record = next(r for r in map(json.loads, RECORDS.read_text().splitlines())
                  if r["task"] == "tabletop/push_large_cube" and r["instance"] == 1)
    dist, height, pushed, hand = distances(record)
    assert dist.shape == height.shape == (len(record["actions"]) + 1, 4)
    assert hand.shape == (len(record["actions"]) + 1, 4)
    assert record["success"] and classify(dist, height, pushed) == "solved"
    # the pushed object starts 9.6 cm from its goal and ends 1.3 cm from it
    assert dist[0, pushed] == pytest.approx(0.096, abs=0.001)
    assert dist[-1, pushed] == pytest.approx(0.013, abs=0.001)


def test_a_committed_failure_is_classed_untouched():
    # push_small_cube #1 at 50 samples: the planner lifted the hand (21 cm) and never touched
    # the cube, which stays 16.8 cm from its goal.
    record = next(r for r in map(json.loads, RECORDS.read_text().splitlines())
                  if r["task"] == "tabletop/push_small_cube" and r["instance"] == 1)
    dist, height, pushed, hand = distances(record)
    assert not record["success"] and classify(dist, height, pushed) == "untouched"
    assert dist[:, pushed].min() == pytest.approx(0.168, abs=0.001)
    assert hand[:, 3].max() - hand[0, 3] == pytest.approx(0.214, abs=0.002)
