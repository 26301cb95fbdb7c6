"""What a seed is: a non-negative integer, since every seed of vp2 ends in NumPy's
``SeedSequence`` (a trial's, a trajectory's, a clip choice's), which refuses negative ones."""

from __future__ import annotations

import operator
from typing import Any


def check_seed(seed: Any, name: str = "seed") -> None:
    """Raises ``ValueError`` naming ``name`` unless ``seed`` is a non-negative integer (a
    Python or NumPy integer; not a bool)."""
    try:
        valid = not isinstance(seed, bool) and operator.index(seed) >= 0
    except TypeError:
        valid = False
    if not valid:
        raise ValueError(f"{name} must be a non-negative integer, got {seed!r}")
