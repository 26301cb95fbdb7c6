"""Video prediction models: the interface the planner uses, SVG′ and FitVid, and a registry.

- :class:`VideoPredictionModel`: the protocol (shapes, ranges, dtypes in its docstring);
  :class:`VideoPredictor`: base class of trainable networks, whose ``predict`` checks every
  call; :class:`CheckedModel`: the same checks around any other implementation.
- :func:`build_model` / :func:`load_model`: a fresh model from a name and preset, or a trained
  one from a checkpoint. Training lives in :mod:`vp2.training`. See ``docs/models.md``.
"""

from vp2.models.base import (
    DEFAULT_MAX_BATCH_SIZE,
    NUM_CONTEXT,
    NUM_FUTURE,
    CheckedModel,
    LossOutput,
    ModelContractError,
    PerceptualLoss,
    TrainingDefaults,
    VideoPredictionModel,
    VideoPredictor,
    check_inputs,
    check_output,
    checked,
    predict_in_chunks,
)
from vp2.models.fitvid import FitVid, FitVidConfig
from vp2.models.maskvit import MaskViT, MaskViTConfig, MaskViTTokenizer, MaskViTTokenizerConfig
from vp2.models.mcvd import MCVD, MCVDConfig
from vp2.models.registry import (
    CHECKPOINT_FORMAT,
    MODELS,
    all_variants,
    apply_overrides,
    build_model,
    latest_checkpoint,
    load_model,
    load_model_spec,
    make_config,
    model_from_config,
    model_names,
    parse_model_spec,
    parse_overrides,
    preset_names,
    read_checkpoint,
)
from vp2.models.struct_vrnn import StructVRNN, StructVRNNConfig
from vp2.models.svg_prime import SVGPrime, SVGPrimeConfig

__all__ = [
    "CHECKPOINT_FORMAT",
    "DEFAULT_MAX_BATCH_SIZE",
    "MODELS",
    "NUM_CONTEXT",
    "NUM_FUTURE",
    "CheckedModel",
    "FitVid",
    "FitVidConfig",
    "LossOutput",
    "MCVD",
    "MCVDConfig",
    "MaskViT",
    "MaskViTConfig",
    "MaskViTTokenizer",
    "MaskViTTokenizerConfig",
    "ModelContractError",
    "PerceptualLoss",
    "SVGPrime",
    "SVGPrimeConfig",
    "StructVRNN",
    "StructVRNNConfig",
    "TrainingDefaults",
    "VideoPredictionModel",
    "VideoPredictor",
    "all_variants",
    "apply_overrides",
    "build_model",
    "check_inputs",
    "check_output",
    "checked",
    "latest_checkpoint",
    "load_model",
    "load_model_spec",
    "make_config",
    "model_from_config",
    "model_names",
    "parse_model_spec",
    "parse_overrides",
    "predict_in_chunks",
    "preset_names",
    "read_checkpoint",
]
