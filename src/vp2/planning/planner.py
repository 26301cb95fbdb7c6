"""What the planning agent builds per task: its cost (SPEC §6) and its optimizer (SPEC §5).

Costs per environment: tabletop = pixel SSE to the goal image repeated over the 10 frames;
RoboDesk = 0.5 × SSE + 10 × (−Σ_t classifier logit). The RoboDesk success classifiers are looked
up per task in :data:`vp2.classifiers.registry.CLASSIFIERS`; when a task has none,
:func:`build_cost` falls back to ``0.5 × SSE`` alone and reports the cost kind
``"pixel_only"``, which every trial record carries, so results with and without classifiers are
never silently mixed.

The optimizer's settings (:class:`PlannerConfig`) default to SPEC §5 per task: MPPI with 200
samples (800 for ``open_slide`` and ``open_drawer``), γ = 0.05 and the environment's σ.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Literal

import torch
from torch import Tensor

from vp2 import spec
from vp2.classifiers.registry import CLASSIFIERS, ClassifierRegistry
from vp2.envs import split_name
from vp2.planning.costs import PixelSSE, WeightedCost, robodesk_cost, tabletop_cost
from vp2.planning.optimizers import OPTIMIZERS, Optimizer

# --------------------------------------------------------------------------- cost

#: How a trial's plans were scored. ``"pixel"``: tabletop SPEC cost; ``"pixel+classifier"``:
#: RoboDesk SPEC cost; ``"pixel_only"``: RoboDesk without its classifier (not the SPEC cost);
#: ``"none"``: no cost (the random-action baseline).
CostKind = Literal["pixel", "pixel+classifier", "pixel_only", "none"]
#: ``"auto"``: the SPEC cost, falling back to pixel-only where a RoboDesk task has no
#: classifier; ``"spec"``: the SPEC cost or an error; ``"pixel_only"``: never a classifier.
CostMode = Literal["auto", "spec", "pixel_only"]
COST_MODES: tuple[str, ...] = ("auto", "spec", "pixel_only")


def build_cost(
    task: str,
    goal: Tensor,
    mode: CostMode = "auto",
    classifiers: ClassifierRegistry = CLASSIFIERS,
    device: torch.device | None = None,
) -> tuple[WeightedCost, CostKind]:
    """The planning cost of a task (SPEC §6) and its kind.

    Args:
        task: Registered task name.
        goal: ``(3, H, W)`` goal image in [0, 1].
        mode: See :data:`CostMode`.
        classifiers: Where RoboDesk classifiers are looked up.
        device: Device the classifier is loaded on (default: the goal's).

    Returns:
        The cost and its :data:`CostKind`.

    Raises:
        ValueError: for an unknown mode, or ``mode="spec"`` on a RoboDesk task without a
            registered classifier.
    """
    if mode not in COST_MODES:
        raise ValueError(f"unknown cost mode {mode!r}; choose one of {', '.join(COST_MODES)}")
    env, _ = split_name(task)
    if env == "tabletop":
        return tabletop_cost(goal), "pixel"
    classifier = None if mode == "pixel_only" else classifiers.get(task, device or goal.device)
    if classifier is not None:
        return robodesk_cost(goal, classifier), "pixel+classifier"
    if mode == "spec":
        raise ValueError(
            f"{task}: no success classifier is registered (vp2.classifiers.CLASSIFIERS), so the "
            "SPEC cost cannot be built; use cost mode 'auto' or 'pixel_only' to plan on pixels"
        )
    # The RoboDesk cost without its classifier term: the pixel term keeps its SPEC weight so
    # that MPPI's γ sees the same score scale as in the full cost.
    return WeightedCost([(spec.ROBODESK_PIXEL_WEIGHT, PixelSSE(goal))]), "pixel_only"


# --------------------------------------------------------------------------- planner


#: Optimizers that need gradients of the predictions with respect to the actions: the runner
#: checks the model gives them (:func:`vp2.models.contract.gradient_problem`) before any trial.
GRADIENT_OPTIMIZERS: tuple[str, ...] = ("cem_gd", "lbfgs")


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


def planner_settings(task: str, config: PlannerConfig) -> dict[str, Any]:
    """The optimizer's resolved constructor arguments for one task (recorded in every trial).

    Returns:
        ``{"optimizer": name, **kwargs}`` with plain-data values.
    """
    if config.optimizer not in OPTIMIZERS:
        raise ValueError(
            f"unknown optimizer {config.optimizer!r}; choose one of {', '.join(OPTIMIZERS)}"
        )
    env, _ = split_name(task)
    sigma = list(config.sigma if config.sigma is not None else spec.SIGMA[env])
    if len(sigma) != len(spec.SIGMA[env]):
        raise ValueError(
            f"{task}: sigma has {len(sigma)} entries, the action has {len(spec.SIGMA[env])}"
        )
    samples = config.num_samples if config.num_samples is not None else spec.num_samples_for(task)
    kwargs: dict[str, Any]
    if config.optimizer == "mppi":
        kwargs = {"sigma": sigma, "num_samples": samples, "gamma": config.gamma}
    elif config.optimizer == "cem":
        kwargs = {"sigma": sigma, "num_samples": samples}
    elif config.optimizer == "cem_gd":
        kwargs = {"sigma": sigma}
        if config.num_samples is not None:
            kwargs["num_samples"] = config.num_samples
    else:  # lbfgs: one sequence, no sampling
        kwargs = {}
    if config.num_iterations is not None:
        if config.optimizer == "lbfgs":
            raise ValueError("lbfgs has no sampling iterations; set options={'num_steps': ...}")
        kwargs["num_iterations"] = config.num_iterations
    kwargs.update(config.options)
    return {"optimizer": config.optimizer, **kwargs}


def build_optimizer(task: str, config: PlannerConfig) -> Optimizer:
    """A fresh optimizer for one task, from :func:`planner_settings`."""
    settings = planner_settings(task, config)
    name = settings.pop("optimizer")
    return OPTIMIZERS[name](**settings)
