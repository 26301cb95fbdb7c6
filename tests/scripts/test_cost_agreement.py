"""``benchmarks.studies.cost_agreement``: does a model rank candidates as the simulator does
(the agreement itself: tests/diagnose/test_model.py)."""

from __future__ import annotations

import json

import pytest
from benchmarks.studies.cost_agreement import correlations, markdown, success_of


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
