"""Making and filling zoo entries (:mod:`vp2.models.zoo` is the card format and the reading).

:func:`add_to_zoo` makes an entry from a checkpoint: the fields its metadata gives (family,
preset, parameters, dataset, steps, the training command), its sha256, and the measured fields
(action conditioning, metrics, control) a user passes; those left out stay ``null`` and the card
reports them as not measured. :func:`fill_card` later rewrites the measured sections of an
entry's card without touching its checkpoint.
"""

from __future__ import annotations

import json
import os
import shlex
import shutil
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from vp2.models.checkpoint import latest_checkpoint, read_model_checkpoint
from vp2.models.registry import MODELS, model_from_config
from vp2.models.zoo import (
    CARD_FILE,
    CARD_FORMAT,
    CHECKPOINT_FILE,
    DERIVED,
    FIELDS,
    MEASURED,
    NAME_PATTERN,
    ZooCard,
    ZooError,
    get_card,
    sha256_of,
    zoo_dir,
)
from vp2.utils.io import atomic_path, json_safe


def train_command(train_config: Mapping[str, Any]) -> str:
    """The ``vp2 train`` command of a checkpoint's training config (the fields that set what
    is computed; logging settings left at their defaults)."""
    cfg = dict(train_config)
    args = ["vp2", "train", "--model", str(cfg["model"])]
    if cfg.get("preset"):
        args += ["--preset", str(cfg["preset"])]
    if cfg.get("model_overrides"):
        args += ["--model-arg", *(f"{k}={v}" for k, v in cfg["model_overrides"].items())]
    args += ["--data", str(cfg["dataset"])]
    if cfg.get("tasks"):
        args += ["--tasks", *map(str, cfg["tasks"])]
    flags = {"max_trajectories": "--num-trajectories", "steps": "--steps",
             "max_minutes": "--max-minutes", "batch_size": "--batch-size", "lr": "--lr",
             "optimizer": "--optimizer", "weight_decay": "--weight-decay",
             "grad_clip": "--grad-clip", "seed": "--seed", "perceptual": "--perceptual"}
    for key, flag in flags.items():
        if cfg.get(key) is not None:
            args += [flag, str(cfg[key])]
    if cfg.get("perceptual"):
        args += ["--perceptual-weight", str(cfg.get("perceptual_weight", 1.0))]
    if cfg.get("device"):
        args += ["--device", str(cfg["device"])]
    if cfg.get("amp") is not None:
        args.append("--amp" if cfg["amp"] else "--no-amp")
    args += ["--out", str(cfg["out_dir"])]
    return shlex.join(args)


def _scalar(value: Any) -> Any:
    """A command-line override (``"0.125"``) as the number it is."""
    if isinstance(value, str):
        for kind in (int, float):
            try:
                return kind(value)
            except ValueError:
                pass
    return value


def describe_checkpoint(path: str | os.PathLike[str], name: str) -> dict[str, Any]:
    """The card fields a checkpoint's metadata gives (everything but ``checkpoint``,
    ``sha256`` and the measured fields, which are ``null``).

    Raises:
        FileNotFoundError: no checkpoint at ``path``.
        ZooError: not a vp2 checkpoint, or one without the training metadata a card needs.
    """
    path = latest_checkpoint(path)
    try:
        payload = read_model_checkpoint(path)
    except ValueError as err:
        raise ZooError(str(err)) from None
    entry, train = payload["model"], payload.get("train_config") or {}
    dataset = payload.get("dataset") or {}
    data_config = dataset.get("config") or {}
    if not train or not dataset:
        raise ZooError(f"{path}: no training metadata (train_config, dataset): a zoo entry is "
                       "made from a checkpoint of `vp2 train` or its export")
    model = model_from_config(entry["name"], entry["config"])
    step = int(payload.get("step", (payload.get("exported") or {}).get("from_step", 0)))
    seconds = payload.get("train_seconds")
    return {
        "name": name,
        "family": entry["name"],
        "preset": train.get("preset") or MODELS[entry["name"]].default_preset,
        "model_args": {k: _scalar(v) for k, v in (train.get("model_overrides") or {}).items()},
        "parameters": sum(p.numel() for p in model.parameters()),
        "env": data_config.get("env"),
        "dataset": {
            "name": str(train.get("dataset") or dataset.get("path")),
            "made_with": None,
            "trajectories_per_task": data_config.get("trajectories_per_stream"),
            "tasks": data_config.get("streams"),
            "image_size": data_config.get("image_size"),
            "train_clips": dataset.get("train_clips"),
        },
        "steps": step,
        "budget": {
            "wall_minutes": None if seconds is None else round(float(seconds) / 60, 2),
            "max_minutes": train.get("max_minutes"),
            "cores": None,
            "date": None,
        },
        "device": train.get("device"),
        "action_conditioning": None,
        "metrics": None,
        "control": None,
        "rebuild": [
            train_command(train),
            shlex.join(["vp2", "zoo", "add",
                        f"{train['out_dir']}/checkpoints/step_{step:08d}.pt", "--name", name]),
        ],
        "notes": None,
    }


def _merge(derived: dict[str, Any], given: Mapping[str, Any], where: str) -> dict[str, Any]:
    """The derived fields with a user's fields on top (sections merged key by key)."""
    card = dict(derived)
    for key, value in given.items():
        if key in ("format", "checkpoint", "sha256"):  # of the file add_to_zoo writes
            continue
        if key not in FIELDS:
            raise ZooError(f"{where}: unknown field {key!r}; a card has {', '.join(FIELDS)}")
        if key == "name" and value != derived["name"]:
            raise ZooError(f"{where}: the card of {value!r}, not of {derived['name']!r}")
        if key in DERIVED or (key == "env" and derived["env"] is not None):
            if value != derived[key]:
                raise ZooError(f"{where}: {key} is read from the checkpoint ({derived[key]!r}), "
                               f"not {value!r}; leave it out")
        elif key in ("dataset", "budget") and isinstance(value, dict):
            card[key] = {**derived[key], **value}
        else:
            card[key] = value
    return card


def fill_card(
    name: str,
    sections: Mapping[str, Any],
    directory: str | os.PathLike[str] | None = None,
) -> ZooCard:
    """Replaces measured sections of entry ``name``'s card and rewrites it, the checkpoint
    untouched (it must still match the card). ``sections`` holds ``metrics`` and/or
    ``control``; a ``control`` row replaces the row of its environment and keeps the others.

    Raises:
        ZooError: no such entry, a checkpoint that no longer matches, or sections that are not
            :data:`MEASURED` fields or fail the card's checks.
    """
    unknown = sorted(set(sections) - set(MEASURED))
    if unknown:
        raise ZooError(f"can only fill the measured fields {', '.join(MEASURED)}, not "
                       f"{', '.join(unknown)}")
    card = get_card(name, directory)  # verified: the figures will be of this checkpoint
    data = card.to_json()
    for key, value in json_safe(dict(sections)).items():
        data[key] = {**(data.get(key) or {}), **value} if key == "control" else value
    where = str(card.directory / CARD_FILE)
    filled = ZooCard.from_json(data, card.directory, where)
    with atomic_path(card.directory / CARD_FILE) as tmp:
        tmp.write_text(json.dumps(filled.to_json(), indent=2) + "\n")
    return filled


def add_to_zoo(
    source: str | os.PathLike[str],
    name: str,
    given: Mapping[str, Any] | None = None,
    directory: str | os.PathLike[str] | None = None,
    *,
    write: Callable[[Path, Path], Any] | None = None,
    force: bool = False,
) -> ZooCard:
    """Makes zoo entry ``name`` from a checkpoint: ``NAME/model.pt`` and ``NAME/card.json``.

    Args:
        source: A checkpoint file or a training run directory (its newest checkpoint).
        name: The entry's name (``--model zoo:NAME``).
        given: Card fields the checkpoint cannot give (the measured ones, ``budget``,
            ``device``, ``dataset`` details, ``rebuild``, ``notes``); the rest stay ``null``.
        directory: The zoo (default :func:`zoo_dir`).
        write: Writes the checkpoint file from ``source`` (default: a byte copy), e.g. an
            inference-only export.
        force: Replace an existing entry of that name.

    Raises:
        FileExistsError: the entry exists and ``force`` is off.
        ZooError: a bad name, a checkpoint without training metadata, or ``given`` fields that
            are unknown, malformed or contradict the checkpoint.
    """
    if not NAME_PATTERN.fullmatch(name):
        raise ZooError(f"zoo name {name!r}: use letters, digits, '.', '_' and '-' "
                       "(e.g. svg_prime-tiny-robodesk)")
    root = Path(directory) if directory is not None else zoo_dir()
    entry = root / name
    if (entry / CARD_FILE).exists() and not force:
        raise FileExistsError(f"the zoo already has {name!r} ({entry}); choose another name or "
                              "replace it with --force")
    source = latest_checkpoint(source)
    where = "the card's fields"
    data = _merge(describe_checkpoint(source, name), json_safe(dict(given or {})), where)
    if data["env"] is None:
        raise ZooError(f"{source}: its dataset names no environment; give \"env\" in the card "
                       "JSON")
    entry.mkdir(parents=True, exist_ok=True)
    target = entry / CHECKPOINT_FILE
    with atomic_path(target) as tmp:
        (write or shutil.copyfile)(source, tmp)
    data.update(checkpoint=CHECKPOINT_FILE, sha256=sha256_of(target))
    card = ZooCard.from_json({"format": CARD_FORMAT, **{k: data[k] for k in FIELDS}}, entry,
                             where)
    with atomic_path(entry / CARD_FILE) as tmp:
        tmp.write_text(json.dumps(card.to_json(), indent=2) + "\n")
    return card
