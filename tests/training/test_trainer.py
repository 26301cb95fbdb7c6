from __future__ import annotations

import csv
import json

import numpy as np
import pytest
import torch
from PIL import Image

from tests.models.synthetic import write_moving_square_dataset
from vp2.models import FitVid, load_model, load_model_spec
from vp2.training import StepBatchSampler, TrainConfig, train, trainer
from vp2.training.checkpoint import run_payload

# Tiny models so that a training step takes milliseconds on a CPU.
TINY = {
    "fitvid": ("mini", {}),
    "svg_prime": ("m0.25k0.25", {"m": "0.125", "k": "0.125"}),
}


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    # 6 trajectories of 16 frames at 32x32, A = 4; every 3rd is validation: 20 train clips.
    return write_moving_square_dataset(tmp_path_factory.mktemp("data") / "squares")


def _config(dataset, out_dir, model="fitvid", **kwargs) -> TrainConfig:
    preset, overrides = TINY[model]
    defaults = dict(
        model=model,
        preset=preset,
        model_overrides=overrides,
        dataset=dataset,
        out_dir=out_dir,
        steps=4,
        batch_size=4,
        eval_interval=2,
        eval_batches=1,
        ckpt_interval=2,
        log_interval=1,
        workers=0,
        progress=False,
        lr=1e-3,
    )
    return TrainConfig(**{**defaults, **kwargs})


def _rows(out_dir):
    with (out_dir / "metrics.csv").open() as f:
        return list(csv.DictReader(f))


def test_train_writes_a_complete_run(dataset, tmp_path):
    out = tmp_path / "run"
    result = train(_config(dataset, out))
    assert result.step == 4 and result.checkpoint == out / "checkpoints" / "step_00000004.pt"
    assert sorted(p.name for p in (out / "checkpoints").iterdir()) == [
        "step_00000002.pt",
        "step_00000004.pt",
    ]
    saved = json.loads((out / "config.json").read_text())
    assert (
        saved["model"]["config"]["action_dim"] == 4 and saved["model"]["config"]["image_size"] == 32
    )
    assert saved["dataset"]["train_clips"] == 20

    rows = _rows(out)
    losses = [float(r["value"]) for r in rows if r["tag"] == "train/loss"]
    assert [int(r["step"]) for r in rows if r["tag"] == "train/loss"] == [1, 2, 3, 4]
    assert all(np.isfinite(losses))
    assert [int(r["step"]) for r in rows if r["tag"] == "valid/pred_mse"] == [2, 4]
    assert {"train/grad_norm", "train/mse", "train/kl", "valid/loss", "valid/mse"} <= {
        r["tag"] for r in rows
    }
    assert set(result.valid_metrics) >= {"valid/loss", "valid/pred_mse"}

    # Grid: 4 validation clips x (true row + predicted row), 12 frames, 1-pixel borders.
    grid = np.asarray(Image.open(out / "samples" / "step_00000004.png"))
    assert grid.shape == (8 * 33, 12 * 33, 3) and grid.dtype == np.uint8

    # A checkpoint is plain data (weights_only) with everything needed to resume.
    payload = torch.load(result.checkpoint, weights_only=True)
    assert {"model", "optimizer", "rng", "step", "train_config", "dataset"} <= set(payload)
    assert payload["dataset"]["config"]["env"] == "synthetic"

    model = load_model(out, device="cpu")
    assert isinstance(model, FitVid) and not model.training
    # Its layout is the one run_payload makes (the model entry's: vp2.models.checkpoint).
    layout = run_payload(
        model,
        step=4,
        optimizer=torch.optim.Adam(model.parameters()),
        scaler=torch.amp.GradScaler("cpu", enabled=False),
        noise=torch.Generator(),
        train_config={},
        dataset={},
        metrics={},
        train_seconds=0.0,
    )
    assert list(payload) == ["format", *layout] and list(payload["model"]) == list(layout["model"])
    # The newest checkpoint's weights, exactly.
    loaded = model.state_dict()
    for key, value in payload["model"]["state_dict"].items():
        torch.testing.assert_close(loaded[key], value, rtol=0, atol=0, msg=key)
    assert (model.name, model.action_dim, model.image_size) == ("fitvid", 4, 32)
    pred = model.predict(torch.rand(2, 2, 3, 32, 32), torch.zeros(2, 11, 4))
    assert pred.shape == (2, 10, 3, 32, 32)
    assert load_model_spec(f"fitvid:{result.checkpoint}").name == "fitvid"
    with pytest.raises(ValueError, match="holds a 'fitvid' model, not 'svg_prime'"):
        load_model_spec(f"svg_prime:{out}")


@pytest.mark.parametrize("model", sorted(TINY))
def test_resume_is_bit_identical(dataset, tmp_path, model):
    # Validation and checkpoints at different steps must not perturb training either.
    straight = train(_config(dataset, tmp_path / "a", model, steps=6, eval_interval=4))
    train(_config(dataset, tmp_path / "b", model, steps=3, ckpt_interval=3, eval_interval=2))
    resumed = train(
        _config(
            dataset,
            tmp_path / "b",
            model,
            steps=6,
            ckpt_interval=3,
            eval_interval=2,
            workers=2,
            resume=True,
        )
    )
    assert resumed.step == 6
    a = torch.load(straight.checkpoint, weights_only=True)
    b = torch.load(resumed.checkpoint, weights_only=True)
    for key, value in a["model"]["state_dict"].items():
        torch.testing.assert_close(b["model"]["state_dict"][key], value, rtol=0, atol=0, msg=key)
    for key, state in a["optimizer"]["state"].items():
        torch.testing.assert_close(
            b["optimizer"]["state"][key]["exp_avg"], state["exp_avg"], rtol=0, atol=0
        )
    # The resumed log continues the interrupted one (steps 1-3, then 4-6).
    steps = [int(r["step"]) for r in _rows(tmp_path / "b") if r["tag"] == "train/loss"]
    assert steps == [1, 2, 3, 4, 5, 6]


def test_existing_runs_are_not_overwritten(dataset, tmp_path):
    train(_config(dataset, tmp_path / "run", steps=2))
    with pytest.raises(FileExistsError, match="resume=True"):
        train(_config(dataset, tmp_path / "run", steps=2))
    with pytest.raises(
        ValueError, match=r"configuration changed \(lr: checkpoint 0.001 vs now 0.01\)"
    ):
        train(_config(dataset, tmp_path / "run", steps=4, lr=1e-2, resume=True))
    # Resuming a finished run does nothing and returns its checkpoint.
    done = train(_config(dataset, tmp_path / "run", steps=2, resume=True))
    assert done.step == 2 and done.checkpoint.name == "step_00000002.pt"


def test_config_errors(dataset, tmp_path):
    with pytest.raises(ValueError, match="action_dim=5 disagrees with the dataset"):
        train(_config(dataset, tmp_path / "x", model_overrides={"action_dim": 5}))
    with pytest.raises(ValueError, match="needs a perceptual loss"):
        train(_config(dataset, tmp_path / "y", perceptual_weight=1.0))
    with pytest.raises(ValueError, match="fewer than batch_size=64"):
        train(_config(dataset, tmp_path / "z", batch_size=64))


def test_perceptual_loss_term(dataset, tmp_path):
    calls = []

    def l1(pred, target):
        calls.append(pred.shape)
        return (pred - target).abs().mean(dim=(1, 2, 3))

    result = train(
        _config(dataset, tmp_path / "p", steps=2, perceptual_weight=1.0), perceptual_fn=l1
    )
    assert calls[0] == (4 * 11, 3, 32, 32)
    assert "train/perceptual" in result.train_metrics

    with pytest.raises(FloatingPointError, match="loss is nan by step 1"):
        train(
            _config(dataset, tmp_path / "nan", steps=2, perceptual_weight=1.0),
            perceptual_fn=lambda p, t: torch.full(p.shape[:1], float("nan")),
        )


def test_step_batch_sampler_is_a_function_of_seed_and_step():
    full = list(StepBatchSampler(10, 3, seed=7, start=0, stop=9))
    assert len(full) == 9 and all(len(b) == 3 for b in full)
    assert list(StepBatchSampler(10, 3, seed=7, start=4, stop=9)) == full[4:]
    for epoch in range(3):  # 3 batches per epoch, no index repeated within one
        seen = sum(full[3 * epoch : 3 * epoch + 3], [])
        assert len(set(seen)) == 9
    assert full[:3] != full[3:6]  # a new permutation each epoch
    assert list(StepBatchSampler(10, 3, seed=8, start=0, stop=9)) != full


@pytest.mark.parametrize("half", [True, False])
def test_exported_checkpoint_predicts_like_the_training_one(dataset, tmp_path, half):
    from vp2.training.export import EXPORT_KEYS, export_checkpoint

    out = tmp_path / "run"
    train(_config(dataset, out, model="svg_prime", steps=2))
    path = export_checkpoint(out, tmp_path / "model.pt", half=half)
    payload = torch.load(path, weights_only=True)
    assert list(payload) == ["format", *EXPORT_KEYS, "exported"] and payload["step"] == 2
    assert payload["exported"] == {"half": half, "from_step": 2}
    dtypes = {v.dtype for v in payload["model"]["state_dict"].values() if v.is_floating_point()}
    assert dtypes == ({torch.float16} if half else {torch.float32})
    full, small = load_model(out, device="cpu"), load_model(path, device="cpu")
    assert next(small.parameters()).dtype == torch.float32
    g = torch.Generator().manual_seed(0)
    context, actions = torch.rand(2, 2, 3, 32, 32, generator=g), torch.rand(2, 11, 4) * 2 - 1
    a = full.predict(context, actions, generator=torch.Generator().manual_seed(1))
    b = small.predict(context, actions, generator=torch.Generator().manual_seed(1))
    torch.testing.assert_close(a, b, atol=2e-2 if half else 0, rtol=0)


@pytest.fixture
def step_clock(monkeypatch):
    """The trainer's clock, made deterministic: every optimisation step takes 30 s, every
    validation 10 min, nothing else any time. Returns the clock's reading (a one-element list)."""
    now = [1000.0]
    real_step, real_validation = trainer.optimisation_step, trainer.run_validation

    def timed_step(run, batch):
        now[0] += 30.0
        return real_step(run, batch)

    def timed_validation(run, step):
        now[0] += 600.0  # left out of the budget: it would spend it at once
        return real_validation(run, step)

    monkeypatch.setattr(trainer, "clock", lambda: now[0])
    monkeypatch.setattr(trainer, "optimisation_step", timed_step)
    monkeypatch.setattr(trainer, "run_validation", timed_validation)
    return now


def test_time_budget_stops_early_and_resumes_within_it(dataset, tmp_path, step_clock):
    out = tmp_path / "budget"
    # 30 s a step: a budget of 1.5 min is spent at step 3, long before steps=20.
    first = train(_config(dataset, out, steps=20, max_minutes=1.5))
    assert (first.step, first.train_minutes, first.budget_reached) == (3, 1.5, True)
    # It ends as at `steps`: a final checkpoint, validation and log row at the step it stopped.
    assert first.checkpoint == out / "checkpoints" / "step_00000003.pt"
    assert torch.load(first.checkpoint, weights_only=True)["train_seconds"] == 90.0
    assert [int(r["step"]) for r in _rows(out) if r["tag"] == "valid/pred_mse"] == [2, 3]
    minutes = {int(r["step"]): float(r["value"]) for r in _rows(out) if r["tag"] == "train/minutes"}
    assert minutes == {1: 0.5, 2: 1.0, 3: 1.5}
    finished = json.loads((out / "config.json").read_text())["finished"]
    assert finished == {"step": 3, "train_minutes": 1.5, "stopped_by": "max_minutes"}

    # Resuming with the same budget trains nothing: the time is spent.
    clock_before = step_clock[0]
    again = train(_config(dataset, out, steps=20, max_minutes=1.5, resume=True))
    assert (again.step, again.checkpoint, again.budget_reached) == (3, first.checkpoint, True)
    assert step_clock[0] == clock_before and again.train_minutes == 1.5

    # A larger budget continues the run, counting the 1.5 min already spent: 2 more steps.
    more = train(_config(dataset, out, steps=20, max_minutes=2.5, resume=True))
    assert (more.step, more.train_minutes, more.budget_reached) == (5, 2.5, True)
    assert [int(r["step"]) for r in _rows(out) if r["tag"] == "train/loss"] == [1, 2, 3, 4, 5]

    # Stopping by the budget and resuming changes nothing in what is computed: the weights
    # are those of 5 uninterrupted steps without a budget.
    straight = train(_config(dataset, tmp_path / "straight", steps=5))
    assert (straight.budget_reached, straight.train_minutes) == (False, 2.5)
    a = torch.load(straight.checkpoint, weights_only=True)["model"]["state_dict"]
    b = torch.load(more.checkpoint, weights_only=True)["model"]["state_dict"]
    for key, value in a.items():
        torch.testing.assert_close(b[key], value, rtol=0, atol=0, msg=key)


def test_time_budget_larger_than_the_steps_need(dataset, tmp_path, step_clock):
    result = train(_config(dataset, tmp_path / "run", steps=4, max_minutes=60))
    assert (result.step, result.train_minutes, result.budget_reached) == (4, 2.0, False)
    finished = json.loads((tmp_path / "run" / "config.json").read_text())["finished"]
    assert finished["stopped_by"] == "steps"
    with pytest.raises(ValueError, match="max_minutes must be > 0"):
        _config(dataset, tmp_path / "x", max_minutes=0)
    with pytest.raises(ValueError, match="seed must be a non-negative integer, got -2"):
        _config(dataset, tmp_path / "x", seed=-2)
