"""Where datasets live by default: ``data/<env>-<N>x-<size>px``, the directory ``vp2 collect
<env>`` writes, which ``vp2 train`` and ``vp2 metrics`` read when given ``--env`` without
``--data``."""

from __future__ import annotations

from pathlib import Path

#: Image size of the datasets ``vp2 collect`` writes by default.
DEFAULT_IMAGE_SIZE = 64
#: Trajectories per data stream of each environment's default dataset (``vp2 collect ENV``):
#: small enough to generate in CI time. Paper scale: robodesk 5,000 per task, tabletop 50,000.
DEFAULT_TRAJECTORIES = {"robodesk": 20, "tabletop": 100}


def default_trajectories() -> dict[str, int]:
    """Trajectories per data stream of each environment's default dataset."""
    return dict(DEFAULT_TRAJECTORIES)


def dataset_dir(env: str, trajectories: int, image_size: int | None = DEFAULT_IMAGE_SIZE) -> Path:
    """``data/<env>-<trajectories>x-<image_size>px`` (``...x-states`` for ``image_size=None``,
    a collection without images)."""
    kind = "states" if image_size is None else f"{image_size}px"
    return Path("data") / f"{env}-{trajectories}x-{kind}"


def default_dataset(env: str) -> Path:
    """The dataset directory that ``vp2 collect <env>`` writes with its defaults."""
    return dataset_dir(env, default_trajectories()[env])
