"""The shipped oracle's tables: from oracle runs to ``results/oracle`` to the asset, byte for
byte; refusals; loading. How runs are normalised by it: test_normalisation.py."""

from __future__ import annotations

import dataclasses
import json
import os
from pathlib import Path

import pytest

from tests.benchmark import tiny_suite_path
from tests.oracle.fixtures import OUTCOMES, TASK, actions, sha, write_oracle_run
from vp2 import cli
from vp2.data.suite import SUITE_FORMAT, TaskSuite
from vp2.envs.render_specs import render_fingerprint
from vp2.oracle.build import (
    asset_text,
    build_asset,
    build_oracle_asset,
    build_table,
    read_table,
    table_of,
    write_oracle_asset,
    write_table,
)
from vp2.oracle.shipped import (
    ASSET_FORMAT,
    ENV_VAR,
    default_asset_path,
    load_shipped_oracle,
)

REPO = Path(__file__).resolve().parents[2]


def _results(tmp_path: Path) -> Path:
    """A results tree of two tables: ``spec`` (SPEC samples, rate 2/3) and ``samples-8``."""
    results = tmp_path / "results" / "oracle"
    write_table(*build_table([write_oracle_run(tmp_path / "spec-run")], note="spec"), results)
    eight = write_oracle_run(tmp_path / "eight-run", {(0, 0): True, (1, 0): False},
                             num_samples=8, day=5)
    write_table(*build_table([eight]), results)
    return results


# --------------------------------------------------------------------------- one table


def test_build_table_records_provenance_and_compact_trials(tmp_path):
    meta, trials = build_table([write_oracle_run(tmp_path / "run")], note="test runs")
    assert meta["name"] == "spec"  # every task at the SPEC's count
    assert meta["suite_format"] == SUITE_FORMAT and meta["date"] == "2026-11-22"
    assert meta["note"] == "test runs" and meta["vp2_version"] == "test"
    assert meta["render"] == {"tabletop": render_fingerprint("tabletop")}
    assert meta["classifiers"] == {} and "num_steps=15" in meta["measured_by"]
    assert meta["commands"] == [
        f"vp2 run --model simulator --suite {tiny_suite_path()} --tasks {TASK} "
        "--num-instances 2 --seeds 0 1 2 --out run"]
    assert [(r["instance"], r["seed"]) for r in trials] == sorted(OUTCOMES)
    first = trials[0]
    assert first == {"task": TASK, "instance": 0, "seed": 0, "instance_sha": sha(0),
                     "success": True, "first_success_step": 1, "num_steps": 2,
                     "num_samples": 200, "actions": actions(0, 0)}
    table = table_of(meta, trials)
    assert table["tasks"] == {
        TASK: {"successes": 4, "trials": 6, "rate": pytest.approx(2 / 3), "instances": [0, 1],
               "seeds": [0, 1, 2], "num_samples": 200}}
    assert table["instance_fingerprints"] == {f"{TASK}#0": sha(0), f"{TASK}#1": sha(1)}
    assert "commands" not in table and table["name"] == "spec"


def test_table_names_and_dates(tmp_path):
    eight = write_oracle_run(tmp_path / "a", {(0, 0): True}, num_samples=8)
    assert build_table([eight])[0]["name"] == "samples-8"
    meta, _ = build_table([eight], name="mine", date="2027-01-02")
    assert (meta["name"], meta["date"]) == ("mine", "2027-01-02")
    with pytest.raises(ValueError, match="table name 'Bad Name'"):
        build_table([eight], name="Bad Name")
    with pytest.raises(ValueError, match="date '2/1/2027': give it as YYYY-MM-DD"):
        build_table([eight], date="2/1/2027")


def test_the_classifier_is_recorded_and_mixed_ones_refused(tmp_path):
    first = {"sha256": "aaaa", "dataset": "data/d", "heldout_accuracy": 0.98}
    meta, trials = build_table([write_oracle_run(tmp_path / "one", classifier=first)])
    assert meta["classifiers"] == {TASK: {**first, "weight": 10.0}}
    assert {r["classifier"] for r in trials} == {"aaaa"}
    assert table_of(meta, trials)["classifiers"] == {TASK: {**first, "weight": 10.0}}
    # Evidence that disagrees with its meta.json is refused when the asset is built.
    with pytest.raises(ValueError, match="planned with classifier 'aaaa', meta.json names 'bbbb'"):
        table_of({**meta, "classifiers": {TASK: {**first, "sha256": "bbbb"}}}, trials)
    a = write_oracle_run(tmp_path / "a", {(0, 0): True}, classifier=first)
    b = write_oracle_run(tmp_path / "b", {(0, 1): True}, classifier={**first, "sha256": "bbbb"})
    with pytest.raises(ValueError, match="2 different success classifiers"):
        build_table([a, b])


def test_the_classifier_weight_is_recorded_and_mixed_weights_refused(tmp_path):
    first = {"sha256": "aaaa", "dataset": "data/d", "heldout_accuracy": 0.98}
    # Records from before the weight was recorded planned at the SPEC's weight, 10 (as the
    # matcher reads them): they join records at 10, and only at 10.
    old = write_oracle_run(tmp_path / "old", {(0, 0): True}, classifier=first)
    meta, _ = build_table([old])
    assert meta["classifiers"] == {TASK: {**first, "weight": 10.0}}
    at_10 = write_oracle_run(tmp_path / "w10", {(0, 2): True}, classifier={**first, "weight": 10.0})
    meta, _ = build_table([old, at_10])
    assert meta["classifiers"] == {TASK: {**first, "weight": 10.0}}
    new = write_oracle_run(tmp_path / "new", {(0, 1): False}, classifier={**first, "weight": 1.0})
    for mixed in ([old, new], [new, at_10]):
        with pytest.raises(ValueError, match="2 classifier weights"):
            build_table(mixed)


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
        ("budgets", "different planner samples"),
        ("render", "another camera or render spec"),
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
        "budgets": lambda: [
            write_oracle_run(tmp_path / "a", {(0, 0): True}),
            write_oracle_run(tmp_path / "b", {(0, 1): True}, num_samples=8),
        ],
        "render": lambda: [write_oracle_run(tmp_path / "r")],
    }[case]()
    if case == "no_config":
        (runs[0] / "config.yaml").unlink()
    if case == "stale_suite":  # ran on the other suite, whose file was since replaced
        (runs[0] / "config.yaml").write_text(
            (runs[0] / "config.yaml").read_text().replace(
                str(tmp_path / "other-suite.npz"), str(tiny_suite_path())))
    if case == "render":  # records that say they rendered differently from this vp2
        lines = (runs[0] / "trials.jsonl").read_text().splitlines()
        lines = [json.dumps({**json.loads(x), "render_fingerprint": "0" * 16}) for x in lines]
        (runs[0] / "trials.jsonl").write_text("\n".join(lines) + "\n")
    with pytest.raises(ValueError, match=message):
        build_table(runs)


def test_a_run_ships_only_finished_task_categories(tmp_path, capsys):
    # A long run over two categories that has finished one of them (push_red has no trials).
    suite = tiny_suite_path(include_robodesk=True)
    run = write_oracle_run(tmp_path / "r", suite=suite, tasks=[TASK, "robodesk/push_red"])
    with pytest.raises(ValueError, match=r"3 of its 9 planned trials have not finished \(e\.g\. "
                       r"robodesk/push_red#0 seed 0\).*--tasks"):
        build_table([run])
    meta, trials = build_table([run], tasks=["tabletop"])  # an environment: its categories
    assert {t["task"] for t in trials} == {TASK} and len(trials) == len(OUTCOMES)
    assert build_table([run], tasks=[TASK]) == (meta, trials)
    with pytest.raises(ValueError, match="push_red#0 seed 0"):
        build_table([run], tasks=["robodesk/push_red"])
    with pytest.raises(ValueError, match="planned no trials of tabletop/push_large_cube"):
        build_table([run], tasks=["tabletop/push_large_cube"])
    # One finished instance short of what the run planned is refused as well.
    short = write_oracle_run(tmp_path / "s", {k: v for k, v in OUTCOMES.items() if k != (1, 2)})
    with pytest.raises(ValueError, match=r"1 of its 6 planned trials .*push_sphere#1 seed 2"):
        build_table([short])
    results = tmp_path / "results"
    args = ["ship-oracle", str(run), "--results", str(results), "--out", str(tmp_path / "a.json")]
    assert cli.main(args + ["--tasks", TASK]) == 0
    assert read_table(results / "spec")[1] == trials
    capsys.readouterr()
    assert cli.main(args) == 2 and "have not finished" in capsys.readouterr().err
    assert cli.main(["ship-oracle", "--results", str(results), "--tasks", TASK]) == 2
    assert "--tasks describe a table made from RUN_DIRs" in capsys.readouterr().err


# --------------------------------------------------------------------------- results -> asset


def test_the_asset_is_rebuilt_from_results_byte_for_byte(tmp_path, monkeypatch):
    results = _results(tmp_path)
    assert sorted(p.name for p in (results / "spec").iterdir()) == ["meta.json", "trials.jsonl"]
    lines = (results / "spec" / "trials.jsonl").read_text().splitlines()
    assert len(lines) == 6 and all(" " not in x for x in lines)  # compact, one per line
    asset = build_asset(results)
    assert asset["format"] == ASSET_FORMAT
    assert [t["name"] for t in asset["tables"]] == ["samples-8", "spec"]
    assert [t["date"] for t in asset["tables"]] == ["2026-11-25", "2026-11-22"]  # the records'
    first = write_oracle_asset(asset, tmp_path / "a" / "oracle.json").read_bytes()
    # From the files alone: another day, another working directory, files touched.
    for f in results.rglob("*"):
        os.utime(f, (0, 0))
    monkeypatch.chdir(tmp_path / "a")
    assert write_oracle_asset(build_asset(results), tmp_path / "b.json").read_bytes() == first
    assert cli.main(["ship-oracle", "--from-results", str(results),
                     "--out", str(tmp_path / "c.json")]) == 0
    assert (tmp_path / "c.json").read_bytes() == first
    assert first.decode() == asset_text(json.loads(first))
    oracle = load_shipped_oracle(tmp_path / "c.json")
    assert [t.name for t in oracle.tables] == ["samples-8", "spec"]
    eight, spec = oracle.tables
    assert (eight.samples, spec.samples) == ("8", "200")
    assert eight.tasks[TASK].rate == 0.5 and spec.tasks[TASK].rate == pytest.approx(2 / 3)
    assert spec.render == {"tabletop": render_fingerprint("tabletop")}
    assert spec.describe() == (
        "shipped oracle table 'spec' (200 planner samples, measured 2026-11-22): simulator "
        f"oracle on 1 task(s), 2 instance(s) per task, seed(s) 0, 1, 2, suite {SUITE_FORMAT}")


def test_the_committed_asset_is_what_results_give():
    results = REPO / "results" / "oracle"
    assert results.is_dir() and any(results.iterdir()), (
        "results/oracle holds no table: the shipped oracle's evidence is missing"
    )
    asset = REPO / "src" / "vp2" / "assets" / "oracle.json"
    assert asset.is_file(), "results/oracle has tables but vp2/assets/oracle.json is missing"
    assert asset_text(build_asset(results)) == asset.read_text(), (
        "vp2/assets/oracle.json is not what results/oracle gives: run `vp2 ship-oracle`")


def test_inconsistent_results_are_refused(tmp_path):
    results = _results(tmp_path)
    (results / "spec").rename(results / "renamed")
    with pytest.raises(ValueError, match="meta.json names the table 'spec', its folder 'renamed'"):
        build_asset(results)
    (results / "renamed").rename(results / "spec")
    meta, trials = read_table(results / "spec")
    write_table(meta, [*trials, {**trials[0], "seed": 9, "num_samples": 50}], results)
    with pytest.raises(ValueError, match="at several planner samples"):
        build_asset(results)
    with pytest.raises(ValueError, match="no oracle tables"):
        build_asset(tmp_path / "empty")


def test_a_one_table_asset_straight_from_runs(tmp_path):
    data = build_oracle_asset([write_oracle_run(tmp_path / "run")], name="t")
    assert data["format"] == ASSET_FORMAT and [t["name"] for t in data["tables"]] == ["t"]
    oracle = load_shipped_oracle(write_oracle_asset(data, tmp_path / "sub" / "oracle.json"))
    assert not list((tmp_path / "sub").glob(".*.tmp"))
    assert oracle.table("t").tasks[TASK].trials == 6
    with pytest.raises(KeyError, match="no shipped oracle table 'x' \\(tables: t at 200\\)"):
        oracle.table("x")


# --------------------------------------------------------------------------- the command


def test_ship_oracle_command(tmp_path, capsys):
    results, out = tmp_path / "results", tmp_path / "oracle.json"
    run = write_oracle_run(tmp_path / "run")
    assert cli.main(["ship-oracle", str(run), "--results", str(results), "--out", str(out),
                     "--note", "by hand"]) == 0
    printed = capsys.readouterr().out
    assert f"wrote {results / 'spec'} (6 trials)" in printed and f"wrote {out}" in printed
    assert "66.7%  (4/6 trials, 2 instances, 200 samples)" in printed
    assert "shipped oracle table 'spec' (200 planner samples" in printed
    assert json.loads(out.read_text())["tables"][0]["note"] == "by hand"
    # A second table joins the first; --check compares the asset with the results.
    eight = write_oracle_run(tmp_path / "eight", {(0, 0): True}, num_samples=8)
    assert cli.main(["ship-oracle", str(eight), "--table", "samples-8", "--results",
                     str(results), "--out", str(out)]) == 0
    assert [t["name"] for t in json.loads(out.read_text())["tables"]] == ["samples-8", "spec"]
    check = ["ship-oracle", "--check", "--results", str(results), "--out", str(out)]
    assert cli.main(check) == 0
    out.write_text(out.read_text().replace('"by hand"', '"edited"'))
    assert cli.main(check) == 1 and "differs from" in capsys.readouterr().out
    # Refusals write nothing.
    bad = write_oracle_run(tmp_path / "bad", model="repeat_last_frame")
    assert cli.main(["ship-oracle", str(bad), "--results", str(results),
                     "--out", str(tmp_path / "x.json")]) == 2
    assert "not a simulator-oracle run" in capsys.readouterr().err
    assert not (tmp_path / "x.json").exists() and sorted(os.listdir(results)) == [
        "samples-8", "spec"]
    assert cli.main(["ship-oracle", str(run), "--from-results", str(results)]) == 2
    assert "give no RUN_DIR" in capsys.readouterr().err
    assert cli.main(["ship-oracle", "--table", "x", "--results", str(results)]) == 2
    assert "describe a table made from RUN_DIRs" in capsys.readouterr().err


# --------------------------------------------------------------------------- loading


def test_loading_a_missing_broken_or_old_asset(tmp_path, monkeypatch):
    assert load_shipped_oracle(tmp_path / "absent.json") is None
    monkeypatch.setenv(ENV_VAR, str(tmp_path / "absent.json"))
    assert load_shipped_oracle() is None
    (tmp_path / "broken.json").write_text('{"format": "something else"}')
    with pytest.raises(ValueError, match="not a vp2 oracle file"):
        load_shipped_oracle(tmp_path / "broken.json")
    (tmp_path / "old.json").write_text('{"format": "vp2-oracle/1", "tasks": {}}')
    with pytest.raises(ValueError, match="old format vp2-oracle/1 .* rebuild it with `vp2 ship-"):
        load_shipped_oracle(tmp_path / "old.json")


def test_the_packaged_asset_loads_if_there_is_one(monkeypatch):
    monkeypatch.delenv(ENV_VAR, raising=False)
    oracle = load_shipped_oracle()
    if not default_asset_path().is_file():
        assert oracle is None
    else:
        assert oracle is not None and oracle.tables
        # RoboDesk rows measured on suite v3, whose RoboDesk instances the current suite keeps;
        # the tabletop rows on the current suite (the spec table's are v3's until re-measured).
        assert all(t.suite_format in ("vp2-task-suite/3", SUITE_FORMAT) and t.tasks
                   for t in oracle.tables)


def test_the_shipped_table_normalises_a_run_of_the_shipped_classifiers(monkeypatch):
    """A 50-sample run of every category, planned as `vp2 run` plans today (the shipped
    classifier files at each task's weight), is normalised on every task by the packaged
    `samples-50` table: a classifier or weight change that leaves the table stale fails here."""
    from vp2.classifiers.checkpoint import file_sha256
    from vp2.classifiers.registry import shipped_path
    from vp2.envs import TASK_NAMES
    from vp2.envs.tasks import get_task
    from vp2.oracle.shipped import summarize_run
    from vp2.planning.config import PlannerConfig

    monkeypatch.delenv(ENV_VAR, raising=False)
    oracle = load_shipped_oracle()
    suite = TaskSuite.load()
    records = []
    for task in TASK_NAMES:
        record = {"task": task, "instance": 0, "seed": 0, "success": True, "error": None,
                  "instance_sha": suite.get(task, 0).fingerprint, "cost": "pixel"}
        weight = get_task(task).classifier_weight
        if weight is not None:
            record["agent"] = {"agent": "planning", "classifier": {
                "sha256": file_sha256(shipped_path(task))[:16], "weight": weight}}
        records.append(record)
    summary = summarize_run(records, shipped=oracle, planner=PlannerConfig(num_samples=50))
    assert summary.warnings == [] and summary.oracle_note is None
    assert summary.normalised is not None
    assert "samples-50" in summary.oracle_source
