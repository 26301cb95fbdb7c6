"""The model zoo: the shipped entry's card, finding entries by name, refusing a checkpoint that
is not its card's, and making an entry from a checkpoint (``add_to_zoo``)."""

from __future__ import annotations

import dataclasses
import json
import re
from pathlib import Path

import pytest
import torch

from vp2.models import build_model, load_model, model_entry, write_model_checkpoint
from vp2.models.zoo import (
    CARD_FILE,
    CARD_FORMAT,
    CHECKPOINT_FILE,
    FIELDS,
    ZooCard,
    ZooError,
    get_card,
    list_zoo,
    read_card,
    sha256_of,
    zoo_dir,
)
from vp2.models.zoo_entries import add_to_zoo, describe_checkpoint
from vp2.training.config import TrainConfig

REPO = Path(__file__).resolve().parents[2]
SHIPPED = "svg_prime-tiny-robodesk"
SHIPPED_FILE = REPO / "src/vp2/assets/models/svg_prime_tiny_robodesk.pt"


def shipped_zoo_names() -> list[str]:
    """The names of the package's zoo entries, read from its folder (a card per entry)."""
    return sorted(p.name for p in (REPO / "src/vp2/assets/zoo").iterdir()
                  if (p / "card.json").is_file())


def make_checkpoint(path: Path, seed: int = 3) -> Path:
    """A checkpoint as ``vp2 train`` writes one: a tiny RoboDesk Struct-VRNN (5 actions, 64 px)
    with its training config, dataset, validation metrics, time and optimizer state."""
    model = build_model("struct_vrnn", "tiny", action_dim=5, seed=seed, rnn_size=16)
    train = TrainConfig(model="struct_vrnn", dataset="data/robodesk-tiny", out_dir="runs/tiny",
                        preset="tiny", model_overrides={"rnn_size": "16"}, steps=3,
                        batch_size=2, lr=1e-3, seed=seed)
    dataset = {"path": "/abs/data/robodesk-tiny", "train_clips": 12,
               "config": {"env": "robodesk", "trajectories_per_stream": 2, "image_size": 64,
                          "streams": ["robodesk/push_red"]}}
    return write_model_checkpoint(path, {
        "model": model_entry(model), "step": 3, "optimizer": {"state": {}},
        "train_config": dataclasses.asdict(train), "dataset": dataset,
        "metrics": {"valid/pred_mse": 0.1}, "train_seconds": 90.0,
    })


def test_the_zoo_is_the_package_folder_unless_the_variable_names_another(monkeypatch, tmp_path):
    monkeypatch.delenv("VP2_ZOO_DIR", raising=False)
    assert zoo_dir() == REPO / "src/vp2/assets/zoo"
    monkeypatch.setenv("VP2_ZOO_DIR", str(tmp_path))
    assert zoo_dir() == tmp_path and list_zoo() == []


def test_the_shipped_entry_is_the_shipped_checkpoint_and_its_card_agrees_with_it():
    assert SHIPPED in [c.name for c in list_zoo()]
    card = get_card(SHIPPED)  # verified: the file's sha256 is the card's
    assert card.checkpoint_path == SHIPPED_FILE and card.sha256 == sha256_of(SHIPPED_FILE)
    assert card.spec == f"zoo:{SHIPPED}"
    derived = describe_checkpoint(SHIPPED_FILE, SHIPPED)  # what the checkpoint says of itself
    for key in ("family", "preset", "model_args", "parameters", "env", "steps"):
        assert getattr(card, key) == derived[key], key
    assert card.dataset["name"] == derived["dataset"]["name"] == "data/robodesk-300x-64px"
    model = load_model(SHIPPED_FILE, device="cpu")
    assert card.parameters == sum(p.numel() for p in model.parameters()) == 1_648_955
    # The figures of docs/measurements.md, "Shipped small model".
    assert card.action_conditioning["ratio"] == 1.60
    assert card.action_conditioning["interval"] == [1.49, 1.72]
    assert card.action_conditioning["clips"] == 128
    row = card.control["robodesk"]
    # The zoo comparison's RoboDesk run: 3 instances per task, seeds 0-2 (docs/results.md).
    assert (row["successes"], row["trials"], row["seeds"], row["samples"]) == (30, 63, [0, 1, 2], 50)
    # vp2 metrics on 256 held-out clips of the default dataset.
    assert (card.metrics["fvd"], card.metrics["lpips"], card.metrics["ssim"]) == (
        442.01548, 0.0463, 0.85988)
    assert card.not_measured() == []
    assert any(c.startswith("OMP_NUM_THREADS=1 vp2 train --model svg_prime") for c in card.rebuild)


def test_every_shipped_card_is_complete_and_written_as_read():
    for card in list_zoo():
        path = card.directory / CARD_FILE
        data = json.loads(path.read_text())
        assert list(data) == ["format", *FIELDS], path  # every field, in the card's order
        assert card.to_json() == data
        assert card.rebuild and card.dataset["name"] and card.budget["date"]


def test_an_unknown_name_lists_the_known_ones(tmp_path):
    with pytest.raises(ZooError, match=rf"no model 'nope' in the zoo at .*known: {re.escape(', '.join(shipped_zoo_names()))};"):
        get_card("nope")
    with pytest.raises(ZooError, match="no model '../x' in the zoo"):
        get_card("../x")
    with pytest.raises(ZooError, match="it is empty"):
        get_card("nope", tmp_path)


def test_add_then_read_back(tmp_path):
    source = make_checkpoint(tmp_path / "run" / "checkpoints" / "step_00000003.pt")
    zoo = tmp_path / "zoo"
    control = {"robodesk": {"successes": 1, "trials": 2, "seeds": [0, 1], "instances": 1,
                            "samples": 4, "command": "vp2 run ..."}}
    card = add_to_zoo(tmp_path / "run", "tiny-vrnn", {"control": control, "device": "cpu",
                                                      "budget": {"date": "2026-11-27"}}, zoo)
    assert (zoo / "tiny-vrnn" / CHECKPOINT_FILE).read_bytes() == source.read_bytes()
    assert read_card(zoo / "tiny-vrnn").to_json() == card.to_json()
    assert [c.name for c in list_zoo(zoo)] == ["tiny-vrnn"]
    assert (card.family, card.preset, card.model_args, card.env) == (
        "struct_vrnn", "tiny", {"rnn_size": 16}, "robodesk")
    assert card.steps == 3 and card.control == control and card.device == "cpu"
    assert card.parameters == sum(
        p.numel() for p in load_model(source, device="cpu").parameters())
    assert card.budget == {"wall_minutes": 1.5, "max_minutes": None, "cores": None,
                           "date": "2026-11-27"}
    assert card.dataset["trajectories_per_task"] == 2 and card.dataset["train_clips"] == 12
    assert card.rebuild[1] == "vp2 zoo add runs/tiny/checkpoints/step_00000003.pt --name tiny-vrnn"
    assert card.not_measured() == ["action_conditioning", "metrics"]
    assert card.not_recorded() == ["dataset.made_with", "budget.cores"]
    assert get_card("tiny-vrnn", zoo).sha256 == sha256_of(source)
    with pytest.raises(FileExistsError, match="already has 'tiny-vrnn'.*--force"):
        add_to_zoo(source, "tiny-vrnn", None, zoo)
    add_to_zoo(source, "tiny-vrnn", None, zoo, force=True)
    assert get_card("tiny-vrnn", zoo).control is None


@pytest.mark.parametrize(
    ("given", "match"),
    [
        ({"family": "fitvid"}, "family is read from the checkpoint \\('struct_vrnn'\\)"),
        ({"env": "tabletop"}, "env is read from the checkpoint"),
        ({"colour": "red"}, "unknown field 'colour'"),
        ({"action_conditioning": {"ratio": 1.2}}, "action_conditioning: missing field\\(s\\) "
         "interval, clips, command"),
        ({"metrics": {"fvd": "low", "lpips": None, "ssim": None, "psnr": None, "mse": None,
                      "command": "x"}}, "field 'fvd' must be a number or null, not 'low'"),
        ({"control": {"robodesk": {"successes": 1}}}, "control\\['robodesk'\\]: missing"),
    ],
)
def test_add_refuses_fields_that_are_wrong(given, match, tmp_path):
    source = make_checkpoint(tmp_path / "model.pt")
    with pytest.raises(ZooError, match=match):
        add_to_zoo(source, "tiny", given, tmp_path / "zoo")
    assert list_zoo(tmp_path / "zoo") == []


def test_add_refuses_a_bad_name_and_a_checkpoint_without_training_metadata(tmp_path):
    source = make_checkpoint(tmp_path / "model.pt")
    with pytest.raises(ZooError, match="zoo name 'a/b': use letters"):
        add_to_zoo(source, "a/b", None, tmp_path)
    bare = build_model("struct_vrnn", "tiny", action_dim=5)
    write_model_checkpoint(tmp_path / "bare.pt", {"model": model_entry(bare)})
    with pytest.raises(ZooError, match="no training metadata"):
        add_to_zoo(tmp_path / "bare.pt", "bare", None, tmp_path)


def test_a_checkpoint_that_is_not_its_cards_is_refused(tmp_path):
    add_to_zoo(make_checkpoint(tmp_path / "model.pt"), "tiny", None, tmp_path / "zoo")
    target = tmp_path / "zoo" / "tiny" / CHECKPOINT_FILE
    make_checkpoint(target, seed=4)  # other weights under the same name
    card = get_card("tiny", tmp_path / "zoo", verify=False)
    with pytest.raises(ZooError, match="the checkpoint .*model.pt does not match its card "
                       "\\(sha256 [0-9a-f]{16}\\.\\.\\., the card says"):
        card.verify()
    with pytest.raises(ZooError, match="does not match its card"):
        get_card("tiny", tmp_path / "zoo")
    target.unlink()
    with pytest.raises(ZooError, match="its checkpoint .*model.pt is missing"):
        get_card("tiny", tmp_path / "zoo")


def test_a_malformed_card_names_its_file_and_field(tmp_path):
    add_to_zoo(make_checkpoint(tmp_path / "model.pt"), "tiny", None, tmp_path)
    path = tmp_path / "tiny" / CARD_FILE
    data = json.loads(path.read_text())
    for change, match in [
        ({"parameters": -1}, "field 'parameters' must be a positive integer, not -1"),
        ({"family": "vae"}, "family 'vae' is not a registered model"),
        ({"format": "other/1"}, "not a zoo card \\(format 'other/1'"),
        ({"name": "other"}, "the card's name 'other' is not its folder's name 'tiny'"),
    ]:
        path.write_text(json.dumps({**data, **change}))
        with pytest.raises(ZooError, match=match) as info:
            get_card("tiny", tmp_path, verify=False)
        assert str(path) in str(info.value)
    without = {k: v for k, v in data.items() if k != "rebuild"}
    with pytest.raises(ZooError, match="missing field\\(s\\) rebuild"):
        ZooCard.from_json(without, tmp_path / "tiny")
    assert CARD_FORMAT == data["format"] == "vp2-zoo-card/1"


def test_a_zoo_model_predicts_as_its_checkpoint(tmp_path):
    source = make_checkpoint(tmp_path / "model.pt")
    card = add_to_zoo(source, "tiny", None, tmp_path)
    model, direct = (load_model(p, device="cpu") for p in (card.verify(), source))
    for a, b in zip(model.state_dict().values(), direct.state_dict().values(), strict=True):
        assert torch.equal(a, b)
