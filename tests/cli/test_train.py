from __future__ import annotations

import argparse
import csv
from pathlib import Path

import pytest
import torch

from tests.models.synthetic import write_moving_square_dataset
from vp2.cli.train import config_from_args, configure_parser, default_out_dir, run_from_args


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    # 6 trajectories of 16 frames at 32x32, A = 4: 20 train clips, 10 validation clips.
    return write_moving_square_dataset(tmp_path_factory.mktemp("data") / "squares")


def _parse(*argv: str) -> argparse.Namespace:
    return configure_parser(argparse.ArgumentParser(prog="vp2 train")).parse_args(list(argv))


def _tiny(dataset: Path, out: Path, *extra: str) -> argparse.Namespace:
    return _parse(
        "--model", "fitvid", "--preset", "mini", "--data", str(dataset), "--out", str(out),
        "--batch-size", "4", "--lr", "1e-3", "--workers", "0", "--eval-batches", "1",
        "--log-interval", "1", "--no-progress", "--no-tensorboard", *extra,
    )  # fmt: skip


def _loss_steps(out: Path) -> list[int]:
    with (out / "metrics.csv").open() as f:
        return [int(r["step"]) for r in csv.DictReader(f) if r["tag"] == "train/loss"]


def test_train_then_resume(dataset, tmp_path, capsys):
    out = tmp_path / "run"
    assert run_from_args(_tiny(dataset, out, "--steps", "2")) == 0
    ckpt = out / "checkpoints" / "step_00000002.pt"
    payload = torch.load(ckpt, weights_only=True)
    assert payload["step"] == 2 and payload["train_config"]["lr"] == 1e-3
    assert _loss_steps(out) == [1, 2]
    assert (out / "samples" / "step_00000002.png").is_file()
    printed = capsys.readouterr().out
    assert f"checkpoint: {ckpt} (step 2)" in printed and "valid/pred_mse: " in printed

    # Without --resume the run is protected; with it, training continues at step 3.
    with pytest.raises(FileExistsError, match="resume"):
        run_from_args(_tiny(dataset, out, "--steps", "4"))
    assert run_from_args(_tiny(dataset, out, "--steps", "4", "--resume")) == 0
    assert torch.load(out / "checkpoints" / "step_00000004.pt", weights_only=True)["step"] == 4
    assert _loss_steps(out) == [1, 2, 3, 4]
    with pytest.raises(ValueError, match="configuration changed"):
        run_from_args(_tiny(dataset, out, "--steps", "6", "--resume", "--seed", "1"))


def test_flags_map_onto_the_config(dataset, tmp_path):
    config = config_from_args(
        _tiny(
            dataset, tmp_path / "x",
            "--model-arg", "beta=1e-3", "--model-arg", "rnn_size=32", "g_dim=16",
            "--num-trajectories", "5",
            "--tasks", "synthetic/moving_square", "--optimizer", "adamw",
            "--weight-decay", "0.01", "--grad-clip", "5", "--seed", "3", "--device", "cpu",
            "--no-amp", "--perceptual", "lpips", "--eval-interval", "7",
            "--ckpt-interval", "9", "--keep-checkpoints", "3", "--steps", "11",
            "--max-minutes", "2.5",
        )
    )  # fmt: skip
    assert config.model_overrides == {"beta": "1e-3", "rnn_size": "32", "g_dim": "16"}
    assert (config.max_trajectories, config.tasks) == (5, ["synthetic/moving_square"])
    assert (config.optimizer, config.weight_decay, config.grad_clip) == ("adamw", 0.01, 5.0)
    assert (config.seed, config.device, config.amp, config.steps) == (3, "cpu", False, 11)
    assert config.max_minutes == 2.5
    assert (config.perceptual, config.perceptual_weight) == ("lpips", 1.0)  # weight defaults to 1
    assert (config.eval_interval, config.ckpt_interval, config.keep_checkpoints) == (7, 9, 3)
    assert (config.tensorboard, config.progress, config.resume) == (False, False, False)

    # Defaults: TrainConfig's, the dataset `vp2 collect` writes, a run name from the config.
    config = config_from_args(_parse("--model", "svg_prime", "--data", str(dataset)))
    assert (config.steps, config.batch_size, config.workers, config.amp) == (100_000, 32, 2, None)
    assert config.max_minutes is None
    assert (config.lr, config.optimizer, config.perceptual_weight) == (None, None, 0.0)
    assert config.out_dir == str(Path("runs") / "svg_prime-m1k1-squares-seed0")
    config = config_from_args(
        _parse("--model", "fitvid", "--data", str(dataset), "--perceptual", "lpips_vgg",
               "--perceptual-weight", "10", "--seed", "2")
    )  # fmt: skip
    assert config.out_dir == str(Path("runs") / "fitvid-default-squares-lpips_vgg10-seed2")


def test_clear_errors(dataset, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    with pytest.raises(FileNotFoundError, match=r"data/robodesk-20x-64px .*`vp2 collect robodesk`"):
        config_from_args(_parse("--model", "fitvid", "--env", "robodesk"))
    with pytest.raises(FileNotFoundError, match="data/tabletop-100x-64px"):
        config_from_args(_parse("--model", "fitvid", "--env", "tabletop"))
    with pytest.raises(
        FileNotFoundError, match=r"`vp2 collect tabletop --out elsewhere`, or pass --data"
    ):
        config_from_args(_parse("--model", "fitvid", "--env", "tabletop", "--data", "elsewhere"))
    with pytest.raises(ValueError, match="--env ENV .* or --data DIR"):
        config_from_args(_parse("--model", "fitvid"))
    with pytest.raises(ValueError, match="--env robodesk but .* holds a 'synthetic' dataset"):
        config_from_args(_parse("--model", "fitvid", "--env", "robodesk", "--data", str(dataset)))
    with pytest.raises(ValueError, match="unknown preset 'huge'"):
        config_from_args(_parse("--model", "fitvid", "--preset", "huge", "--data", str(dataset)))
    with pytest.raises(ValueError, match=r"unknown FitVidConfig field\(s\) \['depth'\]"):
        config_from_args(
            _parse("--model", "fitvid", "--model-arg", "depth=3", "--data", str(dataset))
        )
    with pytest.raises(ValueError, match="--perceptual-weight 10 needs --perceptual NAME"):
        config_from_args(
            _parse("--model", "fitvid", "--data", str(dataset), "--perceptual-weight", "10")
        )
    with pytest.raises(SystemExit):  # argparse: not a registered model
        _parse("--model", "no_such_model", "--env", "robodesk")


def test_help_names_only_registered_presets():
    """The sizes under `vp2 train --help` name real presets (a renamed preset fails here)."""
    import re

    from vp2.cli.train import SIZES_EPILOG
    from vp2.models.registry import MODELS

    named = re.findall(r"\b(struct_vrnn|maskvit_tokenizer|maskvit|fitvid|mcvd|svg_prime) (\S+)",
                       SIZES_EPILOG)
    assert {m for m, _ in named} == set(MODELS)
    for model, preset in named:
        assert preset in MODELS[model].presets, (model, preset)


def test_the_generated_parser_gives_the_trainconfig_of_the_hand_written_one(dataset, tmp_path):
    """Every field, as the hand-written flag-to-field code set it (before the flags were
    generated from TrainConfig's fields)."""
    from vp2.training.config import TrainConfig

    config = config_from_args(
        _tiny(
            dataset, tmp_path / "o",
            "--preset", "mini", "--model-arg", "beta=1e-3", "rnn_size=16", "--tasks",
            "synthetic/moving_square", "--num-trajectories", "4", "--steps", "7",
            "--max-minutes", "2.5", "--optimizer", "adamw", "--weight-decay", "0.01",
            "--grad-clip", "5", "--seed", "3", "--perceptual", "lpips", "--perceptual-weight",
            "10", "--resume", "--device", "cpu", "--amp", "--eval-interval", "3",
            "--ckpt-interval", "2", "--keep-checkpoints", "5",
        )
    )  # fmt: skip
    assert config == TrainConfig(
        model="fitvid", dataset=str(dataset), out_dir=str(tmp_path / "o"), preset="mini",
        model_overrides={"beta": "1e-3", "rnn_size": "16"}, tasks=["synthetic/moving_square"],
        max_trajectories=4, steps=7, max_minutes=2.5, batch_size=4, lr=1e-3, optimizer="adamw",
        weight_decay=0.01, grad_clip=5.0, seed=3, perceptual="lpips", perceptual_weight=10.0,
        eval_interval=3, eval_batches=1, ckpt_interval=2, keep_checkpoints=5, log_interval=1,
        workers=0, device="cpu", amp=True, tensorboard=False, progress=False, resume=True,
    )  # fmt: skip
    default = config_from_args(_parse("--model", "svg_prime", "--data", str(dataset)))
    assert default == TrainConfig(model="svg_prime", dataset=str(dataset),
                                  out_dir=default_out_dir(default).as_posix())
