"""Registered models, their size presets, and loading trained models from checkpoints.

A model is named ``name`` (e.g. ``"fitvid"``) plus a preset (e.g. ``"mini"``) plus optional
field overrides of its config dataclass. Presets live here, in one place::

    model = build_model("svg_prime", "m0.5k0.5", action_dim=4, seed=0)
    model = load_model("runs/svg/checkpoints")          # a trained one, ready for planning
    model = load_model_spec("svg_prime:runs/svg")       # the runner's --model syntax

The checkpoint format is :mod:`vp2.models.checkpoint`; :class:`CheckpointSpec` is the
``NAME:CHECKPOINT`` form of ``--model`` (:class:`vp2.run.model_spec.ModelSpec`).
"""

from __future__ import annotations

import dataclasses
import os
import types
import typing
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from vp2.models.base import VideoPredictor
from vp2.models.checkpoint import latest_checkpoint, read_model_checkpoint
from vp2.models.fitvid import FitVid
from vp2.models.maskvit import MaskViT
from vp2.models.maskvit.tokenizer import MaskViTTokenizer
from vp2.models.mcvd import MCVD
from vp2.models.struct_vrnn import StructVRNN
from vp2.models.svg_prime import SVGPrime
from vp2.utils.kv import parse_key_values
from vp2.utils.tensors import resolve_device


@dataclasses.dataclass(frozen=True)
class ModelEntry:
    """A registered model: its class and named presets (config field overrides)."""

    model_class: type[VideoPredictor]
    presets: Mapping[str, Mapping[str, Any]]
    default_preset: str = "default"


#: Tokenizer size presets, shared by ``maskvit_tokenizer`` and the ``maskvit`` presets.
MASKVIT_TOKENIZER_PRESETS: dict[str, dict[str, Any]] = {
    "small": {"channels": 32, "num_res_blocks": 1, "codebook_size": 512, "disc_channels": 32},
    "tiny": {
        "channels": 16,
        "num_res_blocks": 1,
        "codebook_size": 64,
        "code_dim": 16,
        "disc_channels": 16,
    },
}

MODELS: dict[str, ModelEntry] = {
    SVGPrime.name: ModelEntry(
        SVGPrime,
        presets={
            # Reference parameter counts (rnn_size 512): 5.8 M, 21.5 M, 83 M, 325 M.
            "m0.25k0.25": {"m": 0.25, "k": 0.25},
            "m0.5k0.5": {"m": 0.5, "k": 0.5},
            "m1k1": {"m": 1.0, "k": 1.0},
            "m2k2": {"m": 2.0, "k": 2.0},
        },
        default_preset="m1k1",
    ),
    FitVid.name: ModelEntry(
        FitVid,
        presets={
            # Reference parameter counts: 10.4 M, 6.6 M, 1.5 M.
            "default": {},
            "small_encoder": {"g_dim": 64, "rnn_size": 128},
            "mini": {"g_dim": 32, "rnn_size": 64, "num_base_filters": 8},
        },
    ),
    StructVRNN.name: ModelEntry(
        StructVRNN,
        presets={
            # The paper's model (K = 64 keypoints, LSTM 512 x 2); ~7.5 M parameters here.
            "default": {},
            "small": {
                "num_keypoints": 32,
                "filters": 16,
                "decoder_filters": 64,
                "rnn_size": 128,
                "rnn_layers": 1,
            },
            # Trains on a CPU in minutes (tests, demos).
            "tiny": {
                "num_keypoints": 8,
                "filters": 8,
                "decoder_filters": 32,
                "rnn_size": 32,
                "rnn_layers": 1,
            },
        },
    ),
    MCVD.name: ModelEntry(
        MCVD,
        presets={
            # The paper's U-Net (base 64, [1, 2, 3, 4], attention at 32/16/8), 100 steps.
            "default": {},
            "small": {
                "base_channels": 32,
                "channel_mult": (1, 2, 2, 2),
                "num_res_blocks": 1,
                "attn_resolutions": (8,),
                "spade_hidden": 32,
            },
            # Trains on a CPU in minutes; 10 sampling steps (override sampling_steps=...).
            # Base 32, not 16: the output head must carry the 15 noise channels through a
            # SiLU (see MCVDConfig.base_channels); at 16 training stalled at ε-MSE 0.20.
            "tiny": {
                "base_channels": 32,
                "channel_mult": (1, 2, 2),
                "num_res_blocks": 1,
                "attn_resolutions": (),
                "spade_hidden": 16,
                "dropout": 0.0,
                "sampling_steps": 10,
            },
        },
    ),
    MaskViTTokenizer.name: ModelEntry(
        MaskViTTokenizer,
        presets={
            "default": {},
            "small": dict(MASKVIT_TOKENIZER_PRESETS["small"]),
            "tiny": dict(MASKVIT_TOKENIZER_PRESETS["tiny"]),
        },
    ),
    MaskViT.name: ModelEntry(
        MaskViT,
        presets={
            # Pair each with the tokenizer preset of the same name (or a trained one via
            # tokenizer_checkpoint=..., which brings its own architecture).
            "default": {},
            "small": {
                "dim": 256,
                "depth": 4,
                "heads": 4,
                "tokenizer": dict(MASKVIT_TOKENIZER_PRESETS["small"]),
            },
            "tiny": {
                "dim": 64,
                "depth": 2,
                "heads": 2,
                "tokenizer": dict(MASKVIT_TOKENIZER_PRESETS["tiny"]),
            },
        },
    ),
}


def model_names() -> list[str]:
    """Names of the registered models."""
    return sorted(MODELS)


def preset_names(name: str) -> list[str]:
    """Presets of a registered model."""
    return list(_entry(name).presets)


def all_variants() -> list[tuple[str, str]]:
    """Every ``(model name, preset)`` pair (for contract tests and benchmarks)."""
    return [(name, preset) for name in model_names() for preset in MODELS[name].presets]


def _entry(name: str) -> ModelEntry:
    if name not in MODELS:
        raise ValueError(f"unknown model {name!r}; registered: {', '.join(model_names())}")
    return MODELS[name]


def _coerce(value: Any, annotation: Any, key: str) -> Any:
    """Converts a command-line string to a config field's type; leaves typed values alone."""
    if not isinstance(value, str):
        return value
    hint = annotation
    origin = typing.get_origin(hint)
    if origin in (typing.Union, types.UnionType):  # e.g. ``float | None``
        if value.lower() in ("none", "null"):
            return None
        hint = next(a for a in typing.get_args(hint) if a is not type(None))
        origin = typing.get_origin(hint)
    try:
        if hint is bool:
            if value.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError(value)
            return value.lower() in ("true", "1", "yes")
        if hint in (int, float, str):
            return hint(value)
        if origin in (tuple, list):
            (item,) = {a for a in typing.get_args(hint) if a is not Ellipsis} or {str}
            items = [item(v) for v in value.strip("()[]").split(",") if v.strip()]
            return tuple(items) if origin is tuple else items
    except ValueError as exc:
        raise ValueError(f"override {key}={value!r}: not a valid {hint}") from exc
    return value


def apply_overrides(config: Any, overrides: Mapping[str, Any]) -> Any:
    """A copy of a config dataclass with ``overrides`` applied, strings coerced to field types.

    Raises:
        ValueError: on an unknown field (listing the known ones) or an unparsable value.
    """
    hints = typing.get_type_hints(type(config))
    fields = {f.name for f in dataclasses.fields(config)}
    unknown = set(overrides) - fields
    if unknown:
        raise ValueError(
            f"unknown {type(config).__name__} field(s) {sorted(unknown)}; known: {sorted(fields)}"
        )
    return dataclasses.replace(config, **{k: _coerce(v, hints[k], k) for k, v in overrides.items()})


def parse_overrides(items: Sequence[str]) -> dict[str, str]:
    """Parses command-line ``key=value`` strings (values stay strings; see
    :func:`apply_overrides`)."""
    return parse_key_values(items, "override")


def make_config(name: str, preset: str | None = None, **overrides: Any) -> Any:
    """The config of a registered model: its class defaults, then the preset, then overrides."""
    entry = _entry(name)
    preset = entry.default_preset if preset is None else preset
    if preset not in entry.presets:
        raise ValueError(
            f"unknown preset {preset!r} of {name}; presets: {', '.join(entry.presets)}"
        )
    config = entry.model_class.config_class()
    config = apply_overrides(config, dict(entry.presets[preset]))
    return apply_overrides(config, overrides)


def model_from_config(name: str, config: Any | Mapping[str, Any], seed: int = 0) -> VideoPredictor:
    """Builds a registered model from its config (dataclass or plain dict from a checkpoint).

    Weights are initialised from ``seed`` in a forked RNG, so building a model neither reads
    nor changes the global random state.
    """
    cls = _entry(name).model_class
    if isinstance(config, Mapping):
        config = cls.config_class(**config)
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return cls(config)


def build_model(
    name: str, preset: str | None = None, seed: int = 0, **overrides: Any
) -> VideoPredictor:
    """A freshly initialised model: ``model_from_config(name, make_config(...), seed)``."""
    return model_from_config(name, make_config(name, preset, **overrides), seed)


# --------------------------------------------------------------------------- loading


def load_model(
    path: str | os.PathLike[str],
    device: str | torch.device | None = None,
    expected_name: str | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> VideoPredictor:
    """A trained model from a checkpoint, in eval mode, ready for ``predict``.

    Args:
        path: A checkpoint file or a training run directory (its newest checkpoint).
        device: Where to put it; default CUDA if available, else CPU.
        expected_name: If given, the checkpoint must hold this model.
        overrides: Config fields to change at inference, e.g. ``{"sampling_steps": 10}`` for
            MCVD or ``{"decoding_iterations": 8}`` for MaskViT (strings are coerced to the
            field's type). A change that alters the architecture is refused.

    Raises:
        FileNotFoundError: no checkpoint at ``path``.
        ValueError: not a vp2 checkpoint or a different model than ``expected_name``
            (:class:`~vp2.models.checkpoint.CheckpointError`), an unknown override field, or
            an override the checkpoint's weights do not fit.
    """
    device = resolve_device(device)
    path = latest_checkpoint(path)
    entry = read_model_checkpoint(path, expected_name=expected_name)["model"]
    name = entry["name"]
    config: Any = entry["config"]
    if overrides:
        config = apply_overrides(_entry(name).model_class.config_class(**config), overrides)
    model = model_from_config(name, config)
    try:
        model.load_state_dict(entry["state_dict"])
    except RuntimeError as err:
        if not overrides:
            raise
        raise ValueError(
            f"{path}: the overrides {dict(overrides)} change the {name} "
            f"architecture, so the checkpoint's weights no longer fit; override only "
            f"inference settings (e.g. sampling_steps, decoding_iterations)"
        ) from err
    return model.to(device).eval()


@dataclasses.dataclass(frozen=True)
class CheckpointSpec:
    """A trained registered model named ``NAME:CHECKPOINT`` (e.g. ``svg_prime:runs/svg``), the
    runner's ``--model`` form for checkpoints; :meth:`match` is the one place it is parsed.

    Attributes:
        name: The registered model the checkpoint must hold.
        path: A checkpoint file or a training run directory (its newest checkpoint).
    """

    name: str
    path: Path

    @classmethod
    def match(cls, spec: str) -> CheckpointSpec | None:
        """``spec`` parsed if it is ``NAME:CHECKPOINT`` with a registered ``NAME`` (split at
        the first colon), else ``None``.

        Raises:
            ValueError: a registered name and a colon with no path after it.
        """
        name, sep, path = spec.partition(":")
        if not sep or name not in MODELS:
            return None
        if not path:
            raise ValueError(f"model {spec!r}: expected NAME:CHECKPOINT, e.g. svg_prime:runs/svg")
        return cls(name, Path(path))

    def check(self) -> Path:
        """Reads the checkpoint (``torch.load(weights_only=True)``) without building the model;
        returns its file.

        Raises:
            FileNotFoundError: no checkpoint at ``path``.
            CheckpointError: not a vp2 checkpoint, or not of this model (a ``ValueError``).
        """
        path = latest_checkpoint(self.path)
        read_model_checkpoint(path, expected_name=self.name)
        return path

    def load(
        self,
        device: str | torch.device | None = None,
        overrides: Mapping[str, Any] | None = None,
    ) -> VideoPredictor:
        """The trained model: :func:`load_model` of ``path``, checked to be a ``name`` model."""
        return load_model(self.path, device=device, expected_name=self.name, overrides=overrides)


def parse_model_spec(spec: str) -> tuple[str, Path]:
    """Splits the runner's ``name:path`` model syntax (e.g. ``svg_prime:runs/svg``).

    Raises:
        ValueError: without a colon, or with an unregistered name.
    """
    checkpoint = CheckpointSpec.match(spec)
    if checkpoint is not None:
        return checkpoint.name, checkpoint.path
    if ":" not in spec:
        raise ValueError(f"model {spec!r}: expected NAME:CHECKPOINT, e.g. svg_prime:runs/svg")
    raise ValueError(
        f"model {spec!r}: unknown model before the colon; registered: {', '.join(model_names())}"
    )


def load_model_spec(
    spec: str,
    device: str | torch.device | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> VideoPredictor:
    """:func:`load_model` from ``name:path``, checking the checkpoint holds that model."""
    return CheckpointSpec(*parse_model_spec(spec)).load(device=device, overrides=overrides)
