"""The report reads a run directory through ``RunDir``: either form of ``config.yaml``."""

from __future__ import annotations

import shutil

import yaml

from tests.report.report_runs import small_runs
from vp2.report.runs import load_runs
from vp2.report.sections import runs_table


def test_the_report_shows_the_planner_of_either_config_form(tmp_path):
    new = small_runs()["repeat"]  # written nested (``planner:``)
    old = tmp_path / "old"
    shutil.copytree(new, old)
    data = yaml.safe_load((old / "config.yaml").read_text())
    planner = data["config"].pop("planner")
    data["config"].update({k: planner[k] for k in ("optimizer", "num_samples", "gamma",
                                                   "num_iterations")})
    (old / "config.yaml").write_text(yaml.safe_dump(data))  # the flat form of older runs
    views = load_runs([new, old], ["new", "old"])
    for view in views:
        assert view.config["optimizer"] == "mppi" and view.config["num_samples"] == 8
        assert view.deviations[0] == "num_steps=3 (SPEC: 15)" and view.outside is None
        assert "planner" not in view.config
    assert views[0].summary.mean == views[1].summary.mean == 0.5
    assert runs_table(views).count("mppi, 8 samples, 3 steps, cost auto") == 2
