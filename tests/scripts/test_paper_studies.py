"""The ensemble, loss and scaling studies of the paper (benchmarks.paper.ensemble, .losses,
.scaling): their columns, and each end to end on a tiny suite with small zoo models."""

from __future__ import annotations

import json
import re
import xml.etree.ElementTree as ET

import pytest
from benchmarks.paper import ensemble, losses, scaling

from tests.benchmark import tiny_suite_path

SVG = "zoo:svg_prime-tiny-tabletop"
FITVID = "zoo:fitvid-tabletop-15min"


def _common(out) -> list[str]:
    return ["--out", str(out), "--suite", str(tiny_suite_path()), "--tasks", "tabletop/push_sphere",
            "--num-instances", "1", "--seeds", "0", "--num-samples", "8", "--num-steps", "2",
            "--no-gifs", "--no-progress"]


def test_the_ensemble_is_planned_beside_each_of_its_members(tmp_path):
    cols = ensemble.columns(["a", "b", "c"])
    assert [(c.name, c.model) for c in cols] == [
        ("ensemble", "ensemble(a,b,c)"), ("member-1", "a"), ("member-2", "b"), ("member-3", "c")]
    assert ensemble.TASKS == ("robodesk/upright_block_off_table", "robodesk/push_green",
                              "robodesk/open_slide")
    out = tmp_path / "ens"
    ensemble.main(["--members", SVG, FITVID, *_common(out)])
    data = json.loads((out / "ensemble.json").read_text())
    assert [c["name"] for c in data["columns"]] == ["ensemble", "member-1", "member-2"]
    assert all(c["summary"]["tasks"][0]["num_trials"] == 1 for c in data["columns"])
    (line,) = (out / "runs" / "ensemble" / "trials.jsonl").read_text().splitlines()
    record = json.loads(line)
    assert record["error"] is None and record["agent"]["ensemble"]["members"] == [SVG, FITVID]
    page = (out / "ensemble.md").read_text()
    assert f"- `member-2`: `{FITVID}`" in page and "![" in page
    svg = (out / "ensemble.svg").read_text()
    assert 'data-series="member-1"' in svg
    assert ET.fromstring(svg).tag == "{http://www.w3.org/2000/svg}svg"  # displays as an image
    with pytest.raises(SystemExit):
        ensemble.main(["--members", SVG, *_common(out)])  # one member is no ensemble


def test_the_loss_variants_are_planned_with_their_metrics_beside(tmp_path):
    assert losses.TASKS == ("robodesk/push_red", "robodesk/upright_block_off_table",
                            "robodesk/open_slide")
    assert list(losses.VARIANTS) == ["svg-mse", "svg-lpips1", "svg-lpips10", "fitvid-mse",
                                     "fitvid-lpips1", "fitvid-lpips10"]
    assert losses.parse_column("a=zoo:x=y") == ("a", "zoo:x=y")
    with pytest.raises(ValueError, match="expected LABEL=MODEL"):
        losses.parse_column("zoo:x")
    out = tmp_path / "t1"
    (out / "metrics").mkdir(parents=True)
    (out / "metrics" / "mse.json").write_text(json.dumps(
        {"display": {"fvd": 812.34, "lpips_alex_x100": 6.15, "ssim_x100": 78.09}, "num_clips": 16}))
    losses.main(["--column", f"mse={SVG}", "--column", f"fv={FITVID}", *_common(out)])
    data = json.loads((out / "losses.json").read_text())
    assert [(c["name"], c["model"]) for c in data["columns"]] == [("mse", SVG), ("fv", FITVID)]
    assert all(c["summary"]["tasks"][0]["num_trials"] == 1 for c in data["columns"])
    page = (out / "losses.md").read_text()
    assert "| mse | 812.3 | 6.2 | 78.1 | 16 |" in page
    assert "| fv | not measured | not measured | not measured | – |" in page
    with pytest.raises(SystemExit):
        losses.main(["--column", f"a={SVG}", "--column", f"a={FITVID}", *_common(out)])


def test_the_tabletop_half_plans_the_zoos_tabletop_variants_on_the_four_pushes(tmp_path):
    tasks, variants = losses.ENVS["tabletop"]
    assert tasks == ("tabletop/push_large_cube", "tabletop/push_small_cube",
                     "tabletop/push_cylinder", "tabletop/push_sphere")
    assert list(variants) == list(losses.VARIANTS)
    assert variants["fitvid-lpips10"] == "zoo:fitvid-tabletop-lpips10"
    assert losses.ENVS["robodesk"] == (losses.TASKS, losses.VARIANTS)
    out = tmp_path / "t1t"
    losses.main(["--env", "tabletop", "--only", "svg-lpips1", *_common(out)])
    (line,) = (out / "runs" / "svg-lpips1" / "trials.jsonl").read_text().splitlines()
    record = json.loads(line)
    assert record["error"] is None and record["task"] == "tabletop/push_sphere"
    assert record["model"]["zoo"]["name"] == "svg_prime-tabletop-lpips1"
    assert (out / "losses.md").read_text().startswith("# Table 1 (tabletop): losses")


def test_scaling_draws_a_curve_per_family_over_x(tmp_path, capsys):
    with pytest.raises(ValueError, match="X must be a number"):
        scaling.columns([("svg", "a", SVG, "many")])
    with pytest.raises(ValueError, match="each FAMILY NAME once"):
        scaling.columns([("svg", "a", SVG, "1"), ("svg", "a", SVG, "2")])
    with pytest.raises(ValueError, match="name a folder"):
        scaling.columns([("svg/x", "a", SVG, "1")])
    out = tmp_path / "size"
    scaling.main(["--x", "parameters", "--point", "svg_prime", "small", SVG, "1.65e6",
                  "--point", "fitvid", "mini", FITVID, "1.52e6", *_common(out)])
    data = json.loads((out / "scaling.json").read_text())
    assert [(c["name"], c["x"], c["group"]) for c in data["columns"]] == [
        ("svg_prime-small", 1.65e6, "svg_prime"), ("fitvid-mini", 1.52e6, "fitvid")]
    svg = (out / "scaling.svg").read_text()
    assert svg.count('class="pt"') == 2 and 'data-series="fitvid"' in svg
    assert 'data-x="1650000.0"' in svg and 'data-x="1520000.0"' in svg
    assert "- `fitvid-mini`: `zoo:fitvid-tabletop-15min` at 1.52e+06 parameters" in (
        out / "scaling.md").read_text()
    capsys.readouterr()
    with pytest.raises(SystemExit):
        scaling.main(["--x", "parameters", "--point", "svg", "a", SVG, "lots", *_common(out)])
    assert "X must be a number" in capsys.readouterr().err


def test_scaling_replots_its_record_with_the_papers_numbers_on_a_log_axis(tmp_path, capsys):
    # What the committed evidence allows on a machine without the runs: draw the curve again
    # from scaling.json, with a published number beside it.
    out = tmp_path / "size"
    summary = {"mean": 0.25, "min": 0.2, "max": 0.3,
               "tasks": [{"task": "tabletop/push_sphere", "mean": 0.25, "min": 0.2, "max": 0.3,
                          "num_trials": 4}]}  # fmt: skip
    out.mkdir()
    (out / "scaling.json").write_text(json.dumps({"command": "python -m x", "columns": [
        {"name": "svg_prime-a", "model": SVG, "planner": {"optimizer": "mppi"}, "x": 5e5,
         "group": "svg_prime", "summary": summary},
        {"name": "svg_prime-b", "model": SVG, "planner": {"optimizer": "mppi"}, "x": 5e6,
         "group": "svg_prime", "summary": {**summary, "mean": 0.1}}]}))  # fmt: skip
    scaling.main(["--x", "parameters", "--out", str(out), "--replot", "--log-x",
                  "--paper-point", "paper", "8.3e7", "0.8"])
    svg = (out / "scaling.svg").read_text()
    xs = dict(re.findall(r'data-series="([^"]+)" data-x="([\d.e+]+)"', svg)[-1:])
    assert xs == {"paper": "83000000.0"} and svg.count('class="pt"') == 3
    assert ">1e+05<" in svg and ">1e+08<" in svg  # decades as ticks
    page = (out / "scaling.md").read_text()
    assert "Command: `python -m x`" in page and "| **25** [20, 30] | **10** [20, 30] |" in page
    assert "- paper: 80% at 8.3e+07 (published)" in page
    assert json.loads((out / "scaling.json").read_text())["extra"] == {"paper": [[8.3e7, 0.8]]}
    for bad, message in ((["--paper-point", "p", "1e6", "80"], "success fraction"),
                         (["--point", "s", "a", SVG, "1"], "leave out --point")):
        with pytest.raises(SystemExit):
            scaling.main(["--x", "parameters", "--out", str(out), "--replot", *bad])
        assert message in capsys.readouterr().err
    with pytest.raises(SystemExit, match="no .*scaling.json"):
        scaling.main(["--x", "parameters", "--out", str(tmp_path / "none"), "--replot"])
