"""Training logs: a CSV file always, TensorBoard when it is installed, PNG prediction grids.

``metrics.csv`` has one row per logged scalar (``step,tag,value,wall_time``), so tags can be
added without changing the header; ``pandas.read_csv(...).pivot(index="step", columns="tag")``
gives the wide table.
"""

from __future__ import annotations

import csv
import logging
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch
from PIL import Image
from torch import Tensor

from vp2.utils.io import atomic_path

log = logging.getLogger(__name__)

CSV_NAME = "metrics.csv"
_HEADER = ["step", "tag", "value", "wall_time"]


class MetricsLogger:
    """Appends scalars to ``<out_dir>/metrics.csv`` and, if available, TensorBoard.

    Args:
        out_dir: Run directory.
        resume_step: When resuming, rows logged after this step (by the interrupted run,
            past its last checkpoint) are dropped so the log matches the resumed run.
        tensorboard: Also write TensorBoard events (``<out_dir>/tb``) if ``tensorboard`` is
            importable; it is an optional dependency.
    """

    def __init__(
        self,
        out_dir: str | os.PathLike[str],
        resume_step: int | None = None,
        tensorboard: bool = True,
    ):
        self.path = Path(out_dir) / CSV_NAME
        self.path.parent.mkdir(parents=True, exist_ok=True)
        if resume_step is not None and self.path.exists():
            with self.path.open(newline="") as f:
                rows = [r for r in csv.DictReader(f) if int(r["step"]) <= resume_step]
            with atomic_path(self.path) as tmp, tmp.open("w", newline="") as f:
                writer = csv.DictWriter(f, _HEADER)
                writer.writeheader()
                writer.writerows(rows)
        elif not self.path.exists() or resume_step is None:
            with self.path.open("w", newline="") as f:
                csv.writer(f).writerow(_HEADER)
        self._file = self.path.open("a", newline="")
        self._csv = csv.writer(self._file)
        self._tb: Any = None
        if tensorboard:
            try:
                from torch.utils.tensorboard import SummaryWriter
            except ImportError:
                log.info(
                    "tensorboard not installed; logging to %s only (pip install 'vp2[tensorboard]')",
                    self.path,
                )
            else:
                self._tb = SummaryWriter(str(Path(out_dir) / "tb"), purge_step=resume_step)

    def log(self, step: int, scalars: dict[str, float]) -> None:
        now = time.time()
        for tag, value in scalars.items():
            self._csv.writerow([step, tag, f"{float(value):.8g}", f"{now:.3f}"])
            if self._tb is not None:
                self._tb.add_scalar(tag, float(value), step)
        self._file.flush()

    def log_image(self, step: int, tag: str, image: np.ndarray) -> None:
        """An ``(H, W, 3)`` uint8 image, to TensorBoard only (PNG files are written apart)."""
        if self._tb is not None:
            self._tb.add_image(tag, image, step, dataformats="HWC")

    def close(self) -> None:
        self._file.close()
        if self._tb is not None:
            self._tb.close()


def prediction_grid(true_frames: Tensor, predicted: Tensor, border: int = 1) -> np.ndarray:
    """A picture of predictions: for each clip a row of true frames above a row of predicted.

    Args:
        true_frames: ``(N, C + T, 3, H, W)`` in [0, 1], context then future.
        predicted: ``(N, T, 3, H, W)`` in [0, 1]; the predicted row repeats the context frames.
        border: Pixels of white between frames.

    Returns:
        ``(2N(H + border), (C + T)(W + border), 3)`` uint8.
    """
    n, total = true_frames.shape[:2]
    context = total - predicted.shape[1]
    pred_row = torch.cat([true_frames[:, :context], predicted.to(true_frames)], 1)
    rows = torch.stack([true_frames, pred_row], 1).flatten(0, 1)  # (2N, C + T, 3, H, W)
    rows = torch.nn.functional.pad(rows.float().cpu(), (0, border, 0, border), value=1.0)
    _, _, _, h, w = rows.shape
    grid = rows.permute(0, 3, 1, 4, 2).reshape(2 * n * h, total * w, 3)
    return (grid.clamp(0, 1) * 255 + 0.5).to(torch.uint8).numpy()


def save_png(path: str | os.PathLike[str], image: np.ndarray) -> Path:
    """Writes an ``(H, W, 3)`` uint8 image as PNG, atomically."""
    with atomic_path(path) as tmp:
        Image.fromarray(image).save(tmp, format="PNG")
    return Path(path)
