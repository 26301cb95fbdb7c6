"""Video prediction models: the interface the planner uses, the trained networks, a registry.

- :mod:`vp2.models.contract`: :class:`VideoPredictionModel`, the protocol (shapes, ranges,
  dtypes in its docstring), its boundary checks, and :class:`CheckedModel`, the same checks
  around any implementation.
- :mod:`vp2.models.base`: :class:`VideoPredictor`, base class of the trainable networks,
  whose ``predict`` checks every call; :mod:`vp2.models.layers`: what the networks share.
- :func:`build_model` / :func:`load_model` (:mod:`vp2.models.registry`): a fresh model from a
  name and preset, or a trained one from a checkpoint (:mod:`vp2.models.checkpoint`, the
  format; :class:`CheckpointSpec`, the ``NAME:CHECKPOINT`` form of ``--model``).
  Training lives in :mod:`vp2.training`. See ``docs/models.md``.
"""

from vp2.models.base import LossOutput, ModelConfig, TrainingDefaults, VideoPredictor
from vp2.models.checkpoint import (
    CHECKPOINT_FORMAT,
    CheckpointError,
    latest_checkpoint,
    model_entry,
    read_model_checkpoint,
    write_model_checkpoint,
)
from vp2.models.contract import (
    DEFAULT_MAX_BATCH_SIZE,
    CheckedModel,
    ModelContractError,
    VideoPredictionModel,
    check_inputs,
    check_output,
    checked,
    predict_in_chunks,
)
from vp2.models.fitvid import FitVid, FitVidConfig
from vp2.models.layers import PerceptualLoss
from vp2.models.maskvit import MaskViT, MaskViTConfig
from vp2.models.maskvit.tokenizer import MaskViTTokenizer, MaskViTTokenizerConfig
from vp2.models.mcvd import MCVD, MCVDConfig
from vp2.models.registry import (
    MODELS,
    CheckpointSpec,
    all_variants,
    apply_overrides,
    build_model,
    load_model,
    load_model_spec,
    make_config,
    model_from_config,
    model_names,
    parse_model_spec,
    parse_overrides,
    preset_names,
)
from vp2.models.struct_vrnn import StructVRNN, StructVRNNConfig
from vp2.models.svg_prime import SVGPrime, SVGPrimeConfig
from vp2.spec import NUM_CONTEXT, NUM_FUTURE

__all__ = [
    "CHECKPOINT_FORMAT",
    "DEFAULT_MAX_BATCH_SIZE",
    "MODELS",
    "NUM_CONTEXT",
    "NUM_FUTURE",
    "CheckedModel",
    "CheckpointError",
    "CheckpointSpec",
    "FitVid",
    "FitVidConfig",
    "LossOutput",
    "MCVD",
    "MCVDConfig",
    "MaskViT",
    "MaskViTConfig",
    "MaskViTTokenizer",
    "MaskViTTokenizerConfig",
    "ModelConfig",
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
    "model_entry",
    "model_from_config",
    "model_names",
    "parse_model_spec",
    "parse_overrides",
    "predict_in_chunks",
    "preset_names",
    "read_model_checkpoint",
    "write_model_checkpoint",
]
