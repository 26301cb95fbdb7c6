"""The model checkpoint format: layout, locating, writing, reading, and refusing other files."""

from __future__ import annotations

import pickle
import random
from pathlib import Path, PurePosixPath

import pytest
import torch

from vp2.models import CheckpointSpec, build_model, load_model
from vp2.models.checkpoint import (
    CHECKPOINT_FORMAT,
    MODEL_KEYS,
    CheckpointError,
    checkpoint_path,
    latest_checkpoint,
    list_checkpoints,
    model_entry,
    read_model_checkpoint,
    write_model_checkpoint,
)

SHIPPED = Path(__file__).resolve().parents[2] / "src/vp2/assets/models/svg_prime_tiny_robodesk.pt"


@pytest.fixture(scope="module")
def fitvid_file(tmp_path_factory):
    """A checkpoint of a tiny FitVid (``step_00000007.pt``) and the model it holds."""
    model = build_model("fitvid", "mini", action_dim=4, image_size=32, seed=1)
    path = tmp_path_factory.mktemp("ckpt") / "step_00000007.pt"
    write_model_checkpoint(path, {"model": model_entry(model), "step": 7})
    return path, model


def test_write_then_read_and_load(fitvid_file):
    path, model = fitvid_file
    payload = read_model_checkpoint(path)
    assert list(payload) == ["format", "model", "step"]
    assert payload["format"] == CHECKPOINT_FORMAT and payload["step"] == 7
    assert not list(path.parent.glob("*.tmp*"))  # written atomically: no temporary left behind
    loaded = load_model(path.parent, device="cpu")
    for (k, a), b in zip(model.state_dict().items(), loaded.state_dict().values(), strict=True):
        assert torch.equal(a, b), k


def test_the_same_payload_gives_the_same_bytes_under_any_name(fitvid_file, tmp_path):
    # A zoo entry's SHA-256 names its checkpoint, so re-adding an entry must not change it.
    payload = read_model_checkpoint(fitvid_file[0])
    payload.pop("format")
    a = write_model_checkpoint(tmp_path / "a" / "model.pt", payload)
    b = write_model_checkpoint(tmp_path / "other.pt", payload)
    assert a.read_bytes() == b.read_bytes()


def test_model_entry_is_name_config_and_weights(fitvid_file):
    _, model = fitvid_file
    entry = model_entry(model)
    assert tuple(entry) == MODEL_KEYS == ("name", "config", "state_dict")
    assert entry["name"] == "fitvid" and entry["config"] == model.config_dict()
    assert list(entry["state_dict"]) == list(model.state_dict())


def test_layout_of_a_run_directory(tmp_path):
    run = tmp_path / "run"
    assert checkpoint_path(run, 300) == run / "checkpoints" / "step_00000300.pt"
    for step in (5, 40, 300):
        write_model_checkpoint(checkpoint_path(run, step), {"step": step})
    assert [p.name for p in list_checkpoints(run)] == [
        "step_00000005.pt",
        "step_00000040.pt",
        "step_00000300.pt",
    ]
    assert latest_checkpoint(run).name == "step_00000300.pt"
    assert latest_checkpoint(run / "checkpoints").name == "step_00000300.pt"
    assert latest_checkpoint(run / "checkpoints" / "step_00000005.pt").name == "step_00000005.pt"
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="no checkpoint at .*empty: expected a .pt file"):
        latest_checkpoint(tmp_path / "empty")
    with pytest.raises(FileNotFoundError, match="no checkpoint at .*missing: no such file"):
        latest_checkpoint(tmp_path / "missing")


class Pickled:
    """An object a weights-only load refuses to rebuild."""


def _random_bytes(path: Path, good: Path) -> None:
    path.write_bytes(random.Random(0).randbytes(4096))  # seeded: torch fails in many ways


def _truncated(path: Path, good: Path) -> None:
    path.write_bytes(good.read_bytes()[: good.stat().st_size // 2])


def _empty(path: Path, good: Path) -> None:
    path.write_bytes(b"")


def _text(path: Path, good: Path) -> None:
    path.write_text("hello\n")


def _plain_pickle(path: Path, good: Path) -> None:
    path.write_bytes(pickle.dumps({"model": {}}))


def _pickled_class(path: Path, good: Path) -> None:
    torch.save({"format": CHECKPOINT_FORMAT, "model": Pickled()}, path)


def _pickled_path(path: Path, good: Path) -> None:
    torch.save({"format": CHECKPOINT_FORMAT, "where": PurePosixPath("x")}, path)


def _no_format_tag(path: Path, good: Path) -> None:
    torch.save({"model": {}}, path)


def _other_format(path: Path, good: Path) -> None:
    torch.save({"format": "vp2-checkpoint/0", "model": {}}, path)


def _a_tensor(path: Path, good: Path) -> None:
    torch.save(torch.zeros(3), path)


def _no_model_entry(path: Path, good: Path) -> None:
    torch.save({"format": CHECKPOINT_FORMAT, "step": 1}, path)


BAD_FILES = {
    _random_bytes: "not a readable PyTorch file: UnpicklingError",
    _truncated: "not a readable PyTorch file: failed reading zip archive",
    _empty: "not a readable PyTorch file: EOFError",
    _text: "not a readable PyTorch file",
    _plain_pickle: "not a readable PyTorch file: UnpicklingError",
    _pickled_class: "it holds a pickled Python object, tests.models.test_checkpoint.Pickled,",
    _pickled_path: "it holds a pickled Python object, pathlib.PurePosixPath,",
    _no_format_tag: "a PyTorch file with no 'vp2-checkpoint/1' tag",
    _other_format: "a PyTorch file with format 'vp2-checkpoint/0'",
    _a_tensor: "a PyTorch file with no 'vp2-checkpoint/1' tag",
    _no_model_entry: "no 'model' entry with name, config, state_dict",
}


@pytest.mark.parametrize("make", BAD_FILES, ids=lambda f: f.__name__.strip("_"))
def test_other_files_are_refused_in_one_line(make, fitvid_file, tmp_path, recwarn):
    path = tmp_path / "bad.pt"
    make(path, fitvid_file[0])
    for read in (read_model_checkpoint, lambda p: load_model(p, device="cpu")):
        with pytest.raises(CheckpointError) as info:
            read(path)
        message = str(info.value)
        assert message.startswith(f"{path} is not a vp2 checkpoint (")
        assert BAD_FILES[make] in message
        assert "\n" not in message and "weights_only" not in message.lower()
        # torch's own error (with its advice to load unsafely) is not chained for display.
        error = info.value
        assert error.__cause__ is None and (error.__context__ is None or error.__suppress_context__)
    assert not [w for w in recwarn.list if "weights_only" in str(w.message)]


def test_a_checkpoint_of_another_model_is_refused(fitvid_file):
    path, _ = fitvid_file
    with pytest.raises(CheckpointError, match=f"^{path} holds a 'fitvid' model, not 'svg_prime'$"):
        read_model_checkpoint(path, expected_name="svg_prime")
    with pytest.raises(CheckpointError, match="holds a 'fitvid' model, not 'svg_prime'"):
        load_model(path.parent, expected_name="svg_prime")
    with pytest.raises(CheckpointError, match="holds a 'fitvid' model, not 'svg_prime'"):
        CheckpointSpec("svg_prime", path).check()
    assert CheckpointSpec("fitvid", path.parent).check() == path


def test_the_shipped_checkpoint_reads_weights_only():
    payload = torch.load(SHIPPED, map_location="cpu", weights_only=True)
    assert payload["format"] == CHECKPOINT_FORMAT and tuple(payload["model"]) == MODEL_KEYS
    assert CheckpointSpec("svg_prime", SHIPPED).check() == SHIPPED
