"""The planner's settings, :class:`PlannerConfig`: plain data, importable without torch (a run's
configuration holds one, :class:`vp2.run.config.RunConfig`)."""

from __future__ import annotations

import dataclasses
from typing import Any

from vp2 import spec

#: The :class:`PlannerConfig` fields that only some optimizers read (``None``: the optimizer's
#: own default). Each optimizer class names those it reads (``Optimizer.config_fields``); a run
#: that sets one its optimizer does not read is refused
#: (:func:`vp2.planning.planner.planner_settings`).
OPTIMIZER_FIELDS: tuple[str, ...] = (
    "num_elites", "num_samples_first", "num_refined", "lr", "grad_steps"
)


@dataclasses.dataclass(frozen=True)
class PlannerConfig:
    """The planner of a benchmark run. ``None`` fields take the SPEC §5 per-task defaults, or
    the optimizer's own defaults where the SPEC has none.

    Attributes:
        optimizer: ``"mppi"`` (SPEC default), ``"cem"``, ``"cem_gd"`` or ``"lbfgs"``.
        num_samples: Samples per iteration (``None``: 200, 800 for ``open_slide`` and
            ``open_drawer``). For ``cem_gd`` this sets the warm-started steps' samples.
            Other values are for tests and ablations, not for benchmark scores.
        gamma: MPPI inverse temperature γ.
        num_iterations: Sampling iterations per step (``None``: the optimizer's default).
        num_elites: CEM and CEM-GD: samples the distribution is refitted to.
        num_samples_first: CEM-GD: samples per CEM iteration on a trial's first planning step.
        num_refined: CEM-GD: best CEM samples refined by gradient steps.
        lr: CEM-GD: the Adam step size of the refinement; L-BFGS: its step length (the paper
            tuned it over 1e-3, 1e-2, 5e-2, 7e-2).
        grad_steps: CEM-GD: most accepted gradient steps per refined sequence; L-BFGS: calls
            of ``LBFGS.step`` per planning step (each up to ``max_iter`` iterations).
        sigma: Noise scale per action dimension (``None``: :data:`vp2.spec.SIGMA` of the env).
        options: Further keyword arguments of the optimizer class (override the fields).
    """

    optimizer: str = "mppi"
    num_samples: int | None = None
    gamma: float = spec.GAMMA
    num_iterations: int | None = None
    num_elites: int | None = None
    num_samples_first: int | None = None
    num_refined: int | None = None
    lr: float | None = None
    grad_steps: int | None = None
    sigma: tuple[float, ...] | None = None
    options: dict[str, Any] = dataclasses.field(default_factory=dict)

    def optimizer_fields(self) -> dict[str, Any]:
        """The :data:`OPTIMIZER_FIELDS` this config sets (not ``None``), in that order."""
        return {
            name: getattr(self, name)
            for name in OPTIMIZER_FIELDS
            if getattr(self, name) is not None
        }
