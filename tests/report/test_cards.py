"""``vp2.report.cards``: a zoo card's control and metrics from run directories and a metrics file."""

from __future__ import annotations

import json

import pytest
import yaml

from vp2.data.suite import SUITE_FORMAT
from vp2.report.cards import control_section, control_sections, metrics_section


def _trial(task, instance, seed, success, samples=50, error=None):
    return {"task": task, "instance": instance, "seed": seed, "success": success,
            "num_steps": 15, "error": error, "finished_at": f"2026-11-2{instance}T10:00:00+00:00",
            "agent": {"planner": {"num_samples": samples}}}  # fmt: skip


def make_run(path, trials, tasks=("robodesk",), samples=50):
    path.mkdir(parents=True)
    config = {"model": "svg_prime:m.pt", "tasks": list(tasks), "num_instances": 2, "seeds": [0],
              "planner": {"num_samples": samples}, "stop_on_success": False, "out": str(path),
              "suite": None}  # fmt: skip
    (path / "config.yaml").write_text(yaml.safe_dump({"config": config}))
    (path / "trials.jsonl").write_text("".join(json.dumps(t) + "\n" for t in trials))
    return path


def test_control_counts_finished_trials_per_environment(tmp_path):
    run = make_run(tmp_path / "a", [
        _trial("robodesk/push_red", 0, 0, True), _trial("robodesk/push_red", 1, 0, False),
        _trial("robodesk/open_slide", 0, 0, False), _trial("robodesk/open_slide", 1, 0, True),
        _trial("robodesk/open_slide", 1, 1, None, error={"type": "X"}),  # unfinished: left out
        _trial("tabletop/push_sphere", 0, 0, False),
    ])  # fmt: skip
    row = control_section([run], "robodesk")
    assert (row["successes"], row["trials"], row["seeds"], row["instances"]) == (2, 4, [0], 2)
    assert (row["samples"], row["steps"], row["tasks"]) == (50, 15, 2)
    assert row["solved"] == ["robodesk/open_slide", "robodesk/push_red"]
    assert row["suite"] == SUITE_FORMAT and row["date"] == "2026-11-21"
    # vp2.oracle.build.run_command, with the folder the run was written to
    assert row["command"] == ("vp2 run --model svg_prime:m.pt --tasks robodesk --num-instances 2 "
                              f"--seeds 0 --num-samples 50 --out {tmp_path / 'a'}")  # fmt: skip
    both = control_sections([run])
    assert sorted(both) == ["robodesk", "tabletop"] and both["tabletop"]["trials"] == 1
    # A second run of the same trials replaces them (the latest record counts once).
    again = make_run(tmp_path / "b", [_trial("robodesk/push_red", 1, 0, True)])
    assert control_section([run, again], "robodesk")["successes"] == 3


def test_control_reads_the_compact_records_results_keeps(tmp_path):
    # benchmarks.comparison.records.compact_trial: the planner samples at the top level.
    def compact(instance, success, samples=50):
        trial = _trial("robodesk/push_red", instance, 0, success)
        del trial["agent"]
        return {**trial, "num_samples": samples, "model_spec": "zoo:maskvit-robodesk-120min"}

    run = make_run(tmp_path / "a", [compact(0, True), compact(1, False)])
    row = control_section([run], "robodesk")
    assert (row["successes"], row["trials"], row["samples"]) == (1, 2, 50)
    bare = make_run(tmp_path / "b", [{k: v for k, v in compact(0, True).items()
                                      if k != "num_samples"}])  # fmt: skip
    with pytest.raises(ValueError, match="push_red #0 seed 0: its record names no planner samples"):
        control_section([bare], "robodesk")


def test_control_refuses_mixed_protocols_and_empty_runs(tmp_path):
    a = make_run(tmp_path / "a", [_trial("robodesk/push_red", 0, 0, True)])
    b = make_run(tmp_path / "b", [_trial("robodesk/push_red", 1, 0, True, samples=200)])
    with pytest.raises(ValueError, match=r"differ in planner samples \[50, 200\]"):
        control_section([a, b], "robodesk")
    with pytest.raises(ValueError, match="no finished tabletop trial"):
        control_section([a], "tabletop")
    with pytest.raises(ValueError, match="no config.yaml; give the directory of a vp2 run"):
        control_section([tmp_path], "robodesk")


def test_metrics_from_a_vp2_metrics_result(tmp_path):
    path = tmp_path / "m.json"
    path.write_text(json.dumps({
        "metrics": {"lpips_alex": 0.046302672, "ssim": 0.85987847, "psnr": 23.4829, "mse": 0.0053840},
        "model": {"spec": "zoo:x"}, "dataset": "data/robodesk-20x-64px", "num_clips": 256,
        "seed": 0, "split": "valid", "context": 2, "future": 10, "skipped": {},
        "settings": {"fvd": False, "lpips_nets": ["alex"]},
    }))  # fmt: skip
    section = metrics_section(path)
    assert {k: section[k] for k in ("fvd", "lpips", "ssim", "psnr", "mse")} == {
        "fvd": None, "lpips": 0.0463, "ssim": 0.85988, "psnr": 23.4829, "mse": 0.00538}
    assert section["command"] == ("vp2 metrics --model zoo:x --data data/robodesk-20x-64px "
                                  "--num-clips 256 --seed 0 --no-fvd --lpips alex")
    assert "LPIPS with AlexNet" in section["note"] and "FVD not measured" in section["note"]
    path.write_text("{}")
    with pytest.raises(ValueError, match="not a vp2 metrics result"):
        metrics_section(path)
