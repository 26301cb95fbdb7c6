"""Summary math (mean/min/max over seeds, errors, normalisation) and trials.jsonl reading."""

from __future__ import annotations

import json
import math

import pytest

from vp2.run.results import (
    TrialLog,
    format_summary,
    summarize,
    task_success,
)
from vp2.run.run_dir import read_trials


def _records(task: str, outcomes: dict[int, list[bool | None]], cost: str = "pixel"):
    """``outcomes[seed][instance]``: True/False, or None for an error record."""
    out = []
    for seed, per_instance in outcomes.items():
        for index, success in enumerate(per_instance):
            record = {"task": task, "instance": index, "seed": seed, "cost": cost}
            if success is None:
                record.update(success=None, error={"type": "ValueError", "message": "x"})
            else:
                record.update(success=success, error=None)
            out.append(record)
    return out


T, F = True, False
PUSH = "tabletop/push_sphere"
CUBE = "tabletop/push_large_cube"
RED = "robodesk/push_red"


def test_success_rate_per_seed_then_mean_min_max():
    records = _records(PUSH, {0: [T, T, F, F], 1: [T, F, F, F], 2: [T, T, T, F]})
    (row,) = task_success(records).values()
    assert row.per_seed == {0: 0.5, 1: 0.25, 2: 0.75}
    assert row.mean == pytest.approx(0.5) and (row.min, row.max) == (0.25, 0.75)
    assert row.num_instances == 4 and row.num_trials == 12 and row.num_errors == 0


def test_errors_are_neither_successes_nor_failures():
    records = _records(PUSH, {0: [T, None, F, None], 1: [None, T, T, F]})
    (row,) = task_success(records).values()
    assert row.per_seed == {0: 0.5, 1: pytest.approx(2 / 3)}
    assert row.num_errors == 3 and row.num_trials == 5


def test_overall_score_env_means_and_seed_spread():
    records = (
        _records(PUSH, {0: [T, T], 1: [T, F]})  # 1.0, 0.5 -> 0.75
        + _records(CUBE, {0: [F, F], 1: [T, T]})  # 0.0, 1.0 -> 0.5
        + _records(RED, {0: [T, F], 1: [F, F]}, cost="pixel_only")  # 0.5, 0.0 -> 0.25
    )
    s = summarize(records)
    assert [t.task for t in s.tasks] == [RED, CUBE, PUSH]  # the suite order
    assert s.mean == pytest.approx(0.5)
    assert s.env_means == {"tabletop": pytest.approx(0.625), "robodesk": pytest.approx(0.25)}
    # Per seed, the mean over tasks: seed 0 (1 + 0 + .5) / 3, seed 1 (.5 + 1 + 0) / 3.
    assert s.seed_means == {0: pytest.approx(0.5), 1: pytest.approx(0.5)}
    assert any("pixel_only" in w for w in s.warnings)
    assert s.normalised is None


def test_normalisation_by_the_oracle_is_a_ratio_of_means():
    model = _records(PUSH, {0: [T, F], 1: [F, F]}) + _records(CUBE, {0: [T, T], 1: [T, F]})
    oracle = _records(PUSH, {0: [T, T], 1: [T, F]}) + _records(CUBE, {0: [T, T], 1: [T, T]})
    s = summarize(model, oracle)
    cube, push = s.tasks  # the suite order: large cube before sphere
    assert push.oracle_mean == pytest.approx(0.75) and push.normalised == pytest.approx(0.25 / 0.75)
    assert cube.oracle_mean == 1.0 and cube.normalised == pytest.approx(0.75)
    oracle_mean = (0.75 + 1.0) / 2
    assert s.normalised == pytest.approx(0.5 / oracle_mean)
    # Seed means of the model: seed 0 (.5 + 1) / 2 = .75, seed 1 (0 + .5) / 2 = .25.
    assert s.normalised_min == pytest.approx(0.25 / oracle_mean)
    assert s.normalised_max == pytest.approx(0.75 / oracle_mean)
    text = format_summary(s)
    assert "normalised" in text and "0.571" in text


def test_normalisation_skips_tasks_the_oracle_lacks_and_zero_oracle_rates():
    model = _records(PUSH, {0: [T, F]}) + _records(CUBE, {0: [T, F]})
    oracle = _records(PUSH, {0: [F, F]})
    s = summarize(model, oracle)
    cube, push = s.tasks  # the suite order: large cube before sphere
    assert push.oracle_mean == 0.0 and push.normalised is None
    assert cube.oracle_mean is None
    assert s.normalised is None  # the oracle's mean over the shared tasks is 0
    assert any("no oracle results" in w for w in s.warnings)


def test_mixed_costs_and_unequal_seeds_are_flagged():
    records = _records(RED, {0: [T]}, cost="pixel_only") + _records(
        RED, {1: [T]}, cost="pixel+classifier"
    )
    records += _records(PUSH, {0: [T]})
    s = summarize(records)
    assert any("different costs" in w for w in s.warnings)
    assert any("different sets of seeds" in w for w in s.warnings)
    assert s.seed_means == {0: 1.0}


def test_read_trials_drops_a_partial_last_line_and_repairs(tmp_path):
    path = tmp_path / "trials.jsonl"
    with TrialLog(path) as log:
        log.append({"task": PUSH, "instance": 0, "seed": 0, "success": True, "error": None})
        log.append({"task": PUSH, "instance": 1, "seed": 0, "success": False, "error": None})
    with open(path, "ab") as fh:
        fh.write(b'{"task": "tab')
    assert len(read_trials(path)) == 2
    assert not path.read_bytes().endswith(b"\n")  # reading alone changes nothing
    assert len(read_trials(tmp_path, repair=True)) == 2
    assert path.read_bytes().endswith(b"\n") and path.read_bytes().count(b"\n") == 2
    assert read_trials(tmp_path / "missing.jsonl") == []


def test_read_trials_refuses_a_damaged_middle_line(tmp_path):
    path = tmp_path / "trials.jsonl"
    path.write_text('{"a": 1}\nnot json\n{"b": 2}\n')
    with pytest.raises(ValueError, match="trials.jsonl:2"):
        read_trials(path)


def test_summary_of_nothing_is_nan_not_an_error():
    s = summarize([])
    assert s.tasks == [] and math.isnan(s.mean)
    assert "all tasks" in format_summary(s)
    json.dumps(s.to_dict())


def test_tasks_come_in_suite_order_not_finish_order():
    from vp2.run.results import task_success

    def rec(task, seed=0):
        return {"task": task, "instance": 0, "seed": seed, "success": True, "error": None}

    finished = [rec("tabletop/push_sphere"), rec("robodesk/open_slide"), rec("robodesk/push_red"),
                rec("custom/task"), rec("robodesk/push_blue")]
    assert list(task_success(finished)) == [
        "robodesk/push_red", "robodesk/push_blue", "robodesk/open_slide", "tabletop/push_sphere",
        "custom/task",
    ]
