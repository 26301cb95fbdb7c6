"""``vp2 diagnose`` where a new user starts: an empty folder, no dataset, an empty cache. It
collects the default dataset's validation trajectories itself (:mod:`vp2.data.held_out`)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np
import pytest
import torch

from vp2 import cli
from vp2.data import held_out
from vp2.data.collect import DEFAULT_TRAJECTORIES, CollectionConfig, collect
from vp2.diagnose.measures import held_out_clips, held_out_trajectories

MODEL = "zoo:svg_prime-tiny-tabletop"
#: The tabletop's default dataset shrunk to 10 trajectories, so that its validation split is
#: one trajectory (index 9, the same trajectory as in the 100-trajectory default dataset).
SMALL_DEFAULT = 10


def _diagnose(*flags: str) -> int:
    return cli.main(["diagnose", "--model", MODEL, "--clips", "8", "--instances-per-task", "0",
                     "--no-progress", *flags])


def test_diagnose_in_an_empty_folder_makes_its_held_out_clips(tmp_path, monkeypatch, capsys,
                                                              caplog):
    monkeypatch.setitem(DEFAULT_TRAJECTORIES, "tabletop", SMALL_DEFAULT)
    monkeypatch.setenv("VP2_CACHE_DIR", str(tmp_path / "cache"))
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    caplog.set_level(logging.INFO, logger="vp2")

    assert _diagnose() == 0
    printed = capsys.readouterr().out.splitlines()
    assert printed[0] == f"svg_prime ({MODEL}) on tabletop"
    assert printed[1].startswith("action conditioning: shuffled/true error ratio ")
    assert "over 1 trajectories], " in printed[1] and " -> " in printed[1]
    cache = held_out.held_out_dir("tabletop")
    assert cache.parent == tmp_path / "cache" / "held-out"
    (said,) = [r.getMessage() for r in caplog.records if r.name == "vp2.data.held_out"]
    assert said == (f"no dataset at data/tabletop-{SMALL_DEFAULT}x-64px: collecting its 1 held-out "
                    f"trajectories into {cache} (once; `vp2 collect tabletop` makes the whole "
                    "dataset)")
    report_file = work / "runs/diagnose/zoo-svg_prime-tiny-tabletop-tabletop/diagnose.json"
    first = json.loads(report_file.read_text())
    assert first["action_conditioning"]["dataset"] == str(cache)
    assert first["action_conditioning"]["clips"] == 8
    # The shipped tabletop SVG' uses its actions (ratio 1.40 on this clip draw here).
    assert first["verdicts"]["action_conditioning"]["status"] == "uses"
    assert printed[1].endswith("-> predictions depend on the actions")
    assert sorted(p.name for p in work.iterdir()) == ["runs"]  # nothing under data/

    # The held-out clips are the default dataset's: the same validation trajectory collected
    # by vp2.data.collect on its own, bit for bit.
    reference = collect(CollectionConfig(env="tabletop", trajectories_per_stream=SMALL_DEFAULT),
                        tmp_path / "reference", workers=1, progress=False, indices=[9])
    for clips in (8, 25):  # the measure's draw, and every clip of the split
        ours, theirs = held_out_clips(cache, clips, 0, 2, 10), held_out_clips(reference, clips, 0, 2, 10)
        assert torch.equal(ours[0], theirs[0]) and torch.equal(ours[1], theirs[1])
        assert ours[0].shape == (clips, 12, 3, 64, 64) and ours[1].shape == (clips, 11, 4)
    np.testing.assert_array_equal(held_out_trajectories(cache, 8, 0, 2, 10), np.zeros(8))

    # The second call reads the cache; its measure is the first's, and the one on the
    # reference dataset given with --data.
    shards = {p: p.stat().st_mtime_ns for p in (cache / "shards").iterdir()}
    caplog.clear()
    assert _diagnose() == 0
    second = json.loads(report_file.read_text())
    assert second["timing"]["held_out_s"] < 1.0 < first["timing"]["held_out_s"]
    assert not [r for r in caplog.records if r.name == "vp2.data.held_out"]
    assert shards == {p: p.stat().st_mtime_ns for p in (cache / "shards").iterdir()}
    assert second["action_conditioning"] == first["action_conditioning"]
    assert _diagnose("--data", str(reference), "--out", "ref.json") == 0
    on_reference = json.loads(Path("ref.json").read_text())["action_conditioning"]
    assert on_reference == {**first["action_conditioning"], "dataset": str(reference)}


def test_without_rendering_it_says_so_in_one_line(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("VP2_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("MUJOCO_GL", "egl")
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(held_out, "rendering_problem", lambda: "EGLError: EGL_NOT_INITIALIZED")
    assert _diagnose("--env", "tabletop") == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [
        "vp2 diagnose: error: no dataset at data/tabletop-100x-64px, and its 10 held-out "
        "trajectories cannot be rendered here (MUJOCO_GL=egl: EGLError: EGL_NOT_INITIALIZED); "
        "run with MUJOCO_GL=egl on a machine with EGL (Mesa's libEGL or an NVIDIA driver), or "
        "pass --data DIR, or --clips 0 to skip the action-conditioning measure"
    ]
    assert not (tmp_path / "cache" / "held-out").exists()


def test_a_missing_data_dir_is_still_an_error(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("VP2_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.chdir(tmp_path)
    assert _diagnose("--data", "nowhere") == 2
    err = capsys.readouterr().err
    assert err.startswith("vp2 diagnose: error: no dataset at nowhere (manifest.json missing); "
                          "create it with `vp2 collect tabletop --out nowhere`")
    assert not (tmp_path / "cache" / "held-out").exists()


@pytest.fixture(autouse=True)
def _no_user_cache(tmp_path, monkeypatch):
    """Never the user's own cache, whatever a test forgets."""
    monkeypatch.setenv("VP2_CACHE_DIR", str(tmp_path / "cache"))
