"""``benchmarks.comparison.zoo_training``: round-robin training with the conditioning curve,
resumed by the same command (slow: a tiny dataset, two families, two rounds of a few steps)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
from benchmarks.comparison.zoo_training import (
    curve_markdown,
    parse_args,
    settings_from_args,
    stage_minutes,
    target_interval,
    train_config,
)

from vp2.data.collect import CollectionConfig, collect

REPO = Path(__file__).resolve().parents[2]
MODULE = "benchmarks.comparison.zoo_training"
TINY = CollectionConfig(
    env="robodesk",
    trajectories_per_stream=3,
    streams=("robodesk/push_red",),
    image_size=64,
    horizon=15,
    chunk_size=3,
    valid_every=3,
)


def _run(data: Path, out: Path, *levels: str) -> str:
    command = [sys.executable, "-m", MODULE, "--smoke", "--data", str(data), "--out", str(out),
               "--families", "svg_prime", "fitvid", "--levels", *levels, "--clips", "4",
               "--samples", "1", "--eval-batches", "1"]  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-5000:]
    return proc.stdout


def test_maskvit_spends_its_first_minutes_on_the_tokenizer():
    assert stage_minutes("svg_prime", 30, 20) == [30]
    assert stage_minutes("maskvit", 15, 20) == [15, 0.0]  # no transformer yet
    assert stage_minutes("maskvit", 30, 20) == [20, 10]
    assert stage_minutes("maskvit", 120, 20) == [20, 100]


def test_cpu_clock_needs_one_thread_on_a_cpu(tmp_path):
    args = parse_args(["--data", str(tmp_path), "--device", "cpu"])
    assert settings_from_args(args, None).clock == "cpu"
    args = parse_args(["--data", str(tmp_path), "--device", "cpu", "--threads", "2"])
    with pytest.raises(SystemExit, match="--threads 1"):
        settings_from_args(args, None)
    args = parse_args(["--data", str(tmp_path), "--threads", "2", "--clock", "wall"])
    assert settings_from_args(args, None).clock == "wall"


def test_a_variant_changes_one_familys_model_settings(tmp_path):
    argv = ["--data", str(tmp_path), "--families", "struct_vrnn", "maskvit", "--model-arg",
            "struct_vrnn:keypoint_sigma=0.3", "--model-arg", "maskvit:decoding_iterations=3"]
    s = settings_from_args(parse_args(argv), argv)
    assert s.model_args == (("struct_vrnn", "keypoint_sigma", 0.3),
                            ("maskvit", "decoding_iterations", 3))
    assert train_config(s, "struct_vrnn", 0, 15, 15).model_overrides == {"keypoint_sigma": 0.3}
    # MaskViT's setting goes to its predictor (the transformer), not to the tokenizer
    assert train_config(s, "maskvit", 0, 15, 15).model_overrides == {}
    for bad, says in [("struct_vrnn:keypoint_sigma", "expected FAMILY:KEY=VALUE"),
                      ("nope:x=1", "expected FAMILY:KEY=VALUE"),
                      ("fitvid:x=1", "fitvid is not among --families")]:
        argv = ["--data", str(tmp_path), "--families", "struct_vrnn", "--model-arg", bad]
        with pytest.raises(SystemExit, match=says):
            settings_from_args(parse_args(argv), argv)


def test_a_data_quantity_point_trains_on_the_first_trajectories_only(tmp_path):
    argv = ["--data", str(tmp_path), "--families", "svg_prime", "--num-trajectories", "300"]
    s = settings_from_args(parse_args(argv), argv)
    assert s.max_trajectories == 300
    assert train_config(s, "svg_prime", 0, 15, 15).max_trajectories == 300
    s = settings_from_args(parse_args(["--data", str(tmp_path)]), None)
    assert train_config(s, "svg_prime", 0, 15, 15).max_trajectories is None
    with pytest.raises(SystemExit, match="--num-trajectories must be a positive count, got 0"):
        settings_from_args(parse_args(["--data", str(tmp_path), "--num-trajectories", "0"]), None)


def test_curve_markdown_marks_the_points_above_the_target():
    point = {
        "family": "fitvid", "level_minutes": 15, "train_minutes": 15.02, "step": 812,
        "conditioning": {"ratio": 1.31, "ci": [1.2, 1.4], "wins": 60, "clips": 64,
                         "trajectory_ci": [1.15, 1.5], "trajectories": 14},
        "conditioning_moving": {"ratio": 1.25}, "valid": {"valid/pred_mse": 0.00421},
        "above_target": True,
    }  # fmt: skip
    older = {**point, "family": "maskvit", "above_target": False,
             "conditioning": {"ratio": 1.05, "ci": [1.0, 1.1], "wins": 40, "clips": 64}}
    rows = [line for line in curve_markdown([point, older], 1.1, "cmd").splitlines()
            if line.startswith(("| fitvid", "| maskvit"))]
    assert rows == [
        "| fitvid | 15 | 15.0 | 812 | 1.310 | [1.200, 1.400] | [1.150, 1.500] | 1.250 | 60/64 | "
        "0.00421 | yes |",
        "| maskvit | 15 | 15.0 | 812 | 1.050 | [1.000, 1.100] | – | 1.250 | 40/64 | 0.00421 | no |",
    ]
    # The target is judged on the interval over trajectories where a point has it.
    assert target_interval(point["conditioning"]) == [1.15, 1.5]
    assert target_interval(older["conditioning"]) == [1.0, 1.1]


@pytest.mark.slow
def test_rounds_train_every_family_in_turn_and_resume(tmp_path):
    data = collect(TINY, tmp_path / "data", workers=1, progress=False)
    out = tmp_path / "zoo"
    first = _run(data, out, "1")
    assert "[1min] svg_prime: step 2" in first and "[1min] fitvid: step 2" in first
    point = json.loads((out / "curve" / "svg_prime-1min.json").read_text())
    assert point["step"] == 2 and point["conditioning"]["clips"] == 4
    assert point["settings"]["clock"] == "cpu"  # a budget minute is a core-minute on a CPU
    lo, hi = point["conditioning"]["ci"]
    assert lo <= point["conditioning"]["ratio"] <= hi
    lo, hi = point["conditioning"]["trajectory_ci"]  # the tiny dataset's valid trajectories
    assert lo <= point["conditioning"]["ratio"] <= hi and point["conditioning"]["trajectories"] >= 1
    assert point["above_target"] == (lo > 1.1)
    assert (out / "snapshots" / "svg_prime-1min.pt").is_file()

    # The same command with one more round: round 1 is read back, round 2 resumes at step 2.
    second = _run(data, out, "1", "2")
    again = json.loads((out / "curve" / "svg_prime-1min.json").read_text())
    assert again["date"] == point["date"]
    later = json.loads((out / "curve" / "fitvid-2min.json").read_text())
    assert later["step"] == 4
    assert "[2min] fitvid: step 4" in second
    svg = (out / "curve.svg").read_text()
    assert svg.count('class="pt"') == 4 and 'data-series="fitvid"' in svg
    assert "training time (core-minutes)" in svg
    assert svg.startswith('<svg xmlns="http://www.w3.org/2000/svg" ')  # displays as an image
    (out / "curve.svg").unlink()
    _run(data, out, "1", "2", "--publish-only")  # rewrites the page, trains nothing
    assert (out / "curve.svg").read_text() == svg
    table = (out / "curve.md").read_text()
    assert sum(line.startswith(("| svg_prime |", "| fitvid |")) for line in table.splitlines()) == 4

    # A point from before the interval over trajectories: --remeasure measures its snapshot
    # again (the same ratio), gives it the interval and leaves the other points alone.
    path = out / "curve" / "fitvid-2min.json"
    old = json.loads(path.read_text())
    for key in ("trajectory_ci", "trajectories"):
        del old["conditioning"][key]
    path.write_text(json.dumps(old))
    assert "| fitvid | 2 |" in (_run(data, out, "1", "2", "--publish-only"))
    remeasured = _run(data, out, "1", "2", "--remeasure")
    assert remeasured.count("over") == 1 and "[2min] fitvid: ratio " in remeasured
    new = json.loads(path.read_text())
    assert new["conditioning"]["ratio"] == pytest.approx(old["conditioning"]["ratio"], rel=1e-9)
    assert new["conditioning"]["trajectory_ci"] and new["remeasured"]
    assert json.loads((out / "curve" / "svg_prime-2min.json").read_text()).get("remeasured") is None


def test_card_fields_of_a_round_make_a_valid_zoo_card(tmp_path):
    from benchmarks.comparison.zoo_training import card_fields

    from tests.models.test_zoo import make_checkpoint
    from vp2.models.zoo_entries import add_to_zoo

    stats = {"ratio": 1.3204, "ci": [1.1985, 1.4459], "clips": 64, "wins": 58, "ties": 0,
             "sign_p": 9.03e-12, "mse_true": 0.006424, "mse_shuffled": 0.008482,
             "trajectory_ci": [1.1512, 1.5033], "trajectories": 14}
    record = {"conditioning": stats, "conditioning_moving": {**stats, "ratio": 1.35},
              "family": "struct_vrnn", "level_minutes": 30.0, "date": "2026-11-26T10:31:43+00:00",
              "device": "cpu (test)", "train_minutes": 30.016, "step": 1514,
              "settings": {"data": "data/robodesk-20x-64px", "clock": "cpu", "batch_size": 8,
                           "samples": 2}}  # fmt: skip
    fields = card_fields(record, "python -m benchmarks.comparison.zoo_training --out o")
    assert fields["budget"]["core_minutes"] == 30.0 and fields["budget"]["wall_minutes"] is None
    assert fields["rebuild"][0] == "vp2 collect robodesk"
    card = add_to_zoo(make_checkpoint(tmp_path / "m.pt"), "t", fields, tmp_path / "zoo")
    assert card.action_conditioning["ratio"] == 1.32
    assert card.action_conditioning["interval"] == [1.198, 1.446]
    assert card.action_conditioning["trajectory_interval"] == [1.151, 1.503]
    assert card.action_conditioning["trajectories"] == 14
    assert card.action_conditioning["true_wins"] == "58 of 64 clips (sign test p = 9e-12)"
    assert card.not_measured() == ["metrics", "control"] and card.device == "cpu (test)"
