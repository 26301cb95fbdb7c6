"""Training and evaluating success classifiers.

:func:`train_classifier` trains a fresh network on labelled frames (BCE with logits, Adam 1e-3,
gradient norm clipped to 1, seeded); :func:`evaluate` gives held-out accuracy, precision and
recall; :func:`train_task` does both for one task of a collected dataset and describes the
result in the checkpoint's metadata.
"""

from __future__ import annotations

import dataclasses
import datetime
import logging
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from vp2.classifiers.data import LABELS, FrameSet, load_frames, to_tensor
from vp2.classifiers.networks import build_classifier, multiply_adds
from vp2.classifiers.registry import short_task
from vp2.data.storage import load_manifest
from vp2.utils.seeds import check_seed
from vp2.utils.tensors import images_to_float

log = logging.getLogger(__name__)


#: Learning-rate schedules of :class:`ClassifierTrainConfig`.
LR_SCHEDULES = ("constant", "cosine")


def learning_rate(config: ClassifierTrainConfig, step: int) -> float:
    """The learning rate of 1-based ``step`` under ``config.lr_schedule``."""
    if config.lr_schedule == "constant":
        return config.lr
    return 0.5 * config.lr * (1.0 + math.cos(math.pi * (step - 1) / config.steps))


@dataclasses.dataclass(frozen=True)
class ClassifierTrainConfig:
    """How one classifier is trained (the defaults are the shipped classifiers').

    Attributes:
        arch: ``"ours"`` or ``"paper"``.
        steps: Gradient steps (paper: 3,000).
        batch_size: Frames per step, drawn uniformly with replacement from the train frames.
        lr: Adam learning rate (model-specs §6: 1e-3).
        lr_schedule: ``"constant"`` (the paper's) or ``"cosine"``: the rate decays from ``lr``
            to 0 along a half cosine over ``steps``.
        width: Channel multiplier of ours (:func:`vp2.classifiers.networks.build_classifier`).
        grad_clip: Gradient norm clip (model-specs §6: 1).
        shift: Augmentation: random translation of each training frame by up to ``shift``
            pixels (edge pixels repeated); 0 disables it.
        pos_weight: Weight of the positive class in the loss; ``None`` for the unweighted
            loss (as the paper), ``"balanced"`` for ``negatives / positives`` of the train set.
        seed: Seeds the initialisation, the batches and the augmentation.
        device: Training device.
        label: Frame label, a key of :data:`LABELS`.
    """

    arch: str = "ours"
    steps: int = 3000
    batch_size: int = 64
    lr: float = 1e-3
    lr_schedule: str = "constant"
    width: int = 1
    grad_clip: float = 1.0
    shift: int = 2
    pos_weight: float | str | None = None
    seed: int = 0
    device: str = "cpu"
    label: str = "success"

    def __post_init__(self) -> None:
        check_seed(self.seed)
        if self.lr_schedule not in LR_SCHEDULES:
            raise ValueError(
                f"lr_schedule must be one of {', '.join(LR_SCHEDULES)}, got {self.lr_schedule!r}"
            )

    def resolved_pos_weight(self, train: FrameSet) -> float | None:
        if self.pos_weight is None:
            return None
        if self.pos_weight == "balanced":
            return (len(train) - train.positives) / max(train.positives, 1)
        return float(self.pos_weight)


def random_shift(images: Tensor, shift: int, generator: torch.Generator) -> Tensor:
    """Translates every image of ``(B, C, H, W)`` by its own random offset in ``[-shift, shift]``.

    Pixels shifted in from outside repeat the edge. One gather for the whole batch.
    """
    if shift <= 0:
        return images
    b, c, h, w = images.shape
    padded = F.pad(images, (shift, shift, shift, shift), mode="replicate")  # (B, C, H+2s, W+2s)
    offsets = torch.randint(0, 2 * shift + 1, (b, 2), generator=generator).to(images.device)
    rows = offsets[:, 0, None] + torch.arange(h, device=images.device)  # (B, H)
    cols = offsets[:, 1, None] + torch.arange(w, device=images.device)  # (B, W)
    batch = torch.arange(b, device=images.device)[:, None, None, None]
    channel = torch.arange(c, device=images.device)[None, :, None, None]
    return padded[batch, channel, rows[:, None, :, None], cols[:, None, None, :]]  # (B, C, H, W)


def train_classifier(
    train: FrameSet,
    config: ClassifierTrainConfig,
    log_every: int = 500,
    on_log: Callable[[int, float], None] | None = None,
) -> nn.Module:
    """Trains a fresh classifier on frames: BCE with logits, Adam, clipped gradients.

    Args:
        train: Training frames and labels.
        config: Architecture, steps and the rest; fully determines the result on one device.
        log_every: Steps between loss reports (mean loss since the last one).
        on_log: ``(step, mean loss)`` callback; defaults to the module logger.

    Returns:
        The trained network in eval mode, on ``config.device``.
    """
    if len(train) == 0:
        raise ValueError("no training frames")
    device = torch.device(config.device)
    image_size = int(train.images.shape[1])
    # Initialisation from a forked global generator seeded by the config: reproducible, and it
    # leaves the caller's global random state untouched.
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(config.seed)
        model = build_classifier(config.arch, image_size, config.width).to(device)
    generator = torch.Generator().manual_seed(config.seed + 1)
    images = torch.from_numpy(np.ascontiguousarray(train.images))  # (N, H, W, 3) uint8, CPU
    labels = torch.from_numpy(train.training_targets())  # (N,) in [0, 1]
    pos_weight = config.resolved_pos_weight(train)
    loss_fn = nn.BCEWithLogitsLoss(
        pos_weight=None if pos_weight is None else torch.tensor(pos_weight, device=device)
    )
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    model.train()
    running, count = 0.0, 0
    report = on_log or (lambda step, loss: log.info("step %d: loss %.4f", step, loss))
    for step in range(1, config.steps + 1):
        for group in optimizer.param_groups:
            group["lr"] = learning_rate(config, step)
        idx = torch.randint(len(train), (config.batch_size,), generator=generator)
        x = images_to_float(images[idx], device, channels_first=True)  # (B, 3, H, W)
        x = random_shift(x, config.shift, generator)  # (B, 3, H, W)
        y = labels[idx].to(device)  # (B,)
        loss = loss_fn(model(x), y)
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        nn.utils.clip_grad_norm_(model.parameters(), config.grad_clip)
        optimizer.step()
        running += loss.item()
        count += 1
        if step % log_every == 0 or step == config.steps:
            report(step, running / count)
            running, count = 0.0, 0
    return model.eval()


@torch.no_grad()
def predict_logits(
    classifier: Callable[[Tensor], Tensor], images: np.ndarray, batch_size: int = 500
) -> np.ndarray:
    """Logits ``(N,)`` float32 of ``(N, H, W, 3)`` uint8 frames, in batches."""
    device = next(iter(getattr(classifier, "parameters", lambda: iter([]))()), None)
    device = device.device if device is not None else torch.device("cpu")
    out = [
        classifier(to_tensor(images[i : i + batch_size], device)).float().cpu()
        for i in range(0, len(images), batch_size)
    ]
    return torch.cat(out).numpy() if out else np.zeros(0, np.float32)


def classification_metrics(
    logits: np.ndarray, labels: np.ndarray, threshold: float = 0.0
) -> dict[str, Any]:
    """Accuracy, precision and recall of ``logit > threshold`` against boolean labels.

    Precision is ``None`` when nothing is predicted positive and recall ``None`` when there is
    no positive frame (undefined, rather than a misleading 0 or 1).
    """
    predicted = np.asarray(logits) > threshold
    labels = np.asarray(labels, bool)
    tp = int((predicted & labels).sum())
    fp = int((predicted & ~labels).sum())
    fn = int((~predicted & labels).sum())
    tn = int((~predicted & ~labels).sum())
    n = tp + fp + fn + tn
    return {
        "frames": n,
        "positives": tp + fn,
        "accuracy": (tp + tn) / n if n else None,
        "precision": tp / (tp + fp) if tp + fp else None,
        "recall": tp / (tp + fn) if tp + fn else None,
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "tn": tn,
    }


def evaluate(classifier: Callable[[Tensor], Tensor], frames: FrameSet) -> dict[str, Any]:
    """Held-out metrics of a classifier on labelled frames (see :func:`classification_metrics`)."""
    return classification_metrics(
        predict_logits(classifier, frames.images), frames.labels, frames.threshold
    )


def train_task(
    root: str | Path, task: str, config: ClassifierTrainConfig, command: str = ""
) -> tuple[nn.Module, dict[str, Any]]:
    """Trains and evaluates one task's classifier.

    Returns:
        The network and its metadata (arch, task, image size, held-out metrics, data
        description, training settings and time, command).
    """
    train = load_frames(root, task, "train", config.label)
    valid = load_frames(root, task, "valid", config.label)
    manifest = load_manifest(root)
    full = f"robodesk/{short_task(task)}"
    log.info(
        "%s [%s]: %d train frames (%d positive), %d held-out (%d positive)",
        full,
        config.arch,
        len(train),
        train.positives,
        len(valid),
        valid.positives,
    )
    start = time.perf_counter()
    model = train_classifier(
        train,
        config,
        on_log=lambda s, loss: log.info("%s [%s] step %d: loss %.4f", full, config.arch, s, loss),
    )
    seconds = time.perf_counter() - start
    metrics = evaluate(model, valid)
    train_metrics = evaluate(model, train)
    meta = {
        "arch": config.arch,
        "task": full,
        "image_size": int(train.images.shape[1]),
        "width": config.width,
        "heldout": metrics,
        "train": {k: train_metrics[k] for k in ("accuracy", "precision", "recall")},
        "data": {
            "dataset": str(root),
            "collection": manifest.get("config", {}),
            "label": LABELS[config.label],
            "split": "the dataset's mask/train and mask/valid (by trajectory)",
            "train": train.describe(),
            "valid": valid.describe(),
        },
        "training": {
            **dataclasses.asdict(config),
            "resolved_pos_weight": config.resolved_pos_weight(train),
            "seconds": round(seconds, 1),
            "torch_threads": torch.get_num_threads(),
        },
        "parameters": sum(p.numel() for p in model.parameters()),
        "multiply_adds_per_frame": multiply_adds(model.cpu(), int(train.images.shape[1])),
        "command": command,
        "date": datetime.date.today().isoformat(),
    }
    model.to(config.device)
    return model, meta
