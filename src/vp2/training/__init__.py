"""Training video prediction models on vp2 datasets.

:func:`train` takes a :class:`TrainConfig` (model name + preset + overrides, dataset, steps,
optimiser, intervals) and writes a run directory with checkpoints that
:func:`vp2.models.load_model` turns back into a model for planning. See ``docs/models.md``.

Modules: :mod:`~vp2.training.config` (the configuration), :mod:`~vp2.training.setup` (building
or resuming a run), :mod:`~vp2.training.trainer` (the loop), :mod:`~vp2.training.batches` (data
order and seeds), :mod:`~vp2.training.checkpoint` (resume files), :mod:`~vp2.training.export`
(inference-only copies), :mod:`~vp2.training.logger`, :mod:`~vp2.training.perceptual`
(LPIPS, the perceptual loss the metrics share) with :mod:`~vp2.training.lpips_weights` (its
weight files) and :mod:`~vp2.training.weight_files` (where weight files are looked for, and
how the JAX packages' pickles are read; the I3D of FVD uses it too).
"""

from typing import Any

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


def __getattr__(name: str) -> Any:
    # The exports are loaded on first use, so that importing one submodule (the metrics stage
    # imports `vp2.training.perceptual`) does not load the models and the training loop.
    if name not in __all__:
        raise AttributeError(f"module 'vp2.training' has no attribute {name!r}")
    from vp2.models import registry
    from vp2.training import batches, config, perceptual, trainer

    for module in (config, trainer, batches, perceptual, registry):
        if name in vars(module):
            globals()[name] = vars(module)[name]
            return globals()[name]
    raise AttributeError(f"module 'vp2.training' has no attribute {name!r}")
