"""The planning agent: visual foresight with a video prediction model (SPEC §4–§6).

The agent joins a model, a cost and an optimizer. At every planning step it builds the
batched objective ::

    objective(candidates (N, 10, A)) -> scores (N,)
        = -cost(model.predict(last 2 observations, cat[last executed action, candidates]))

and lets the optimizer (MPPI by default) maximise it, warm-started from its previous plan
shifted by one step. The optimizer knows nothing about the model; the model knows nothing
about the cost. The cost and the optimizer of a task come from :mod:`vp2.planning.planner`.

With an ensemble (:class:`vp2.models.ensemble.EnsembleModel`) every member predicts the
candidates and the score is SPEC §5's: a randomly chosen member's score minus
``λ · max_i ‖Iⁱ − mean‖₁`` (:class:`~vp2.planning.costs.EnsembleCost`, a member drawn per
sample from a generator seeded by the trial seed); the trial record names the members and, per
planning step, how often each was drawn and which one scored the best sample.

:class:`RandomActions` is the baseline agent without a model: uniform random actions.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

import numpy as np
import torch
from torch import Tensor

from vp2.classifiers.registry import CLASSIFIERS, ClassifierRegistry
from vp2.models.contract import VideoPredictionModel, checked, predict_in_chunks, unwrap
from vp2.models.ensemble import as_ensemble
from vp2.planning.costs import (
    COST_MODES,
    ENSEMBLE_DISAGREEMENT_WEIGHT,
    CostMode,
    EnsembleCost,
    build_cost,
)
from vp2.planning.optimizers import shift_plan
from vp2.planning.planner import PlannerConfig, build_optimizer, planner_settings
from vp2.utils.tensors import images_to_float


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
    """What a :class:`vp2.run.trial.ControlTrial` drives.

    Attributes:
        name: Identity in results (``"planning"``, ``"random_actions"``).
        action_dim: ``A``; must equal the environment's.
        image_size: Side of the frames the trial renders for it.
        cost_kind: :data:`vp2.planning.costs.CostKind` of the current trial (set by ``reset``).
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


def classifier_provenance(classifier: Any) -> dict[str, Any]:
    """What a trial record says of the classifier in its cost: the file's hash, the dataset it
    was trained on and its held-out accuracy, where the classifier carries that metadata."""
    meta = getattr(classifier, "meta", None) or {}
    out: dict[str, Any] = {}
    if "sha256" in meta:
        out["sha256"] = meta["sha256"][:16]
    dataset = (meta.get("data") or {}).get("dataset")
    if dataset:
        out["dataset"] = dataset
    accuracy = (meta.get("heldout") or {}).get("accuracy")
    if accuracy is not None:
        out["heldout_accuracy"] = round(float(accuracy), 4)
    return out or {"class": type(classifier).__name__}


def frames_to_tensor(frames: np.ndarray, device: torch.device) -> Tensor:
    """``(..., H, W, 3)`` uint8 -> ``(..., 3, H, W)`` float32 in [0, 1] on ``device``."""
    # A copy: suite arrays are read-only, which torch warns about. The channel axis moves by a
    # view, so the frames keep their (..., H, W, 3) memory layout.
    return images_to_float(np.array(frames, dtype=np.uint8), device).movedim(-1, -3)


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

    Called by :class:`vp2.run.trial.ControlTrial`: :meth:`reset` at the start of a
    trial, then :meth:`act` at every control step after the first (the trial executes the
    zero action first, so that two context frames exist).

    Args:
        model: Any :class:`vp2.models.contract.VideoPredictionModel`; passed through
            :func:`vp2.models.contract.checked` (wrapped unless it already checks its calls).
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
        self._classifier: dict[str, Any] = {}
        #: The ensemble the model is, else ``None``; then, per trial, its cost and per step
        #: what its member draws were (``describe()["ensemble"]["steps"]``).
        self.ensemble = as_ensemble(self.model)
        self._ensemble_steps: list[dict[str, Any]] = []

    def describe(self) -> dict[str, Any]:
        out = {"agent": self.name, "planner": self._settings, "cost": self.cost_kind}
        if self._classifier:
            out["classifier"] = self._classifier
        if self.ensemble is not None:
            out["ensemble"] = {
                "members": list(self.ensemble.labels),
                "lam": ENSEMBLE_DISAGREEMENT_WEIGHT,
                "member_choice": "per sample, from the trial seed's fourth stream",
                "steps": list(self._ensemble_steps),
            }
        return out

    def reset(self, task: str, goal_image: np.ndarray, seed: int) -> None:
        """Starts a trial: builds the optimizer and cost for ``task``, seeds the generators."""
        self._task = task
        self._settings = planner_settings(task, self.planner)
        self.optimizer = build_optimizer(task, self.planner)
        self.optimizer.reset()
        goal = frames_to_tensor(goal_image, self.device)  # (3, H, W)
        # The oracle's plans must be the same bits on every CPU (its tables are measured once
        # and replayed anywhere), so its classifier runs the exact arithmetic; a learned model's
        # predictions already differ per CPU and keep the faster float32 inference.
        exact = bool(getattr(self.model, "needs_simulator_state", False))
        self.cost, self.cost_kind = build_cost(
            task, goal, self.cost_mode, self.classifiers, self.device, exact=exact
        )
        # The classifier's provenance and its weight in the cost (one weight per task,
        # SPEC §6), so that a record (and an oracle table built from records) names both.
        self._classifier = (
            classifier_provenance(self.classifiers.get(task, self.device))
            | {"weight": float(self.cost.terms[1][0])}
            if self.cost_kind == "pixel+classifier"
            else {}
        )
        # Independent streams: the planner's samples must not shift when the model draws more
        # or less noise, and recording predictions must not change the plans.
        # (The first three words do not depend on how many are drawn: a fourth, the ensemble's
        # member choice, leaves single models' streams as they were.)
        streams = np.random.SeedSequence(seed).generate_state(4)
        planner_seed, model_seed, record_seed, ensemble_seed = (int(x) for x in streams)
        self.generator = torch.Generator().manual_seed(planner_seed)
        self.model_generator = torch.Generator().manual_seed(model_seed)
        self._record_seed = record_seed
        if self.ensemble is not None:
            self.ensemble_generator = torch.Generator().manual_seed(ensemble_seed)
            self.ensemble_cost = EnsembleCost(self.cost, self.ensemble_generator)
            self._ensemble_steps = []
            self._new_ensemble_step()
        self.plan = torch.zeros(self.horizon, self.action_dim, device=self.device)  # (H, A)

    def objective(self, context: Tensor, last_action: Tensor) -> Callable[[Tensor], Tensor]:
        """The optimizer's objective at one planning step.

        Args:
            context: ``(num_context, 3, H, W)`` the last observations in [0, 1].
            last_action: ``(A,)`` the last executed action.

        Returns:
            ``candidates (N, T, A) -> scores (N,)``: ``-cost(predictions)``; for an ensemble
            ``-(cost(Iᵐ) + λ · max_i ‖Iⁱ − mean‖₁)`` with ``m`` drawn per candidate
            (:meth:`_ensemble_scores`).
        """

        def objective(candidates: Tensor) -> Tensor:
            n = candidates.shape[0]
            frames = context.expand(n, *context.shape)  # (N, C, 3, H, W)
            previous = last_action.to(candidates).expand(n, 1, -1)  # (N, 1, A)
            actions = torch.cat([previous, candidates], dim=1)  # (N, C - 1 + T, A)
            if self.ensemble is not None:
                return self._ensemble_scores(frames, actions.float()).to(candidates.dtype)
            predicted = predict_in_chunks(
                self.model, frames, actions.float(), generator=self.model_generator
            )  # (N, T, 3, H, W)
            return self.cost.score(predicted.to(self.device)).to(candidates.dtype)  # (N,)

        return objective

    def _new_ensemble_step(self) -> None:
        """Starts counting a planning step's member draws (and its best sample's member)."""
        assert self.ensemble is not None
        self._ensemble_step: dict[str, Any] = {
            "draws": torch.zeros(len(self.ensemble.members), dtype=torch.long),
            "best_score": -math.inf,
            "best_member": None,
        }

    def _ensemble_scores(self, frames: Tensor, actions: Tensor) -> Tensor:
        """``(N,)`` SPEC §5 ensemble scores of the candidates; counts the step's member draws."""
        assert self.ensemble is not None
        predicted = self.ensemble.predict_members(
            frames, actions, generator=self.model_generator
        )  # (M, N, T, 3, H, W)
        scores = self.ensemble_cost.score(predicted.to(self.device))  # (N,)
        members = self.ensemble_cost.last_members
        assert members is not None
        step = self._ensemble_step
        step["draws"] += torch.bincount(members.cpu(), minlength=len(self.ensemble.members))
        best = int(torch.argmax(scores.detach()))
        if float(scores[best].detach()) > step["best_score"]:
            step["best_score"] = float(scores[best].detach())
            step["best_member"] = int(members[best])
        return scores

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
        if self.ensemble is not None:
            self._new_ensemble_step()
        plan, report = self.optimizer.optimize(objective, self.plan, self.generator)  # (T, A)
        plan = plan.detach()
        if self.ensemble is not None:
            step = self._ensemble_step
            self._ensemble_steps.append(
                {"draws": step["draws"].tolist(), "best_member": step["best_member"]}
            )
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

    def trial_state(self) -> dict[str, Any]:
        """What the agent carries from one control step to the next: the warm-start plan, the
        states of its generators and the optimizer's (for a trial resumed mid-way,
        :mod:`vp2.run.partial`)."""
        state = {
            "plan": self.plan.detach().cpu().numpy(),
            "generator": self.generator.get_state().numpy(),
            "model_generator": self.model_generator.get_state().numpy(),
            "optimizer": self.optimizer.trial_state(),
        }
        if self.ensemble is not None:
            state["ensemble_generator"] = self.ensemble_generator.get_state().numpy()
            state["ensemble_steps"] = list(self._ensemble_steps)
        return state

    def load_trial_state(self, state: dict[str, Any]) -> None:
        """Restores what :meth:`trial_state` returned (after :meth:`reset` for the trial)."""
        self.plan = torch.as_tensor(np.asarray(state["plan"]), dtype=self.plan.dtype,
                                    device=self.device)
        names = ["generator", "model_generator"]
        if self.ensemble is not None:
            names.append("ensemble_generator")
            self._ensemble_steps = list(state["ensemble_steps"])
        for name in names:
            getattr(self, name).set_state(torch.from_numpy(np.asarray(state[name], np.uint8)))
        self.optimizer.load_trial_state(state["optimizer"])

    def _predict_plan(self, context: Tensor, last_action: Tensor, plan: Tensor) -> np.ndarray:
        """``(T, H, W, 3)`` uint8 predicted frames of one plan (for the plan GIF)."""
        generator = torch.Generator().manual_seed(self._record_seed)
        actions = torch.cat([last_action[None], plan.to(last_action)])[None]  # (1, C - 1 + T, A)
        with torch.no_grad():
            frames = self.model.predict(context[None], actions, generator=generator, grad=False)
        return tensor_to_frames(frames[0])


class RandomActions:
    """Baseline agent: uniform random actions in ``[-1, 1]^A``, ignoring every observation.

    It has the planning agent's interface (``reset``/``act``, see :class:`PlanningAgent`) but no
    model. Its actions depend only on the trial seed given to :meth:`reset`.

    Args:
        action_dim: ``A`` of the environment.
        image_size: Side of the frames the trial renders (for the execution GIF).
    """

    name = "random_actions"
    cost_kind = "none"

    def __init__(self, action_dim: int, image_size: int = 64) -> None:
        self.action_dim = int(action_dim)
        self.image_size = int(image_size)
        self._rng = np.random.default_rng(0)

    def describe(self) -> dict[str, Any]:
        """Identity for result records."""
        return {"agent": self.name}

    def reset(self, task: str, goal_image: np.ndarray, seed: int) -> None:
        """Starts a trial: reseeds the generator from the trial seed."""
        self._rng = np.random.default_rng(seed)

    def act(self, observation: Any) -> tuple[np.ndarray, dict[str, Any]]:
        """A uniform random action ``(A,)``; the observation is ignored."""
        return self._rng.uniform(-1.0, 1.0, self.action_dim), {}

    def trial_state(self) -> dict[str, Any]:
        """The generator's state (for a trial resumed mid-way)."""
        return {"rng": self._rng.bit_generator.state}

    def load_trial_state(self, state: dict[str, Any]) -> None:
        self._rng.bit_generator.state = state["rng"]


def check_agent_for_env(agent: Agent, action_dim: int, task: str) -> None:
    """Raises a clear error when an agent's action size does not fit a task."""
    if agent.action_dim != action_dim:
        raise ValueError(
            f"{task} has {action_dim}-D actions but the {agent.name} agent (model "
            f"{getattr(getattr(agent, 'model', None), 'name', '-')}) has action_dim "
            f"{agent.action_dim}; a model is trained for one environment"
        )
