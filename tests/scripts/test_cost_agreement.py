"""``benchmarks.studies.cost_agreement``: does a model rank candidates as the simulator does."""

from __future__ import annotations

import json

import numpy as np
import pytest
from benchmarks.studies.cost_agreement import (
    agreement,
    correlations,
    markdown,
    point_context,
    success_of,
)

from vp2.benchmark.diagnose_measures import first_step_context
from vp2.data.suite import TaskSuite


def test_agreement_of_the_same_the_reversed_and_a_constant_ranking():
    oracle = np.arange(20.0)  # candidate 19 is the oracle's best
    same = agreement(oracle * 3 + 1, oracle)
    assert same == {"rho": pytest.approx(1.0), "oracle_best_rank": 1, "oracle_best_in_top": True}
    reversed_ = agreement(-oracle, oracle)
    assert reversed_["rho"] == pytest.approx(-1.0)
    assert reversed_["oracle_best_rank"] == 20 and not reversed_["oracle_best_in_top"]
    flat = agreement(np.zeros(20), oracle)  # orders nothing; ties count against the best
    assert flat == {"rho": 0.0, "oracle_best_rank": 20, "oracle_best_in_top": False}
    second = oracle.copy()
    second[[18, 19]] = second[[19, 18]]  # the oracle's best is the model's second of 20
    assert agreement(second, oracle)["oracle_best_rank"] == 2
    assert agreement(second, oracle)["oracle_best_in_top"]  # top 10% of 20: 2


def _trials(path, successes):
    path.mkdir()
    rows = [{"task": "t", "instance": i, "seed": 0, "success": s, "error": None}
            for i, s in enumerate(successes)]  # fmt: skip
    rows.append({"task": "t", "instance": 9, "seed": 0, "success": False, "error": "boom"})
    (path / "trials.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return path


def test_success_leaves_out_errors_and_correlations_rank_the_models(tmp_path):
    assert success_of([_trials(tmp_path / "a", [True, False]), _trials(tmp_path / "b", [True])]) == (2, 3)

    def model(name, rho, top, success):
        point = {"median_rho": rho, "oracle_best_in_top": top}
        return {"model": name, "start": point, "mid-push": point, "success": success, "trials": 4}

    summary = [model("a", 0.1, 0.0, 0.0), model("b", 0.5, 0.5, 0.25), model("c", 0.9, 1.0, 0.75)]
    assert correlations(summary) == {
        "start/median_rho": pytest.approx(1.0), "start/oracle_best_in_top": pytest.approx(1.0),
        "mid-push/median_rho": pytest.approx(1.0), "mid-push/oracle_best_in_top": pytest.approx(1.0),
    }  # fmt: skip
    assert set(correlations(summary[:2]).values()) == {None}  # fewer than 3 models
    page = markdown({"models": summary, "correlations": correlations(summary)})
    assert "| c | +0.90 | 100% | +0.90 | 100% | 75% (4) |" in page
    assert "- start/median_rho: +1.00" in page


def test_the_start_point_is_the_first_planning_step_and_mid_push_follows_the_script():
    (instance,) = TaskSuite.load(None).select(["robodesk/push_red"], 1)
    start = point_context(instance, 64, 0)
    goal, frames, state = first_step_context(instance, 64)
    np.testing.assert_array_equal(start["frames"], frames)
    np.testing.assert_array_equal(start["goal"], goal)
    assert not start["last_action"].any() and len(start["rest"]) == len(instance.actions)
    half = len(instance.actions) // 2
    mid = point_context(instance, 64, half)
    np.testing.assert_array_equal(mid["last_action"], instance.actions[half - 1])
    np.testing.assert_array_equal(mid["rest"], instance.actions[half:])
    assert not np.array_equal(mid["frames"], frames)  # the hand has moved
