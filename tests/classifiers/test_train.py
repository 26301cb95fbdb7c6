"""Training and evaluating classifiers: metrics by hand, a separable problem, reproducibility."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch

from tests.classifiers import make_frame
from vp2.classifiers.data import FrameSet
from vp2.classifiers.train import (
    ClassifierTrainConfig,
    classification_metrics,
    evaluate,
    learning_rate,
    predict_logits,
    train_classifier,
)


def test_metrics_on_hand_made_logits():
    m = classification_metrics(
        np.array([2.0, -1.0, 0.5, -3.0, 1.0]), np.array([1, 1, 0, 0, 1], bool)
    )
    assert (m["tp"], m["fp"], m["fn"], m["tn"]) == (2, 1, 1, 1)
    assert m["accuracy"] == pytest.approx(3 / 5)
    assert m["precision"] == pytest.approx(2 / 3) and m["recall"] == pytest.approx(2 / 3)
    none = classification_metrics(np.array([-1.0, -2.0]), np.array([False, False]))
    assert none["accuracy"] == 1.0 and none["precision"] is None and none["recall"] is None


def _separable(n: int, seed: int) -> FrameSet:
    rng = np.random.default_rng(seed)
    labels = rng.random(n) < 0.4
    return FrameSet(
        images=np.stack([make_frame(bool(s), rng) for s in labels]),
        labels=labels,
        trajectories=np.arange(n),
        steps=np.zeros(n, np.int64),
    )


def test_training_learns_a_separable_problem_reproducibly():
    train, held_out = _separable(256, 0), _separable(128, 1)
    config = ClassifierTrainConfig(arch="ours", steps=150, batch_size=32, seed=3)
    state = torch.random.get_rng_state()
    model = train_classifier(train, config, log_every=1000)
    assert torch.equal(torch.random.get_rng_state(), state)  # global random state untouched
    m = evaluate(model, held_out)
    assert m["accuracy"] >= 0.95 and m["recall"] >= 0.9 and m["precision"] >= 0.9
    again = train_classifier(train, config, log_every=1000)
    for a, b in zip(model.state_dict().values(), again.state_dict().values(), strict=True):
        torch.testing.assert_close(a, b, atol=0, rtol=0)


def test_balanced_pos_weight_is_negatives_over_positives():
    frames = _separable(50, 0)
    negatives = len(frames) - frames.positives
    assert ClassifierTrainConfig(pos_weight="balanced").resolved_pos_weight(frames) == pytest.approx(
        negatives / frames.positives
    )
    assert ClassifierTrainConfig().resolved_pos_weight(frames) is None


def test_cosine_schedule_decays_from_lr_to_zero_and_constant_stays():
    cosine = ClassifierTrainConfig(lr=1e-3, steps=100, lr_schedule="cosine")
    assert learning_rate(cosine, 1) == pytest.approx(1e-3)
    assert learning_rate(cosine, 51) == pytest.approx(0.5e-3)
    assert learning_rate(cosine, 100) == pytest.approx(0.5e-3 * (1 + np.cos(np.pi * 0.99)))
    rates = [learning_rate(cosine, s) for s in range(1, 101)]
    assert all(a > b for a, b in zip(rates, rates[1:], strict=False))
    constant = ClassifierTrainConfig(lr=1e-3, steps=100)
    assert {learning_rate(constant, s) for s in (1, 50, 100)} == {1e-3}
    with pytest.raises(ValueError, match="lr_schedule must be one of constant, cosine"):
        ClassifierTrainConfig(lr_schedule="linear")
    with pytest.raises(ValueError, match="seed must be a non-negative integer, got -1"):
        ClassifierTrainConfig(seed=-1)


def test_cosine_training_changes_the_result_and_still_learns():
    train, held_out = _separable(256, 0), _separable(128, 1)
    constant = train_classifier(train, ClassifierTrainConfig(steps=150, batch_size=32, seed=3))
    config = ClassifierTrainConfig(steps=150, batch_size=32, seed=3, lr_schedule="cosine")
    cosine = train_classifier(train, config, log_every=1000)
    assert evaluate(cosine, held_out)["accuracy"] >= 0.95
    differs = [
        not torch.equal(a, b)
        for a, b in zip(constant.state_dict().values(), cosine.state_dict().values(), strict=True)
    ]
    assert any(differs)


def test_soft_targets_are_fitted_and_scored_at_the_frame_set_threshold():
    # Frames with the bright square get target 0.9, the others 0.2: the trained logits
    # approach logit(0.9) and logit(0.2), and scoring uses the frame set's threshold.
    frames = _separable(256, 0)
    soft = FrameSet(
        images=frames.images,
        labels=frames.labels,
        trajectories=frames.trajectories,
        steps=frames.steps,
        targets=np.where(frames.labels, 0.9, 0.2).astype(np.float32),
        threshold=1.0,
    )
    config = ClassifierTrainConfig(arch="ours", steps=300, batch_size=32, seed=3)
    model = train_classifier(soft, config, log_every=1000)
    held_out = _separable(128, 1)
    p = 1 / (1 + np.exp(-predict_logits(model, held_out.images)))
    assert abs(p[held_out.labels].mean() - 0.9) < 0.06
    assert abs(p[~held_out.labels].mean() - 0.2) < 0.06
    # at threshold 1.0 (p = 0.73) the square frames are positive, the others negative
    m = evaluate(model, dataclasses.replace(held_out, threshold=1.0))
    assert m["accuracy"] >= 0.95
    assert evaluate(model, dataclasses.replace(held_out, threshold=5.0))["tp"] == 0
