"""Success classifiers of the RoboDesk tasks: the networks, their data, training and shipping.

The RoboDesk planning cost (SPEC §6) adds ``10 × (−Σ_t logit)`` of a per-task success
classifier to the pixel error. This package provides

* ``networks.py``: the paper's network, :class:`PaperClassifier` (8 full-resolution 3×3
  convolutions, then ``Linear 12288 → 1024 → 1``; about 246 M multiply-adds per 64×64 frame),
  and ours, :class:`SuccessClassifier` (four stride-2 convolutions and a small head; about
  3 M), both ``images (M, 3, 64, 64) float in [0, 1] -> logits (M,)``;
* ``data.py``: :func:`load_frames`, every frame of a task's trajectories in a collected
  dataset, labelled with the simulator's success flag of that frame, split by trajectory with
  the dataset's own ``mask/train`` / ``mask/valid``;
* ``train.py``: :func:`train_classifier` (BCE with logits, Adam 1e-3, gradient norm clipped to
  1, seeded) and :func:`evaluate` (held-out accuracy, precision, recall);
* ``checkpoint.py``: :func:`save_classifier` / :func:`load_classifier`, small checkpoints
  (state dict + plain metadata) that load with ``torch.load(weights_only=True)``;
* ``registry.py``: :data:`CLASSIFIERS`, where the planning cost looks a task's classifier up;
  the classifiers shipped in ``vp2/assets/classifiers/<task>.pt`` are registered into it when
  it is imported (:func:`register_shipped_classifiers`); a task without a file keeps the
  ``pixel_only`` fallback;
* the ``vp2 train-classifier`` command lives in :mod:`vp2.cli.train_classifier`.

See ``docs/classifiers.md`` (figures in ``docs/measurements.md``).
"""

from vp2.classifiers.checkpoint import (
    FORMAT,
    load_classifier,
    read_classifier_checkpoint,
    save_classifier,
)
from vp2.classifiers.data import LABELS, FrameSet, load_frames, to_tensor
from vp2.classifiers.networks import (
    ARCHS,
    IMAGE_SIZE,
    FrameClassifierModule,
    PaperClassifier,
    SuccessClassifier,
    build_classifier,
    multiply_adds,
)
from vp2.classifiers.registry import (
    ASSETS_DIR,
    CLASSIFIER_TASKS,
    CLASSIFIERS,
    CLASSIFIERS_ENV_VAR,
    METRICS_FILE,
    ClassifierLoader,
    ClassifierRegistry,
    checkpoint_name,
    register_shipped_classifiers,
    shipped_path,
    short_task,
    update_metrics,
)
from vp2.classifiers.train import (
    ClassifierTrainConfig,
    classification_metrics,
    evaluate,
    predict_logits,
    random_shift,
    train_classifier,
    train_task,
)

__all__ = [
    "ARCHS",
    "ASSETS_DIR",
    "CLASSIFIERS",
    "CLASSIFIERS_ENV_VAR",
    "CLASSIFIER_TASKS",
    "FORMAT",
    "IMAGE_SIZE",
    "LABELS",
    "METRICS_FILE",
    "ClassifierLoader",
    "ClassifierRegistry",
    "ClassifierTrainConfig",
    "FrameClassifierModule",
    "FrameSet",
    "PaperClassifier",
    "SuccessClassifier",
    "build_classifier",
    "checkpoint_name",
    "classification_metrics",
    "evaluate",
    "load_classifier",
    "load_frames",
    "multiply_adds",
    "predict_logits",
    "random_shift",
    "read_classifier_checkpoint",
    "register_shipped_classifiers",
    "save_classifier",
    "shipped_path",
    "short_task",
    "to_tensor",
    "train_classifier",
    "train_task",
    "update_metrics",
]
