"""The shipped oracle: building the asset from oracle runs, refusals, loading, and the default
normalisation of ``vp2 run`` / ``vp2 main`` / ``vp2 report`` (with an injected asset, and
without one)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest
import yaml

from tests.benchmark import tiny_suite_path
from vp2 import cli
from vp2.benchmark.main_job import MainJobConfig, run_main_job
from vp2.benchmark.results import format_summary, summarize
from vp2.benchmark.ship_oracle import build_oracle_asset, write_oracle_asset
from vp2.benchmark.shipped_oracle import (
    ASSET_FORMAT,
    ENV_VAR,
    NO_SHIPPED_ORACLE,
    default_asset_path,
    load_shipped_oracle,
    summarize_run,
)
from vp2.data.suite import SUITE_FORMAT, TaskSuite
from vp2.report.page import write_report

TASK = "tabletop/push_sphere"
#: (instance, seed) -> success: per seed 1.0, 0.5, 0.5, so the rate is 2/3 (4 of 6).
OUTCOMES = {(0, 0): True, (1, 0): True, (0, 1): True, (1, 1): False, (0, 2): True, (1, 2): False}


def _sha(index: int, suite: Path | None = None) -> str:
    return TaskSuite.load(suite or tiny_suite_path()).get(TASK, index).fingerprint


def write_oracle_run(
    run_dir: Path,
    outcomes: dict[tuple[int, int], bool | None] = OUTCOMES,
    *,
    model: str = "simulator",
    suite: Path | None = None,
    classifier: dict | None = None,
    **config_overrides,
) -> Path:
    """A simulator-oracle run directory as the runner leaves it (config.yaml, trials.jsonl);
    an outcome ``None`` is an error record."""
    suite = suite or tiny_suite_path()
    run_dir.mkdir(parents=True)
    config = {
        "model": model, "agent": "planning", "suite": str(suite), "optimizer": "mppi",
        "num_samples": None, "gamma": 0.05, "num_iterations": None, "cost": "auto",
        "num_steps": 15, "seeds": sorted({s for _, s in outcomes}), "oracle": None,
        **config_overrides,
    }
    (run_dir / "config.yaml").write_text(
        yaml.safe_dump({"vp2_version": "test", "spec_deviations": [], "config": config})
    )
    lines = []
    for (i, s), ok in outcomes.items():
        record = {
            "task": TASK, "instance": i, "instance_sha": _sha(i, suite), "seed": s,
            "success": ok, "cost": "pixel", "num_steps": 15, "vp2_version": "test",
            "finished_at": f"2026-11-2{s}T10:00:00+00:00",
            "error": None if ok is not None else {"type": "SimError", "message": "x"},
        }
        if classifier is not None:
            record["agent"] = {"agent": "planning", "classifier": classifier}
        lines.append(json.dumps(record, sort_keys=True))
    (run_dir / "trials.jsonl").write_text("\n".join(lines) + "\n")
    return run_dir


@pytest.fixture
def asset(tmp_path, monkeypatch) -> Path:
    """An asset built from a fake oracle run, injected through ``VP2_ORACLE_ASSET``."""
    path = write_oracle_asset(
        build_oracle_asset([write_oracle_run(tmp_path / "oracle-run")]), tmp_path / "oracle.json"
    )
    monkeypatch.setenv(ENV_VAR, str(path))
    return path


@pytest.fixture
def no_asset(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "absent.json"))


# --------------------------------------------------------------------------- building


def test_build_write_and_load_round_trip(tmp_path):
    data = build_oracle_asset([write_oracle_run(tmp_path / "run")], note="test runs")
    assert data["format"] == ASSET_FORMAT and data["suite_format"] == SUITE_FORMAT
    assert data["date"] == "2026-11-22"  # the last trial's finish
    assert data["note"] == "test runs" and "num_steps=15" in data["measured_by"]
    assert data["tasks"] == {
        TASK: {"successes": 4, "trials": 6, "rate": pytest.approx(2 / 3), "instances": [0, 1],
               "seeds": [0, 1, 2], "num_samples": 200}  # the SPEC default the run used
    }
    assert data["instance_fingerprints"] == {f"{TASK}#0": _sha(0), f"{TASK}#1": _sha(1)}
    path = write_oracle_asset(data, tmp_path / "sub" / "oracle.json")
    assert not list(path.parent.glob(".*.tmp"))
    oracle = load_shipped_oracle(path)
    assert oracle is not None and oracle.path == path and oracle.date == "2026-11-22"
    t = oracle.tasks[TASK]
    assert (t.successes, t.trials, t.instances, t.seeds, t.num_samples) == (
        4, 6, (0, 1), (0, 1, 2), 200)
    line = oracle.describe()
    for part in ("2 instance(s) per task", "200 planner samples", "seed(s) 0, 1, 2",
                 f"suite {SUITE_FORMAT}", "measured 2026-11-22"):
        assert part in line


def test_build_combines_runs_and_records_the_samples_they_used(tmp_path):
    a = write_oracle_run(tmp_path / "a", {k: v for k, v in OUTCOMES.items() if k[1] < 2},
                         num_samples=8)
    b = write_oracle_run(tmp_path / "b", {k: v for k, v in OUTCOMES.items() if k[1] == 2},
                         num_samples=8)
    data = build_oracle_asset([a, b], date="2027-01-02")
    assert data["date"] == "2027-01-02"
    assert data["tasks"][TASK]["num_samples"] == 8 and data["tasks"][TASK]["trials"] == 6
    assert data["tasks"][TASK]["rate"] == pytest.approx(2 / 3)


def test_describe_names_the_tasks_with_other_samples(tmp_path):
    tasks = {
        name: {"successes": 1, "trials": 2, "rate": 0.5, "instances": [0], "seeds": [0, 1],
               "num_samples": n}
        for name, n in [("robodesk/push_red", 200), ("robodesk/open_slide", 800),
                        ("robodesk/open_drawer", 800), ("robodesk/push_green", 200),
                        ("robodesk/push_blue", 200)]
    }
    path = write_oracle_asset({"format": ASSET_FORMAT, "suite_format": SUITE_FORMAT,
                               "date": "2027-01-01", "tasks": tasks, "instance_fingerprints": {}},
                              tmp_path / "o.json")
    line = load_shipped_oracle(path).describe()
    assert "200 planner samples (800 on robodesk/open_drawer, robodesk/open_slide)" in line


def test_build_records_the_classifier_and_refuses_mixed_ones(tmp_path):
    first = {"sha256": "aaaa", "dataset": "data/d", "heldout_accuracy": 0.98}
    data = build_oracle_asset([write_oracle_run(tmp_path / "one", classifier=first)])
    assert data["tasks"][TASK]["classifier"] == first
    assert "classifier" not in build_oracle_asset(
        [write_oracle_run(tmp_path / "none")])["tasks"][TASK]
    a = write_oracle_run(tmp_path / "a", {(0, 0): True}, classifier=first)
    b = write_oracle_run(tmp_path / "b", {(0, 1): True}, classifier={**first, "sha256": "bbbb"})
    with pytest.raises(ValueError, match="2 different success classifiers"):
        build_oracle_asset([a, b])


def _other_suite(tmp_path: Path) -> Path:
    """The tiny suite with instance 0's goal image changed: another suite version."""
    suite = TaskSuite.load(tiny_suite_path())
    changed = [
        dataclasses.replace(i, goal_image=255 - i.goal_image) if i.index == 0 else i
        for i in suite
    ]
    path = tmp_path / "other-suite.npz"
    TaskSuite(changed, seed=suite.seed).save(path)
    return path


@pytest.mark.parametrize(
    "case, message",
    [
        ("not_oracle", "is not a simulator-oracle run"),
        ("error", "ended in an error"),
        ("no_config", "no config.yaml"),
        ("stale_suite", "another version of the task suite"),
        ("mixed_suites", "mixed task suites"),
        ("duplicate", "is in both"),
        ("settings", "settings"),
    ],
)
def test_build_refuses(tmp_path, case, message):
    runs = {
        "not_oracle": lambda: [write_oracle_run(tmp_path / "r", model="repeat_last_frame")],
        "error": lambda: [write_oracle_run(tmp_path / "r", {**OUTCOMES, (1, 2): None})],
        "no_config": lambda: [write_oracle_run(tmp_path / "r")],
        "stale_suite": lambda: [write_oracle_run(tmp_path / "r", suite=_other_suite(tmp_path))],
        "mixed_suites": lambda: [
            write_oracle_run(tmp_path / "a", {(0, 0): True}),
            write_oracle_run(tmp_path / "b", {(0, 1): True}, suite=_other_suite(tmp_path)),
        ],
        "duplicate": lambda: [write_oracle_run(tmp_path / "a"), write_oracle_run(tmp_path / "b")],
        "settings": lambda: [
            write_oracle_run(tmp_path / "a", {(0, 0): True}),
            write_oracle_run(tmp_path / "b", {(0, 1): True}, num_steps=3),
        ],
    }[case]()
    if case == "no_config":
        (runs[0] / "config.yaml").unlink()
    if case == "stale_suite":  # ran on the other suite, whose file was since replaced
        (runs[0] / "config.yaml").write_text(
            (runs[0] / "config.yaml").read_text().replace(
                str(tmp_path / "other-suite.npz"), str(tiny_suite_path())))
    with pytest.raises(ValueError, match=message):
        build_oracle_asset(runs)


def test_ship_oracle_command(tmp_path, capsys):
    run = write_oracle_run(tmp_path / "run")
    out = tmp_path / "oracle.json"
    assert cli.main(["ship-oracle", str(run), "--out", str(out), "--note", "by hand"]) == 0
    printed = capsys.readouterr().out
    assert "66.7%  (4/6 trials" in printed and "shipped oracle:" in printed and str(out) in printed
    assert json.loads(out.read_text())["note"] == "by hand"
    bad = write_oracle_run(tmp_path / "bad", model="repeat_last_frame")
    assert cli.main(["ship-oracle", str(bad), "--out", str(tmp_path / "x.json")]) == 2
    assert "not a simulator-oracle run" in capsys.readouterr().err
    assert not (tmp_path / "x.json").exists()


# --------------------------------------------------------------------------- loading


def test_loading_a_missing_or_broken_asset(tmp_path, monkeypatch):
    assert load_shipped_oracle(tmp_path / "absent.json") is None
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "absent.json"))
    assert load_shipped_oracle() is None
    (tmp_path / "broken.json").write_text('{"format": "something else"}')
    with pytest.raises(ValueError, match="not a vp2 oracle file"):
        load_shipped_oracle(tmp_path / "broken.json")


def test_the_packaged_asset_loads_if_there_is_one(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    oracle = load_shipped_oracle()
    if not default_asset_path().is_file():
        assert oracle is None
    else:
        assert oracle is not None and oracle.tasks and oracle.suite_format == SUITE_FORMAT


# --------------------------------------------------------------------------- normalising


def _model_records(outcomes: dict[tuple[int, int], bool], sha=_sha):
    return [
        {"task": TASK, "instance": i, "instance_sha": sha(i), "seed": s, "success": ok,
         "error": None, "cost": "pixel"}
        for (i, s), ok in outcomes.items()
    ]


def test_normalisation_by_the_shipped_oracle(asset):
    oracle = load_shipped_oracle()
    records = _model_records({(0, 0): True, (1, 0): False})
    summary = summarize_run(records, shipped=oracle)
    assert summary.tasks[0].oracle_mean == pytest.approx(2 / 3)
    assert summary.normalised == pytest.approx(0.5 / (2 / 3))
    # The same as normalising by the oracle run's records.
    by_run = summarize(records, [
        {"task": TASK, "instance": i, "seed": s, "success": ok, "error": None}
        for (i, s), ok in OUTCOMES.items()])
    assert summary.normalised == pytest.approx(by_run.normalised)
    text = format_summary(summary)
    assert "Oracle-normalised score: 0.750" in text
    assert f"Normalised by the {oracle.describe()}" in text
    # An oracle run is not normalised.
    assert summarize_run(records, is_oracle=True, shipped=oracle).normalised is None


def test_the_shipped_oracle_is_not_used_on_other_instances_or_suites(asset):
    oracle = load_shipped_oracle()
    # Another suite version of the instance: the task is omitted, and the summary says why.
    summary = summarize_run(_model_records({(0, 0): True}, sha=lambda i: "0" * 16),
                            shipped=oracle)
    assert summary.normalised is None and summary.tasks[0].oracle_mean is None
    assert any("ran on other instances" in w and TASK in w for w in summary.warnings)
    # A task the oracle lacks: omitted too.
    other = [{"task": "tabletop/push_large_cube", "instance": 0, "seed": 0, "success": True,
              "error": None}]
    summary = summarize_run(_model_records({(0, 0): True}) + other, shipped=oracle)
    assert summary.normalised == pytest.approx(1.5)  # push_sphere only: 1.0 / (2/3)
    assert any("no oracle results for ['tabletop/push_large_cube']" in w
               for w in summary.warnings)
    # Another suite format: not normalised at all.
    stale = dataclasses.replace(oracle, suite_format="vp2-task-suite/0")
    summary = summarize_run(_model_records({(0, 0): True}), shipped=stale)
    assert summary.normalised is None
    assert any("measured on task suite 'vp2-task-suite/0'" in w for w in summary.warnings)


def _run_args(out: Path, *extra: str) -> list[str]:
    return ["run", "--model", "repeat_last_frame", "--suite", str(tiny_suite_path()),
            "--tasks", TASK, "--num-instances", "1", "--seeds", "0", "--num-steps", "3",
            "--num-samples", "8", "--no-gifs", "--no-progress", "--out", str(out), *extra]


def test_vp2_run_is_normalised_by_the_shipped_oracle_by_default(asset, tmp_path, capsys,
                                                                monkeypatch):
    out = tmp_path / "run"
    assert cli.main(_run_args(out)) == 0
    printed = capsys.readouterr().out
    # repeat_last_frame succeeds on instance 0 by construction: 1.0 / (2/3).
    assert "Oracle-normalised score: 1.500" in printed
    assert "Normalised by the shipped oracle: simulator oracle" in printed
    assert "Normalised by the shipped oracle" in (out / "summary.md").read_text()
    assert json.loads((out / "summary.json").read_text())["normalised"] == pytest.approx(1.5)
    html = (out / "report.html").read_text()
    assert '<span class="score">1.500</span>' in html and "measured 2026-11-22" in html
    # --oracle RUN_DIR overrides the shipped oracle (a resumed run only re-summarises).
    oracle_run = write_oracle_run(tmp_path / "other-oracle", {(0, 0): True, (0, 1): False})
    assert cli.main(_run_args(out, "--resume", "--oracle", str(oracle_run))) == 0
    printed = capsys.readouterr().out
    assert "Oracle-normalised score: 2.000" in printed and "Normalised by the oracle run" in printed
    # No shipped oracle: no crash, one note, no normalised score.
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "absent.json"))
    assert cli.main(_run_args(out, "--resume")) == 0
    printed = capsys.readouterr().out
    assert printed.count("no shipped oracle") == 1 and "Oracle-normalised" not in printed
    html = write_report([out], tmp_path / "report.html").read_text()
    assert html.count("no shipped oracle") == 1


def test_an_oracle_run_is_not_normalised(asset, tmp_path):
    html = write_report([tmp_path / "oracle-run"], tmp_path / "r.html").read_text()
    assert "the oracle (1.000 by definition)" in html and "no shipped oracle" not in html


def test_main_job_shows_the_shipped_oracle_column(asset, tmp_path):
    config = MainJobConfig(out=str(tmp_path / "main"), suite=str(tiny_suite_path()),
                           num_steps=3, workers=1, agents=("random",))
    table, path = run_main_job(config, gallery=False)
    lines = table.splitlines()
    assert lines[0] == "| task | random actions | oracle (shipped) |"
    assert lines[2].startswith(f"| {TASK} |") and lines[2].endswith("| 67% (6) |")
    assert any(line.startswith("| **oracle-normalised score** | **") for line in lines)
    assert "normalised by the shipped oracle: simulator oracle" in path.read_text()


def test_main_job_without_a_shipped_oracle(no_asset, tmp_path):
    config = MainJobConfig(out=str(tmp_path / "main"), suite=str(tiny_suite_path()),
                           num_steps=3, workers=1, agents=("random",))
    table, _ = run_main_job(config, gallery=False)
    assert "oracle (shipped)" not in table and table.count(NO_SHIPPED_ORACLE) == 1
