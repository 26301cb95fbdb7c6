"""The predicted control score: features of a diagnose report, the fitted predictor, and its
leave-one-model-out validation (on synthetic reports whose success is known)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from benchmarks.studies import diagnose_validation as dv

from vp2.diagnose.measures import spearman
from vp2.diagnose.score import (
    FEATURES,
    NO_PREDICTOR,
    RIDGE,
    choose_ridge,
    deviance,
    features,
    fit,
    leave_one_out,
    oracle_rates,
    predict,
    predicted_score,
    rescale,
    transfer,
)
from vp2.oracle.shipped import load_shipped_oracle


def _report(low: float, top: float, rank: float, rho: float | None, gs: float, env="robodesk",
            agree: float | None = None):
    return {
        "env": env,
        "action_conditioning": {"ratio": low + 0.05, "ci": [low, low + 0.1]},
        "planning": {
            "scripted_plan": {"instances": 14, "of": 51, "median_rank": rank, "top_fraction": top},
            "repeatability": {"median_rho": rho},
            "spread": {"median_gamma_spread": gs},
            "oracle_agreement": {"instances": 14, "median_rho": agree},
        },
    }


def test_features_of_a_report():
    f = features(_report(1.5, 0.5, 11, 0.8, 2.0, agree=0.6))
    assert list(f) == list(FEATURES)
    assert f["log_conditioning"] == pytest.approx(math.log(1.5))
    assert f["scripted_top"] == 0.5
    assert f["scripted_rank"] == pytest.approx(1 - 10 / 50)
    assert f["repeatability"] == 0.8
    assert f["steering"] == pytest.approx(1 - math.exp(-2.0))
    assert f["oracle_agreement"] == 0.6
    assert features(_report(1.5, 0.5, 11, 0.8, 2.0, agree=-0.3))["oracle_agreement"] == 0.0
    # An action-blind model: interval below 1, undefined ranking, flat scores: no credit.
    blind = features(_report(0.98, 0.0, 51, None, 0.0))
    assert blind == {"log_conditioning": 0.0, "scripted_top": 0.0, "scripted_rank": 0.0,
                     "repeatability": 0.0, "steering": 0.0, "oracle_agreement": 0.0}  # fmt: skip


def _synthetic(n: int = 8):
    """Models whose success rises with their conditioning and scripted-plan rank."""
    reports, success = [], []
    for k in range(n):
        q = k / (n - 1)
        reports.append(_report(1.0 + 0.6 * q, q, 51 - 50 * q, q, 3 * q, agree=0.7 * q))
        success.append(0.05 + 0.6 * q)
    return [features(r) for r in reports], success


def test_fit_reproduces_a_monotone_relation_and_leave_one_out_ranks_held_out_models():
    rows, success = _synthetic()
    predictor = fit(rows, success, [20] * len(rows))
    predicted = [predict(predictor, r) for r in rows]
    assert np.all(np.diff(predicted) > 0)
    assert max(abs(p - s) for p, s in zip(predicted, success, strict=True)) < 0.1
    held_out = leave_one_out(rows, success, [20] * len(rows))
    assert np.all(np.diff(held_out) > 0)  # every held-out model in its measured place
    json.dumps(predictor)  # plain data


def test_the_ridge_is_chosen_by_the_fitted_models_alone():
    rows, success = _synthetic()
    trials = [20] * len(rows)
    # Success that rises with the features takes a moderate penalty; success unrelated to
    # them (a fixed shuffle) the strongest, which predicts the overall rate for every model.
    noise = [success[i] for i in (3, 0, 6, 1, 7, 4, 2, 5)]
    assert choose_ridge(rows, success, trials, grid=(0.1, 1.0, 100.0)) == 1.0
    assert choose_ridge(rows, noise, trials, grid=(0.1, 1.0, 100.0)) == 100.0
    assert choose_ridge(rows[:2], noise[:2], trials[:2]) == RIDGE  # too few to choose
    # The chosen penalty's held-out deviance is the least of the grid's.
    dev = {r: deviance(leave_one_out(rows, noise, trials, r), noise, trials)
           for r in (0.1, 1.0, 100.0)}  # fmt: skip
    assert min(dev, key=dev.get) == 100.0
    # Nested: each held-out model's fit chooses its own penalty, never from the model it predicts.
    nested = leave_one_out(rows, success, trials, ridge="auto")
    assert np.all(np.diff(nested) > 0)
    assert deviance([0.5], [0.5], [4]) == pytest.approx(-4 * math.log(0.5))


def test_predict_refuses_a_predictor_of_other_features():
    rows, success = _synthetic(4)
    predictor = fit(rows, success, [10] * 4)
    predictor["features"] = ["ssim"]
    with pytest.raises(ValueError, match="refit"):
        predict(predictor, rows[0])


def test_fit_rejects_bad_input():
    rows, _ = _synthetic(3)
    with pytest.raises(ValueError, match="in \\[0, 1\\]"):
        fit(rows, [0.1, 1.5, 0.2], [5, 5, 5])
    with pytest.raises(ValueError, match=">= 2 models"):
        fit(rows[:1], [0.1], [5])


def test_predicted_score_says_why_when_there_is_none():
    report = _report(1.5, 0.5, 11, 0.8, 2.0)
    assert predicted_score(report, None) == (None, NO_PREDICTOR)
    rows, success = _synthetic(5)
    predictor = fit(rows, success, [10] * 5)
    predictor.update(models_fitted=5, validation={"held_out_spearman": 0.9, "models": 5})
    asset = {"predictors": {"robodesk": predictor}}
    score, reason = predicted_score(report, asset)
    assert 0 < score < 1 and "held-out Spearman +0.90 over 5 models" in reason
    score, reason = predicted_score(_report(1.5, 0.5, 11, 0.8, 2.0, env="tabletop"), asset)
    assert score is None and "not fitted for tabletop" in reason
    report["planning"]["scripted_plan"]["instances"] = 0
    assert predicted_score(report, asset)[0] is None
    # A predictor of other measures (an older vp2's asset): no score, and what to do, not a crash.
    old = {"predictors": {"robodesk": {**predictor, "features": list(FEATURES[:-1])}}}
    score, reason = predicted_score(_report(1.5, 0.5, 11, 0.8, 2.0), old)
    assert score is None and "fitted on other measures" in reason and "--write-asset" in reason


def test_a_transferred_predictor_rescales_by_the_oracles_ratio():
    rows, success = _synthetic(5)
    source = fit(rows, success, [10] * 5)
    source.update(models_fitted=5, validation={"held_out_spearman": 0.9, "models": 5})
    rates = {"robodesk": 0.8, "tabletop": 0.2}
    moved = transfer(source, "robodesk", "tabletop", "t50")
    # The asset names the table; the rates are read when it scores, not frozen in it.
    assert moved["transfer"] == {"from": "robodesk", "to": "tabletop", "table": "t50"}
    assert rescale(moved, rates) == pytest.approx(0.25) and rescale(source) == 1.0
    assert "validation" not in moved  # the source's figure is not the target's
    for row in rows:
        assert predict(moved, row, rates) == pytest.approx(0.25 * predict(source, row), rel=1e-12)
    moved["validation"] = {"held_out_spearman": 0.5, "models": 3}
    report = _report(1.5, 0.5, 11, 0.8, 2.0, env="tabletop")
    score, reason = predicted_score(report, {"predictors": {"tabletop": moved}}, rates)
    assert score == pytest.approx(0.25 * predict(source, features(report)))
    assert reason == (
        "success fraction, the robodesk predictor (fitted on 5 robodesk models) times the "
        "oracles' success ratio tabletop/robodesk, 20%/80% (table t50); on tabletop models: "
        "Spearman +0.50 over 3 models"
    )
    with pytest.raises(ValueError, match="needs both oracle rates"):
        predict(moved, rows[0], {"robodesk": 0.8})
    # Without rates given they come from the shipped oracle asset; a table it lacks: no score,
    # and why.
    score, reason = predicted_score(report, {"predictors": {"tabletop": moved}})
    assert score is None and reason.startswith("not predicted: no shipped oracle table 't50'")


def test_a_transferred_predictor_follows_the_shipped_oracle_table():
    rows, success = _synthetic(5)
    source = fit(rows, success, [10] * 5)
    moved = transfer(source, "robodesk", "tabletop", "samples-50")
    shipped = load_shipped_oracle().table("samples-50")
    rates = shipped.env_rates()
    expected = (
        sum(t.successes for n, t in shipped.tasks.items() if n.startswith("tabletop/"))
        / sum(t.trials for n, t in shipped.tasks.items() if n.startswith("tabletop/"))
    ) / (
        sum(t.successes for n, t in shipped.tasks.items() if n.startswith("robodesk/"))
        / sum(t.trials for n, t in shipped.tasks.items() if n.startswith("robodesk/"))
    )
    assert oracle_rates("samples-50") == rates
    assert rescale(moved) == pytest.approx(expected, rel=1e-12)
    assert predict(moved, rows[0]) == pytest.approx(expected * predict(source, rows[0]))


def test_an_environment_with_few_models_borrows_the_fitted_one(tmp_path):
    rows, success = _synthetic(6)
    fitted = [{"label": f"r{k}", "env": "robodesk", "features": r, "success": y, "trials": 10,
               "ssim": None, "lpips": None, "fvd": None}
              for k, (r, y) in enumerate(zip(rows, success, strict=True))]  # fmt: skip
    # Three tabletop models, success in the order of their measures, and perceptual metrics
    # that favour the worst (as repeat-last-frame's do on the tabletop).
    few = [{**fitted[k], "label": f"t{k}", "env": "tabletop", "success": y, "fvd": f}
           for k, y, f in ((0, 0.0, 100.0), (3, 0.05, 200.0), (5, 0.1, 300.0))]  # fmt: skip
    result = dv.validate(fitted + few, ("t50", {"robodesk": 0.5, "tabletop": 0.1}))
    table = result["tabletop"]
    assert table["transferred_from"] == "robodesk" and table["models"] == 3
    source = result["robodesk"]["predictor"]
    for m in few:
        assert table["held_out"][m["label"]] == pytest.approx(0.2 * predict(source, m["features"]))
    assert table["spearman"]["predicted (held out)"] == {"rho": pytest.approx(1.0), "models": 3}
    assert table["spearman"]["fvd"]["rho"] == pytest.approx(-1.0)
    assert table["predictor"]["validation"] == {"held_out_spearman": pytest.approx(1.0),
                                                "models": 3}  # fmt: skip
    page = dv.validation_markdown(fitted + few, result, "cmd")
    assert "Fewer than 5 models: the robodesk predictor" in page and "= 0.200)" in page
    # Without oracle rates there is nothing to rescale by: said, not guessed.
    alone = dv.validate(fitted + few)["tabletop"]
    assert alone == {"models": 3,
                     "skipped": "fewer than 5 models to fit, and no oracle rates given"}


def test_oracle_rates_pool_the_shipped_table_of_the_budget():
    table, rates = dv.oracle_rates(50)
    # samples-50: RoboDesk 49 of 70 trials, the tabletop 25 of 40 (docs/measurements.md).
    assert table == "samples-50"
    assert rates == {"robodesk": pytest.approx(49 / 70), "tabletop": pytest.approx(25 / 40)}
    with pytest.raises(ValueError, match="no shipped oracle table at 123 samples"):
        dv.oracle_rates(123)


def _write_model(root, label, q, outcomes):
    """A diagnose report of quality ``q`` under ``root/out/reports`` and a control run of
    ``outcomes`` ({(instance, seed): solved} on push_red); returns the model list entry."""
    report = _report(1.0 + 0.6 * q, q, 51 - 50 * q, q, 3 * q, agree=0.7 * q)
    (root / "out" / "reports").mkdir(parents=True, exist_ok=True)
    (root / "out" / "reports" / f"{label}.json").write_text(json.dumps(report))
    run = root / "runs" / label
    run.mkdir(parents=True)
    (run / "trials.jsonl").write_text("".join(
        json.dumps({"task": "robodesk/push_red", "instance": i, "seed": s, "success": ok}) + "\n"
        for (i, s), ok in outcomes.items()))  # fmt: skip
    return {"label": label, "env": "robodesk", "model": "unused", "control": [str(run)]}


def test_validation_script_fits_held_out_and_compares_with_the_metrics(tmp_path):
    rows, success = _synthetic(6)
    entries = []
    for k, q in enumerate(np.linspace(0, 1, 6)):
        label = f"m{k}"
        solved = round(10 * success[k])
        entry = _write_model(tmp_path, label, q, {(t, 0): t < solved for t in range(10)})
        metrics = tmp_path / "runs" / f"{label}.json"
        # SSIM unrelated to success; FVD falls as success rises.
        metrics.write_text(json.dumps({"metrics": {"ssim": [0.5, 0.9, 0.6, 0.8, 0.7, 0.55][k],
                                                   "fvd": 500 - 50 * k}}))  # fmt: skip
        entries.append({**entry, "metrics": str(metrics)})
    models = tmp_path / "models.json"
    models.write_text(json.dumps({"models": entries}))
    asset = tmp_path / "asset.json"
    dv.main(["--models", str(models), "--out", str(tmp_path / "out"), "--write-asset",
             "--asset", str(asset)])  # fmt: skip
    result = json.loads((tmp_path / "out" / "validation.json").read_text())["result"]["robodesk"]
    assert result["spearman"]["predicted (held out), ridge fixed at 1"]["rho"] == pytest.approx(1.0)
    # The nested choice of the penalty on five models at a time: one neighbouring pair swaps.
    assert result["spearman"]["predicted (held out)"]["rho"] == pytest.approx(33 / 35)
    assert result["spearman"]["fvd"]["rho"] == pytest.approx(1.0)  # -FVD rises with success
    assert abs(result["spearman"]["ssim"]["rho"]) < 0.5
    assert result["spearman"]["lpips"]["rho"] is None
    shipped = json.loads(asset.read_text())
    assert shipped["models"]["robodesk"] == [f"m{k}" for k in range(6)]
    assert shipped["predictors"]["robodesk"]["validation"]["held_out_spearman"] == pytest.approx(
        33 / 35
    )
    page = (tmp_path / "out" / "validation.md").read_text()
    assert "| predicted (held out) | +0.94 | 6 |" in page
    assert "| oracle_agreement alone | +1.00 | 6 |" in page  # each measure, nothing fitted


def test_models_of_another_protocol_are_predicted_not_fitted_and_all_meet_on_common_trials(
    tmp_path,
):
    # Six fitted models on instances #0-#9 (seed 0), success rising with their measures; two
    # models of a study's protocol (#0-#2, seeds 0 and 1) kept out of the fit.
    entries = [_write_model(tmp_path, f"m{k}", q, {(i, 0): i <= k for i in range(10)})
               for k, q in enumerate(np.linspace(0, 1, 6))]  # fmt: skip
    study = {"u0": (0.2, {(0, 0): False, (1, 0): False, (2, 0): True, (0, 1): True}),
             "u1": (0.9, {(0, 0): True, (1, 0): True, (2, 0): True, (1, 1): False})}
    entries += [{**_write_model(tmp_path, label, q, outcomes), "fit": False}
                for label, (q, outcomes) in study.items()]  # fmt: skip
    # m0 lacks #2 of the common trials below (solved only #0): drop its #2.
    m0 = tmp_path / "runs" / "m0" / "trials.jsonl"
    m0.write_text("".join(line + "\n" for line in m0.read_text().splitlines()
                          if '"instance": 2,' not in line))  # fmt: skip
    listing = {"models": entries,
               "common_trials": {"robodesk": {"tasks": ["robodesk/push_red"],
                                              "instances": [0, 1, 2], "seeds": [0]}}}
    (tmp_path / "models.json").write_text(json.dumps(listing))
    dv.main(["--models", str(tmp_path / "models.json"), "--out", str(tmp_path / "out"),
             "--write-asset", "--asset", str(tmp_path / "asset.json")])  # fmt: skip
    asset = json.loads((tmp_path / "asset.json").read_text())
    # The fit and its figures are the six fitted models' alone.
    assert asset["models"]["robodesk"] == [f"m{k}" for k in range(6)]
    fitted = asset["predictors"]["robodesk"]
    assert fitted["models_fitted"] == 6 and fitted["validation"]["models"] == 6
    result = json.loads((tmp_path / "out" / "validation.json").read_text())["result"]["robodesk"]
    assert set(result["held_out"]) == {f"m{k}" for k in range(6)}
    reports = {label: json.loads((tmp_path / "out" / "reports" / f"{label}.json").read_text())
               for label in ("u0", "u1")}  # fmt: skip
    for label in ("u0", "u1"):
        assert result["unfitted"][label] == pytest.approx(
            predict(fitted, features(reports[label])))
    assert result["unfitted"]["u1"] > result["unfitted"]["u0"]
    # The common trials: #0-#2 at seed 0. m0 lacks one; the other seven are scored on the three.
    common = result["common"]
    assert common["trials"] == [["robodesk/push_red", i, 0] for i in range(3)]
    assert common["missing"] == {"m0": 1}
    assert common["success"] == pytest.approx(
        {"m1": 2 / 3, "m2": 1, "m3": 1, "m4": 1, "m5": 1, "u0": 1 / 3, "u1": 1})
    assert common["fitted"] == {**{f"m{k}": True for k in range(1, 6)}, "u0": False, "u1": False}
    predicted = {**result["held_out"], **result["unfitted"]}
    expected = spearman(np.array([predicted[m] for m in common["success"]]),
                        np.array(list(common["success"].values())))
    assert common["spearman"]["predicted (held out)"] == {"rho": pytest.approx(expected),
                                                          "models": 7}  # fmt: skip
    page = (tmp_path / "out" / "validation.md").read_text()
    assert "### Every model on the same 3 trials" in page
    assert "| u0 | no | 1 of 3 |" in page and "Not on these trials (trials lacking): m0 (1)." in page
    assert "| u1 | 75% | 4 |" in page  # its own protocol's success, beside its prediction
    # One trial recorded both ways in a model's two runs is refused, not averaged.
    other = tmp_path / "runs" / "u1b"
    other.mkdir()
    (other / "trials.jsonl").write_text(json.dumps(
        {"task": "robodesk/push_red", "instance": 1, "seed": 1, "success": True}) + "\n")
    with pytest.raises(ValueError, match=r"push_red#1 seed 1 is recorded both solved and failed"):
        dv.control_trials([str(tmp_path / "runs" / "u1"), str(other)], "robodesk")
    # The same trial in two runs counts once.
    assert dv.control_success([str(tmp_path / "runs" / "u0")] * 2, "robodesk") == (0.5, 4)


def test_a_wide_interval_around_1_is_inconclusive_not_blind():
    from vp2.diagnose.verdicts import conditioning_verdict

    # The pre-check of a model that does use its actions, on 16 clips (64 clips: 1.13 [1.04, 1.23]).
    wide = conditioning_verdict({"ratio": 1.07, "ci": [0.84, 1.39], "clips": 16})
    assert wide["status"] == "inconclusive" and "39%" in wide["text"]
    assert wide["text"].endswith("measure on more clips than these 16 (vp2 diagnose --clips 64)")
    assert conditioning_verdict({"ratio": 1.0, "ci": [0.999, 1.001]})["status"] == "blind"
    assert conditioning_verdict({"ratio": 1.13, "ci": [1.04, 1.23]})["status"] == "uses"


def test_the_shipped_predictor_orders_a_planning_model_above_a_blind_one():
    # vp2/assets/diagnose_predictor.json, fitted on 12 RoboDesk models' control runs by
    # benchmarks.studies.diagnose_validation (docs/findings/diagnose-validation.md).
    from vp2.diagnose.score import load_predictor

    asset = load_predictor()
    predictor = asset["predictors"]["robodesk"]
    assert predictor["features"] == list(FEATURES) and predictor["models_fitted"] == 12
    assert predictor["validation"]["held_out_spearman"] == pytest.approx(0.8126, abs=1e-4)
    assert predictor["ridge"] == 30.0  # chosen by the twelve models' leave-one-out deviance
    uses = _report(1.35, 1.0, 1, 0.996, 8.9, agree=0.666)  # the shipped SVG′'s measures
    blind = {"env": "robodesk", "action_conditioning": {"ratio": 1.0, "ci": [1.0, 1.0]},
             "planning": {"scripted_plan": {"instances": 14, "of": 51, "median_rank": 51,
                                            "top_fraction": 0.0},
                          "repeatability": {"median_rho": None},
                          "spread": {"median_gamma_spread": 0.0},
                          "oracle_agreement": {"instances": 14, "median_rho": 0.0}}}  # fmt: skip
    good, reason = predicted_score(uses, asset)
    bad, _ = predicted_score(blind, asset)
    assert good > 0.45 > 0.05 > bad and "fitted on 12 models (held-out Spearman +0.81" in reason
    assert bad == pytest.approx(0.017911, abs=1e-6)
    # The tabletop fits its own on seven models of the paper's scene (five SVG′, FitVid, one
    # repeat-last-frame); on so few the penalty chosen is the grid's largest.
    tabletop = asset["predictors"]["tabletop"]
    assert "transfer" not in tabletop and tabletop["models_fitted"] == 7
    assert tabletop["ridge"] == 100.0
    assert tabletop["validation"]["held_out_spearman"] == pytest.approx(-0.234244, abs=1e-6)
    assert asset["models"]["tabletop"][-1] == "repeat_last_frame-tabletop"
    flat, reason = predicted_score({**blind, "env": "tabletop"}, asset)
    assert flat == pytest.approx(0.078471, abs=1e-6)
    assert reason.endswith("fitted on 7 models (held-out Spearman -0.23 over 7 models)")


def test_the_shipped_predictor_rebuilds_from_its_committed_evidence(tmp_path, monkeypatch):
    # results/diagnose holds the reports, metrics and compact control records the shipped
    # predictor was fitted on (benchmarks/studies/diagnose_models.json points there).
    import shutil
    from pathlib import Path

    from vp2.diagnose.score import load_predictor

    root = Path(__file__).resolve().parents[2]
    shutil.copytree(root / "results" / "diagnose" / "reports", tmp_path / "out" / "reports")
    monkeypatch.chdir(root)  # the model list names its files from the repository root
    dv.main(["--models", "benchmarks/studies/diagnose_models.json", "--out",
             str(tmp_path / "out"), "--write-asset", "--asset", str(tmp_path / "asset.json")])
    rebuilt = json.loads((tmp_path / "asset.json").read_text())["predictors"]["robodesk"]
    shipped = load_predictor()["predictors"]["robodesk"]
    assert rebuilt.keys() == shipped.keys() and rebuilt["features"] == shipped["features"]
    # Equal to the last bits the BLAS's thread count and kernels move (Newton's solves).
    for key in ("intercept", "mean", "scale", "weights"):
        assert rebuilt[key] == pytest.approx(shipped[key], rel=1e-9, abs=1e-12), key
    assert rebuilt["validation"]["held_out_spearman"] == pytest.approx(
        shipped["validation"]["held_out_spearman"])
    assert rebuilt["models_fitted"] == shipped["models_fitted"] == 12
    tabletop = json.loads((tmp_path / "asset.json").read_text())["predictors"]["tabletop"]
    for key in ("intercept", "mean", "scale", "weights"):
        assert tabletop[key] == pytest.approx(
            load_predictor()["predictors"]["tabletop"][key], rel=1e-9, abs=1e-12), key


def test_a_control_run_is_copied_compactly_and_reads_as_the_same_success(tmp_path):
    run = tmp_path / "run"
    run.mkdir()
    (run / "config.yaml").write_text("config:\n  planner:\n    num_samples: 50\n")
    full = {"task": "robodesk/push_red", "instance": 1, "seed": 2, "success": True,
            "first_success_step": 8, "num_steps": 15, "error": None, "instance_sha": "2c9d",
            "finished_at": "2026-11-26T23:49:12+00:00", "actions": [[0.1] * 5] * 15,
            "model": {"spec": "zoo:fitvid-robodesk-120min", "name": "fitvid"}}  # fmt: skip
    (run / "trials.jsonl").write_text(json.dumps(full) + "\n" + json.dumps(
        {**full, "instance": 2, "success": False, "first_success_step": None}) + "\n")
    dest = tmp_path / "results" / "fitvid-120min"
    assert dv.compact_run(run, dest) == 2
    first = json.loads((dest / "trials.jsonl").read_text().splitlines()[0])
    assert first == {k: v for k, v in full.items() if k != "model"} | {
        "model_spec": "zoo:fitvid-robodesk-120min", "num_samples": 50}
    assert (dest / "config.yaml").read_text() == (run / "config.yaml").read_text()
    assert dv.control_success([str(dest)], "robodesk") == dv.control_success([str(run)], "robodesk")
