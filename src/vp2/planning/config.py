"""The planner's settings, :class:`PlannerConfig`: plain data, importable without torch (a run's
configuration holds one, :class:`vp2.run.config.RunConfig`)."""

from __future__ import annotations

import dataclasses
from typing import Any

from vp2 import spec


@dataclasses.dataclass(frozen=True)
class PlannerConfig:
    """The planner of a benchmark run. ``None`` fields take the SPEC §5 per-task defaults.

    Attributes:
        optimizer: ``"mppi"`` (SPEC default), ``"cem"``, ``"cem_gd"`` or ``"lbfgs"``.
        num_samples: Samples per iteration (``None``: 200, 800 for ``open_slide`` and
            ``open_drawer``). For ``cem_gd`` this sets the warm-started steps' samples.
            Other values are for tests and ablations, not for benchmark scores.
        gamma: MPPI inverse temperature γ.
        num_iterations: Sampling iterations per step (``None``: the optimizer's default).
        sigma: Noise scale per action dimension (``None``: :data:`vp2.spec.SIGMA` of the env).
        options: Further keyword arguments of the optimizer class.
    """

    optimizer: str = "mppi"
    num_samples: int | None = None
    gamma: float = spec.GAMMA
    num_iterations: int | None = None
    sigma: tuple[float, ...] | None = None
    options: dict[str, Any] = dataclasses.field(default_factory=dict)
