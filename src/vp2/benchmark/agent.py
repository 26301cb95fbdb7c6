"""The planning agent: visual foresight with a video prediction model (SPEC §4–§6).

The agent joins a model, a cost and an optimizer. At every planning step it builds the
batched objective ::

    objective(candidates (N, 10, A)) -> scores (N,)
        = -cost(model.predict(last 2 observations, cat[last executed action, candidates]))

and lets the optimizer (MPPI by default) maximise it, warm-started from its previous plan
shifted by one step. The optimizer knows nothing about the model; the model knows nothing
about the cost.

Costs per environment (SPEC §6): tabletop = pixel SSE to the goal image repeated over the 10
frames; RoboDesk = 0.5 × SSE + 10 × (−Σ_t classifier logit). The RoboDesk success classifiers
are looked up per task in :data:`CLASSIFIERS`; when a task has none, the agent falls back to
``0.5 × SSE`` alone and reports the cost kind ``"pixel_only"``, which every trial record
carries, so results with and without classifiers are never silently mixed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, Literal, Protocol, runtime_checkable

import numpy as np
import torch
from torch import Tensor

from vp2.envs import split_name
from vp2.models.base import VideoPredictionModel, checked, predict_in_chunks, unwrap
from vp2.planning import (
    DEFAULT_SIGMA,
    OPTIMIZERS,
    Optimizer,
    PixelSSE,
    WeightedCost,
    robodesk_cost,
    shift_plan,
    tabletop_cost,
)
from vp2.planning.costs import ROBODESK_PIXEL_WEIGHT, FrameClassifier

#: Planner samples per step (SPEC §5): 200, and 800 for the two hardest RoboDesk tasks.
DEFAULT_NUM_SAMPLES = 200
LARGE_NUM_SAMPLES = 800
LARGE_SAMPLE_TASKS = frozenset({"robodesk/open_slide", "robodesk/open_drawer"})
#: MPPI inverse temperature γ (SPEC §5).
DEFAULT_GAMMA = 0.05

#: How a trial's plans were scored. ``"pixel"``: tabletop SPEC cost; ``"pixel+classifier"``:
#: RoboDesk SPEC cost; ``"pixel_only"``: RoboDesk without its classifier (not the SPEC cost);
#: ``"none"``: no cost (the random-action baseline).
CostKind = Literal["pixel", "pixel+classifier", "pixel_only", "none"]
#: ``"auto"``: the SPEC cost, falling back to pixel-only where a RoboDesk task has no
#: classifier; ``"spec"``: the SPEC cost or an error; ``"pixel_only"``: never a classifier.
CostMode = Literal["auto", "spec", "pixel_only"]
COST_MODES: tuple[str, ...] = ("auto", "spec", "pixel_only")


# --------------------------------------------------------------------------- classifiers

#: ``loader(device) -> classifier`` with ``classifier(images (M, 3, H, W) in [0, 1]) -> logits
#: (M,)``. Registered per RoboDesk task.
ClassifierLoader = Callable[[torch.device], FrameClassifier]


class ClassifierRegistry:
    """Success classifiers per task, registered by whoever provides them.

    The classifiers shipped with the package are registered here when :mod:`vp2.benchmark` is
    imported (:func:`vp2.benchmark.classifiers.register_shipped_classifiers`). Loaded
    classifiers are cached per ``(task, device)`` in the process.
    """

    def __init__(self) -> None:
        self._loaders: dict[str, ClassifierLoader] = {}
        self._loaded: dict[tuple[str, str], FrameClassifier] = {}

    def register(self, task: str, loader: ClassifierLoader) -> None:
        """Registers (or replaces) the classifier loader of ``task``."""
        split_name(task)
        self._loaders[task] = loader
        self._loaded = {k: v for k, v in self._loaded.items() if k[0] != task}

    def unregister(self, task: str) -> None:
        """Removes a task's classifier (tests, or to force the fallback)."""
        self._loaders.pop(task, None)
        self._loaded = {k: v for k, v in self._loaded.items() if k[0] != task}

    def __contains__(self, task: str) -> bool:
        return task in self._loaders

    def get(self, task: str, device: torch.device) -> FrameClassifier | None:
        """The task's classifier on ``device``, or ``None`` if none is registered."""
        if task not in self._loaders:
            return None
        key = (task, str(device))
        if key not in self._loaded:
            self._loaded[key] = self._loaders[task](device)
        return self._loaded[key]


#: The process-wide registry the benchmark looks classifiers up in.
CLASSIFIERS = ClassifierRegistry()


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
            f"{task}: no success classifier is registered (vp2.benchmark.CLASSIFIERS), so the "
            "SPEC cost cannot be built; use cost mode 'auto' or 'pixel_only' to plan on pixels"
        )
    # The RoboDesk cost without its classifier term: the pixel term keeps its SPEC weight so
    # that MPPI's γ sees the same score scale as in the full cost.
    return WeightedCost([(ROBODESK_PIXEL_WEIGHT, PixelSSE(goal))]), "pixel_only"


# --------------------------------------------------------------------------- planner


#: Optimizers that need gradients of the predictions with respect to the actions: the runner
#: checks the model gives them (:func:`vp2.models.base.gradient_problem`) before any trial.
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
        sigma: Noise scale per action dimension (``None``: ``DEFAULT_SIGMA`` of the env).
        options: Further keyword arguments of the optimizer class.
    """

    optimizer: str = "mppi"
    num_samples: int | None = None
    gamma: float = DEFAULT_GAMMA
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
    sigma = list(config.sigma if config.sigma is not None else DEFAULT_SIGMA[env])
    if len(sigma) != len(DEFAULT_SIGMA[env]):
        raise ValueError(
            f"{task}: sigma has {len(sigma)} entries, the action has {len(DEFAULT_SIGMA[env])}"
        )
    default_samples = LARGE_NUM_SAMPLES if task in LARGE_SAMPLE_TASKS else DEFAULT_NUM_SAMPLES
    samples = config.num_samples if config.num_samples is not None else default_samples
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


# --------------------------------------------------------------------------- agents


@dataclasses.dataclass
class Observation:
    """What a trial shows an agent at a control step.

    Attributes:
        step: Index of the control step about to be taken (``1 .. num_steps - 1``).
        frames: All frames of the trial so far, ``(step + 1, H, W, 3)`` uint8, oldest first.
        last_action: ``(A,)`` the action executed at the previous step.
        env_meta: Metadata of the trial's environment (to rebuild it).
        state: ``(S,)`` current simulator state. Only models that declare
            ``needs_simulator_state`` (the oracle) ever receive it.
    """

    step: int
    frames: np.ndarray
    last_action: np.ndarray
    env_meta: dict[str, Any]
    state: np.ndarray


@runtime_checkable
class Agent(Protocol):
    """What a :class:`vp2.benchmark.trial.ControlTrial` drives.

    Attributes:
        name: Identity in results (``"planning"``, ``"random_actions"``).
        action_dim: ``A``; must equal the environment's.
        image_size: Side of the frames the trial renders for it.
        cost_kind: :data:`CostKind` of the current trial (set by ``reset``).
    """

    name: str
    action_dim: int
    image_size: int
    cost_kind: str

    def reset(self, task: str, goal_image: np.ndarray, seed: int) -> None:
        """Starts a trial: the task, its ``(H, W, 3)`` uint8 goal image and the trial seed."""

    def act(self, observation: Observation) -> tuple[np.ndarray, dict[str, Any]]:
        """The action ``(A,)`` to execute now and an info dict (for records)."""

    def describe(self) -> dict[str, Any]:
        """JSON-able settings of the current trial (planner, cost), for records."""


@runtime_checkable
class SimulatorStateModel(Protocol):
    """A model that plans from the true simulator state (the oracle) rather than from images.

    The planning agent calls ``set_simulator_state`` before every planning step when
    ``needs_simulator_state`` is true. Learned models must never implement this.
    """

    needs_simulator_state: bool

    def set_simulator_state(self, env_meta: dict[str, Any], state: np.ndarray) -> None: ...


def frames_to_tensor(frames: np.ndarray, device: torch.device) -> Tensor:
    """``(..., H, W, 3)`` uint8 -> ``(..., 3, H, W)`` float32 in [0, 1] on ``device``."""
    # A copy: suite arrays are read-only, which torch.from_numpy warns about.
    x = torch.from_numpy(np.array(frames, dtype=np.uint8)).to(device)
    return x.movedim(-1, -3).float().div_(255)


def tensor_to_frames(x: Tensor) -> np.ndarray:
    """``(..., 3, H, W)`` float in [0, 1] -> ``(..., H, W, 3)`` uint8."""
    return x.detach().movedim(-3, -1).clamp(0, 1).mul(255).round().to(torch.uint8).cpu().numpy()


def _model_device(model: Any) -> torch.device | None:
    model = unwrap(model)
    if isinstance(model, torch.nn.Module):
        for p in model.parameters():
            return p.device
    return None


class PlanningAgent:
    """Visual-foresight agent: replans with the model and optimizer at every control step.

    Called by :class:`vp2.benchmark.trial.ControlTrial`: :meth:`reset` at the start of a
    trial, then :meth:`act` at every control step after the first (the trial executes the
    zero action first, so that two context frames exist).

    Args:
        model: Any :class:`vp2.models.base.VideoPredictionModel`; passed through
            :func:`vp2.models.base.checked` (wrapped unless it already checks its calls).
        planner: Optimizer settings (SPEC defaults per task where ``None``).
        cost_mode: See :data:`CostMode`.
        classifiers: Where RoboDesk classifiers are looked up.
        device: Where frames, plans and costs live (default: the model's device, else CPU).
        record_predictions: Also predict the chosen plan at every step (one extra model call
            of batch 1) and return its frames in the info dict, for the plan GIF.
    """

    name = "planning"

    def __init__(
        self,
        model: VideoPredictionModel,
        planner: PlannerConfig | None = None,
        cost_mode: CostMode = "auto",
        classifiers: ClassifierRegistry = CLASSIFIERS,
        device: str | torch.device | None = None,
        record_predictions: bool = False,
    ) -> None:
        self.model = checked(model)
        self.planner = planner or PlannerConfig()
        if cost_mode not in COST_MODES:
            raise ValueError(
                f"unknown cost mode {cost_mode!r}; choose one of {', '.join(COST_MODES)}"
            )
        self.cost_mode: CostMode = cost_mode
        self.classifiers = classifiers
        self.device = (
            torch.device(device)
            if device is not None
            else (_model_device(model) or torch.device("cpu"))
        )
        self.record_predictions = record_predictions
        self.action_dim = int(model.action_dim)
        self.image_size = int(model.image_size)
        self.horizon = int(model.num_future)
        self.num_context = int(model.num_context)
        self.cost_kind: str = "none"
        self._task: str | None = None
        self._settings: dict[str, Any] = {}

    def describe(self) -> dict[str, Any]:
        return {"agent": self.name, "planner": self._settings, "cost": self.cost_kind}

    def reset(self, task: str, goal_image: np.ndarray, seed: int) -> None:
        """Starts a trial: builds the optimizer and cost for ``task``, seeds the generators."""
        self._task = task
        self._settings = planner_settings(task, self.planner)
        self.optimizer = build_optimizer(task, self.planner)
        self.optimizer.reset()
        goal = frames_to_tensor(goal_image, self.device)  # (3, H, W)
        self.cost, self.cost_kind = build_cost(
            task, goal, self.cost_mode, self.classifiers, self.device
        )
        # Independent streams: the planner's samples must not shift when the model draws more
        # or less noise, and recording predictions must not change the plans.
        planner_seed, model_seed, record_seed = np.random.SeedSequence(seed).generate_state(3)
        self.generator = torch.Generator().manual_seed(int(planner_seed))
        self.model_generator = torch.Generator().manual_seed(int(model_seed))
        self._record_seed = int(record_seed)
        self.plan = torch.zeros(self.horizon, self.action_dim, device=self.device)  # (H, A)

    def objective(self, context: Tensor, last_action: Tensor) -> Callable[[Tensor], Tensor]:
        """The optimizer's objective at one planning step.

        Args:
            context: ``(num_context, 3, H, W)`` the last observations in [0, 1].
            last_action: ``(A,)`` the last executed action.

        Returns:
            ``candidates (N, T, A) -> scores (N,)``.
        """

        def objective(candidates: Tensor) -> Tensor:
            n = candidates.shape[0]
            frames = context.expand(n, *context.shape)  # (N, C, 3, H, W)
            previous = last_action.to(candidates).expand(n, 1, -1)  # (N, 1, A)
            actions = torch.cat([previous, candidates], dim=1)  # (N, C - 1 + T, A)
            predicted = predict_in_chunks(
                self.model, frames, actions.float(), generator=self.model_generator
            )  # (N, T, 3, H, W)
            return self.cost.score(predicted.to(self.device)).to(candidates.dtype)  # (N,)

        return objective

    def act(self, observation: Observation) -> tuple[np.ndarray, dict[str, Any]]:
        """Plans one step; returns the first action of the plan and the optimizer's report."""
        if self._task is None:
            raise RuntimeError("PlanningAgent.act called before reset()")
        if len(observation.frames) < self.num_context:
            raise ValueError(
                f"the agent needs {self.num_context} context frames, the trial gave "
                f"{len(observation.frames)}"
            )
        if getattr(self.model, "needs_simulator_state", False):
            self.model.set_simulator_state(observation.env_meta, observation.state)
        context = frames_to_tensor(observation.frames[-self.num_context :], self.device)
        last_action = torch.as_tensor(
            observation.last_action, dtype=torch.float32, device=self.device
        )
        objective = self.objective(context, last_action)
        plan, report = self.optimizer.optimize(objective, self.plan, self.generator)  # (T, A)
        plan = plan.detach()
        info: dict[str, Any] = {
            "best_score": report.best_score,
            "plan_score": report.plan_score,
            "num_evaluations": report.num_evaluations,
        }
        if self.record_predictions:
            info["predicted_frames"] = self._predict_plan(context, last_action, plan)
        action = plan[0].cpu().double().numpy()
        self.plan = shift_plan(plan)
        return action, info

    def _predict_plan(self, context: Tensor, last_action: Tensor, plan: Tensor) -> np.ndarray:
        """``(T, H, W, 3)`` uint8 predicted frames of one plan (for the plan GIF)."""
        generator = torch.Generator().manual_seed(self._record_seed)
        actions = torch.cat([last_action[None], plan.to(last_action)])[None]  # (1, C - 1 + T, A)
        with torch.no_grad():
            frames = self.model.predict(context[None], actions, generator=generator, grad=False)
        return tensor_to_frames(frames[0])


def check_agent_for_env(agent: Agent, action_dim: int, task: str) -> None:
    """Raises a clear error when an agent's action size does not fit a task."""
    if agent.action_dim != action_dim:
        raise ValueError(
            f"{task} has {action_dim}-D actions but the {agent.name} agent (model "
            f"{getattr(getattr(agent, 'model', None), 'name', '-')}) has action_dim "
            f"{agent.action_dim}; a model is trained for one environment"
        )


__all__ = [
    "CLASSIFIERS",
    "COST_MODES",
    "Agent",
    "ClassifierRegistry",
    "CostKind",
    "CostMode",
    "GRADIENT_OPTIMIZERS",
    "Observation",
    "PlannerConfig",
    "PlanningAgent",
    "SimulatorStateModel",
    "build_cost",
    "build_optimizer",
    "planner_settings",
]
