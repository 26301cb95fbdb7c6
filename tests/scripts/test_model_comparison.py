"""End to end: ``benchmarks.comparison.model_comparison --smoke`` on a tiny collected RoboDesk dataset,
then again to show that it resumes (slow: about a minute per invocation on a loaded 2-core CPU).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from vp2.data.collect import CollectionConfig, collect
from vp2.run.run_dir import read_trials

REPO = Path(__file__).resolve().parents[2]
MODULE = "benchmarks.comparison.model_comparison"
FAMILIES = ("fitvid", "struct_vrnn")
# A model evaluated beside the families, not trained by the comparison: the shipped SVG′.
EXTRA = ("shipped", "svg_prime:src/vp2/assets/models/svg_prime_tiny_robodesk.pt")
RUNS = (*FAMILIES, EXTRA[0], "repeat_last_frame", "random")
TASK = "robodesk/push_red"  # the task --smoke runs

# 3 trajectories of 15 actions at 64x64 (the benchmark's size): 10 train and 5 valid clips.
TINY = CollectionConfig(
    env="robodesk",
    trajectories_per_stream=3,
    streams=(TASK,),
    image_size=64,
    horizon=15,
    chunk_size=3,
    valid_every=3,
)


def _compare(data: Path, out: Path, *extra: str) -> None:
    command = [sys.executable, "-m", MODULE, "--smoke", "--data", str(data), "--out", str(out),
               "--families", *FAMILIES, "--threads", "1", "--extra", "=".join(EXTRA),
               "--docs", str(out.parent / "docs" / "results.md"), *extra]  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-5000:]


def _log(out: Path) -> list[list[dict]]:
    """``log.jsonl`` grouped by invocation, in order."""
    lines = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    invocations = list(dict.fromkeys(line["invocation"] for line in lines))
    return [[x for x in lines if x["invocation"] == i] for i in invocations]


def _table(markdown: str, header_start: str) -> list[list[str]]:
    """The rows (cells) of the Markdown table whose header row starts with ``header_start``."""
    lines = markdown.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(header_start))
    rows = []
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip() for c in line.strip("|").split("|")])
    return rows


@pytest.mark.slow
def test_model_comparison_smoke_runs_every_stage_and_resumes(tmp_path):
    data = collect(TINY, tmp_path / "data", workers=1, progress=False)
    out = tmp_path / "comparison"
    _compare(data, out)

    results = (out / "results.md").read_text()
    # Success: a row per task, a cell per agent plus the shipped oracle's, then the means.
    table = _table(results, "| task |")
    assert table[0] == ["task", *RUNS, "oracle (shipped)"]
    assert [row[0] for row in table[2:]] == [
        TASK,
        "**mean over tasks**",
        "**oracle-normalised mean**",
    ]
    assert all(cell.endswith("(1)") for cell in table[2][1:-1])  # 1 trial each
    for name in RUNS:
        records = read_trials(out / "runs" / name)
        assert [(r["task"], r["instance"], r["seed"]) for r in records] == [(TASK, 0, 0)]
        assert records[0]["error"] is None
    # The budget stopped each training run, which wrote its final checkpoint.
    budget = _table(results, "| family |")
    assert [row[0] for row in budget[2:]] == [*FAMILIES, EXTRA[0]]
    assert budget[-1][1:4] == [f"`{EXTRA[1]}`", "–", "not trained here"]
    for family in FAMILIES:
        record = json.loads((out / "train" / f"{family}.json").read_text())
        assert record["budget_reached"] and record["step"] >= 1
        assert record["train_minutes"] >= record["budget_minutes"] == 0.1
        assert Path(record["checkpoint"]).is_file()
        assert f"| {family} | {family} (" in results
    # Action conditioning: finite ratios inside their bootstrap intervals, in the table too.
    for family in (*FAMILIES, EXTRA[0]):
        r = json.loads((out / "conditioning" / f"{family}.json").read_text())
        for stats in (r, r["moving"]):
            low, high = stats["ci"]
            assert math.isfinite(stats["ratio"]) and low <= stats["ratio"] <= high
        assert r["clips"] == 5  # every held-out clip of the tiny dataset
        assert f"| {family} | {r['ratio']:.3f} [" in results
        low, high = r["trajectory_ci"]
        assert low <= r["ratio"] <= high
        assert f"[{low:.3f}, {high:.3f}] ({r['trajectories']} trajectories)" in results
    # Metrics of every predictor; the study ranked them; the report page exists.
    for name in (*FAMILIES, EXTRA[0], "repeat_last_frame"):
        metrics = json.loads((out / "metrics" / name / "metrics.json").read_text())
        assert metrics["num_clips"] == 5 and 0 < metrics["metrics"]["mse"] < 1
        assert f"| {name} | {metrics['metrics']['mse']:.5f} |" in results
    assert json.loads((out / "study" / "study.json").read_text())["labels"] == [
        *FAMILIES,
        EXTRA[0],
        "repeat_last_frame",
    ]
    assert (out / "report.html").stat().st_size > 10_000
    # vp2 diagnose of every predictor, beside the success its run measured.
    diagnosis = _table(results, "| model | actions |")
    assert [row[0] for row in diagnosis[2:]] == [*FAMILIES, EXTRA[0], "repeat_last_frame"]
    for row in diagnosis[2:]:
        record = json.loads((out / "diagnose" / f"{row[0]}.json").read_text())
        assert record["settings"]["clips"] == 4 and record["settings"]["instances_per_task"] == 0
        report = record["report"]
        assert report["action_conditioning"]["clips"] == 4
        assert row[1] == report["verdicts"]["action_conditioning"]["text"]
        assert row[2] == "–" and row[4] == "–"  # no instance probed: no predicted score
        mean = json.loads((out / "runs" / row[0] / "summary.json").read_text())["mean"]
        assert row[5] == f"{100 * mean:.0f}%"
        assert row[6] == f"{report['timing']['total_s']:.0f} s / " + (
            f"{read_trials(out / 'runs' / row[0])[0]['timings']['total_s']:.0f} s (1 trial)"
        )
    assert "predictions do not depend on the actions" in diagnosis[-1][1]  # repeat-last-frame
    # The baselines ran first; the page was published after each run with what was pending.
    (first,) = _log(out)
    assert [x["name"] for x in first if x["stage"] == "run"] == [*RUNS[3:], EXTRA[0], *FAMILIES]
    assert [x["pending"] for x in first if x["stage"] == "results"] == [
        ["random", EXTRA[0], *FAMILIES], [EXTRA[0], *FAMILIES], list(FAMILIES), [FAMILIES[1]], []
    ]
    assert "**Incomplete**" not in results
    # The published copy: the same page, its screenshot beside it.
    published = (tmp_path / "docs" / "results.md").read_text()
    if "![vp2 report](report.png)" in results:
        assert published.replace("results-report.png", "report.png") == results
        assert (tmp_path / "docs" / "results-report.png").read_bytes() == (
            out / "report.png"
        ).read_bytes()
    else:
        assert published == results
    if "![vp2 report](report.png)" in results:
        assert (out / "report.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    else:
        assert "no screenshot" in results

    # Again, with one stage's output removed: only that stage runs; nothing is trained or
    # planned again.
    checkpoints = {f: json.loads((out / "train" / f"{f}.json").read_text()) for f in FAMILIES}
    mtimes = {f: Path(c["checkpoint"]).stat().st_mtime_ns for f, c in checkpoints.items()}
    trials = {name: (out / "runs" / name / "trials.jsonl").read_text() for name in RUNS}
    (out / "conditioning" / "fitvid.json").unlink()
    _compare(data, out)
    first, second = _log(out)
    status = {(x["stage"], x["name"]): x["status"] for x in second}
    assert {status[("train", f)] for f in FAMILIES} == {"done earlier"}
    assert status[("conditioning", "fitvid")] == "ran"
    assert status[("conditioning", "struct_vrnn")] == "done earlier"
    assert {status[("diagnose", n)] for n in (*FAMILIES, EXTRA[0], "repeat_last_frame")} == {
        "done earlier"
    }
    assert {status[("metrics", n)] for n in (*FAMILIES, EXTRA[0], "repeat_last_frame")} == {
        "done earlier"
    }
    assert [x["num_run"] for x in second if x["stage"] == "run"] == [0] * len(RUNS)
    assert [x["num_run"] for x in first if x["stage"] == "run"] == [1] * len(RUNS)
    for family, record in checkpoints.items():
        assert Path(record["checkpoint"]).stat().st_mtime_ns == mtimes[family]
    for name in RUNS:
        assert (out / "runs" / name / "trials.jsonl").read_text() == trials[name]
    assert (out / "results.md").read_text().split("## Training budget")[1] == results.split(
        "## Training budget"
    )[1]

    # --publish-only: the page again from what is on disk, with a Reading section that links
    # the notes (from each page's folder); nothing trained or planned, and the page still
    # names the build's command.
    notes = tmp_path / "notes.md"
    notes.write_text("The baselines solve nothing here.\n")
    _compare(data, out, "--publish-only", "--notes", str(notes))
    third = _log(out)[2]
    assert {x["stage"] for x in third} == {"study", "report", "results"}
    page = (out / "results.md").read_text()
    assert "## Reading\n\n" in page and "](../notes.md)." in page
    assert "The baselines solve nothing here." not in page  # linked, not copied
    assert "](../notes.md)." in (tmp_path / "docs" / "results.md").read_text()
    assert "--publish-only" not in page  # the command shown is the build's
    assert page.split("## Training budget")[1].split("## Reading")[0].rstrip() == results.split(
        "## Training budget"
    )[1].split("## The report")[0].rstrip()
    for name in RUNS:
        assert (out / "runs" / name / "trials.jsonl").read_text() == trials[name]

    # --records: the evidence kept beside (one folder per environment) brings back a part
    # whose measurements were lost; nothing is measured or planned again.
    kept = tmp_path / "records"
    _compare(data, out, "--records", str(kept))
    assert sorted(p.name for p in (kept / "robodesk" / "runs").iterdir()) == sorted(RUNS)
    assert f"compact copy, kept in the repository: `{kept / 'robodesk'}`" in (
        out / "results.md").read_text()
    for stage in ("runs", "metrics", "diagnose", "conditioning"):
        shutil.rmtree(out / stage)
    _compare(data, out, "--records", str(kept))
    fifth = _log(out)[4]
    status = {(x["stage"], x["name"]): x for x in fifth}
    assert status[("records", str(kept / "robodesk"))]["runs"] == len(RUNS)
    assert {x["status"] for x in fifth if x["stage"] in ("conditioning", "diagnose",
                                                         "metrics")} == {"done earlier"}
    assert [x["num_run"] for x in fifth if x["stage"] == "run"] == [0] * len(RUNS)
    for name in RUNS:
        (before,), (after,) = [json.loads(t) for t in trials[name].splitlines()], read_trials(
            out / "runs" / name)
        keys = ("task", "instance", "seed", "success", "actions", "timings")
        assert {k: after[k] for k in keys} == {
            **{k: before[k] for k in keys}, "timings": {"total_s": before["timings"]["total_s"]}}
    assert (out / "results.md").read_text().split("## Training budget")[1].split(
        "## Action conditioning")[0] == results.split("## Training budget")[1].split(
        "## Action conditioning")[0]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        ("svg_prime:model.pt", "expected LABEL=MODEL"),
        ("=svg_prime:model.pt", "expected LABEL=MODEL"),
        ("random=svg_prime:model.pt", "the label 'random' is already used"),
        ("fitvid=svg_prime:model.pt", "the label 'fitvid' is already used"),
    ],
)
def test_a_malformed_extra_model_stops_before_anything_runs(tmp_path, extra, message):
    out = tmp_path / "comparison"
    command = [sys.executable, "-m", MODULE, "--smoke", "--out", str(out), "--extra", extra]
    proc = subprocess.run(command, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1
    assert message in proc.stderr and "Traceback" not in proc.stderr
    assert not out.exists()


def test_the_page_leaves_out_correlations_of_a_metric_no_model_has(tmp_path):
    from benchmarks.comparison.model_comparison_results import study_lines

    def corr(scope, metric, n, rho):
        note = "" if n >= 3 else f"{n} model(s); a rank correlation needs at least 3"
        return {"scope": scope, "metric": metric, "n": n, "spearman": rho, "spearman_p": 0.5,
                "kendall": rho, "kendall_p": 0.3, "note": note}

    rows = [
        {"label": name, "metrics": {"fvd": fvd, "lpips": None, "ssim": ssim},
         "success": success, "success_min": success, "success_max": success, "num_trials": 6}
        for name, fvd, ssim, success in
        (("a", 300.0, 0.8, 0.5), ("b", 1454.85, 0.6, 0.2), ("c", 99.44, 0.9, 0.0))
    ]
    scopes = ("robodesk/push_red", "all tasks")
    study = {
        "rows": {"all tasks": rows},
        "correlations": [
            corr(s, m, 0 if m == "lpips" else 3, None if m == "lpips" else -1.0)
            for s in scopes for m in ("fvd", "lpips", "ssim")
        ],
        "notes": ["a: no LPIPS ×100 in ['m.json']"],
    }
    path = tmp_path / "study.json"
    path.write_text(json.dumps(study))
    text = "\n".join(study_lines(path))
    table = [line for line in text.splitlines() if line.startswith("| robodesk/") or
             line.startswith("| all tasks |")]
    assert len(table) == 4  # FVD and SSIM in each of the two scopes; LPIPS in none
    assert not any("LPIPS" in line for line in table)
    assert "| all tasks | FVD | 3 | -1.000 (p 0.5) | -1.000 (p 0.3) |  |" in table
    assert "Left out: LPIPS ×100, which no model has" in text
    # one decimal, as the metrics table prints them
    assert "| a | 300.0 | n/a | 0.8 | 50 [50, 50] | 6 |" in text
    assert "| b | 1454.8 | n/a | 0.6 |" in text and "| c | 99.4 | n/a | 0.9 |" in text


@pytest.fixture
def comparison():
    """The script as a module."""
    import benchmarks.comparison.model_comparison as module

    return module


def _settings(module, *argv: str):

    argv = ["--smoke", "--families", *FAMILIES, "--seeds", "0", "1", *argv]
    return module.settings_from_args(module.parse_args(argv), argv)


def test_seeds_for_gives_one_run_a_subset_of_the_seeds(comparison, tmp_path):
    run_config = comparison.run_config
    s = _settings(
        comparison, "--seeds-for", "fitvid=1", "--seeds-for", "random=1,0", "--out", str(tmp_path)
    )
    assert s.seeds_for == (("fitvid", (1,)), ("random", (0, 1)))
    assert tuple(run_config(s, "fitvid", "fitvid:x.pt").seeds) == (1,)
    assert tuple(run_config(s, "struct_vrnn", "struct_vrnn:x.pt").seeds) == (0, 1)
    assert tuple(run_config(s, "random", None).seeds) == (0, 1)
    assert s.seeds_of("repeat_last_frame") == (0, 1)


@pytest.mark.parametrize(
    ("item", "message"),
    [
        ("fitvid", "expected RUN=SEEDS"),
        ("fitvid=", "expected RUN=SEEDS"),
        ("fitvid=a", "expected RUN=SEEDS"),
        ("mcvd=0", "no run 'mcvd' in this comparison; the runs are fitvid, struct_vrnn"),
        ("fitvid=2", "seed(s) [2] are not among --seeds 0 1"),
    ],
)
def test_a_malformed_seeds_for_says_what_is_wrong(comparison, item, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        _settings(comparison, "--seeds-for", item)


def test_runs_finished_before_their_metrics_publish_without_a_study(comparison, tmp_path,
                                                                     monkeypatch):
    """A run finished beside a build still measuring metrics (`--publish-only` meanwhile): the
    page is written, the study waits (a stale one is removed, not shown)."""
    s = _settings(comparison, "--out", str(tmp_path / "cmp"))
    (s.out / "study").mkdir(parents=True)
    (s.out / "study" / "study.json").write_text("{}")
    import benchmarks.comparison.model_comparison_publish as publishing

    monkeypatch.setattr(publishing, "write_report", lambda runs, out, **kw: out)
    monkeypatch.setattr(publishing, "screenshot", lambda html, png: "no browser")
    monkeypatch.setattr(publishing, "results_markdown", lambda out, note, pending, *a, **kw:
                        f"pending {' '.join(pending)}\n")
    log = comparison.StageLog(s.out)
    path = comparison.publish(s, {"fitvid": tmp_path / "runs" / "fitvid"}, {}, log, ["mcvd"])
    assert path.read_text() == "pending mcvd\n"
    assert not (s.out / "study").exists()
    (line,) = [x for x in _log(s.out)[-1] if x["stage"] == "study"]
    assert line["status"] == "waits" and "metrics" in line["why"]


def test_the_page_names_the_runs_on_fewer_seeds(tmp_path):
    from benchmarks.comparison.model_comparison_results import success_lines

    s = {"run_names": ["fitvid"], "tasks": ["robodesk"], "num_instances": 3, "seeds": [0, 1],
         "seeds_for": [["fitvid", [0]]], "num_samples": 50, "num_steps": 15}  # fmt: skip
    text = "\n".join(success_lines(tmp_path, s))
    assert "seeds 0, 1 (fitvid: seed 0 only, `--seeds-for`), MPPI" in text
    assert "| robodesk" not in text  # no summary on disk: no task rows


def test_the_oracle_column_is_the_table_the_note_names(tmp_path):
    # A random agent has no planner samples, so its run is normalised by the SPEC count's table;
    # the column must still show the table the note names (the first run's), not the last's.
    from benchmarks.comparison.model_comparison_results import success_lines

    from vp2.run.run_dir import RunDir

    for name, source, oracle in (("svg", "table 'samples-50'", 0.9), ("random", "table 'spec'", 0.8)):
        summary = {"oracle_source": source, "mean": 0.5, "min": 0.5, "max": 0.5, "normalised": 0.5,
                   "tasks": [{"task": "tabletop/push_sphere", "mean": 0.5, "min": 0.5, "max": 0.5,
                              "num_trials": 1, "oracle_mean": oracle}]}  # fmt: skip
        path = RunDir(tmp_path / "runs" / name).summary_json
        path.parent.mkdir(parents=True)
        path.write_text(json.dumps(summary))
    s = {"run_names": ["svg", "random"], "tasks": ["tabletop"], "num_instances": 1, "seeds": [0],
         "num_samples": 50, "num_steps": 15}  # fmt: skip
    text = "\n".join(success_lines(tmp_path, s))
    rows = {r[0]: r for r in _table(text, "| task |")[2:]}
    assert rows["tabletop/push_sphere"][-1] == "90" and rows["**mean over tasks**"][-1] == "90"
    assert "- normalised by the table 'samples-50'" in text
    assert "- random: normalised by the table 'spec' instead" in text


def test_the_reading_section_links_the_notes_from_where_the_page_is_written(tmp_path):
    from benchmarks.comparison.model_comparison_results import relative_link, results_markdown

    notes = Path("docs/findings/model-comparison.md")
    assert relative_link(notes, Path("docs/results.md")) == "findings/model-comparison.md"
    assert relative_link(notes, Path("outputs/comparison/results.md")) == (
        "../../docs/findings/model-comparison.md"
    )
    # A comparison that has nothing on disk yet: the page still has its sections.
    settings = {
        "vp2_version": "0", "torch_version": "0", "command": "python -m x", "data": "d",
        "batch_size": 4, "budget_minutes": 0.1, "families": [], "family_stages": {},
        "run_names": [], "tasks": ["robodesk"], "num_instances": 1, "seeds": [0],
        "num_samples": 8, "num_steps": 3, "conditioning_clips": 8, "conditioning_samples": 1,
        "metrics_names": [], "lpips": [], "fvd": False,
    }  # fmt: skip
    (tmp_path / "comparison.json").write_text(json.dumps(settings))
    page = results_markdown(tmp_path, "no screenshot", notes="findings/model-comparison.md")
    reading = page.split("## Reading\n\n")[1].split("\n\n## The report")[0]
    assert reading == (
        "What these numbers say is written apart from this generated page: "
        "[findings/model-comparison.md](findings/model-comparison.md)."
    )
    assert "## Reading" not in results_markdown(tmp_path, "no screenshot")


def test_a_zoo_model_shows_the_budget_its_card_records(comparison, tmp_path):
    from benchmarks.comparison.model_comparison_results import budget_lines

    from vp2.models.zoo import get_card

    argv = ["--smoke", "--families", "--extra", "svg=zoo:svg_prime-tiny-tabletop"]
    s = comparison.settings_from_args(comparison.parse_args(argv), argv)
    assert s.families == () and s.extras == (("svg", "zoo:svg_prime-tiny-tabletop"),)
    s = dataclasses.replace(s, out=tmp_path)
    assert comparison.write_zoo_cards(s) == [tmp_path / "zoo" / "svg.json"]
    card = json.loads((tmp_path / "zoo" / "svg.json").read_text())
    assert card == get_card("svg_prime-tiny-tabletop").to_json()
    page = {"families": [], "family_stages": {}, "extra_models": dict(s.extras)}
    text = "\n".join(budget_lines(tmp_path, page))
    assert "No family is trained by this comparison" in text
    assert (
        f"| svg | `zoo:svg_prime-tiny-tabletop` (svg_prime, {card['preset']}) | "
        f"{card['parameters'] / 1e6:.2f} M | 30 (zoo card) | – | {card['steps']:,} | "
        f"{card['device']} | – |"
    ) in text
    (tmp_path / "zoo" / "svg.json").unlink()  # not from the zoo: no card, no budget
    assert "| svg | `zoo:svg_prime-tiny-tabletop` | – | not trained here |" in "\n".join(
        budget_lines(tmp_path, page)
    )


def _fake_dataset(root: Path, env: str) -> Path:
    """A folder with a dataset manifest naming ``env`` (what the part split reads)."""
    from vp2.data.storage import FORMAT, MANIFEST

    root.mkdir(parents=True)
    (root / MANIFEST).write_text(json.dumps({"format": FORMAT, "config": {"env": env}}))
    return root


def test_several_datasets_split_the_comparison_by_environment(comparison, tmp_path):
    desk = _fake_dataset(tmp_path / "desk", "robodesk")
    table = _fake_dataset(tmp_path / "table", "tabletop")
    argv = ["--smoke", "--families", "--data", str(desk), "--data", str(table),
            "--out", str(tmp_path / "cmp"), "--tasks", "robodesk/push_red", "tabletop",
            "--extra", "svg=zoo:svg_prime-tiny-tabletop",
            "--extra", "shipped@robodesk=svg_prime:src/vp2/assets/models/svg_prime_tiny_robodesk.pt",
            "--extra", "fit=zoo:fitvid-robodesk-60min"]  # fmt: skip
    args = comparison.parse_args(argv)
    parts = comparison.part_settings(args, argv, args.data)
    assert [(p.out, p.data, p.tasks) for p in parts] == [
        (tmp_path / "cmp" / "robodesk", desk, ("robodesk/push_red",)),
        (tmp_path / "cmp" / "tabletop", table, ("tabletop",)),
    ]
    assert parts[0].extras == (
        ("shipped", "svg_prime:src/vp2/assets/models/svg_prime_tiny_robodesk.pt"),
        ("fit", "zoo:fitvid-robodesk-60min"),
    )
    assert parts[1].extras == (("svg", "zoo:svg_prime-tiny-tabletop"),)
    # every part records the whole command, which rebuilds both; none writes the page itself
    assert all(p.docs is None and p.command == parts[0].command for p in parts)
    assert "--data " + str(table) in parts[0].command


@pytest.mark.parametrize(("argv", "message"), [
    (["--families", "fitvid"], "train families with one --data"),
    (["--families", "--extra", "m=svg_prime:x.pt"], "say which environment it plans in: "
                                                    "--extra m@ENV=svg_prime:x.pt"),
    (["--families", "--extra", "m@desk=svg_prime:x.pt"], "it plans in desk, and no --data"),
    (["--families", "--extra", "m=zoo:svg_prime-tiny-tabletop"],
     "--data DESK: no --extra model plans in robodesk"),
    (["--families", "--extra", "m=zoo:svg_prime-tiny-tabletop", "--extra",
      "n=zoo:svg_prime-tiny-robodesk", "--tasks", "robodesk", "tabletop", "desk/x"],
     "--tasks desk/x: no --data of that environment"),
])
def test_a_split_comparison_refuses_what_it_cannot_place(comparison, tmp_path, argv, message):
    desk = _fake_dataset(tmp_path / "desk", "robodesk")
    table = _fake_dataset(tmp_path / "table", "tabletop")
    argv = ["--smoke", "--data", str(desk), "--data", str(table), *argv]
    args = comparison.parse_args(argv)
    with pytest.raises(ValueError) as err:
        comparison.part_settings(args, argv, args.data)
    assert message.replace("DESK", str(desk)) in str(err.value)
    twice = ["--smoke", "--families", "--data", str(desk), "--data", str(desk)]
    with pytest.raises(ValueError, match="two datasets of one environment"):
        comparison.part_settings(comparison.parse_args(twice), twice, [desk, desk])
    with pytest.raises(ValueError, match="not a vp2 dataset"):
        comparison.dataset_env(tmp_path)


def test_the_page_of_several_environments_follows_each_parts_publishing(comparison, tmp_path,
                                                                        monkeypatch):
    """A build that spans sessions: the page is rewritten whenever a part rewrites its own, of
    the parts that have started, so one cut short in its second part still shows both."""
    desk = _fake_dataset(tmp_path / "desk", "robodesk")
    table = _fake_dataset(tmp_path / "table", "tabletop")
    page = tmp_path / "docs" / "results.md"
    page.parent.mkdir()
    argv = ["--smoke", "--families", "--data", str(table), "--data", str(desk),
            "--out", str(tmp_path / "cmp"), "--docs", str(page),
            "--extra", "svg=zoo:svg_prime-tiny-tabletop",
            "--extra", "fit=zoo:fitvid-robodesk-60min"]  # fmt: skip
    args = comparison.parse_args(argv)
    parts = comparison.part_settings(args, argv, args.data)
    monkeypatch.setattr(comparison, "combined_markdown",
                        lambda outs, shots, notes: " ".join(o.name for o in outs) + "\n")
    seen = []

    def run_part(part, after_publish=None):
        part.out.mkdir(parents=True)
        (part.out / "comparison.json").write_text("{}")
        after_publish()  # the part published a run
        seen.append(page.read_text())
        if part.out.name == "robodesk":
            raise KeyboardInterrupt  # the session ends in the second part's runs
        after_publish()
        seen.append(page.read_text())

    monkeypatch.setattr(comparison, "run_comparison", run_part)
    with pytest.raises(KeyboardInterrupt):
        comparison.run_parts(parts, args)
    assert seen == ["tabletop\n", "tabletop\n", "tabletop robodesk\n"]
    assert page.read_text() == "tabletop robodesk\n"


@pytest.mark.slow
def test_a_comparison_over_both_environments_writes_one_page(tmp_path):
    desk = collect(TINY, tmp_path / "desk", workers=1, progress=False)
    table = collect(dataclasses.replace(TINY, env="tabletop", streams=None),
                    tmp_path / "table", workers=1, progress=False)
    out, page = tmp_path / "cmp", tmp_path / "docs" / "results.md"
    command = [sys.executable, "-m", MODULE, "--smoke", "--families", "--data", str(desk),
               "--data", str(table), "--out", str(out), "--threads", "1", "--docs", str(page),
               "--tasks", TASK, "tabletop/push_sphere",
               "--extra", "desk_svg=zoo:svg_prime-tiny-robodesk",
               "--extra", "table_svg=zoo:svg_prime-tiny-tabletop"]  # fmt: skip
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run(command, cwd=REPO, env=env, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-5000:]
    text = page.read_text()
    assert text.index("## RoboDesk") < text.index("## Tabletop")
    assert text.count("```bash") == 1 and "--data " + str(table) in text
    desk_part, table_part = text.split("## Tabletop")
    # each part's success table: its own task, its own model and the baselines
    assert _table(desk_part, "| task |")[0][:2] == ["task", "desk_svg"]
    assert [r[0] for r in _table(desk_part, "| task |")[2:3]] == [TASK]
    assert _table(table_part, "| task |")[0][:2] == ["task", "table_svg"]
    assert [r[0] for r in _table(table_part, "| task |")[2:3]] == ["tabletop/push_sphere"]
    assert "### Success per task" in desk_part and "\n## Success" not in text
    assert "Incomplete" not in text
    for env_name in ("robodesk", "tabletop"):
        assert len(read_trials(out / env_name / "runs" / "random")) == 1


def test_metrics_skipped_for_missing_fvd_weights_are_measured_again(comparison, tmp_path,
                                                                     monkeypatch):
    argv = ["--smoke", "--families", "--out", str(tmp_path)]
    s = comparison.settings_from_args(comparison.parse_args(argv), argv)
    calls = []

    def evaluate(spec, data, **kwargs):
        calls.append(kwargs["fvd_metric"])
        fvd = kwargs["fvd_metric"] is not None
        return {"metrics": {"mse": 0.1, **({"fvd": 9.0} if fvd else {})},
                "skipped": {} if fvd else {"fvd": "FVD weights missing"}}

    import benchmarks.comparison.model_comparison_metrics as metrics

    monkeypatch.setattr(metrics, "evaluate_model", evaluate)
    log, fvd = comparison.StageLog(tmp_path), object()
    path = comparison.metrics_stage(s, "m", "spec", log)
    assert "fvd" in json.loads(path.read_text())["skipped"]
    comparison.metrics_stage(s, "m", "spec", log)  # still no weights: done earlier
    assert calls == [None]
    comparison.metrics_stage(s, "m", "spec", log, fvd)  # the weights are here now
    assert calls == [None, fvd] and json.loads(path.read_text())["metrics"]["fvd"] == 9.0
    comparison.metrics_stage(s, "m", "spec", log, fvd)
    assert calls == [None, fvd]


def test_a_diagnosis_made_before_its_environments_predictor_gets_the_shipped_score(tmp_path):
    from benchmarks.comparison.model_comparison_results import diagnosis_lines

    from vp2.diagnose.score import features, load_predictor, predict

    report = json.loads((REPO / "results/comparison/tabletop-suite-v3/diagnose/svg_prime.json").read_text())
    assert report["predicted_control_score"] is None  # measured before the tabletop had one
    settings = {k: report["settings"][k] for k in ("clips", "instances_per_task", "num_samples")}
    (tmp_path / "diagnose").mkdir()
    for name, predicted in (("old", None), ("new", 0.4)):
        record = {"settings": {**settings, "env": "tabletop"},
                  "report": {**report, "predicted_control_score": predicted}}  # fmt: skip
        (tmp_path / "diagnose" / f"{name}.json").write_text(json.dumps(record))
    text = "\n".join(diagnosis_lines(tmp_path, {"metrics_names": ["old", "new"]}))
    rows = {r[0]: r for r in _table(text, "| model |")[2:]}
    expected = predict(load_predictor()["predictors"]["tabletop"], features(report))
    assert rows["old"][4] == f"{100 * expected:.0f}%†" == "27%†"
    assert rows["new"][4] == "40%"  # a report's own score stands
    assert "†: the report predates the predictor vp2 now ships" in text
