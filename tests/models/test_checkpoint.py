"""The model checkpoint format: locating, writing and reading checkpoints."""

from __future__ import annotations

import pytest
import torch

from vp2.models import build_model, load_model
from vp2.models.checkpoint import (
    CHECKPOINT_FORMAT,
    latest_checkpoint,
    read_model_checkpoint,
    write_model_checkpoint,
)


def test_write_then_read_and_load(tmp_path):
    model = build_model("fitvid", "mini", action_dim=4, image_size=32, seed=1)
    entry = {"name": "fitvid", "config": model.config_dict(), "state_dict": model.state_dict()}
    path = write_model_checkpoint(tmp_path / "step_00000007.pt", {"model": entry, "step": 7})
    payload = read_model_checkpoint(path)
    assert payload["format"] == CHECKPOINT_FORMAT and payload["step"] == 7
    assert not list(tmp_path.glob("*.tmp*"))  # written atomically: no temporary left behind
    loaded = load_model(tmp_path, device="cpu")
    for (k, a), b in zip(model.state_dict().items(), loaded.state_dict().values(), strict=True):
        assert torch.equal(a, b), k


def test_latest_checkpoint_picks_the_newest_step(tmp_path):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    for step in (5, 40, 300):
        write_model_checkpoint(run / "checkpoints" / f"step_{step:08d}.pt", {"step": step})
    assert latest_checkpoint(run).name == "step_00000300.pt"
    assert latest_checkpoint(run / "checkpoints" / "step_00000005.pt").name == "step_00000005.pt"
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        latest_checkpoint(tmp_path / "empty")


def test_read_refuses_other_files(tmp_path):
    torch.save({"model": {}}, tmp_path / "other.pt")  # no format tag
    with pytest.raises(ValueError, match=f"not a {CHECKPOINT_FORMAT} checkpoint"):
        read_model_checkpoint(tmp_path / "other.pt")
