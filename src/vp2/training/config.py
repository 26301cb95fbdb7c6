"""What a training run is: :class:`TrainConfig` (everything that determines it, saved with
every checkpoint and compared on resume) and :class:`TrainResult` (what
:func:`~vp2.training.train` returns).
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

from vp2.utils.seeds import check_seed

#: Fields that may change when resuming: how long and how the run is observed, not what it
#: computes.
RESUMABLE_CHANGES = frozenset(
    {
        "steps",
        "max_minutes",
        "resume",
        "workers",
        "progress",
        "eval_interval",
        "eval_batches",
        "ckpt_interval",
        "keep_checkpoints",
        "log_interval",
        "tensorboard",
        "out_dir",
    }
)


@dataclasses.dataclass
class TrainConfig:
    """Everything that determines a training run.

    Attributes:
        model: Registered model name (``"svg_prime"``, ``"fitvid"``).
        dataset: Dataset directory (from ``vp2 collect``); trained on its ``train`` split,
            validated on its ``valid`` split.
        out_dir: Run directory (created).
        preset: Model size preset (``None``: the model's default); see
            :func:`vp2.models.preset_names`.
        model_overrides: Config field overrides, e.g. ``{"beta": 1e-3}``; strings are
            converted to the field's type (command-line ``key=value``). ``action_dim`` and
            ``image_size`` come from the dataset.
        tasks: Train on these data streams only (``None``: all).
        max_trajectories: Use only the dataset's first N trajectories (data-quantity studies).
        steps: Total optimisation steps (the paper: 153 K).
        max_minutes: A training time budget: the run stops after the first optimisation step at
            which its accumulated training wall time reaches it (or at ``steps``, whichever
            comes first), and ends as at ``steps`` (validation, final checkpoint). Time counts
            from the start of each session's training loop; set-up, validation and checkpoint
            writing are left out. It is stored in every checkpoint, so a resumed run counts
            what its earlier sessions spent up to their last checkpoint. ``None``: no budget.
        batch_size: Clips per step (the paper: 32).
        lr: Learning rate (``None``: the model's default, 3e-4 for both).
        optimizer: ``"adam"`` or ``"adamw"`` (``None``: the model's default, Adam).
        weight_decay: Weight decay (``None``: the model's default, 0).
        grad_clip: Max global gradient norm; ``None``: the model's default (FitVid 100, SVG′
            none); ``<= 0``: off.
        seed: Seeds weights, data order and sampling noise.
        perceptual: Name of an extra perceptual loss in :data:`~vp2.training.perceptual.PERCEPTUAL_LOSSES` (or pass a
            callable to :func:`~vp2.training.train`).
        perceptual_weight: Its weight (the paper: 1 and 10 with LPIPS).
        eval_interval: Steps between validations (and prediction grids); 0 = only at the end.
        eval_batches: Validation batches per validation.
        ckpt_interval: Steps between checkpoints; one is always written at the end.
        keep_checkpoints: Newest checkpoints kept on disk.
        log_interval: Steps between training-loss log rows.
        workers: DataLoader worker processes (0 = load in the training process).
        device: ``"cuda"``, ``"cpu"``, ...; ``None``: CUDA if available.
        amp: Mixed precision (bf16 if supported, else fp16 with gradient scaling); ``None``:
            on for CUDA, off otherwise.
        tensorboard: Also log to TensorBoard when it is installed.
        progress: Show a progress bar (steps/s, ETA).
        resume: Continue from the newest checkpoint in ``out_dir`` (its configuration must
            match, except ``steps`` and logging settings). Without it, a run directory that
            already has checkpoints is refused.
    """

    model: str
    dataset: str
    out_dir: str
    preset: str | None = None
    model_overrides: dict[str, Any] = dataclasses.field(default_factory=dict)
    tasks: list[str] | None = None
    max_trajectories: int | None = None
    steps: int = 100_000
    max_minutes: float | None = None
    batch_size: int = 32
    lr: float | None = None
    optimizer: str | None = None
    weight_decay: float | None = None
    grad_clip: float | None = None
    seed: int = 0
    perceptual: str | None = None
    perceptual_weight: float = 0.0
    eval_interval: int = 2_000
    eval_batches: int = 4
    ckpt_interval: int = 5_000
    keep_checkpoints: int = 2
    log_interval: int = 50
    workers: int = 2
    device: str | None = None
    amp: bool | None = None
    tensorboard: bool = True
    progress: bool = True
    resume: bool = False

    def __post_init__(self) -> None:
        self.dataset, self.out_dir = str(self.dataset), str(self.out_dir)
        self.tasks = list(self.tasks) if self.tasks is not None else None
        self.model_overrides = dict(self.model_overrides)
        for name in ("steps", "batch_size", "eval_batches", "keep_checkpoints", "log_interval"):
            if getattr(self, name) <= 0:
                raise ValueError(f"{name} must be > 0, got {getattr(self, name)}")
        if self.eval_interval < 0 or self.ckpt_interval < 0 or self.workers < 0:
            raise ValueError("eval_interval, ckpt_interval and workers must be >= 0")
        if self.max_minutes is not None and not self.max_minutes > 0:
            raise ValueError(f"max_minutes must be > 0 (or None), got {self.max_minutes}")
        if self.perceptual_weight < 0:
            raise ValueError(f"perceptual_weight must be >= 0, got {self.perceptual_weight}")
        check_seed(self.seed)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> TrainConfig:
        known = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in known})


@dataclasses.dataclass
class TrainResult:
    """What :func:`~vp2.training.train` returns."""

    out_dir: Path
    checkpoint: Path  # the final checkpoint
    step: int
    train_metrics: dict[str, float]  # of the last step
    valid_metrics: dict[str, float]  # of the last validation (empty without a valid split)
    train_minutes: float = 0.0  # training wall time of all sessions, up to the final checkpoint
    budget_reached: bool = False  # stopped by ``max_minutes`` (before or at ``steps``)


def check_resumable(config: TrainConfig, saved: dict[str, Any], where: Path) -> None:
    """Refuses to resume from the checkpoint ``where`` (whose run had the configuration
    ``saved``) when a field outside :data:`RESUMABLE_CHANGES` differs from ``config``."""
    current = config.to_dict()
    diffs = {
        k: (saved.get(k), v)
        for k, v in current.items()
        if k not in RESUMABLE_CHANGES and saved.get(k) != v
    }
    if diffs:
        detail = ", ".join(f"{k}: checkpoint {a!r} vs now {b!r}" for k, (a, b) in diffs.items())
        raise ValueError(f"cannot resume from {where}: the configuration changed ({detail})")
