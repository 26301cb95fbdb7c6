"""The paper's training variants: what each trains, and how the results are packed."""

from __future__ import annotations

import json
import tarfile
from pathlib import Path

import pytest
from benchmarks.paper import train_variants as tv


def test_the_variants_differ_only_in_loss_and_seed():
    table1 = [f"{f}-{env}-{loss}-s0" for env in ("robodesk", "tabletop") for f in ("svg", "fitvid")
              for loss in ("mse", "lpips1", "lpips10")]
    assert sorted(tv.VARIANTS) == sorted(
        [*table1, "svg-robodesk-mse-s1", "svg-robodesk-mse-s2", "svg-robodesk-mse-s3"])
    assert {v.env for n, v in tv.VARIANTS.items() if "tabletop" in n} == {"tabletop"}
    v = tv.VARIANTS["svg-robodesk-lpips10-s0"]
    args = v.train_args("data/x", Path("/tmp/none/run"), 6000, "cpu", None)
    assert args[:5] == ["train", "--model", "svg_prime", "--preset", "m0.25k0.25"]
    assert args[args.index("--perceptual") + 1:args.index("--perceptual") + 4] == ["lpips_vgg", "--perceptual-weight", "10"]
    assert args[args.index("--model-arg") + 1:args.index("--model-arg") + 3] == ["m=0.125", "k=0.125"]
    assert args[args.index("--batch-size") + 1] == "8"
    assert "--resume" not in args and "--max-minutes" not in args
    mse = tv.VARIANTS["fitvid-robodesk-mse-s0"].train_args("d", Path("/tmp/none/r"), 5, "cpu", 2.5)
    assert "--perceptual" not in mse and mse[mse.index("--max-minutes") + 1] == "2.5"
    assert tv.VARIANTS["svg-robodesk-mse-s3"].seed == 3


def _dataset(path: Path, env: str) -> str:
    from vp2.data.storage import FORMAT, MANIFEST

    path.mkdir(parents=True)
    (path / MANIFEST).write_text(json.dumps({"format": FORMAT, "config": {"env": env}}))
    return str(path)


def test_each_dataset_serves_the_variants_of_its_environment(tmp_path):
    robodesk = _dataset(tmp_path / "rd", "robodesk")
    tabletop = _dataset(tmp_path / "tt", "tabletop")
    data = tv.datasets_by_env([robodesk, tabletop])
    assert data == {"robodesk": robodesk, "tabletop": tabletop}
    assert tv.variants_for(None, {"tabletop": tabletop}) == [
        "svg-tabletop-mse-s0", "svg-tabletop-lpips1-s0", "svg-tabletop-lpips10-s0",
        "fitvid-tabletop-mse-s0", "fitvid-tabletop-lpips1-s0", "fitvid-tabletop-lpips10-s0"]
    assert len(tv.variants_for(None, data)) == 15
    with pytest.raises(ValueError, match="no --data for robodesk"):
        tv.variants_for(["svg-tabletop-mse-s0", "svg-robodesk-mse-s1"], {"tabletop": tabletop})
    with pytest.raises(ValueError, match="two robodesk datasets"):
        tv.datasets_by_env([robodesk, _dataset(tmp_path / "rd2", "robodesk")])
    with pytest.raises(ValueError, match="no dataset there"):
        tv.datasets_by_env([str(tmp_path / "none")])


def test_a_run_with_a_checkpoint_resumes(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "checkpoints" / "step_00000100.pt").write_bytes(b"x")
    assert "--resume" in tv.VARIANTS["svg-robodesk-mse-s1"].train_args("d", run, 10, "cpu", None)


def test_children_share_the_cores(monkeypatch):
    monkeypatch.delenv("OMP_NUM_THREADS", raising=False)
    monkeypatch.setattr(tv.os, "cpu_count", lambda: 16)
    assert tv.child_env(9)["OMP_NUM_THREADS"] == "1"
    assert tv.child_env(4)["OMP_NUM_THREADS"] == "4"
    monkeypatch.setenv("OMP_NUM_THREADS", "3")
    assert tv.child_env(4)["OMP_NUM_THREADS"] == "3"


def test_pack_splits_into_tars_under_the_limit(tmp_path):
    out = tmp_path / "out"
    (out / "export").mkdir(parents=True)
    (out / "variants.json").write_text("{}")
    for i in range(3):
        (out / "export" / f"m{i}.pt").write_bytes(bytes(600))
    tars = tv.pack(out, tmp_path / "packed", limit=1300)
    assert [t.name for t in tars] == ["variants-0.tar", "variants-1.tar"]
    names = [sorted(tarfile.open(t).getnames()) for t in tars]
    assert names == [["export/m0.pt", "export/m1.pt", "variants.json"], ["export/m2.pt"]]
