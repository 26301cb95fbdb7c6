"""The HTML report: values of the bars, self-containment, normalisation, study, gallery, CLI,
the runner's hook, and the page in headless Chromium (skipped where none is installed)."""

from __future__ import annotations

import argparse
import base64
import json
import logging
import os
import re
import shutil
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest
import yaml

from tests.benchmark import tiny_suite_path
from tests.report.headless import Browser, find_chromium
from tests.report.report_runs import SUCCESS, TASK, small_runs, write_metrics_file
from vp2.benchmark.runner import run_benchmark
from vp2.cli import report as report_cmd
from vp2.report import page as report_lib
from vp2.report.page import write_report, write_run_report
from vp2.run.config import RunConfig

PLOT_HEIGHT = 240  # bar_chart's default: a bar of value v is v * 240 px high
LABELS = {"repeat": "repeat_last_frame", "random": "random actions", "oracle": "simulator"}
DOCS = Path(__file__).resolve().parents[2] / "docs"


def _report(tmp_path: Path, names=("repeat", "random", "oracle"), **kwargs) -> str:
    runs = small_runs()
    path = write_report([runs[n] for n in names], tmp_path / "report.html", **kwargs)
    return path.read_text()


def _bars(html: str) -> dict[tuple[str, str], tuple[float, float]]:
    """(series, group) -> (data-value, height in px) of every bar."""
    found = re.findall(
        r'<rect class="bar" data-series="([^"]+)" data-group="([^"]+)" data-value="([^"]+)" '
        r'x="[^"]+" y="[^"]+" width="[^"]+" height="([^"]+)"',
        html,
    )
    return {(s, g): (float(v), float(h)) for s, g, v, h in found}


def test_runner_writes_the_report_of_every_run():
    run_dir = small_runs()["repeat"]
    html = (run_dir / "report.html").read_text()
    assert "<h1>vp2 report: repeat_last_frame</h1>" in html
    # 4 trials, 3 shown per task by default, each with its plan GIF.
    assert "showing 3 of 4 trials" in html
    assert html.count("data:image/gif;base64,") == 6


def test_bars_are_proportional_to_success_with_min_max_error_bars(tmp_path):
    html = _report(tmp_path)
    bars = _bars(html)
    assert set(bars) == {(LABELS[n], g) for n in SUCCESS for g in (TASK, "all tasks")}
    for name, success in SUCCESS.items():
        for group in (TASK, "all tasks"):
            value, height = bars[(LABELS[name], group)]
            assert value == pytest.approx(success)
            assert height == pytest.approx(success * PLOT_HEIGHT, abs=1e-3)
    # The oracle's seeds: 1.0, 0.5, 0.5 -> error bar from 0.5 to 1.0.
    errs = re.findall(
        r'<line class="err" data-series="simulator" data-group="([^"]+)" data-low="([^"]+)" '
        r'data-high="([^"]+)" x1="[^"]+" y1="([^"]+)" x2="[^"]+" y2="([^"]+)"',
        html,
    )
    assert len(errs) == 2
    for _, low, high, y_low, y_high in errs:
        assert (float(low), float(high)) == (0.5, 1.0)
        assert float(y_low) - float(y_high) == pytest.approx(0.5 * PLOT_HEIGHT)
    # The table shows the same numbers: mean [min, max] in %.
    assert '66.7 <span class="nw">[50.0, 100.0]</span>' in html
    assert '100.0 <span class="nw">[100.0, 100.0]</span>' in html


def test_report_is_self_contained(tmp_path):
    html = _report(tmp_path)
    # No address outside the page: look outside the embedded base64 payloads, whose bytes may
    # spell anything.
    text = re.sub(r"data:[\w/+.-]+;base64,[A-Za-z0-9+/=]*", "data:", html)
    assert not re.search(r"(https?:|ftp:|//[\w.-]+\.[a-z]{2,})", text, re.IGNORECASE)
    assert "<script" not in html and "<link" not in html and "url(" not in html
    sources = re.findall(r'src="([^"]*)"', html)
    assert sources and all(s.startswith("data:image/gif;base64,") for s in sources)
    # repeat: 3 trials x (execution + plan); random: its 1 trial; the oracle run has no GIFs.
    assert len(sources) == 7
    runs = small_runs()
    first = base64.b64decode(sources[0].split(",", 1)[1])
    gifs = {p.read_bytes() for p in (runs["repeat"] / "gifs").rglob("*.gif")}
    assert first[:6] == b"GIF89a" and first in gifs


def test_oracle_normalised_score(tmp_path, monkeypatch):
    monkeypatch.setenv("VP2_ORACLE_ASSET", str(tmp_path / "absent.json"))  # no shipped oracle
    html = _report(tmp_path)
    # Ratio of means: 0.5 / (2/3) and 1.0 / (2/3).
    assert '<span class="score">0.750</span> [0.750, 0.750]' in html
    assert '<span class="score">1.500</span>' in html
    assert "the oracle (1.000 by definition)" in html
    # Without the oracle among the inputs, a run's own `oracle` setting is used.
    run = tmp_path / "with-oracle-setting"
    shutil.copytree(small_runs()["repeat"], run)
    data = yaml.safe_load((run / "config.yaml").read_text())
    data["config"]["oracle"] = str(small_runs()["oracle"])
    (run / "config.yaml").write_text(yaml.safe_dump(data))
    html = write_report([run], tmp_path / "single.html").read_text()
    assert '<span class="score">0.750</span>' in html
    html = write_report([small_runs()["repeat"]], tmp_path / "none.html").read_text()
    assert "not available (no oracle)" in html and html.count("no shipped oracle") == 1


def test_gallery_shows_successes_first_and_respects_its_caps(tmp_path):
    html = _report(tmp_path, names=("repeat",), trials_per_task=1)
    assert "showing 1 of 4 trials" in html
    figures = re.findall(r'<figure class="trial (ok|fail)">', html)
    assert figures == ["ok"]
    assert "1 of 4 trials with GIFs shown" in html
    html = _report(tmp_path, names=("repeat",), max_gallery_bytes=1000)
    assert "data:image/gif" not in html and "The gallery stopped at" in html


def test_labels_of_two_runs_of_one_model_are_made_distinct(tmp_path):
    runs = small_runs()
    copy = tmp_path / "repeat-copy"
    shutil.copytree(runs["repeat"], copy)
    html = write_report([runs["repeat"], copy], tmp_path / "r.html").read_text()
    assert "repeat_last_frame [repeat]" in html and "repeat_last_frame [repeat-copy]" in html


def test_labels_given_by_the_user_replace_the_model_spec(tmp_path):
    runs = small_runs()
    html = write_report(
        [runs["repeat"], runs["random"]], tmp_path / "r.html", labels=["persistence", None]
    ).read_text()
    assert "<b>persistence</b>" in html and "<b>random actions</b>" in html
    runs_table = html.split("<h2>Runs")[1].split("</table>")[0]
    assert "repeat_last_frame" not in re.sub(r"<code>[^<]*</code>", "", runs_table)
    with pytest.raises(ValueError, match="1 label\\(s\\) for 2 run"):
        write_report([runs["repeat"], runs["random"]], tmp_path / "x.html", labels=["a"])


def test_runs_table_counts_seeds_and_wraps_long_paths(tmp_path):
    runs = small_runs()
    html = write_report([runs["repeat"], runs["random"]], tmp_path / "r.html").read_text()
    table = html.split("<h2>Runs")[1].split("</table>")[0]
    assert '<div class="wide"><table class="runs">' in table
    assert re.findall(r'<td class="num" title="seeds ([\d, ]+)">(\d+)</td>', table) == [
        ("0, 1", "2"), ("0", "1")
    ]
    assert "table.runs code{word-break:break-all}" in html


def test_study_section_appears_with_metrics(tmp_path):
    files = [
        write_metrics_file(tmp_path / "m" / "repeat.json", 300.0, 0.3, 0.7),
        write_metrics_file(tmp_path / "m" / "random.json", 100.0, 0.1, 0.9),
        write_metrics_file(tmp_path / "m" / "oracle.json", 200.0, 0.2, 0.8),
    ]
    html = _report(tmp_path, metrics=files)
    assert "<h2>Metrics versus control</h2>" in html
    # FVD, LPIPS x100, SSIM x100, success of the random agent.
    assert re.search(
        r"<td>random actions</td><td class=\"num\">100.0</td><td class=\"num\">10.0</td>"
        r"<td class=\"num\">90.0</td><td class=\"num\">100.0 \[100.0, 100.0\]</td>",
        html,
    )
    # Success ranks repeat < oracle < random; FVD and LPIPS rank them inversely, SSIM alike.
    # rho and tau of FVD and LPIPS in 2 scopes; of SSIM +1.
    assert html.count("-1.000") == 8 and html.count("+1.000") == 4
    assert html.count('class="chart scatter"') == 3
    assert "<h2>Metrics versus control</h2>" not in _report(tmp_path)
    with pytest.raises(ValueError, match="one metrics file per run"):
        _report(tmp_path, metrics=files[:2])
    # Some runs only: a mapping.
    html = _report(tmp_path, metrics={str(small_runs()["random"]): files[1]})
    assert "1 model(s); a rank correlation needs at least 3" in html


def test_vp2_report_command(tmp_path, capsys):
    runs = small_runs()
    metrics = write_metrics_file(tmp_path / "m.json", 100.0, 0.1, 0.9)
    parser = report_cmd.configure_parser(argparse.ArgumentParser())
    out = tmp_path / "cli.html"
    args = parser.parse_args(
        [
            str(runs["repeat"]),
            str(runs["random"]),
            "--out",
            str(out),
            "--metrics",
            "-",
            str(metrics),
            "--trials-per-task",
            "2",
            "--title",
            "my report",
        ]
    )
    assert report_cmd.run_from_args(args) == 0
    html = out.read_text()
    assert "<h1>my report</h1>" in html and "showing 2 of 4 trials" in html
    assert "<h2>Metrics versus control</h2>" in html
    assert f"wrote {out}" in capsys.readouterr().out


def test_a_failing_report_never_loses_the_results(tmp_path, monkeypatch, caplog):
    def broken(*args, **kwargs):
        raise RuntimeError("report broke (test)")

    monkeypatch.setattr(report_lib, "write_report", broken)
    config = RunConfig(
        model="repeat_last_frame",
        agent="random",
        out=str(tmp_path / "run"),
        suite=str(tiny_suite_path()),
        seeds=(0,),
        num_instances=1,
        num_steps=3,
        progress=False,
    )
    with caplog.at_level(logging.WARNING, logger="vp2.report.page"):
        result = run_benchmark(config, after_run=write_run_report)
    assert result.summary.mean == 1.0
    assert (tmp_path / "run" / "summary.json").is_file()
    assert not (tmp_path / "run" / "report.html").exists()
    assert "could not write the HTML report" in caplog.text and "report broke" in caplog.text


# --------------------------------------------------------------------------- in a browser

CHROMIUM = find_chromium()


def test_report_renders_in_headless_chromium(tmp_path):
    if CHROMIUM is None:
        # .ci/run installs chromium and sets VP2_REQUIRE_BROWSER=1: there, a missing browser fails.
        if os.environ.get("VP2_REQUIRE_BROWSER") == "1":
            pytest.fail("VP2_REQUIRE_BROWSER=1 but no chromium on PATH")
        pytest.skip("no chromium on PATH (Debian: apt-get install chromium; .ci/run installs it)")
    """Loads the report in Chromium: no console messages, every image decodes, the charts
    are laid out, a trial GIF plays (two screenshots of it 0.6 s apart differ), and a
    full-page screenshot is not blank. ``VP2_UPDATE_SCREENSHOT=1`` also refreshes
    docs/report-screenshot.png."""
    files = [
        write_metrics_file(tmp_path / "m" / "repeat.json", 300.0, 0.3, 0.7),
        write_metrics_file(tmp_path / "m" / "random.json", 100.0, 0.1, 0.9),
        write_metrics_file(tmp_path / "m" / "oracle.json", 200.0, 0.2, 0.8),
    ]
    runs = small_runs()
    page = write_report(
        [runs[n] for n in ("repeat", "random", "oracle")], tmp_path / "report.html", files
    )
    with Browser(CHROMIUM, width=1200, height=2000) as browser:
        browser.open(page)
        images = browser.evaluate(
            "Array.from(document.images).map(i => [i.complete, i.naturalWidth, i.naturalHeight])"
        )
        charts = browser.evaluate(
            "Array.from(document.querySelectorAll('svg.chart')).map(s => "
            "[s.getBoundingClientRect().width, s.querySelectorAll('rect.bar, circle.pt').length])"
        )
        box = browser.evaluate(
            "(() => { const r = document.querySelector('img.exec').getBoundingClientRect();"
            " return {x: r.x, y: r.y + window.scrollY, width: r.width, height: r.height}; })()"
        )
        first = iio.imread(browser.screenshot(box))
        changed = 0
        for _ in range(5):  # the GIF has 4 frames of 250 ms; allow for a slow machine
            time.sleep(0.6)
            changed = int((iio.imread(browser.screenshot(box)) != first).any(axis=-1).sum())
            if changed:
                break
        height = browser.evaluate("document.documentElement.scrollHeight")
        full = browser.screenshot({"x": 0, "y": 0, "width": 1200, "height": height})
        # On a page narrower than a chart (many runs and tasks, or a small window) the charts
        # scale down to fit instead of running off the right edge.
        narrow = browser.evaluate(
            "(() => { document.body.style.maxWidth = '300px';"
            " const right = document.body.getBoundingClientRect().right;"
            " return Array.from(document.querySelectorAll('svg.chart')).map(s => {"
            " const r = s.getBoundingClientRect(); return [r.right <= right + 0.5, r.width, r.height]; });"
            " })()"
        )
        # ... and tables wider than the page scroll inside their own box: the page itself never
        # scrolls sideways.
        page_width = browser.evaluate(
            "[document.documentElement.scrollWidth, document.documentElement.clientWidth]"
        )
        browser.drain(0.3)
        console = list(browser.console)
    assert console == []
    assert len(images) == 7 and all(ok and w > 0 and h > 0 for ok, w, h in images)
    assert len(charts) == 4 and all(width > 300 for width, _ in charts)
    assert [n for _, n in charts] == [6, 3, 3, 3]  # 3 models x 2 groups; 3 points per scatter
    assert changed > 0, "the trial GIF did not change between screenshots: not playing"
    assert len(narrow) == 4 and all(fits and 0 < w <= 300 and h > 0 for fits, w, h in narrow)
    assert page_width[0] <= page_width[1], f"the page scrolls sideways: {page_width}"
    shot = iio.imread(full)[..., :3]
    assert shot.shape[1] == 1200 and shot.shape[0] == height
    assert shot.std() > 20 and (shot.min(axis=-1) < 100).mean() > 0.01  # text and charts
    (tmp_path / "screenshot.png").write_bytes(full)
    if os.environ.get("VP2_UPDATE_SCREENSHOT"):
        _save_docs_screenshot(shot)


def _save_docs_screenshot(shot: np.ndarray) -> None:
    """The full page at half size, 128 colours (< 300 KB), for docs/report.md."""
    from PIL import Image

    image = Image.fromarray(np.ascontiguousarray(shot))
    image = image.resize((image.width // 2, image.height // 2), Image.Resampling.LANCZOS)
    image.quantize(128).save(DOCS / "report-screenshot.png", optimize=True)


def test_a_run_without_finished_trials_still_reports(tmp_path):
    run = tmp_path / "errors"
    run.mkdir()
    record = {
        "task": TASK,
        "instance": 0,
        "seed": 0,
        "success": None,
        "error": {"type": "ValueError", "message": "bad frames", "where": "model"},
    }
    (run / "trials.jsonl").write_text(json.dumps(record) + "\n")  # no config.yaml either
    html = write_report([run], tmp_path / "r.html").read_text()
    assert "unknown model" in html and "1 trial(s) ended in an error" in html
    assert _bars(html) == {} and ">n/a</text>" in html
    with pytest.raises(FileNotFoundError, match="not a vp2 run directory"):
        write_report([tmp_path / "nothing"], tmp_path / "x.html")


def test_diagnosis_section_shows_a_vp2_diagnose_report_beside_measured_success(tmp_path):
    from tests.report.report_runs import write_handmade_run

    run = write_handmade_run(tmp_path / "run", "svg_prime:x.pt", {(0, 0): True, (1, 0): False})
    (run / "diagnose.json").write_text(json.dumps({
        "env": "tabletop",
        "action_conditioning": {"ratio": 1.42, "ci": [1.3, 1.55], "clips": 64},
        "planning": {"scripted_plan": {"instances": 8, "of": 51, "median_rank": 3,
                                       "top_fraction": 0.75},
                     "oracle_agreement": {"instances": 8, "median_rho": 0.61,
                                          "best_in_top_fraction": 0.5}},
        "verdicts": {"action_conditioning": {"status": "uses",
                                             "text": "predictions depend on the actions"}},
        "predicted_control_score": 0.41,
        "predicted_control_score_reason": "fitted",
    }))  # fmt: skip
    html = write_report([run], tmp_path / "report.html").read_text()
    row = re.search(r'<table class="diagnosis">.*?</table>', html, re.S).group(0)
    cells = re.findall(r"<td[^>]*>(.*?)</td>", row)
    assert cells == ["<b>svg_prime:x.pt</b>", "tabletop", "vp2 diagnose",
                     "1.420 [1.300, 1.550] on 64 clips", "median rank 3 of 51, top 10% on 75%",
                     "ρ +0.61, its best in the top 10% on 50%", "41%", "50%"]  # fmt: skip
    # The conditioning cell carries its verdict (colour and the sentence on hover).
    assert '<td class="diag-uses" title="predictions depend on the actions">1.420' in row


def test_diagnosis_section_says_when_no_run_has_one(tmp_path):
    html = _report(tmp_path, names=("repeat",))
    section = html.split("<h2>Diagnosis</h2>", 1)[1].split("<h2>", 1)[0]
    assert "No run directory here holds a diagnosis" in section
    assert '<table class="diagnosis">' not in section
