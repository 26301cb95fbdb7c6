"""The paper's planner comparison: its columns, and the study end to end on a tiny suite."""

from __future__ import annotations

import json

import pytest
import yaml
from benchmarks.paper import planners

from tests.benchmark import tiny_suite_path

TINY = "zoo:svg_prime-tiny-tabletop"  # differentiable, 1.6 M parameters


def test_the_columns_are_the_papers_planners_and_the_oracles_sampling_ones():
    names = [(c.name, c.model, c.planner.optimizer, c.planner.lr)
             for c in planners.settings("m", [1e-3, 7e-2], True)]
    assert names == [
        ("mppi", "m", "mppi", None), ("cem", "m", "cem", None), ("cem_gd", "m", "cem_gd", None),
        ("lbfgs-lr0.001", "m", "lbfgs", 1e-3), ("lbfgs-lr0.07", "m", "lbfgs", 7e-2),
        ("oracle-mppi", "simulator", "mppi", None), ("oracle-cem", "simulator", "cem", None),
    ]
    assert planners.LBFGS_LRS == (1e-3, 1e-2, 5e-2, 7e-2)
    columns = planners.settings("m", [1e-2], False, grad_steps=3, num_samples_first=9)
    assert columns[-1].name == "lbfgs-lr0.01" and columns[-1].planner.grad_steps == 3
    assert columns[2].planner.num_samples_first == 9 and columns[0].planner.grad_steps is None


def test_the_study_runs_each_setting_resumably_and_tabulates_them(tmp_path, capsys):
    out = tmp_path / "study"
    argv = ["--model", TINY, "--out", str(out), "--suite", str(tiny_suite_path()),
            "--tasks", "tabletop/push_sphere", "--num-instances", "1", "--seeds", "0",
            "--num-samples", "8", "--num-steps", "2", "--lbfgs-lrs", "0.05", "--no-oracle",
            "--grad-steps", "1", "--no-gifs", "--no-progress", "--only", "mppi", "lbfgs-lr0.05"]
    planners.main(argv)
    assert {p.name for p in (out / "runs").iterdir()} == {"mppi", "lbfgs-lr0.05"}
    config = yaml.safe_load((out / "runs" / "lbfgs-lr0.05" / "config.yaml").read_text())["config"]
    assert config["planner"]["optimizer"] == "lbfgs" and config["planner"]["lr"] == 0.05
    assert config["planner"]["grad_steps"] == 1
    (line,) = (out / "runs" / "lbfgs-lr0.05" / "trials.jsonl").read_text().splitlines()
    record = json.loads(line)
    assert record["error"] is None and record["num_steps"] == 2
    assert record["agent"]["planner"]["optimizer"] == "lbfgs"
    data = json.loads((out / "planners.json").read_text())
    assert [c["name"] for c in data["columns"]] == ["mppi", "cem", "cem_gd", "lbfgs-lr0.05"]
    assert [c["summary"] is None for c in data["columns"]] == [False, True, True, False]
    svg = (out / "planners.svg").read_text()
    assert svg.startswith("<svg") and 'data-series="lbfgs-lr0.05"' in svg
    page = (out / "planners.md").read_text()
    row = next(line for line in page.splitlines() if line.startswith("| tabletop/push_sphere"))
    cells = [c.strip() for c in row.split("|")[2:-1]]
    assert [c.endswith("(1)") for c in cells] == [True, False, False, True]
    assert cells[1:3] == ["pending", "pending"]
    # Run again: every trial is on disk, nothing runs, the table is the same.
    capsys.readouterr()
    planners.main(argv)
    assert (out / "planners.md").read_text() == page
    assert "[mppi]" in capsys.readouterr().out
    with pytest.raises(SystemExit, match="no column oracle-mppi"):
        planners.main(argv + ["oracle-mppi"])


def test_stop_on_success_reaches_every_columns_run():
    from benchmarks.paper import study

    base = ["--model", "m", "--out", "o", "--num-samples", "50"]
    columns = planners.settings("m", [1e-2], True)
    stopping = planners.parse_args(base + ["--stop-on-success"])
    assert [study.run_config(stopping, c).stop_on_success for c in columns] == [True] * 6
    whole = planners.parse_args(base)
    config = study.run_config(whole, columns[-1])  # oracle-cem
    assert config.stop_on_success is False and config.model == "simulator"
    assert (config.out, config.planner.optimizer, config.planner.num_samples) == (
        "o/runs/oracle-cem", "cem", 50)
