"""An ensemble of video prediction models, planned with the ensemble cost of SPEC §5.

:class:`EnsembleModel` holds ``M >= 2`` members that agree on the interface's sizes
(``num_context``, ``num_future``, ``action_dim``, ``image_size``). The planning agent asks it for
every member's predictions of the candidates, :meth:`EnsembleModel.predict_members`
``(M, N, T, 3, H, W)``, and scores them with :class:`vp2.planning.costs.EnsembleCost`: a randomly
chosen member's score minus ``λ · max_i ‖Iⁱ − mean‖₁``. As a plain
:class:`~vp2.models.contract.VideoPredictionModel` (metrics, the plan GIF, the run's pre-check)
it predicts the members' mean.

``vp2 run --model 'ensemble(zoo:a,zoo:b)'`` builds one
(:class:`vp2.run.model_spec.ModelSpec`).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import Any

import torch
from torch import Tensor

from vp2.models.checkpoint import read_model_checkpoint
from vp2.models.contract import checked, gradient_problem, predict_in_chunks, unwrap

#: The interface sizes every member must share.
SHARED_SIZES: tuple[str, ...] = ("num_context", "num_future", "action_dim", "image_size")


class EnsembleMismatch(ValueError):
    """Ensemble members that cannot be planned with together (sizes, environments)."""


class EnsembleModel:
    """``M >= 2`` models predicting the same candidates (module docstring).

    Args:
        members: The models (each wrapped by :func:`~vp2.models.contract.checked`).
        labels: What messages and records call each member (default: the models' names),
            e.g. their ``--model`` specs.

    Raises:
        EnsembleMismatch: fewer than two members, members of different sizes, or a member
            that plans from the simulator state (the oracle).
    """

    name = "ensemble"

    def __init__(self, members: Sequence[Any], labels: Sequence[str] | None = None) -> None:
        self.members = [checked(m) for m in members]
        self.labels = [str(x) for x in labels] if labels is not None else [
            m.name for m in self.members
        ]
        if len(self.members) < 2 or len(self.labels) != len(self.members):
            raise EnsembleMismatch(
                f"an ensemble needs at least 2 members and one label each, got "
                f"{len(self.members)} member(s) and {len(self.labels)} label(s)"
            )
        first, first_label = self.members[0], self.labels[0]
        for member, label in zip(self.members, self.labels, strict=True):
            if getattr(member, "needs_simulator_state", False):
                raise EnsembleMismatch(
                    f"ensemble member {label!r} plans from the simulator state; ensemble "
                    "members predict from frames"
                )
            for size in SHARED_SIZES:
                if int(getattr(member, size)) != int(getattr(first, size)):
                    raise EnsembleMismatch(
                        f"ensemble member {label!r} has {size} {getattr(member, size)}, member "
                        f"{first_label!r} has {getattr(first, size)}; members must agree on "
                        f"{', '.join(SHARED_SIZES)}"
                    )
        self.num_context = int(first.num_context)
        self.num_future = int(first.num_future)
        self.action_dim = int(first.action_dim)
        self.image_size = int(first.image_size)
        self.max_batch_size = min(int(m.max_batch_size) for m in self.members)

    @property
    def num_workers(self) -> int:
        """The most worker processes a member uses (``1`` for members without any)."""
        return max(int(getattr(m, "num_workers", 1) or 1) for m in self.members)

    @num_workers.setter
    def num_workers(self, value: int) -> None:
        for member in self.members:
            if hasattr(member, "num_workers"):
                member.num_workers = value

    def predict_members(self, context_frames: Tensor, actions: Tensor, **options: Any) -> Tensor:
        """Every member's prediction, member by member (each in chunks of its
        ``max_batch_size``; stochastic members draw from ``options["generator"]`` in turn).

        Args:
            context_frames: ``(N, num_context, 3, H, W)`` in [0, 1].
            actions: ``(N, num_context + num_future - 1, A)`` in [-1, 1].
            options: ``generator`` and ``grad``, as :meth:`predict` takes them.

        Returns:
            ``(M, N, num_future, 3, H, W)``.
        """
        return torch.stack(
            [predict_in_chunks(m, context_frames, actions, **options) for m in self.members])

    def predict(self, context_frames: Tensor, actions: Tensor, *,
                generator: torch.Generator | None = None, grad: bool | None = None) -> Tensor:
        """The members' mean prediction ``(N, num_future, 3, H, W)``."""
        return self.predict_members(context_frames, actions, generator=generator,
                                    grad=grad).mean(dim=0)

    def gradient_problem(self, device: str | torch.device = "cpu") -> str | None:
        """Why some member cannot give gradients of its predictions with respect to the
        actions (:func:`~vp2.models.contract.gradient_problem`), or ``None``."""
        for member, label in zip(self.members, self.labels, strict=True):
            problem = gradient_problem(member, device)
            if problem is not None:
                return f"(member {label!r}) {problem}"
        return None

    def close(self) -> None:
        """Closes the members that hold resources (worker pools)."""
        for member in self.members:
            close = getattr(member, "close", None)
            if callable(close):
                close()


def checkpoint_facts(path: str | os.PathLike[str]) -> dict[str, Any]:
    """What a checkpoint says of its model without building it: the interface sizes of its
    config (:data:`SHARED_SIZES`) and ``env``, the environment of its training data, where
    the checkpoint names them."""
    payload = read_model_checkpoint(path)
    env = ((payload.get("dataset") or {}).get("config") or {}).get("env")
    facts: dict[str, Any] = {"env": env} if env is not None else {}
    config = payload["model"]["config"]
    return facts | {size: config[size] for size in SHARED_SIZES if size in config}


def check_checkpoints_agree(checkpoints: Sequence[tuple[str, str | os.PathLike[str]]]) -> None:
    """Refuses ensemble members whose checkpoints disagree on the environment they were trained
    on or on an interface size (before any model is built).

    Args:
        checkpoints: ``(label, checkpoint file or run directory)`` of the members that have one.

    Raises:
        EnsembleMismatch: naming the first member that disagrees with an earlier one.
    """
    seen: dict[str, tuple[str, Any]] = {}  # fact -> (the first member's label, its value)
    for label, path in checkpoints:
        for fact, value in checkpoint_facts(path).items():
            first = seen.setdefault(fact, (label, value))
            if first[1] != value:
                what = "was trained on" if fact == "env" else f"has {fact}"
                raise EnsembleMismatch(
                    f"ensemble member {label!r} {what} {value}, member {first[0]!r} "
                    f"{what} {first[1]}; members must agree on the environment and on "
                    f"{', '.join(SHARED_SIZES)}"
                )


def as_ensemble(model: Any) -> EnsembleModel | None:
    """``model`` itself, or the model a :class:`~vp2.models.contract.CheckedModel` wraps, if
    it is an :class:`EnsembleModel`; else ``None``."""
    inner = unwrap(model)
    return inner if isinstance(inner, EnsembleModel) else None
