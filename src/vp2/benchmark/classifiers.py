"""Success classifiers of the RoboDesk tasks: the networks, their data, training and shipping.

The RoboDesk planning cost (SPEC §6) adds ``10 × (−Σ_t logit)`` of a per-task success
classifier to the pixel error. This module provides

* the paper's network, :class:`PaperClassifier` (8 full-resolution 3×3 convolutions, then
  ``Linear 12288 → 1024 → 1``; about 246 M multiply-adds per 64×64 frame), and ours,
  :class:`SuccessClassifier` (four stride-2 convolutions and a small head; about 3 M), both
  ``images (M, 3, 64, 64) float in [0, 1] -> logits (M,)``;
* :func:`load_frames`: every frame of a task's trajectories in a collected dataset, labelled
  with the simulator's success flag of that frame, split by trajectory with the dataset's own
  ``mask/train`` / ``mask/valid``;
* :func:`train_classifier` (BCE with logits, Adam 1e-3, gradient norm clipped to 1, seeded) and
  :func:`evaluate` (held-out accuracy, precision, recall);
* :func:`save_classifier` / :func:`load_classifier`: small checkpoints (state dict + plain
  metadata) that load with ``torch.load(weights_only=True)``;
* :func:`register_shipped_classifiers`: registers the classifiers shipped in
  ``vp2/assets/classifiers/<task>.pt`` into :data:`vp2.benchmark.agent.CLASSIFIERS` (called when
  :mod:`vp2.benchmark` is imported); a task without a file keeps the ``pixel_only`` fallback;
* the ``vp2 train-classifier`` command (:func:`configure_parser`, :func:`run_from_args`), also
  runnable as ``python -m vp2.benchmark.classifiers``.

See ``docs/benchmark.md`` (Success classifiers) for the measured accuracy and cost.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import fcntl
import json
import logging
import math
import os
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from vp2.benchmark.agent import CLASSIFIERS, ClassifierRegistry
from vp2.data.storage import DatasetError, dataset_index, load_manifest, require_images
from vp2.envs import ROBODESK_TASKS, split_name
from vp2.envs.robodesk import DENSE_LABEL_THRESHOLD
from vp2.utils.io import atomic_path, write_json_atomic

log = logging.getLogger(__name__)

#: Where the shipped classifiers live: ``<task>.pt`` (``task`` like ``push_red``) and
#: ``metrics.json``.
ASSETS_DIR = Path(__file__).resolve().parents[1] / "assets" / "classifiers"
#: Environment variable naming another directory of classifier files to plan with instead of
#: the shipped ones (e.g. to compare classifier variants with the oracle).
CLASSIFIERS_ENV_VAR = "VP2_CLASSIFIERS_DIR"
METRICS_FILE = "metrics.json"
#: Side of the frames the classifiers are trained on (the benchmark's 64×64).
IMAGE_SIZE = 64
ARCHS: tuple[str, ...] = ("ours", "paper")
#: Checkpoint format tag.
FORMAT = "vp2-classifier/1"
#: The RoboDesk tasks that have a success classifier (all 7).
CLASSIFIER_TASKS: tuple[str, ...] = tuple(f"robodesk/{t}" for t in ROBODESK_TASKS)


# --------------------------------------------------------------------------- networks


class PaperClassifier(nn.Module):
    """The paper's success classifier (VP² appendix, Table ``classifier_architecture``).

    Eight 3×3 convolutions at full resolution (padding 1): ``3 → 32``, three residual blocks
    of two ``32 → 32`` convolutions (``x + conv(relu(conv(x)))``, each block followed by a
    ReLU), and ``32 → 3``; then ``Flatten (3·64·64 = 12288) → Linear 1024 → ReLU → Linear 1``.
    The residual connections and the 3-channel last convolution are the authors' released
    code; the paper's table lists the same eight convolutions without them (its flatten size
    12288 = 3 × 64 × 64 only fits a 3-channel last layer). About 246 M multiply-adds and
    12.7 M parameters per 64×64 frame.
    """

    arch = "paper"

    def __init__(self, image_size: int = IMAGE_SIZE, width: int = 32) -> None:
        super().__init__()
        self.image_size = image_size
        self.stem = nn.Conv2d(3, width, 3, padding=1)
        self.blocks = nn.ModuleList(
            nn.Sequential(
                nn.Conv2d(width, width, 3, padding=1),
                nn.ReLU(inplace=True),
                nn.Conv2d(width, width, 3, padding=1),
            )
            for _ in range(3)
        )
        self.last = nn.Conv2d(width, 3, 3, padding=1)
        self.head = nn.Sequential(
            nn.Flatten(),
            nn.Linear(3 * image_size * image_size, 1024),
            nn.ReLU(inplace=True),
            nn.Linear(1024, 1),
        )

    def forward(self, images: Tensor) -> Tensor:
        """``images (M, 3, S, S)`` in [0, 1] -> logits ``(M,)``."""
        x = self.stem(images)  # (M, 32, S, S)
        for block in self.blocks:
            x = F.relu(x + block(x))
        return self.head(self.last(x)).squeeze(-1)  # (M,)


class SuccessClassifier(nn.Module):
    """Our success classifier: four stride-2 3×3 convolutions and a small dense head.

    ``64² × 3 → 32² × 16 → 16² × 32 → 8² × 64 → 4² × 32``, each convolution followed by a
    ReLU, then ``Flatten (512) → Linear 32 → ReLU → Linear 1``. Flattening the 4×4 map (rather
    than pooling it away) keeps *where* things are, which is what success is about on the desk
    (a block over the edge, a drawer pulled out, a button pressed). About 3.1 M multiply-adds
    (80× fewer than :class:`PaperClassifier`) and 58 K parameters (a 0.23 MB file).
    """

    arch = "ours"

    def __init__(
        self,
        image_size: int = IMAGE_SIZE,
        widths: Sequence[int] = (16, 32, 64, 32),
        hidden: int = 32,
    ) -> None:
        super().__init__()
        if image_size % 2 ** len(widths):
            raise ValueError(f"image_size {image_size} must be divisible by {2 ** len(widths)}")
        self.image_size = image_size
        layers: list[nn.Module] = []
        in_ch = 3
        for w in widths:
            layers += [nn.Conv2d(in_ch, w, 3, stride=2, padding=1), nn.ReLU(inplace=True)]
            in_ch = w
        self.features = nn.Sequential(*layers)
        side = image_size // 2 ** len(widths)
        self.head = nn.Sequential(
            nn.Flatten(),
            nn.Linear(in_ch * side * side, hidden),
            nn.ReLU(inplace=True),
            nn.Linear(hidden, 1),
        )

    def forward(self, images: Tensor) -> Tensor:
        """``images (M, 3, S, S)`` in [0, 1] -> logits ``(M,)``."""
        return self.head(self.features(images)).squeeze(-1)  # (M,)


_NETWORKS: dict[str, type[nn.Module]] = {"ours": SuccessClassifier, "paper": PaperClassifier}


def build_classifier(arch: str, image_size: int = IMAGE_SIZE) -> nn.Module:
    """A freshly initialised classifier network (``"ours"`` or ``"paper"``)."""
    if arch not in _NETWORKS:
        raise ValueError(f"unknown classifier arch {arch!r}; choose one of {', '.join(ARCHS)}")
    return _NETWORKS[arch](image_size=image_size)


def multiply_adds(model: nn.Module, image_size: int = IMAGE_SIZE) -> int:
    """Multiply-adds of one frame through the convolutions and linear layers of ``model``."""
    total = 0

    def count(module: nn.Module, inputs: tuple[Tensor, ...], output: Tensor) -> None:
        nonlocal total
        if isinstance(module, nn.Conv2d):
            kernel = module.in_channels // module.groups * math.prod(module.kernel_size)
            total += output[0].numel() * kernel
        elif isinstance(module, nn.Linear):
            total += module.in_features * module.out_features

    hooks = [m.register_forward_hook(count) for m in model.modules()]
    try:
        with torch.no_grad():
            model(torch.zeros(1, 3, image_size, image_size))
    finally:
        for h in hooks:
            h.remove()
    return total


class FrameClassifierModule(nn.Module):
    """What the planning cost calls: a trained network with the benchmark's input contract.

    ``images (M, 3, H, W)`` float in [0, 1] -> success logits ``(M,)``. Frames of another size
    are resized to the network's training size (area average down, bilinear up); inputs are made
    contiguous (a channels-last view changes convolution rounding on the CPU).
    """

    def __init__(self, network: nn.Module, task: str, meta: dict[str, Any]) -> None:
        super().__init__()
        self.network = network
        self.task = task
        self.meta = meta
        self.image_size = int(meta.get("image_size", IMAGE_SIZE))

    def forward(self, images: Tensor) -> Tensor:
        if images.ndim != 4 or images.shape[1] != 3:
            raise ValueError(
                f"{self.task} classifier: images must have shape (M, 3, H, W), "
                f"got {tuple(images.shape)}"
            )
        if images.shape[-2:] != (self.image_size, self.image_size):
            size = (self.image_size, self.image_size)
            if images.shape[-1] > self.image_size:  # box filter: 128 -> 64 averages 2x2 blocks
                images = F.interpolate(images, size=size, mode="area")
            else:
                images = F.interpolate(images, size=size, mode="bilinear", align_corners=False)
        return self.network(images.contiguous())  # (M,)


# --------------------------------------------------------------------------- data


def short_task(task: str) -> str:
    """``"robodesk/push_red"`` or ``"push_red"`` -> ``"push_red"`` (checked)."""
    full = task if "/" in task else f"robodesk/{task}"
    env, name = split_name(full)
    if env != "robodesk":
        raise ValueError(f"{task}: success classifiers exist for RoboDesk tasks only")
    return name


@dataclasses.dataclass
class FrameSet:
    """Frames of one task and split with their success labels.

    Attributes:
        images: ``(N, H, W, 3)`` uint8.
        labels: ``(N,)`` bool, the simulator's success flag of each frame.
        trajectories: ``(N,)`` int64, the dataset index of each frame's trajectory.
        steps: ``(N,)`` int64, the frame's index in its trajectory (0 = the reset frame).
    """

    images: np.ndarray
    labels: np.ndarray
    trajectories: np.ndarray
    steps: np.ndarray

    def __len__(self) -> int:
        return len(self.labels)

    @property
    def positives(self) -> int:
        return int(self.labels.sum())

    @property
    def num_trajectories(self) -> int:
        return len(np.unique(self.trajectories))

    def describe(self) -> dict[str, int]:
        return {
            "trajectories": self.num_trajectories,
            "frames": len(self),
            "positives": self.positives,
            "positive_trajectories": len(np.unique(self.trajectories[self.labels])),
        }


#: Frame labels a classifier can be trained on (SPEC §6): the simulator's strict success flag,
#: or the paper's label, the dense reward summed over the step's 50 action repeats >= 30.
LABELS = {
    "success": "simulator success flag of each frame (success[k] of obs/rgb[k])",
    "dense": "paper: dense reward summed over the step's 50 action repeats >= 30 "
    "(dense_reward[k] of obs/rgb[k])",
}


def load_frames(root: str | Path, task: str, split: str, label: str = "success") -> FrameSet:
    """Every frame of every ``task`` trajectory of one split of a collected dataset.

    Frame ``k`` of a trajectory is ``obs/rgb[k]``, rendered from ``states[k]``. With
    ``label="success"`` its label is ``success[k]``, the simulator's success flag of that state
    (``k = 0`` is the reset frame); with ``label="dense"`` the paper's: ``dense_reward[k] >=
    30`` (:data:`vp2.envs.robodesk.DENSE_LABEL_THRESHOLD`).
    The split is the dataset's own ``mask/train`` / ``mask/valid`` (by trajectory), so no
    trajectory contributes frames to both.

    Args:
        root: Dataset directory (from ``vp2 collect``).
        task: ``"robodesk/<task>"`` or ``"<task>"``.
        split: ``"train"`` or ``"valid"``.

    Raises:
        DatasetError: if the dataset holds no ``split`` trajectory of the task.
    """
    if split not in ("train", "valid"):
        raise ValueError(f"split must be 'train' or 'valid', got {split!r}")
    if label not in LABELS:
        raise ValueError(f"label must be one of {', '.join(LABELS)}, got {label!r}")
    full = f"robodesk/{short_task(task)}"
    records = [r for r in dataset_index(root) if r.task == full and r.split == split]
    if not records:
        raise DatasetError(f"{root}: no {split} trajectories of {full}")
    require_images(root, records)
    images, labels, trajectories, steps = [], [], [], []
    by_file: dict[Path, list[str]] = {}
    for r in records:
        by_file.setdefault(r.path, []).append(r.name)
    for path, names in by_file.items():
        with h5py.File(path, "r") as f:
            for name in names:
                g = f["data"][name]
                rgb = g["obs/rgb"][()]  # (T + 1, H, W, 3)
                if label == "dense":
                    if "dense_reward" not in g:
                        raise DatasetError(
                            f"{path}:{name}: no dense_reward (collected before it was "
                            "recorded); re-collect with `vp2 collect robodesk`, or use "
                            "--label success"
                        )
                    success = g["dense_reward"][()] >= DENSE_LABEL_THRESHOLD
                else:
                    success = g["success"][()].astype(bool)  # (T + 1,)
                if len(rgb) != len(success):
                    raise DatasetError(
                        f"{path}:{name}: {len(rgb)} frames but {len(success)} success flags"
                    )
                images.append(rgb)
                labels.append(success)
                trajectories.append(np.full(len(rgb), int(name.split("_")[1]), np.int64))
                steps.append(np.arange(len(rgb), dtype=np.int64))
    order = np.argsort(np.concatenate(trajectories) * 10_000 + np.concatenate(steps), kind="stable")
    return FrameSet(
        images=np.concatenate(images)[order],
        labels=np.concatenate(labels)[order],
        trajectories=np.concatenate(trajectories)[order],
        steps=np.concatenate(steps)[order],
    )


def to_tensor(images: np.ndarray, device: torch.device | str = "cpu") -> Tensor:
    """``(N, H, W, 3)`` uint8 -> contiguous ``(N, 3, H, W)`` float32 in [0, 1]."""
    x = torch.from_numpy(np.ascontiguousarray(images)).to(device)
    return x.permute(0, 3, 1, 2).contiguous().float().div_(255.0)


# --------------------------------------------------------------------------- training


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """How one classifier is trained (the defaults are the shipped classifiers').

    Attributes:
        arch: ``"ours"`` or ``"paper"``.
        steps: Gradient steps (paper: 3,000).
        batch_size: Frames per step, drawn uniformly with replacement from the train frames.
        lr: Adam learning rate (model-specs §6: 1e-3).
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
    grad_clip: float = 1.0
    shift: int = 2
    pos_weight: float | str | None = None
    seed: int = 0
    device: str = "cpu"
    label: str = "success"

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
    config: TrainConfig,
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
        model = build_classifier(config.arch, image_size).to(device)
    generator = torch.Generator().manual_seed(config.seed + 1)
    images = torch.from_numpy(np.ascontiguousarray(train.images))  # (N, H, W, 3) uint8, CPU
    labels = torch.from_numpy(train.labels.astype(np.float32))  # (N,)
    pos_weight = config.resolved_pos_weight(train)
    loss_fn = nn.BCEWithLogitsLoss(
        pos_weight=None if pos_weight is None else torch.tensor(pos_weight, device=device)
    )
    optimizer = torch.optim.Adam(model.parameters(), lr=config.lr)
    model.train()
    running, count = 0.0, 0
    report = on_log or (lambda step, loss: log.info("step %d: loss %.4f", step, loss))
    for step in range(1, config.steps + 1):
        idx = torch.randint(len(train), (config.batch_size,), generator=generator)
        x = images[idx].to(device).permute(0, 3, 1, 2).contiguous().float().div_(255.0)
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


def classification_metrics(logits: np.ndarray, labels: np.ndarray) -> dict[str, Any]:
    """Accuracy, precision and recall of ``logit > 0`` against boolean labels.

    Precision is ``None`` when nothing is predicted positive and recall ``None`` when there is
    no positive frame (undefined, rather than a misleading 0 or 1).
    """
    predicted = np.asarray(logits) > 0
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
    return classification_metrics(predict_logits(classifier, frames.images), frames.labels)


# --------------------------------------------------------------------------- checkpoints


def save_classifier(path: str | Path, model: nn.Module, meta: dict[str, Any]) -> Path:
    """Writes ``{"format", "state_dict", "meta"}`` atomically; ``meta`` must be plain data.

    ``meta`` must hold ``arch``, ``task`` and ``image_size``; the rest (metrics, data
    description, training command) is kept for readers.
    """
    for key in ("arch", "task", "image_size"):
        if key not in meta:
            raise ValueError(f"classifier metadata needs {key!r}")
    json.dumps(meta)  # plain data only: what weights_only loading accepts
    state = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    path = Path(path)
    with atomic_path(path) as tmp:
        torch.save({"format": FORMAT, "state_dict": state, "meta": meta}, tmp)
    return path


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The checkpoint dict of a classifier file (``weights_only`` loading), checked."""
    path = Path(path)
    try:
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
    except FileNotFoundError:
        raise
    except Exception as exc:  # a truncated or foreign file
        raise ValueError(f"{path}: not a readable classifier checkpoint ({exc})") from exc
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise ValueError(f"{path}: not a {FORMAT} checkpoint")
    return ckpt


def load_classifier(path: str | Path, device: str | torch.device = "cpu") -> FrameClassifierModule:
    """A saved classifier, ready for the planning cost: eval mode, parameters frozen.

    Returns:
        ``images (M, 3, H, W) in [0, 1] -> logits (M,)`` on ``device``.
    """
    ckpt = read_checkpoint(path)
    meta = ckpt["meta"]
    network = build_classifier(meta["arch"], int(meta["image_size"]))
    network.load_state_dict(ckpt["state_dict"])
    module = FrameClassifierModule(network, meta["task"], meta).to(device).eval()
    module.requires_grad_(False)
    return module


def shipped_path(task: str, directory: str | Path = ASSETS_DIR) -> Path:
    """Where the classifier file of ``task`` lives (whether or not it exists)."""
    return Path(directory) / f"{short_task(task)}.pt"


def register_shipped_classifiers(
    registry: ClassifierRegistry = CLASSIFIERS, directory: str | Path | None = None
) -> list[str]:
    """Registers a loader for every task whose classifier file exists in ``directory``
    (default: ``$VP2_CLASSIFIERS_DIR`` if set, else the shipped ones).

    Cheap (files are only checked for existence; a classifier is loaded on first use by the
    registry). Called by :mod:`vp2.benchmark` on import for the shipped classifiers.

    Returns:
        The registered task names.
    """
    if directory is None:
        directory = os.environ.get(CLASSIFIERS_ENV_VAR) or ASSETS_DIR
        if not Path(directory).is_dir():
            raise FileNotFoundError(
                f"${CLASSIFIERS_ENV_VAR} = {directory} is not a directory of classifier files "
                "(vp2 train-classifier --out DIR writes one); unset it to use the shipped ones"
            )
    registered = []
    for task in CLASSIFIER_TASKS:
        path = shipped_path(task, directory)
        if path.is_file():
            registry.register(task, lambda device, path=path: load_classifier(path, device))
            registered.append(task)
    return registered


# --------------------------------------------------------------------------- command


def checkpoint_name(task: str, arch: str) -> str:
    """``push_red.pt`` for ours (the shipped name), ``push_red.paper.pt`` for the paper's."""
    return f"{short_task(task)}.pt" if arch == "ours" else f"{short_task(task)}.{arch}.pt"


def update_metrics(path: Path, arch: str, task: str, entry: dict[str, Any]) -> None:
    """Merges one ``(arch, task)`` entry into a metrics file (written atomically).

    The read-merge-write holds an exclusive lock on the directory, so that two trainings (say
    ours and the paper's, run as two processes) can share one metrics file.
    """
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path.parent, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        metrics = json.loads(path.read_text()) if path.exists() else {}
        metrics.setdefault(arch, {})[short_task(task)] = entry
        write_json_atomic(path, metrics)
    finally:
        os.close(fd)  # releases the lock


def train_task(
    root: str | Path, task: str, config: TrainConfig, command: str = ""
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


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 train-classifier`` arguments to ``p``."""
    p.add_argument(
        "--data", required=True, type=Path, help="dataset directory (vp2 collect robodesk)"
    )
    p.add_argument(
        "--tasks", nargs="+", default=None, help="RoboDesk tasks, e.g. push_red (default: all 7)"
    )
    p.add_argument(
        "--arch",
        nargs="+",
        choices=ARCHS,
        default=["ours"],
        help="networks to train: ours (shipped) and/or paper (for comparison)",
    )
    p.add_argument("--steps", type=int, default=3000, help="gradient steps of ours (paper: 3000)")
    p.add_argument(
        "--paper-steps",
        type=int,
        default=None,
        help="gradient steps of the paper's network (default: --steps)",
    )
    p.add_argument("--batch-size", type=int, default=64, help="frames per gradient step")
    p.add_argument(
        "--shift", type=int, default=2, help="random-shift augmentation in pixels (0: off)"
    )
    p.add_argument(
        "--pos-weight",
        default=None,
        help="positive-class loss weight: a number or 'balanced' (default: none)",
    )
    p.add_argument(
        "--label",
        choices=sorted(LABELS),
        default="success",
        help="frame label: success (the simulator's success flag) or dense (the paper's: "
        "dense reward summed over the step's 50 repeats >= 30)",
    )
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--device", default="cpu")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.add_argument(
        "--ship",
        action="store_true",
        help="write ours into the package (vp2/assets/classifiers) with metrics.json; "
        "the paper's checkpoints (50 MB each) go to --out",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        help="run directory (default: runs/classifiers); with --ship it holds only the "
        "paper's checkpoints",
    )
    return p


def _command_line(args: argparse.Namespace) -> str:
    parts = ["vp2 train-classifier", f"--data {args.data}"]
    if args.tasks:
        parts.append("--tasks " + " ".join(args.tasks))
    parts.append("--arch " + " ".join(args.arch))
    parts.append(f"--steps {args.steps}")
    if args.paper_steps is not None:
        parts.append(f"--paper-steps {args.paper_steps}")
    parts += [f"--batch-size {args.batch_size}", f"--shift {args.shift}", f"--seed {args.seed}"]
    if args.label != "success":
        parts.append(f"--label {args.label}")
    if args.pos_weight is not None:
        parts.append(f"--pos-weight {args.pos_weight}")
    if args.threads is not None:
        parts.append(f"--threads {args.threads}")
    if args.ship:
        parts.append("--ship")
    if args.out is not None:
        parts.append(f"--out {args.out}")
    return " ".join(parts)


def run_from_args(args: argparse.Namespace) -> int:
    """Runs ``vp2 train-classifier``: trains, evaluates and saves per task and arch.

    Prints one table row per (task, arch): held-out frames, positives, accuracy, precision,
    recall. Returns 0.
    """
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    pos_weight: float | str | None = args.pos_weight
    if pos_weight not in (None, "balanced"):
        pos_weight = float(pos_weight)
    tasks = [short_task(t) for t in (args.tasks or ROBODESK_TASKS)]
    run_dir = Path(args.out) if args.out is not None else Path("runs/classifiers")
    metrics_dir = ASSETS_DIR if args.ship else run_dir
    command = _command_line(args)
    print("| task | arch | held-out frames (positive) | accuracy | precision | recall | file |")
    print("|---|---|---|---|---|---|---|")
    for task in tasks:
        for arch in args.arch:
            steps = args.paper_steps if arch == "paper" and args.paper_steps else args.steps
            config = TrainConfig(
                arch=arch,
                steps=steps,
                batch_size=args.batch_size,
                shift=args.shift,
                pos_weight=pos_weight,
                seed=args.seed,
                device=args.device,
                label=args.label,
            )
            model, meta = train_task(args.data, task, config, command)
            directory = ASSETS_DIR if args.ship and arch == "ours" else run_dir
            path = save_classifier(directory / checkpoint_name(task, arch), model, meta)
            entry = {k: v for k, v in meta.items() if k != "data"}
            entry["data"] = {k: meta["data"][k] for k in ("dataset", "train", "valid")}
            entry["file"] = str(path.name if directory == metrics_dir else path)
            entry["file_bytes"] = path.stat().st_size
            update_metrics(metrics_dir / METRICS_FILE, arch, task, entry)
            m = meta["heldout"]
            print(
                f"| {task} | {arch} | {m['frames']} ({m['positives']}) | {_fmt(m['accuracy'])} "
                f"| {_fmt(m['precision'])} | {_fmt(m['recall'])} | {path} |",
                flush=True,
            )
    print(f"metrics: {metrics_dir / METRICS_FILE}")
    return 0


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.3f}"


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m vp2.benchmark.classifiers ...`` (same arguments as ``vp2 train-classifier``)."""
    parser = configure_parser(
        argparse.ArgumentParser(prog="vp2 train-classifier", description=__doc__.splitlines()[0])
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        return run_from_args(args)
    except (ValueError, DatasetError, FileNotFoundError) as exc:
        print(f"vp2 train-classifier: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
