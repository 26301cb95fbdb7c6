"""The GIFs of a trial: its execution next to the goal, and the chosen plans' predictions."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from vp2.run.run_dir import GIF_SUFFIX, RunDir
from vp2.run.trial import TrialResult
from vp2.utils.io import atomic_path


def _upscale(frames: np.ndarray, factor: int) -> np.ndarray:
    return frames.repeat(factor, axis=-3).repeat(factor, axis=-2)


def execution_frames(result: TrialResult, scale: int = 2) -> np.ndarray:
    """``(num_steps + 1, s·H, 2·s·W, 3)``: each observation next to the goal image."""
    goal = np.broadcast_to(result.goal_image, result.frames.shape)
    return _upscale(np.concatenate([result.frames, goal], axis=2), scale)


def prediction_frames(result: TrialResult, scale: int = 2) -> np.ndarray | None:
    """``(num_planning_steps, s·H, s·(T+1)·W, 3)``: the chosen plan's predicted frames in a
    row, then the goal, one GIF frame per planning step."""
    if result.predicted_frames is None:
        return None
    pred = result.predicted_frames  # (P, T, H, W, 3)
    row = np.concatenate(list(pred.transpose(1, 0, 2, 3, 4)), axis=2)  # (P, H, T*W, 3)
    goal = np.broadcast_to(result.goal_image, (pred.shape[0], *result.goal_image.shape))
    return _upscale(np.concatenate([row, goal], axis=2), scale)


def write_gif(path: Path, frames: np.ndarray, duration_ms: int = 250) -> None:
    """Writes an animated GIF atomically."""
    import imageio.v3 as iio

    with atomic_path(path) as tmp:
        iio.imwrite(
            tmp, np.ascontiguousarray(frames), extension=GIF_SUFFIX, duration=duration_ms, loop=0
        )


def write_trial_gifs(run_dir: Path, result: TrialResult, record: dict[str, Any]) -> None:
    """Writes a trial's GIFs (and, with predictions, its plan GIF); adds their paths,
    relative to the run directory, to its ``record``."""
    run = RunDir(run_dir)
    key = (result.task, result.instance, result.seed)
    path = run.gif_path(*key)
    write_gif(path, execution_frames(result))
    record["gif"] = str(path.relative_to(run_dir))
    predicted = prediction_frames(result)
    if predicted is not None:
        plan_path = run.gif_path(*key, plan=True)
        write_gif(plan_path, predicted, duration_ms=500)
        record["plan_gif"] = str(plan_path.relative_to(run_dir))
