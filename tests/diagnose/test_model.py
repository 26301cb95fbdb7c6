"""`vp2.diagnose.model`: its statistics, its verdicts on models that use and ignore their
actions, its report, and the pre-check of `run_benchmark`.

The held-out clips are moving squares (``tests.models.synthetic``: a square moves by
``action[:2] * 8`` pixels per step at 64 px), so a model that shifts its last frame by the
actions predicts them and a model that ignores the actions cannot. The planning measures run on
the tiny tabletop suite of ``tests.benchmark``, its instances given a scripted plan.
"""

from __future__ import annotations

import dataclasses
import json
import logging
import re
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.benchmark import TABLETOP_BLIND_SCORE, TABLETOP_PREDICTOR, tiny_suite_path
from tests.models.synthetic import write_moving_square_dataset
from vp2.benchmark import RunConfig, run_benchmark
from vp2.data.suite import TaskSuite
from vp2.diagnose.measures import (
    effective_sample_size,
    rank_of_last,
    ratio_statistics,
    simulator_agreement,
    simulator_scores,
    spearman,
    step_context,
    trajectory_interval,
)
from vp2.diagnose.model import (
    DiagnoseConfig,
    checkpoint_env,
    diagnose_model,
    format_report,
    precheck_model,
    write_report,
)
from vp2.planning.config import PlannerConfig
from vp2.utils.io import json_safe

HERE = "tests.diagnose.test_model"
#: Pixels a square moves per unit of action (the dataset's speed: size / 8).
SPEED = 8


class ShiftModel:
    """Uses its actions: the last frame moved by the summed x/y actions, as the squares move."""

    num_context, num_future, image_size, max_batch_size = 2, 10, 64, 64

    def __init__(self, action_dim: int) -> None:
        self.action_dim = action_dim

    def predict(self, context: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        last = context[:, -1].float()  # (B, 3, H, W)
        moves = (actions[:, 1:, :2].cumsum(1) * SPEED).round().long()  # (B, 10, 2): dx, dy
        out = [
            torch.stack([torch.roll(last[b], (int(dy), int(dx)), dims=(1, 2)) for dx, dy in seq])
            for b, seq in enumerate(moves.tolist())
        ]
        return torch.stack(out)  # (B, 10, 3, H, W)


class StillModel:
    """Written from the README's DriftModel, but its drift is a constant: it ignores actions."""

    num_context, num_future, image_size = 2, 10, 64

    def __init__(self, action_dim: int, speed: float = 0.01) -> None:
        self.action_dim, self.speed = action_dim, speed

    def predict(self, context: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
        last = context[:, -1]  # (B, 3, 64, 64) in [0, 1]
        drift = self.speed * torch.arange(1, 11, dtype=last.dtype)  # (10,): no action in it
        return (last[:, None] + drift[None, :, None, None, None]).clamp(0, 1)


class NoisyModel:
    """Ignores its actions and adds sampling noise: its scores move with the noise only."""

    num_context, num_future, image_size = 2, 10, 64

    def __init__(self, action_dim: int) -> None:
        self.action_dim = action_dim

    def predict(self, context, actions, *, generator=None):
        last = context[:, -1:].float().expand(-1, 10, -1, -1, -1)
        noise = torch.randn(last.shape, generator=generator) * 0.1
        return (last + noise).clamp(0, 1)


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    # 6 trajectories of 16 frames, every 3rd held out: 10 valid clips of 12 frames.
    return write_moving_square_dataset(
        tmp_path_factory.mktemp("diag") / "squares", size=64, action_dim=4
    )


@pytest.fixture(scope="module")
def suite(tmp_path_factory) -> Path:
    """The tiny tabletop suite, each instance with a scripted plan of 4 actions."""
    plan = np.tile([0.5, -0.5, 0.0, 0.0], (4, 1))
    instances = [dataclasses.replace(i, actions=plan) for i in TaskSuite.load(tiny_suite_path())]
    path = tmp_path_factory.mktemp("diag-suite") / "suite.npz"
    TaskSuite(instances).save(path)
    return path


def _diagnose(model: str, data: Path, suite: Path, partial: Path | None = None, **kwargs) -> dict:
    settings = dict(env="tabletop", data=str(data), suite=str(suite), num_samples=16,
                    progress=False)
    return diagnose_model(DiagnoseConfig(model=model, **{**settings, **kwargs}), partial=partial)


def _status(report: dict) -> dict[str, str]:
    return {k: v["status"] for k, v in report["verdicts"].items()}


# --------------------------------------------------------------------------- statistics


def test_statistics():
    assert spearman(np.array([1.0, 2, 3, 4]), np.array([10.0, 20, 30, 40])) == pytest.approx(1.0)
    assert spearman(np.array([1.0, 2, 3, 4]), np.array([4.0, 3, 2, 1])) == pytest.approx(-1.0)
    # Ties take their average rank: ranks (1.5, 1.5, 3) against (1, 2, 3).
    assert spearman(np.array([1.0, 1, 2]), np.array([1.0, 2, 3])) == pytest.approx(0.8660254)
    assert spearman(np.ones(5), np.arange(5.0)) is None  # a constant side: undefined
    assert effective_sample_size(np.full(50, 1 / 50)) == pytest.approx(50.0)
    assert effective_sample_size(np.eye(1, 50)[0]) == pytest.approx(1.0)
    assert rank_of_last(np.array([3.0, 1.0, 2.0])) == 2
    assert rank_of_last(np.array([2.0, 2.0, 2.0])) == 3  # ties count against the scripted plan
    same = ratio_statistics(np.full(10, 0.5), np.full(10, 0.5))
    assert same["ratio"] == 1.0 and same["ci"] == [1.0, 1.0]
    assert same["wins"] == 0 and same["ties"] == 10 and same["sign_p"] == 1.0
    better = ratio_statistics(np.full(10, 0.1), np.full(10, 0.2))
    assert better["ratio"] == pytest.approx(2.0) and better["wins"] == 10
    assert better["sign_p"] == pytest.approx(2 / 2**10)
    assert "trajectory_ci" not in better  # only given the clips' trajectories


def test_the_interval_over_trajectories_resamples_whole_trajectories():
    trajectory = np.repeat(np.arange(4), 5)  # 4 trajectories of 5 clips each
    true = np.ones(20)
    assert trajectory_interval(true, 1.2 * true, trajectory) == pytest.approx([1.2, 1.2])
    # Each trajectory has its own ratio (1.0, 1.1, 1.3, 1.6), the same on all its clips: the
    # interval spans whole trajectories' ratios, wider than the one over the 20 clips.
    shuffled = np.repeat([1.0, 1.1, 1.3, 1.6], 5)
    stats = ratio_statistics(true, shuffled, trajectory=trajectory)
    low, high = stats["trajectory_ci"]
    assert stats["trajectories"] == 4 and stats["ratio"] == pytest.approx(1.25)
    assert 1.0 <= low < 1.25 < high <= 1.6 and high - low > 0.3
    assert high - low > stats["ci"][1] - stats["ci"][0]
    # A single trajectory resamples to itself.
    assert trajectory_interval(true[:5], shuffled[:5], trajectory[:5]) == pytest.approx([1.0, 1.0])
    with pytest.raises(ValueError, match="3 trajectory ids for 20 clips"):
        trajectory_interval(true, shuffled, trajectory[:3])


# --------------------------------------------------------------------------- verdicts


def test_a_model_that_uses_its_actions_and_one_that_ignores_them(data, suite):
    uses = _diagnose(f"{HERE}:ShiftModel", data, suite)
    c = uses["action_conditioning"]
    assert c["clips"] == 10 and c["ci"][0] > 1.5 and c["wins"] == 10
    # The 10 valid clips are cut from 2 trajectories (every 3rd of 6 held out), 5 each.
    assert c["trajectories"] == 2 and c["trajectory_ci"][0] > 1.5
    assert c["moving"]["trajectory_ci"][0] > 1.0
    rows = uses["planning"]["instances"]
    assert len(rows) == 2 and all(r["of"] == 17 and r["rank"] is not None for r in rows)
    assert uses["planning"]["repeatability"]["median_rho"] == pytest.approx(1.0)  # deterministic
    status = _status(uses)
    assert status.pop("scripted_plan") in ("preferred", "not_preferred")  # ranks: checked above
    # Scored by the simulator too: a shifted square is not the tabletop's future, so any
    # agreement verdict is possible, but it is measured on both instances.
    agree = uses["planning"]["oracle_agreement"]
    assert agree["instances"] == 2 and -1 <= agree["median_rho"] <= 1
    assert status.pop("oracle_agreement") in ("agrees", "partial", "disagrees")
    assert status == {
        "action_conditioning": "uses",
        "repeatability": "repeats",
        "spread": "steers",
        "direction": "undefined",  # one task in the tiny suite
    }

    ignores = _diagnose(f"{HERE}:StillModel", data, suite)
    assert ignores["action_conditioning"]["ratio"] == 1.0
    assert _status(ignores) == {
        "action_conditioning": "blind",
        "scripted_plan": "not_preferred",  # every candidate ties: the scripted plan ranks last
        "repeatability": "undefined",
        "spread": "flat",
        "direction": "undefined",
        "oracle_agreement": "disagrees",  # it orders nothing: rho 0, the simulator's best tied
    }
    assert ignores["planning"]["oracle_agreement"] == {
        "instances": 2, "median_rho": 0.0, "best_in_top_fraction": 0.0
    }
    assert ignores["verdicts"]["action_conditioning"]["text"] == (
        "predictions do not depend on the actions: it will plan like repeat-last-frame"
    )
    assert [r["rank"] for r in ignores["planning"]["instances"]] == [17, 17]
    assert ignores["planning"]["spread"]["median_ess"] == pytest.approx(16.0)


def test_scores_that_move_with_the_noise_are_noise(data, suite):
    report = _diagnose(f"{HERE}:NoisyModel", data, suite, clips=8, num_samples=48)
    status = _status(report)
    # The true and the shuffled actions get the same noise: the ratio is exactly 1.
    assert status["action_conditioning"] == "blind"
    assert report["action_conditioning"]["ratio"] == 1.0
    assert status["repeatability"] == "noise"
    assert abs(report["planning"]["repeatability"]["median_rho"]) < 0.3


def test_repeat_last_frame_report(data, suite, tmp_path):
    report = _diagnose("repeat_last_frame", data, suite, clips=6, instances_per_task=1,
                       oracle_agreement=False)  # fmt: skip
    assert _status(report)["action_conditioning"] == "blind"
    assert _status(report)["oracle_agreement"] == "skipped"
    assert [r["oracle_rho"] for r in report["planning"]["instances"]] == [None]
    path = write_report(tmp_path / "out" / "diagnose.json", report)
    saved = json.loads(path.read_text())
    assert saved["format"] == "vp2-diagnose/1" and saved["env"] == "tabletop"
    assert saved["env_source"] == "flag" and saved["model"]["name"] == "repeat_last_frame"
    assert saved["predicted_control_score"] == pytest.approx(TABLETOP_BLIND_SCORE, abs=1e-5)
    assert saved["predicted_control_score_reason"] == TABLETOP_PREDICTOR
    assert set(saved["action_conditioning"]) >= {"ratio", "ci", "mse_true", "mse_shuffled",
                                                 "wins", "clips", "sign_p", "moving",
                                                 "trajectories", "trajectory_ci"}
    assert set(saved["planning"]) == {"instances", "scripted_plan", "repeatability", "spread",
                                      "direction", "oracle_agreement"}
    assert set(saved["timing"]) == {"model_s", "conditioning_s", "planning_s", "oracle_s",
                                    "total_s"}  # fmt: skip
    assert saved["settings"]["num_samples"] == 16 and saved["settings"]["clips"] == 6
    lines = format_report(report)
    assert len(lines) == 9 and lines[1].startswith("action conditioning: shuffled/true error ")
    assert lines[-3] == "agreement with the simulator: not measured: no simulator scores " \
        "(--no-oracle-agreement, or a model that is the simulator)"
    assert lines[-2] == f"predicted control score: 8% success ({TABLETOP_PREDICTOR})"


def test_missing_dataset_names_how_to_make_it(suite, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    # A missing --data is an error; a missing default dataset is collected
    # (tests/diagnose/test_held_out.py).
    with pytest.raises(FileNotFoundError, match="create it with `vp2 collect tabletop --out d`"):
        diagnose_model(DiagnoseConfig(model="repeat_last_frame", env="tabletop", data="d"))
    # Without the conditioning measure no dataset is needed.
    report = _diagnose("repeat_last_frame", None, suite, clips=0, instances_per_task=1)
    assert report["verdicts"]["action_conditioning"]["status"] == "skipped"


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="clips"):
        DiagnoseConfig(model="repeat_last_frame", clips=1).validate()
    with pytest.raises(ValueError, match="env"):
        DiagnoseConfig(model="repeat_last_frame", env="kitchen").validate()
    with pytest.raises(ValueError, match="seed must be a non-negative integer, got -1"):
        DiagnoseConfig(model="repeat_last_frame", seed=-1).validate()


def test_the_environment_comes_from_the_checkpoint():
    assets = Path(__file__).resolve().parents[2] / "src" / "vp2" / "assets"
    shipped = sorted(p for p in assets.rglob("*.pt") if "svg_prime" in str(p) and "robodesk" in str(p))
    assert shipped, "the shipped SVG' checkpoint is missing from src/vp2/assets"
    assert checkpoint_env(f"svg_prime:{shipped[0]}") == "robodesk"
    assert checkpoint_env("repeat_last_frame") is None


def test_a_checkpoint_is_read_once_for_its_environment(tmp_path, monkeypatch):
    import vp2.models.checkpoint as checkpoint_module

    reads = []

    def read(path):
        reads.append(path)
        return {"dataset": {"config": {"env": "tabletop"}}}

    monkeypatch.setattr(checkpoint_module, "read_model_checkpoint", read)
    path = tmp_path / "model.pt"
    path.write_bytes(b"one")
    assert checkpoint_env(f"svg_prime:{path}") == "tabletop"
    assert checkpoint_env(f"svg_prime:{path}") == "tabletop"
    assert len(reads) == 1  # vp2 diagnose asks twice: its report's path, then its run
    path.write_bytes(b"another")  # a new version of the file is read again
    assert checkpoint_env(f"svg_prime:{path}") == "tabletop"
    assert len(reads) == 2


# --------------------------------------------------------------------------- vp2 run's pre-check


def _run(model: str, out: str, **kwargs):
    return run_benchmark(RunConfig(
        model=model, out=out, suite=str(tiny_suite_path()), tasks=("tabletop/push_sphere",),
        num_instances=1, seeds=(0,), num_steps=2, planner=PlannerConfig(num_samples=4),
        save_gifs=False, progress=False, **kwargs,
    ))


@pytest.fixture
def default_data(tmp_path, monkeypatch) -> Path:
    """A current directory whose data/ holds the default tabletop dataset (moving squares)."""
    write_moving_square_dataset(tmp_path / "data" / "tabletop-100x-64px", size=64, action_dim=4)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def _precheck_warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records
            if r.levelno == logging.WARNING and "vp2 diagnose" in r.getMessage()]


def test_run_warns_before_the_first_trial_of_an_action_blind_model(default_data, caplog):
    caplog.set_level(logging.INFO, logger="vp2")
    result = _run(f"{HERE}:StillModel", "runs/still")
    assert result.num_run == 1 and result.num_errors == 0
    (warning,) = _precheck_warnings(caplog)
    assert warning.startswith(f"model {HERE}:StillModel: predictions do not measurably depend on "
                              "the actions (shuffled/true error ratio 1.00, 95% CI 1.00-1.00 on "
                              "10 held-out clips of data/tabletop-100x-64px)")
    assert warning.endswith("it will plan like repeat-last-frame; see `vp2 diagnose`")


def test_the_precheck_is_kept_in_the_run_and_shown_by_its_report(default_data, tmp_path):
    _run(f"{HERE}:StillModel", "runs/still")
    saved = json.loads(Path("runs/still/precheck.json").read_text())["precheck"]
    assert [m["env"] for m in saved] == ["tabletop"]
    assert saved[0]["ratio"] == pytest.approx(1.0) and saved[0]["verdict"]["status"] == "blind"
    from vp2.report.page import write_report

    html = write_report(["runs/still"], tmp_path / "report.html").read_text()
    row = re.search(r'<table class="diagnosis">.*?</table>', html, re.S).group(0)
    assert "vp2 run pre-check" in row and 'class="diag-blind"' in row
    assert "1.000 [1.000, 1.000] on 10 clips" in row


def test_run_does_not_warn_for_a_model_that_uses_its_actions(default_data, caplog):
    caplog.set_level(logging.INFO, logger="vp2")
    _run(f"{HERE}:ShiftModel", "runs/shift")
    assert _precheck_warnings(caplog) == []
    assert any("pre-check" in r.getMessage() and "depend on the actions" in r.getMessage()
               for r in caplog.records if r.levelno == logging.INFO)


def test_the_precheck_can_be_skipped_and_is_silent_without_a_dataset(
    default_data, tmp_path, caplog, monkeypatch
):
    caplog.set_level(logging.DEBUG, logger="vp2")
    _run(f"{HERE}:StillModel", "runs/off", precheck=False)
    assert _precheck_warnings(caplog) == []
    config = RunConfig(model=f"{HERE}:StillModel", out="x")
    assert precheck_model(RunConfig(model="repeat_last_frame", out="x"), ["tabletop"]) == []
    empty = tmp_path / "empty"
    empty.mkdir()
    monkeypatch.chdir(empty)
    caplog.clear()
    assert precheck_model(config, ["tabletop"]) == []
    assert [r.levelno for r in caplog.records] == [logging.DEBUG]
    assert "no dataset at data/tabletop-100x-64px" in caplog.records[0].getMessage()


# --------------------------------------------------------------------------- agreement


def test_agreement_of_the_same_the_reversed_and_a_constant_ranking():
    oracle = np.arange(20.0)  # candidate 19 is the simulator's best
    same = simulator_agreement(oracle * 3 + 1, oracle)
    assert same == {"oracle_rho": pytest.approx(1.0), "oracle_best_rank": 1,
                    "oracle_best_in_top": True}  # fmt: skip
    reversed_ = simulator_agreement(-oracle, oracle)
    assert reversed_["oracle_rho"] == pytest.approx(-1.0)
    assert reversed_["oracle_best_rank"] == 20 and not reversed_["oracle_best_in_top"]
    flat = simulator_agreement(np.zeros(20), oracle)  # orders nothing; ties count against
    assert flat == {"oracle_rho": 0.0, "oracle_best_rank": 20, "oracle_best_in_top": False}
    second = oracle.copy()
    second[[18, 19]] = second[[19, 18]]  # the simulator's best is the model's second of 20
    assert simulator_agreement(second, oracle)["oracle_best_rank"] == 2
    assert simulator_agreement(second, oracle)["oracle_best_in_top"]  # top 10% of 20: 2


def test_the_simulators_scores_are_cached_by_instance_seed_and_batch(tmp_path):
    from vp2.run.model_spec import resolve_model

    (instance,) = TaskSuite.load(tiny_suite_path()).instances[:1]
    simulator = resolve_model("simulator", {}, env="tabletop", action_dim=4, device="cpu")
    context = step_context(instance, 64)
    batch = torch.zeros(3, 10, 4)
    batch[1, :, 0] = 1.0  # the hand moves along x
    batch[2, :, 1] = 1.0  # ... along y
    cache = tmp_path / "cache"
    fresh = simulator_scores(simulator, instance, batch, context, 0, 2, torch.device("cpu"), cache)
    assert fresh.shape == (3,) and len(set(fresh.tolist())) == 3  # the moves change the future
    (saved,) = cache.glob("*.npy")
    np.testing.assert_array_equal(np.load(saved), fresh)
    np.save(saved, fresh + 1)  # what the cache holds is what comes back
    again = simulator_scores(simulator, instance, batch, context, 0, 2, torch.device("cpu"), cache)
    np.testing.assert_array_equal(again, fresh + 1)
    other = simulator_scores(simulator, instance, batch.flip(0), context, 0, 2,
                             torch.device("cpu"), cache)  # fmt: skip
    np.testing.assert_allclose(other, fresh[::-1])  # another batch: scored anew
    assert len(list(cache.glob("*.npy"))) == 2
    simulator.close()


def test_the_default_probes_read_the_shipped_simulator_scores(tmp_path, monkeypatch):
    # vp2/assets/diagnose_oracle: a first diagnosis on a machine does not pay for the simulator.
    from vp2.diagnose.measures import SHIPPED_ORACLE_SCORES

    monkeypatch.setenv("VP2_CACHE_DIR", str(tmp_path))
    report = diagnose_model(DiagnoseConfig(model="repeat_last_frame", env="robodesk", clips=0,
                                           instances_per_task=1, progress=False))  # fmt: skip
    rows = report["planning"]["instances"]
    assert len(rows) == 7 and all(r["oracle_rho"] == 0.0 for r in rows)
    assert report["timing"]["oracle_s"] < 1.0  # read, not simulated
    assert not (tmp_path / "diagnose-oracle").exists()  # nothing had to be computed
    # 2 instances x (7 RoboDesk + 4 tabletop tasks)
    assert len(list(SHIPPED_ORACLE_SCORES.glob("*.npy"))) == 22


def test_a_step_context_along_the_scripted_path():
    (instance,) = TaskSuite.load(None).select(["robodesk/push_red"], 1)
    start = step_context(instance, 64)
    assert start["frames"].shape == (2, 64, 64, 3) and start["frames"].dtype == np.uint8
    assert not start["last_action"].any()
    np.testing.assert_array_equal(start["rest"], instance.actions)
    one = step_context(instance, 64, 1)  # its older frame is the start's newer one
    np.testing.assert_array_equal(one["frames"][0], start["frames"][1])
    np.testing.assert_array_equal(one["goal"], start["goal"])
    half = len(instance.actions) // 2
    mid = step_context(instance, 64, half)
    np.testing.assert_array_equal(mid["last_action"], instance.actions[half - 1])
    np.testing.assert_array_equal(mid["rest"], instance.actions[half:])
    assert not np.array_equal(mid["frames"], start["frames"])  # the hand has moved


def test_a_stopped_diagnosis_goes_on_from_its_partial_file(data, suite, tmp_path, monkeypatch, caplog):
    from vp2.diagnose import model as diagnose_module

    model = f"{HERE}:NoisyModel"  # sampling noise: the resumed parts must draw the same
    whole = _diagnose(model, data, suite, clips=4, sampling_seeds=1)
    partial = tmp_path / "d.partial.json"
    again = _diagnose(model, data, suite, clips=4, sampling_seeds=1, partial=partial)
    saved = json.loads(partial.read_text())
    assert saved["conditioning"] is not None and len(saved["instances"]) == len(whole["planning"]["instances"])
    # As if stopped after the conditioning and one instance.
    first = next(iter(saved["instances"]))
    saved["instances"] = {first: saved["instances"][first]}
    partial.write_text(json.dumps(saved))
    probed, conditioned = [], []
    real_probe, real_conditioning = diagnose_module.probe_instance, diagnose_module.measure_conditioning
    monkeypatch.setattr(diagnose_module, "probe_instance",
                        lambda model, instance, *a, **k: probed.append(instance.key) or real_probe(model, instance, *a, **k))
    monkeypatch.setattr(diagnose_module, "measure_conditioning",
                        lambda *a, **k: conditioned.append(1) or real_conditioning(*a, **k))
    resumed = _diagnose(model, data, suite, clips=4, sampling_seeds=1, partial=partial)
    assert conditioned == [] and first not in probed
    assert len(probed) == len(whole["planning"]["instances"]) - 1 == 1  # of 2 instances
    assert resumed["timing"]["resumed"] == {"conditioning": True, "instances": 1}

    def measured(report: dict) -> dict:
        """The report without its times (a resumed instance keeps its first run's)."""
        kept = json.loads(json.dumps(json_safe({k: v for k, v in report.items()
                                                if k not in ("timing", "created")})))
        for row in kept["planning"]["instances"]:
            assert row.pop("seconds") >= 0 and row.pop("oracle_seconds") >= 0
        return kept

    assert measured(resumed) == measured(whole) == measured(again)
    # Other settings: the file is not used, and is replaced.
    with caplog.at_level(logging.WARNING):
        other = _diagnose(model, data, suite, clips=4, sampling_seeds=1, seed=1, partial=partial)
    assert "holds a diagnosis of other settings" in caplog.text
    assert "resumed" not in other["timing"] and json.loads(partial.read_text())["key"]["settings"]["seed"] == 1
