"""Normalising by the shipped oracle's tables: each task by the table of the run's planner
samples and render spec, and one line why where none matches, in ``vp2 run``, ``vp2 main``
and ``vp2 report``."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from tests.benchmark import tiny_suite_path
from tests.oracle.fixtures import (
    OUTCOMES,
    TASK,
    model_records,
    table,
    write_oracle_run,
)
from vp2 import cli
from vp2.benchmark.main_job import MainJobConfig, run_main_job
from vp2.envs import tabletop_scene
from vp2.envs.render_specs import render_fingerprint
from vp2.oracle.build import build_asset, build_table, write_oracle_asset, write_table
from vp2.oracle.shipped import (
    ENV_VAR,
    NO_SHIPPED_ORACLE,
    ShippedOracle,
    load_shipped_oracle,
    summarize_run,
)
from vp2.planning.config import PlannerConfig
from vp2.report.page import write_report
from vp2.run.results import format_summary, summarize

ROBODESK = "robodesk/push_red"
NO_TABLE_AT_5 = (
    "no shipped oracle table at 5 planner samples (tables: samples-8 at 8, spec at 200); pass "
    "--oracle RUN_DIR (a simulator-oracle run at the same budget)"
)


@pytest.fixture
def asset(tmp_path, monkeypatch) -> Path:
    """Tables ``spec`` (200 samples, rate 2/3) and ``samples-8`` (rate 1/2) built through
    results/ from fake oracle runs, injected through ``VP2_ORACLE_ASSET``."""
    results = tmp_path / "results"
    write_table(*build_table([write_oracle_run(tmp_path / "oracle-run")]), results)
    eight = write_oracle_run(tmp_path / "eight", {(0, 0): True, (1, 0): False}, num_samples=8,
                             day=5)
    write_table(*build_table([eight]), results)
    path = write_oracle_asset(build_asset(results), tmp_path / "oracle.json")
    monkeypatch.setenv(ENV_VAR, str(path))
    return path


def _oracle(*tables) -> ShippedOracle:
    return ShippedOracle(path=Path("hand.json"), tables=tables)


# --------------------------------------------------------------------------- matching


def test_a_run_is_normalised_by_the_table_of_its_own_budget(asset):
    oracle = load_shipped_oracle()
    records = model_records({(0, 0): True, (1, 0): False})  # 0.5
    at_200 = summarize_run(records, shipped=oracle, planner=PlannerConfig())
    assert at_200.tasks[0].oracle_mean == pytest.approx(2 / 3)
    assert at_200.normalised == pytest.approx(0.5 / (2 / 3))
    assert at_200.oracle_source == oracle.table("spec").describe()
    assert at_200.oracle_source.startswith(
        "shipped oracle table 'spec' (200 planner samples, measured 2026-11-22): ")
    # The same as normalising by the oracle run's records.
    by_run = summarize(records, [{"task": TASK, "instance": i, "seed": s, "success": ok,
                                  "error": None} for (i, s), ok in OUTCOMES.items()])
    assert at_200.normalised == pytest.approx(by_run.normalised)
    text = format_summary(at_200)
    assert "Oracle-normalised score: 0.750" in text
    assert "Normalised by the shipped oracle table 'spec' (200 planner samples" in text
    at_8 = summarize_run(records, shipped=oracle, planner=PlannerConfig(num_samples=8))
    assert at_8.normalised == pytest.approx(1.0) and "'samples-8' (8 planner" in at_8.oracle_source
    assert not at_8.warnings and at_8.oracle_note is None
    # An oracle run is not normalised.
    assert summarize_run(records, is_oracle=True, shipped=oracle).normalised is None


def test_a_run_at_a_budget_without_a_table_says_so_once(asset):
    summary = summarize_run(model_records({(0, 0): True}), shipped=load_shipped_oracle(),
                            planner=PlannerConfig(num_samples=5))
    assert summary.normalised is None and summary.tasks[0].oracle_mean is None
    assert summary.oracle_source is None and summary.oracle_note == NO_TABLE_AT_5
    text = format_summary(summary)
    assert text.count("no shipped oracle table") == 1
    assert f"Not oracle-normalised: {NO_TABLE_AT_5}" in text and "Oracle-normalised" not in text


def test_a_table_rendered_with_another_camera_is_not_used(asset, monkeypatch):
    oracle = load_shipped_oracle()
    before = render_fingerprint("tabletop")
    default = tabletop_scene.DEFAULT_SCENE
    moved = dataclasses.replace(default.camera, pos=(1.0, 0.0, 4.0))
    monkeypatch.setattr(tabletop_scene, "DEFAULT_SCENE", dataclasses.replace(default, camera=moved))
    summary = summarize_run(model_records({(0, 0): True}), shipped=oracle)
    assert summary.normalised is None
    assert summary.oracle_note == (
        "the shipped oracle table 'spec' was rendered with another camera/render spec "
        f"(tabletop render fingerprint {before}, this vp2's {render_fingerprint('tabletop')}); "
        "re-measure it (`vp2 ship-oracle`) or pass --oracle RUN_DIR")


def test_tasks_of_one_run_may_be_matched_by_different_tables():
    oracle = _oracle(table("pushes", {TASK: (0.5, 200)}),
                     table("desk", {ROBODESK: (0.25, 200), TASK: (0.9, 50)}))
    records = model_records({(0, 0): True}) + model_records(
        {(0, 0): False, (1, 0): True}, task=ROBODESK, shas=lambda i: f"r{i}")
    found = oracle.match(records)
    assert {t: tbl.name for t, tbl in found.tables.items()} == {TASK: "pushes", ROBODESK: "desk"}
    summary = summarize_run(records, shipped=oracle)
    assert summary.normalised == pytest.approx((1.0 + 0.5) / 2 / ((0.5 + 0.25) / 2))
    assert summary.oracle_source == (
        "shipped oracle tables 'pushes' (200 planner samples, measured 2026-11-22) on 1 task(s) "
        "and 'desk' (50/200 planner samples, measured 2026-11-22) on 1 task(s)")
    # At 50 samples the desk table matches the push task only: the other is named, once.
    summary = summarize_run(records, shipped=oracle, planner=PlannerConfig(num_samples=50))
    assert summary.normalised == pytest.approx(1.0 / 0.9)
    assert summary.warnings == [
        f"no shipped oracle table at 50 planner samples for {ROBODESK} (tables: pushes at 200, "
        "desk at 50/200): the normalised score omits it; pass --oracle RUN_DIR (a "
        "simulator-oracle run at the same budget)"]
    assert summary.oracle_note is None


def test_a_table_measured_with_another_classifier_or_weight_is_not_used():
    shipped = {"sha256": "aaaa", "weight": 10.0, "dataset": "d"}
    oracle = _oracle(table("desk", {ROBODESK: (0.5, 200)}, classifiers={ROBODESK: shipped}))

    def records(classifier):
        out = model_records({(0, 0): True}, task=ROBODESK, shas=lambda i: f"r{i}")
        if classifier is not False:  # False: records that do not say (no agent field)
            out[0]["agent"] = {"agent": "planning", "classifier": classifier}
        return out

    same = summarize_run(records({"sha256": "aaaa", "weight": 10, "dataset": "other"}),
                         shipped=oracle)
    assert same.normalised == pytest.approx(2.0)
    assert summarize_run(records(False), shipped=oracle).normalised == pytest.approx(2.0)
    # Records (and tables built from them) from before the weight was recorded planned at the
    # SPEC's weight, 10: they match a table or run at 10, and only at 10.
    unweighted = {"sha256": "aaaa", "dataset": "d"}
    assert summarize_run(records(unweighted), shipped=oracle).normalised == pytest.approx(2.0)
    old = _oracle(table("desk", {ROBODESK: (0.5, 200)}, classifiers={ROBODESK: unweighted}))
    assert summarize_run(records(shipped), shipped=old).normalised == pytest.approx(2.0)
    at_100 = summarize_run(records({**shipped, "weight": 100.0}), shipped=old)
    assert at_100.normalised is None and at_100.oracle_note.startswith(
        "the shipped oracle table 'desk' planned with classifier aaaa at weight 10, this run "
        "with classifier aaaa at weight 100")
    remedy = "; re-measure it (`vp2 ship-oracle`) or pass --oracle RUN_DIR"
    for theirs, line in [
        ({"sha256": "bbbb", "weight": 10.0}, "classifier bbbb at weight 10"),
        ({"sha256": "aaaa", "weight": 100.0}, "classifier aaaa at weight 100"),
        (None, "no classifier"),
    ]:
        summary = summarize_run(records(theirs), shipped=oracle)
        assert summary.normalised is None
        assert summary.oracle_note == (
            "the shipped oracle table 'desk' planned with classifier aaaa at weight 10, this "
            f"run with {line}" + remedy)
    # The random agent plans nothing: its records name no classifier and no cost, and the
    # table of its (SPEC) budget normalises it whatever classifier the oracle planned with.
    random = records(False)
    random[0]["agent"], random[0]["cost"] = {"agent": "random_actions"}, "none"
    assert summarize_run(random, shipped=oracle).normalised == pytest.approx(2.0)
    # A run resumed after a classifier change: one trial with the table's, one without.
    mixed = records({"sha256": "aaaa", "weight": 10.0}) + records({"sha256": "bbbb", "weight": 10.0})
    mixed[1]["instance"], mixed[1]["instance_sha"] = 1, "r1"
    summary = summarize_run(mixed, shipped=oracle)
    assert summary.normalised is None and "this run with classifier bbbb at weight 10" in (
        summary.oracle_note)


def test_other_instances_suites_and_missing_tasks(asset):
    oracle = load_shipped_oracle()
    # Another suite version of the instance: the task is omitted, and the summary says why.
    summary = summarize_run(model_records({(0, 0): True}, shas=lambda i: "0" * 16),
                            shipped=oracle)
    assert summary.normalised is None and summary.tasks[0].oracle_mean is None
    assert "'spec' ran on other instances of tabletop/push_sphere" in summary.oracle_note
    # A task no table has: omitted, named once (not again as "no oracle results").
    other = [{"task": "tabletop/push_large_cube", "instance": 0, "seed": 0, "success": True,
              "error": None}]
    summary = summarize_run(model_records({(0, 0): True}) + other, shipped=oracle)
    assert summary.normalised == pytest.approx(1.5)  # push_sphere only: 1.0 / (2/3)
    assert summary.warnings == ["no shipped oracle table has tabletop/push_large_cube: the "
                                "normalised score omits it"]
    # Another suite version: it normalises a task only where it fingerprinted every instance
    # the run used identically (a new version may regenerate only some categories).
    stale = _oracle(*(dataclasses.replace(t, suite_format="vp2-task-suite/0")
                      for t in oracle.tables))
    summary = summarize_run(model_records({(0, 0): True}), shipped=stale)
    assert summary.normalised == pytest.approx(1.5)
    summary = summarize_run(model_records({(0, 0): True}, shas=lambda i: "0" * 16), shipped=stale)
    assert summary.normalised is None
    assert "'spec' was measured on task suite 'vp2-task-suite/0'" in summary.oracle_note


# --------------------------------------------------------------------------- the commands


def _run_args(out: Path, *extra: str, samples: int = 8) -> list[str]:
    return ["run", "--model", "repeat_last_frame", "--suite", str(tiny_suite_path()),
            "--tasks", TASK, "--num-instances", "1", "--seeds", "0", "--num-steps", "3",
            "--num-samples", str(samples), "--no-gifs", "--no-progress", "--out", str(out),
            *extra]


def test_vp2_run_and_report_name_the_table(asset, tmp_path, capsys, monkeypatch):
    out = tmp_path / "run"
    assert cli.main(_run_args(out)) == 0
    printed = capsys.readouterr().out
    # repeat_last_frame succeeds on instance 0 by construction: 1.0 / (1/2), the 8-sample table.
    assert "Oracle-normalised score: 2.000" in printed
    assert "Normalised by the shipped oracle table 'samples-8' (8 planner samples, measured " \
           "2026-11-25)" in printed
    assert "table 'samples-8'" in (out / "summary.md").read_text()
    assert json.loads((out / "summary.json").read_text())["normalised"] == pytest.approx(2.0)
    html = (out / "report.html").read_text()
    assert '<span class="score">2.000</span>' in html
    assert "shipped oracle table &#x27;samples-8&#x27; (8 planner samples" in html
    # --oracle RUN_DIR overrides the shipped oracle (a resumed run only re-summarises).
    oracle_run = write_oracle_run(tmp_path / "other-oracle", {(0, 0): True, (0, 1): False})
    assert cli.main(_run_args(out, "--resume", "--oracle", str(oracle_run))) == 0
    printed = capsys.readouterr().out
    assert "Oracle-normalised score: 2.000" in printed and "Normalised by the oracle run" in printed
    # A budget with no table: one line why, in the run's summary and in the report.
    five = tmp_path / "five"
    assert cli.main(_run_args(five, samples=5)) == 0
    printed = capsys.readouterr().out
    assert printed.count("no shipped oracle table") == 1 and "Oracle-normalised" not in printed
    assert f"Not oracle-normalised: {NO_TABLE_AT_5}" in printed
    html = write_report([five], tmp_path / "report.html").read_text()
    assert html.count("no shipped oracle table at 5 planner samples") == 1
    assert "no shipped oracle (" not in html
    # No shipped oracle at all: one note, no normalised score.
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "absent.json"))
    assert cli.main(_run_args(out, "--resume")) == 0
    printed = capsys.readouterr().out
    assert printed.count("no shipped oracle") == 1 and "Oracle-normalised" not in printed
    html = write_report([out], tmp_path / "report.html").read_text()
    assert html.count("no shipped oracle") == 1


def test_an_oracle_run_is_not_normalised(asset, tmp_path):
    html = write_report([tmp_path / "oracle-run"], tmp_path / "r.html").read_text()
    assert "the oracle (1.000 by definition)" in html and "no shipped oracle" not in html


def _main(tmp_path: Path) -> tuple[str, Path]:
    config = MainJobConfig(out=str(tmp_path / "main"), suite=str(tiny_suite_path()),
                           num_steps=3, workers=1, agents=("random",))
    return run_main_job(config, gallery=False)


def test_main_job_shows_the_table_of_each_agent(asset, tmp_path):
    table_md, path = _main(tmp_path)
    lines = table_md.splitlines()
    # The random agent plans nothing; its run's planner is the SPEC's: the spec table.
    assert lines[0] == "| task | random actions | oracle spec (200 samples) |"
    assert lines[2].startswith(f"| {TASK} |") and lines[2].endswith("| 67% (6) |")
    assert any(line.startswith("| **oracle-normalised score** | **") for line in lines)
    assert ("- random actions: normalised by the shipped oracle table 'spec' (200 planner "
            "samples, measured 2026-11-22)") in path.read_text()


def test_main_job_without_a_matching_table_or_without_an_asset(tmp_path, monkeypatch):
    results = tmp_path / "results"
    eight = write_oracle_run(tmp_path / "eight", {(0, 0): True}, num_samples=8)
    write_table(*build_table([eight]), results)
    monkeypatch.setenv(ENV_VAR, str(write_oracle_asset(build_asset(results),
                                                       tmp_path / "oracle.json")))
    table_md, _ = _main(tmp_path / "a")
    assert table_md.splitlines()[0] == "| task | random actions |"
    assert table_md.count("no shipped oracle table at 200 planner samples") == 1
    assert "- random actions: not oracle-normalised: no shipped oracle table at 200 planner " \
           "samples (tables: samples-8 at 8); pass --oracle RUN_DIR" in table_md
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "absent.json"))
    table_md, _ = _main(tmp_path / "b")
    assert "oracle spec" not in table_md and table_md.count(NO_SHIPPED_ORACLE) == 1
