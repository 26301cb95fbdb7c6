"""``vp2 run`` with a checkpoint that cannot be used: one error line before any trial."""

from __future__ import annotations

import random

import pytest

from vp2 import cli
from vp2.models import build_model, model_entry, write_model_checkpoint


def _corrupt(tmp_path):
    (tmp_path / "corrupt.pt").write_bytes(random.Random(0).randbytes(4096))
    return "corrupt.pt", "corrupt.pt is not a vp2 checkpoint (not a readable PyTorch file: "


def _truncated(tmp_path):
    model = build_model("fitvid", "mini", action_dim=4, image_size=32)
    write_model_checkpoint(tmp_path / "good.pt", {"model": model_entry(model)})
    (tmp_path / "cut.pt").write_bytes((tmp_path / "good.pt").read_bytes()[:2000])
    return "cut.pt", "cut.pt is not a vp2 checkpoint (not a readable PyTorch file: failed reading"


def _missing(tmp_path):
    return "runs/none", "no checkpoint at runs/none: no such file or directory"


def _other_family(tmp_path):
    model = build_model("fitvid", "mini", action_dim=4, image_size=32)
    write_model_checkpoint(tmp_path / "fitvid.pt", {"model": model_entry(model)})
    return "fitvid.pt", "fitvid.pt holds a 'fitvid' model, not 'svg_prime'"


@pytest.mark.parametrize("make", [_corrupt, _truncated, _missing, _other_family],
                         ids=lambda f: f.__name__.strip("_"))
def test_run_refuses_a_bad_checkpoint_before_any_trial(make, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    path, what = make(tmp_path)
    code = cli.main(["run", "--model", f"svg_prime:{path}", "--out", "out", "--seeds", "1", "2",
                     "3", "--num-instances", "1"])
    captured = capsys.readouterr()
    assert code == 2 and captured.out == ""
    # One line, no progress bar, no traceback, and no advice to load the file unsafely.
    assert captured.err.startswith(f"vp2 run: error: model 'svg_prime:{path}': {what}")
    assert captured.err.count("\n") == 1 and "weights_only" not in captured.err
    assert not (tmp_path / "out").exists()  # nothing written: no run directory, no trials.jsonl
