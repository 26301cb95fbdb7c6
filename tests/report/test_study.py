"""The metrics-versus-control study: tables, rank correlations against scipy, plots, CLI."""

from __future__ import annotations

import argparse
import json
import math
import re

import pytest
from scipy import stats

from tests.report.report_runs import SUCCESS, small_runs, write_handmade_run, write_metrics_file
from vp2.cli import study as study_cmd
from vp2.report.correlation import rank_correlation
from vp2.report.study import ALL_TASKS, study


def test_rank_correlation_matches_scipy_with_ties():
    x = [120.0, 80.0, 80.0, 300.0, 45.0, 150.0]
    y = [0.2, 0.5, 0.3, 0.3, 0.9, 0.1]
    rho, rho_p, tau, tau_p, note = rank_correlation(x, y)
    expected_rho = stats.spearmanr(x, y)
    expected_tau = stats.kendalltau(x, y)  # tau-b
    assert note == ""
    assert rho == pytest.approx(expected_rho.statistic)
    # 6 models: the exact permutation p-value, as scipy's own exact permutation test gives it.
    exact = stats.permutation_test(
        (y,),
        lambda y_: stats.spearmanr(x, y_).statistic,
        permutation_type="pairings",
        n_resamples=math.inf,
    )
    assert rho_p == pytest.approx(exact.pvalue)
    assert tau == pytest.approx(expected_tau.statistic) and tau_p == pytest.approx(
        expected_tau.pvalue
    )
    assert -1 < rho < 0 and -1 < tau < 0


def test_rank_correlation_of_a_monotone_relation_is_minus_one():
    rho, rho_p, tau, tau_p, note = rank_correlation([10.0, 20.0, 30.0, 40.0], [0.9, 0.5, 0.2, 0.0])
    assert rho == pytest.approx(-1.0) and tau == pytest.approx(-1.0) and note == ""
    # Exact: 2 of the 4! pairings rank perfectly (either way); Kendall's exact p alike.
    assert rho_p == pytest.approx(2 / 24) and tau_p == pytest.approx(2 / 24)


@pytest.mark.parametrize(
    ("x", "y", "why"),
    [
        ([1.0, 2.0], [0.1, 0.2], "2 model(s); a rank correlation needs at least 3"),
        ([1.0, 2.0, 3.0], [0.0, 0.0, 0.0], "success is the same for every model"),
        ([5.0, 5.0, 5.0], [0.1, 0.2, 0.3], "the metric is the same for every model"),
    ],
)
def test_rank_correlation_undefined_cases_say_why(x, y, why):
    assert rank_correlation(x, y) == (None, None, None, None, why)


def _handmade_study(tmp_path):
    """Four models on one task with 2 instances x 2 seeds; success 0, .25, .75, 1."""
    patterns = {
        "A": [False, False, False, False],
        "B": [True, False, False, False],
        "C": [True, True, True, False],
        "D": [True, True, True, True],
    }
    metrics = {
        "A": (400.0, 0.40, 0.50),
        "B": (250.0, 0.30, 0.70),
        "C": (300.0, 0.20, 0.60),
        "D": (100.0, 0.10, 0.90),
    }
    entries = []
    for label, pattern in patterns.items():
        keys = [(0, 0), (1, 0), (0, 1), (1, 1)]
        run = write_handmade_run(
            tmp_path / label, f"model_{label}", dict(zip(keys, pattern, strict=True))
        )
        m = write_metrics_file(tmp_path / f"{label}.json", *metrics[label])
        entries.append((label, run, m))
    return entries, patterns, metrics


def test_study_tables_and_correlations(tmp_path):
    entries, patterns, metrics = _handmade_study(tmp_path)
    result = study(entries)
    assert result.labels == ["A", "B", "C", "D"]
    assert result.scopes == ["tabletop/push_sphere", ALL_TASKS]  # one env: no env rows
    rows = {r.label: r for r in result.rows["tabletop/push_sphere"]}
    assert rows["C"].success == 0.75 and rows["C"].num_trials == 4
    # Seed 0: instances 0, 1 both succeed; seed 1: one of two.
    assert (rows["C"].success_min, rows["C"].success_max) == (0.5, 1.0)
    assert rows["B"].metrics == {
        "fvd": 250.0,
        "lpips": pytest.approx(30.0),
        "ssim": pytest.approx(70.0),
    }
    success = [0.0, 0.25, 0.75, 1.0]
    for key, column in (("fvd", 0), ("lpips", 1), ("ssim", 2)):
        values = [metrics[label][column] for label in "ABCD"]
        c = result.correlation(ALL_TASKS, key)
        assert c.n == 4 and c.note == ""
        assert c.spearman == pytest.approx(stats.spearmanr(values, success).statistic)
        assert c.kendall == pytest.approx(stats.kendalltau(values, success).statistic)
    assert result.correlation(ALL_TASKS, "lpips").spearman == pytest.approx(-1.0)
    assert result.correlation(ALL_TASKS, "fvd").spearman == pytest.approx(-0.8)
    assert result.correlation(ALL_TASKS, "ssim").spearman == pytest.approx(0.8)

    md = result.to_markdown()
    assert "| C | 300.0 | 20.0 | 60.0 | 75.0 [50.0, 100.0] | 4 |" in md
    assert "| all tasks | FVD | 4 | -0.800 (" in md
    html = result.to_html()
    assert "<svg" in html and "http" not in html
    points = re.findall(
        r'class="pt" data-label="(\w)" data-x="([\d.e+-]+)" data-y="([\d.e+-]+)"', html
    )
    fvd_points = {label: (float(x), float(y)) for label, x, y in points[:4]}
    assert fvd_points == {
        "A": (400.0, 0.0),
        "B": (250.0, 0.25),
        "C": (300.0, 0.75),
        "D": (100.0, 1.0),
    }


def test_study_with_fewer_than_three_models_notes_it(tmp_path):
    entries, _, _ = _handmade_study(tmp_path)
    result = study(entries[:2])
    c = result.correlation(ALL_TASKS, "ssim")
    assert c.spearman is None and c.kendall is None and "at least 3" in c.note
    assert "undefined" in result.to_markdown()


def test_study_of_real_runs(tmp_path):
    runs = small_runs()
    files = {
        "repeat": write_metrics_file(tmp_path / "repeat.json", 300.0, 0.3, 0.7),
        "random": write_metrics_file(tmp_path / "random.json", 100.0, 0.1, 0.9),
        "oracle": write_metrics_file(tmp_path / "oracle.json", 200.0, 0.2, 0.8),
    }
    result = study([(name, runs[name], files[name]) for name in ("repeat", "random", "oracle")])
    rows = {r.label: r for r in result.rows[ALL_TASKS]}
    for name, success in SUCCESS.items():
        assert rows[name].success == pytest.approx(success)
    # success: repeat .5 < oracle .67 < random 1; FVD ranks them exactly inversely.
    assert result.correlation(ALL_TASKS, "fvd").spearman == pytest.approx(-1.0)
    assert result.correlation(ALL_TASKS, "ssim").kendall == pytest.approx(1.0)


def test_study_across_environments(tmp_path):
    a = write_handmade_run(tmp_path / "a", "a", {(0, 0): True})
    with open(a / "trials.jsonl", "a") as fh:
        fh.write(
            json.dumps(
                {
                    "task": "robodesk/push_red",
                    "instance": 0,
                    "seed": 0,
                    "success": False,
                    "error": None,
                    "cost": "pixel",
                }
            )
            + "\n"
        )
    files = [
        write_metrics_file(tmp_path / "t.json", 100.0, 0.1, 0.9),
        write_metrics_file(tmp_path / "r.json", 500.0, 0.5, 0.5, env="robodesk"),
    ]
    result = study([("a", a, files)])
    assert result.scopes == [
        "tabletop/push_sphere",
        "robodesk/push_red",
        "tabletop (mean of tasks)",
        "robodesk (mean of tasks)",
        ALL_TASKS,
    ]
    assert result.rows["robodesk/push_red"][0].metrics["fvd"] == 500.0
    assert result.rows["tabletop (mean of tasks)"][0].metrics["fvd"] == 100.0
    assert result.rows[ALL_TASKS][0].metrics["fvd"] is None  # FVDs of two envs do not average
    assert result.rows[ALL_TASKS][0].success == 0.5
    assert any("per-environment" in n for n in result.notes)


def test_study_rejects_bad_entries(tmp_path):
    entries, _, _ = _handmade_study(tmp_path)
    with pytest.raises(ValueError, match="distinct"):
        study([entries[0], entries[0]])
    with pytest.raises(FileNotFoundError, match="trials.jsonl"):
        study([("x", tmp_path / "nowhere", entries[0][2])])
    with pytest.raises(ValueError, match="at least one"):
        study([])


def test_vp2_study_command_writes_files(tmp_path, capsys):
    entries, _, _ = _handmade_study(tmp_path)
    parser = study_cmd.configure_parser(argparse.ArgumentParser())
    argv = []
    for label, run, metrics in entries:
        argv += ["--entry", label, str(run), str(metrics)]
    args = parser.parse_args([*argv, "--out", str(tmp_path / "study")])
    assert study_cmd.run_from_args(args) == 0
    out = tmp_path / "study"
    assert (
        "| D | 100.0 | 10.0 | 90.0 | 100.0 [100.0, 100.0] | 4 |" in (out / "study.md").read_text()
    )
    data = json.loads((out / "study.json").read_text())
    assert data["labels"] == ["A", "B", "C", "D"]
    svgs = sorted(p.name for p in out.glob("*.svg"))
    assert svgs == [
        "scatter_fvd_all-tasks.svg",
        "scatter_lpips_all-tasks.svg",
        "scatter_ssim_all-tasks.svg",
    ]
    assert (out / svgs[0]).read_text().startswith('<svg xmlns="http://www.w3.org/2000/svg" ')
    assert "Rank correlation" in capsys.readouterr().out
