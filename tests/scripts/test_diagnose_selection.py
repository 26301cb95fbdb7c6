"""benchmarks/studies/diagnose_selection.py: the choice of measures made inside each fold."""

import numpy as np
import pytest
from benchmarks.studies.diagnose_selection import CANDIDATES, choose, only, select_then_predict

from vp2.diagnose.measures import spearman
from vp2.diagnose.score import FEATURES


def _models(count: int, seed: int = 0):
    """Models whose success follows log_conditioning alone; the other measures are noise."""
    rng = np.random.default_rng(seed)
    rows, success = [], []
    for i in range(count):
        cond = 0.05 * i
        rows.append({f: (cond if f == "log_conditioning" else float(rng.uniform())) for f in FEATURES})
        success.append(min(0.9, 2.5 * cond))
    return rows, success, [60] * count


def test_only_keeps_the_named_measures():
    row = {f: 0.5 for f in FEATURES}
    kept = only(row, ("steering",))
    assert kept["steering"] == 0.5 and sum(kept.values()) == 0.5
    assert set(CANDIDATES) == {"all six", *FEATURES}


def test_the_measure_that_carries_success_is_chosen():
    rows, success, trials = _models(6)
    assert choose(rows, success, trials) == "log_conditioning"


def test_each_model_is_predicted_without_taking_part_in_the_choice():
    rows, success, trials = _models(6, seed=1)
    predictions, chosen = select_then_predict(rows, success, trials)
    assert len(predictions) == len(chosen) == 6 and set(chosen) <= set(CANDIDATES)
    assert chosen.count("log_conditioning") >= 4
    assert spearman(predictions, success) > 0.8  # success rises with conditioning
    # The held-out model's own success cannot move its prediction.
    moved = list(success)
    moved[2] = 0.0
    again, _ = select_then_predict(rows, moved, trials)
    assert again[2] == pytest.approx(predictions[2])
