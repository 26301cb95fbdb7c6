"""``vp2 diagnose``: flags onto DiagnoseConfig, the printed verdicts, the report, the errors."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.benchmark import TABLETOP_BLIND_SCORE, TABLETOP_PREDICTOR
from tests.diagnose.test_model import HERE
from tests.models.synthetic import write_moving_square_dataset
from vp2 import cli
from vp2.cli import diagnose as diagnose_cmd
from vp2.cli._fields import build
from vp2.diagnose.model import DiagnoseConfig

#: The shipped predictor is fitted on RoboDesk models only (vp2/assets/diagnose_predictor.json).


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    return write_moving_square_dataset(
        tmp_path_factory.mktemp("cli-diag") / "squares", size=64, action_dim=4
    )


def test_defaults_and_flags_map_onto_the_config():
    args = cli.build_parser().parse_args(["diagnose", "--model", "repeat_last_frame"])
    assert build(DiagnoseConfig, args, diagnose_cmd.FLAGS) == DiagnoseConfig(
        model="repeat_last_frame"
    )
    assert args.out is None
    args = cli.build_parser().parse_args([
        "diagnose", "--model", "m:f", "--env", "tabletop", "--model-arg", "speed=0.5",
        "--clips", "8", "--instances-per-task", "1", "--num-samples", "20", "--seed", "3",
        "--device", "cpu", "--sampling-seeds", "1", "--no-progress", "--out", "r.json",
        "--no-oracle-agreement",
    ])
    assert build(DiagnoseConfig, args, diagnose_cmd.FLAGS) == DiagnoseConfig(
        model="m:f", env="tabletop", model_args={"speed": 0.5}, clips=8, instances_per_task=1,
        num_samples=20, seed=3, device="cpu", sampling_seeds=1, progress=False,
        oracle_agreement=False,
    )
    assert args.out == "r.json"


def test_prints_a_verdict_per_measure_and_writes_the_report(data, tmp_path, capsys):
    from tests.benchmark import tiny_suite_path

    out = tmp_path / "report.json"
    code = cli.main([
        "diagnose", "--model", f"{HERE}:StillModel", "--env", "tabletop", "--data", str(data),
        "--suite", str(tiny_suite_path()), "--clips", "8", "--instances-per-task", "1",
        "--num-samples", "8", "--no-progress", "--out", str(out),
    ])
    assert code == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == f"StillModel ({HERE}:StillModel) on tabletop"
    assert printed[1].endswith("-> predictions do not depend on the actions: it will plan like "
                               "repeat-last-frame")
    assert printed[2] == "scripted plan: not measured: the instances store no scripted plan"
    assert printed[4].endswith("-> the scores are too flat to steer MPPI: it executes the mean "
                               "of its samples, as with repeat-last-frame")
    assert printed[6] == (
        "agreement with the simulator: Spearman +0.00 (median over 1 instances), its best "
        "candidate in the model's top 10% on 0 -> the model's ranking of the candidates is not "
        "the simulator's: its favourites are not what would happen"
    )
    assert printed[7] == f"predicted control score: 8% success ({TABLETOP_PREDICTOR})"
    assert printed[-1] == f"wrote {out}"
    # The measurements waited in report.partial.json while it ran; the report replaces them.
    assert sorted(p.name for p in out.parent.iterdir() if "report" in p.name) == ["report.json"]
    report = json.loads(out.read_text())
    assert report["verdicts"]["action_conditioning"]["status"] == "blind"
    assert report["action_conditioning"]["clips"] == 8
    assert report["predicted_control_score"] == pytest.approx(TABLETOP_BLIND_SCORE, abs=1e-5)


def test_default_report_path_and_missing_dataset(tmp_path, monkeypatch, capsys):
    from tests.benchmark import tiny_suite_path

    monkeypatch.chdir(tmp_path)
    code = cli.main(["diagnose", "--model", "repeat_last_frame", "--env", "tabletop",
                     "--data", "data/tabletop-100x-64px"])
    assert code == 2
    err = capsys.readouterr().err
    assert "no dataset at data/tabletop-100x-64px" in err and "`vp2 collect tabletop --out" in err
    code = cli.main(["diagnose", "--model", "repeat_last_frame", "--env", "tabletop",
                     "--clips", "0", "--instances-per-task", "1", "--num-samples", "4",
                     "--suite", str(tiny_suite_path()), "--no-progress"])
    assert code == 0
    written = tmp_path / "runs/diagnose/repeat_last_frame-tabletop/diagnose.json"
    assert json.loads(written.read_text())["action_conditioning"] == {"skipped": "--clips 0"}
    assert cli.main(["diagnose", "--model", "repeat_last_frame", "--clips", "1"]) == 2
    assert "clips must be 0 (skip) or >= 2" in capsys.readouterr().err
