"""A labelled contact sheet of every registered task (the package's smoke check of the envs)."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from PIL import Image

from vp2.envs.factory import make_env
from vp2.envs.rendering import contact_sheet
from vp2.envs.tasks import TASK_NAMES


@dataclasses.dataclass
class TaskPreview:
    """What the gallery measured for one task."""

    task: str
    image: np.ndarray  # (size, size, 3) uint8
    action_dim: int
    state_dim: int
    success_at_reset: bool
    step_ms: float  # one step including the observation render
    render_ms: float

    def summary(self) -> str:
        return (
            f"{self.task:34s} action_dim={self.action_dim} state_dim={self.state_dim:4d} "
            f"success_at_reset={self.success_at_reset!s:5s} step+obs={self.step_ms:7.1f} ms "
            f"render={self.render_ms:6.1f} ms"
        )


def preview_task(task: str, seed: int = 0, size: int = 64) -> TaskPreview:
    """Resets a task with ``seed``, renders it, and times one zero-action step."""
    with make_env(task, seed=seed, observation_size=size) as env:
        obs, _ = env.reset(seed=seed)
        state = env.get_state()
        # Goal-relative criteria (tabletop) have no goal at a bare reset: report False.
        success = env.is_success(None) if task.startswith("robodesk/") else False
        t0 = time.perf_counter()
        image = env.render(size)
        render_ms = 1000 * (time.perf_counter() - t0)
        t0 = time.perf_counter()
        env.step(np.zeros(env.action_dim))
        step_ms = 1000 * (time.perf_counter() - t0)
        return TaskPreview(task, obs if obs is not None else image, env.action_dim, state.size,
                           bool(success), step_ms, render_ms)


def render_gallery(
    out_dir: str | Path, tasks: Sequence[str] = TASK_NAMES, seed: int = 0, size: int = 64
) -> tuple[Path, list[TaskPreview]]:
    """Writes ``tasks.png`` (a labelled contact sheet) and ``tasks.txt`` (one line per task)."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    previews = [preview_task(t, seed, size) for t in tasks]
    sheet = contact_sheet([p.image for p in previews], [p.task for p in previews], columns=4, scale=3)
    png = out / "tasks.png"
    Image.fromarray(sheet).save(png)
    (out / "tasks.txt").write_text("\n".join(p.summary() for p in previews) + "\n")
    return png, previews
