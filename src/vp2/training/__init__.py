"""Training video prediction models on vp2 datasets.

:func:`train` takes a :class:`TrainConfig` (model name + preset + overrides, dataset, steps,
optimiser, intervals) and writes a run directory with checkpoints that
:func:`vp2.models.load_model` turns back into a model for planning. See ``docs/models.md``.
"""

from vp2.models.registry import load_model, load_model_spec, parse_model_spec, parse_overrides
from vp2.training.trainer import (
    PERCEPTUAL_LOSSES,
    StepBatchSampler,
    TrainConfig,
    TrainResult,
    seed_torch,
    train,
    validate,
)

__all__ = [
    "PERCEPTUAL_LOSSES",
    "StepBatchSampler",
    "TrainConfig",
    "TrainResult",
    "load_model",
    "load_model_spec",
    "parse_model_spec",
    "parse_overrides",
    "seed_torch",
    "train",
    "validate",
]
