"""benchmarks/studies/block_trial_trace.py: the scripted push traced to its success, and a
committed SPEC-count record of a failed flat-block trial traced to the false optimum the
findings report (the block hidden behind the raised arm, scored above the real success)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from benchmarks.studies.block_trial_trace import planned_weight, summarise

from vp2.data.suite import TaskSuite
from vp2.planning.agent import frames_to_tensor
from vp2.planning.planner import build_cost

RECORDS = Path(__file__).resolve().parents[2] / "results" / "oracle" / "spec" / "trials.jsonl"
TASK = "robodesk/flat_block_off_table"


def _summary(index, actions=None):
    inst = TaskSuite.load().get(TASK, index)
    if actions is None:
        record = next(r for r in map(json.loads, RECORDS.read_text().splitlines())
                      if r["task"] == TASK and r["instance"] == index)
    else:
        record = {"actions": actions, "success": False}
    goal = frames_to_tensor(inst.goal_image, torch.device("cpu"))
    return summarise(inst, record, build_cost(TASK, goal, "spec")[0])


def test_the_scripted_push_reaches_progress_one_and_the_zero_plan_none():
    s = _summary(3, actions=np.zeros((15, 5)).tolist())
    scripted = s["scripted"]
    first = s["scripted_success_step"]
    assert scripted[first]["success"] and not any(r["success"] for r in scripted[:first])
    assert scripted[first]["progress"] == pytest.approx(1.0)
    assert scripted[first]["block"][2] < 0.6 < scripted[0]["block"][2]
    assert s["max_progress"] == pytest.approx(0.0, abs=1e-3)
    assert s["verdict"] == "short"  # the arm at rest scores worse than success
    assert len(s["executed"]) == 16


def test_a_failed_spec_count_trial_is_a_false_optimum():
    s = _summary(1)
    assert not s["success"] and s["verdict"] == "false optimum"
    assert s["max_progress"] < 0.01  # the block never moved along the push
    best = s["executed"][s["best_cost_step"]]
    assert best["logit"] > max(r["logit"] for r in s["scripted"][: s["scripted_success_step"] + 1])
    assert "upright_block" in best["others_moved"]


def test_the_trace_scores_at_the_weight_the_trial_planned_with():
    assert planned_weight({"weight": 10.0}) == 10.0
    assert planned_weight({"agent": {"classifier": {"weight": 100.0}}}) == 100.0
    assert planned_weight({"agent": {"agent": "random"}}) is None
