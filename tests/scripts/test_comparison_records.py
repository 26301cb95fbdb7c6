"""The model comparison's committed evidence (``benchmarks.comparison.records``): compact
trial records that a run resumes from, and the round trip between ``--out`` and the records."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from benchmarks.comparison import records

from vp2.benchmark.runner import run_benchmark
from vp2.planning.config import PlannerConfig
from vp2.run.config import RunConfig
from vp2.run.run_dir import read_trials

REPO = Path(__file__).resolve().parents[2]
COMMITTED = REPO / "results" / "comparison" / "robodesk"

FULL_RECORD = {
    "task": "robodesk/push_red", "instance": 1, "seed": 2, "instance_sha": "abc",
    "success": True, "success_steps": [False, True], "first_success_step": 1, "num_steps": 2,
    "error": None, "cost": "pixel+classifier", "actions": [[0.1] * 5, [0.2] * 5],
    "agent": {"kind": "planning"}, "scores": [1.0, 2.0], "finished_at": "2026-11-27T00:00:00",
    "model": {"spec": "zoo:x", "class": "X"},
    "timings": {"planning_s": [1.0, 2.0], "planning_mean_s": 1.5, "env_s": 0.5, "total_s": 4.0},
}  # fmt: skip


def test_a_compact_trial_keeps_the_outcome_actions_and_time_and_is_stable():
    compact = records.compact_trial(FULL_RECORD, 50)
    assert compact == {
        "task": "robodesk/push_red", "instance": 1, "seed": 2, "instance_sha": "abc",
        "success": True, "success_steps": [False, True], "first_success_step": 1,
        "num_steps": 2, "error": None, "cost": "pixel+classifier",
        "actions": [[0.1] * 5, [0.2] * 5], "finished_at": "2026-11-27T00:00:00",
        "model_spec": "zoo:x", "num_samples": 50, "timings": {"total_s": 4.0},
    }  # fmt: skip
    assert records.compact_trial(compact, 200) == compact  # compacting again changes nothing
    older = {k: v for k, v in FULL_RECORD.items() if k not in ("timings", "cost", "actions")}
    assert "timings" not in records.compact_trial(older, 50)


def _fake_part(out: Path) -> None:
    run = out / "runs" / "m"
    run.mkdir(parents=True)
    (run / "config.yaml").write_text("config:\n  planner:\n    num_samples: 50\n")
    (run / "trials.jsonl").write_text(json.dumps(FULL_RECORD) + "\n")
    (out / "metrics" / "m").mkdir(parents=True)
    (out / "metrics" / "m" / "metrics.json").write_text(json.dumps({"metrics": {"mse": 0.01}}))
    report = {"settings": {"model": "zoo:x", "data": "d", "env": "robodesk", "num_samples": 50,
                           "clips": 64, "instances_per_task": 2, "sampling_seeds": 2, "seed": 0,
                           "device": "cpu"}, "verdicts": {}}  # fmt: skip
    (out / "diagnose").mkdir()
    (out / "diagnose" / "m.json").write_text(json.dumps(records.diagnose_record(report)))
    (out / "conditioning").mkdir()
    (out / "conditioning" / "m.json").write_text(json.dumps({"ratio": 1.2}))


def test_what_a_part_saves_it_restores_into_an_empty_out(tmp_path):
    out, saved, again = tmp_path / "out", tmp_path / "records", tmp_path / "again"
    _fake_part(out)
    assert records.save(out, saved) == {"runs": 1, "metrics": 1, "diagnose": 1, "conditioning": 1}
    assert read_trials(saved / "runs" / "m") == [records.compact_trial(FULL_RECORD, 50)]
    assert json.loads((saved / "diagnose" / "m.json").read_text())["verdicts"] == {}
    assert records.restore(saved, again) == {
        "runs": 1, "metrics": 1, "diagnose": 1, "conditioning": 1}
    for name in ("metrics/m/metrics.json", "diagnose/m.json", "conditioning/m.json"):
        assert json.loads((again / name).read_text()) == json.loads((out / name).read_text())
    assert (again / "runs/m/config.yaml").read_text() == (out / "runs/m/config.yaml").read_text()
    # a second save writes nothing new, even after a resumed run re-dated its config; a
    # restore leaves what is there alone
    config = again / "runs" / "m" / "config.yaml"
    config.write_text("written_at: '2026-11-28T00:00:00'\n" + config.read_text())
    records.save(again, saved)
    before = {p: p.stat().st_mtime_ns for p in saved.rglob("*") if p.is_file()}
    config.write_text(config.read_text().replace("2026-11-28", "2026-11-29"))
    records.save(again, saved)
    assert {p: p.stat().st_mtime_ns for p in saved.rglob("*") if p.is_file()} == before
    assert records.restore(saved, again) == {
        "runs": 0, "metrics": 0, "diagnose": 0, "conditioning": 0}


def test_a_run_with_trials_of_its_own_is_not_overwritten(tmp_path):
    out, saved = tmp_path / "out", tmp_path / "records"
    _fake_part(out)
    records.save(out, saved)
    newer = {**FULL_RECORD, "seed": 0}
    (out / "runs" / "m" / "trials.jsonl").write_text(
        json.dumps(FULL_RECORD) + "\n" + json.dumps(newer) + "\n")
    assert records.restore(saved, out)["runs"] == 0
    assert len(read_trials(out / "runs" / "m")) == 2


def test_the_diagnose_record_repeats_the_settings_the_comparison_checks():
    report = json.loads((COMMITTED / "diagnose" / "svg_prime.json").read_text())
    assert records.diagnose_record(report)["settings"] == {
        "model": "zoo:svg_prime-robodesk-120min", "data": "data/robodesk-20x-64px",
        "env": "robodesk", "num_samples": 50, "clips": 64, "instances_per_task": 2,
        "sampling_seeds": 2, "seed": 0,
    }  # fmt: skip


@pytest.mark.parametrize(("name", "solved"), [("repeat_last_frame", 0), ("svg_prime", 33)])
def test_a_run_resumes_from_its_committed_records_without_planning(tmp_path, name, solved):
    """The committed compact records are enough for `vp2 run --resume`: nothing is planned
    again and the summary counts every trial (63 each: 3 instances x 7 tasks x 3 seeds)."""
    restored = records.restore(COMMITTED, tmp_path)
    assert restored["runs"] >= 5 * 63
    config = RunConfig(
        model=read_trials(COMMITTED / "runs" / name)[0]["model_spec"],
        out=str(tmp_path / "runs" / name), tasks=("robodesk",), num_instances=3,
        seeds=(0, 1, 2), planner=PlannerConfig(num_samples=50), num_steps=15, resume=True,
    )  # fmt: skip
    result = run_benchmark(config)
    assert (result.num_run, result.num_skipped, len(result.records)) == (0, 63, 63)
    assert sum(bool(r["success"]) for r in result.records) == solved
