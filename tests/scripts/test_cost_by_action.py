"""``benchmarks.studies.cost_by_action``: which way the planning cost pushes a model's plans."""

from __future__ import annotations

import numpy as np
import pytest
from benchmarks.studies.cost_by_action import headline, parse_models, probe, statistics, table

from tests.benchmark import tiny_suite_path
from vp2.data.suite import TaskSuite
from vp2.models.baselines import RepeatLastFrame
from vp2.run.model_spec import resolve_model

SHIPPED = "svg_prime:src/vp2/assets/models/svg_prime_tiny_robodesk.pt"


def test_statistics_find_the_axis_the_scores_follow():
    rng = np.random.default_rng(0)
    candidates = rng.uniform(-1, 1, size=(40, 10, 5))
    z = candidates[:, :, 2].sum(axis=1)
    first = -z  # moving down scores higher, the same on both scorings
    out = statistics(first, first.copy(), candidates)
    assert out["repeat_rho"] == pytest.approx(1.0)
    assert out["rho_z"] == pytest.approx(-1.0)
    assert abs(out["rho_x"]) < 0.4 and abs(out["rho_y"]) < 0.4
    noise = statistics(rng.normal(size=40), rng.normal(size=40), candidates)
    assert abs(noise["repeat_rho"]) < 0.4  # two independent scorings: a ranking by noise
    flat = statistics(np.zeros(40), np.zeros(40), candidates)
    assert flat == {"repeat_rho": None, "rho_x": None, "rho_y": None, "rho_z": None,
                    "score_spread": 0.0}  # fmt: skip


def test_headline_and_table_report_each_instance():
    rows = [
        {"model": "m", "task": "robodesk/push_red", "instance": 0, "repeat_rho": 0.1,
         "rho_x": 0.2, "rho_y": None, "rho_z": -0.5, "score_spread": 12.345},
        {"model": "m", "task": "robodesk/push_blue", "instance": 0, "repeat_rho": 0.3,
         "rho_x": 0.0, "rho_y": 0.1, "rho_z": 0.25, "score_spread": 1.0},
    ]  # fmt: skip
    assert headline("m", rows) == "m: mean repeat ρ +0.20, mean ρ z -0.12, ρ z < 0 on 1 of 2 instances"
    assert "| m | robodesk/push_red | 0 | +0.10 | +0.20 | – | -0.50 | 12.3 |" in table(rows)


def test_models_are_label_equals_spec_or_a_bare_spec():
    assert parse_models(["a=svg_prime:x.pt", "repeat_last_frame"]) == [
        ("a", "svg_prime:x.pt"), ("repeat_last_frame", "repeat_last_frame")]  # fmt: skip
    with pytest.raises(ValueError, match="expected LABEL=MODEL"):
        parse_models(["=x"])


@pytest.fixture(scope="module")
def instance():
    suite = TaskSuite.load(tiny_suite_path(include_robodesk=True))
    return next(i for i in suite.instances if i.task.startswith("robodesk/"))


def test_an_action_blind_model_scores_every_candidate_alike(instance):
    row = probe(RepeatLastFrame(action_dim=5, image_size=64), instance, num_samples=8, seed=0)
    assert row["cost"] == "pixel+classifier"
    assert row["score_spread"] == 0.0
    assert row["repeat_rho"] is None and row["rho_z"] is None


def test_the_shipped_model_ranks_candidates_by_their_actions(instance):
    model = resolve_model(SHIPPED, env="robodesk", action_dim=5, device="cpu")
    row = probe(model, instance, num_samples=16, seed=0)
    assert row["score_spread"] > 0
    assert row["repeat_rho"] > 0.5  # the ranking is mostly the candidates', not the noise's
    assert all(-1 <= row[f"rho_{a}"] <= 1 for a in "xyz")
