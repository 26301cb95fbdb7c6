"""A value beyond what there is runs what there is, and says so (no silent clamps)."""

from __future__ import annotations

import logging

from tests.benchmark import tiny_suite_path
from vp2 import cli
from vp2.cli import metrics as metrics_cmd
from vp2.data.storage import MANIFEST


def test_metrics_num_clips_beyond_the_split_is_said(tmp_path, monkeypatch, caplog):
    (tmp_path / "data").mkdir()
    (tmp_path / "data" / MANIFEST).write_text("{}")

    def evaluate(model, data, num_clips, **kwargs):  # the split has 10 clips
        n = min(num_clips, 10)
        return {"model": {"name": model}, "num_clips": n, "num_clips_requested": num_clips,
                "split": "valid", "dataset": str(data), "display": {"mse": 0.1}, "skipped": {}}

    monkeypatch.setattr(metrics_cmd, "evaluate_model", evaluate)
    argv = ["metrics", "--model", "repeat_last_frame", "--env", "tabletop", "--data",
            str(tmp_path / "data"), "--out", str(tmp_path / "m.json")]
    with caplog.at_level(logging.WARNING, logger="vp2.cli.metrics"):
        assert cli.main([*argv, "--num-clips", "1000"]) == 0
    assert caplog.messages == [
        "--num-clips 1000: the dataset's valid split has 10 clips; evaluated those 10"
    ]
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="vp2.cli.metrics"):
        assert cli.main([*argv, "--num-clips", "10"]) == 0
    assert caplog.messages == []


def test_tasks_show_max_beyond_the_suite_is_said(tmp_path, monkeypatch, caplog):
    import vp2.data.suite_view as suite_view

    shown = []
    monkeypatch.setattr(
        suite_view, "suite_contact_sheet",
        lambda suite, task, out, max_instances: shown.append(max_instances) or tmp_path / "x.png",
    )
    argv = ["tasks", "show", "tabletop/push_sphere", "--suite", str(tiny_suite_path())]
    with caplog.at_level(logging.WARNING, logger="vp2.cli.tasks"):
        assert cli.main([*argv, "--max", "50"]) == 0
        assert cli.main([*argv, "--max", "2"]) == 0
    assert caplog.messages == [
        "--max 50: tabletop/push_sphere has 2 instances in the suite; showing those 2"
    ]
    assert shown == [50, 2]
