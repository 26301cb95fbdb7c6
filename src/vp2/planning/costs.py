"""Planning costs on predicted frames (SPEC §6).

A **cost term** maps predicted frames to one cost per sample (lower is better)::

    term(frames) -> cost        frames: (N, T, C, H, W) float in [0, 1],   cost: (N,)

Terms are combined by :class:`WeightedCost`, and the planning agent turns a cost into the
optimizer's score with ``score = -cost``. The benchmark's costs are

* tabletop: ``1 × PixelSSE`` (:func:`tabletop_cost`);
* RoboDesk: ``0.5 × PixelSSE + 10 × ClassifierCost`` (:func:`robodesk_cost`), i.e. the score is
  ``-0.5 × SSE + 10 × Σ_t logit``.

:func:`build_cost` builds a task's cost from its registry entry (``Task.cost``, its weights and
classifier key, :data:`vp2.envs.tasks.TASKS`), with the RoboDesk classifier looked up in
:data:`vp2.classifiers.registry.CLASSIFIERS`; when a task has none it falls back to the pixel
term alone and reports the cost kind ``"pixel_only"``, which every trial record carries, so
results with and without classifiers are never silently mixed.

Everything here is plain differentiable torch, so gradient-based planners can backpropagate
through a cost. Goals are ``(C, H, W)`` (the same goal image for every predicted frame, as in
the benchmark) or ``(T, C, H, W)``; they are moved to the frames' device and dtype on use.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, Literal

import torch
from torch import Tensor

from vp2 import spec
from vp2.envs.tasks import get_task
from vp2.utils.fixedsum import fixed_sum

if TYPE_CHECKING:
    from vp2.classifiers.registry import ClassifierRegistry

#: ``term(frames (N, T, C, H, W)) -> cost (N,)``.
CostTerm = Callable[[Tensor], Tensor]
#: ``classifier(images (M, C, H, W)) -> success logits (M,) or (M, 1)``.
FrameClassifier = Callable[[Tensor], Tensor]
#: ``distance(images (M, C, H, W), goals (M, C, H, W)) -> distances (M,)`` (e.g. LPIPS).
PerceptualDistance = Callable[[Tensor, Tensor], Tensor]

#: Ensemble disagreement weight λ of SPEC §5 (:data:`vp2.spec.ENSEMBLE_DISAGREEMENT_WEIGHT`).
ENSEMBLE_DISAGREEMENT_WEIGHT = spec.ENSEMBLE_DISAGREEMENT_WEIGHT

#: Values per block of the CPU pixel error (about 4 MB of float32, a cache-sized block).
_CPU_BLOCK_VALUES = 1 << 20


def _check_frames(frames: Tensor) -> None:
    if frames.ndim != 5:
        raise ValueError(f"frames must have shape (N, T, C, H, W), got {tuple(frames.shape)}")


def _goal_for(goal: Tensor, frames: Tensor) -> Tensor:
    """``goal`` as a ``(1, T or 1, C, H, W)`` tensor that broadcasts against ``frames``."""
    goal = goal.to(frames)
    if goal.ndim == 3:
        goal = goal[None]  # (1, C, H, W): one goal image for every predicted frame
    if goal.ndim != 4 or goal.shape[1:] != frames.shape[2:]:
        raise ValueError(
            f"goal must have shape (C, H, W) or (T, C, H, W) matching frames "
            f"{tuple(frames.shape)}, got {tuple(goal.shape)}"
        )
    if goal.shape[0] not in (1, frames.shape[1]):
        raise ValueError(f"goal has {goal.shape[0]} frames but predictions have {frames.shape[1]}")
    return goal[None]


def pixel_sse(frames: Tensor, goal: Tensor) -> Tensor:
    """Squared pixel error to the goal, summed over predicted frames, channels and pixels.

    Args:
        frames: ``(N, T, C, H, W)`` predictions in ``[0, 1]``.
        goal: ``(C, H, W)`` or ``(T, C, H, W)`` goal in ``[0, 1]``.

    Returns:
        ``(N,)`` costs.
    """
    _check_frames(frames)
    goal = _goal_for(goal, frames)  # (1, T or 1, C, H, W)
    # On a CPU, a full-batch difference (100 MB for 200 x 10 frames of 64x64) is written to and
    # read back from memory; blocks of about a million values stay in cache and run faster.
    # A GPU prefers one large kernel. Either way the difference is formed explicitly: expanding
    # the square (sum f^2 - 2 f.g + sum g^2) is faster still but cancels catastrophically in
    # float32 exactly where it matters, close to the goal. The squares are added pairwise in an
    # order fixed by the frame size (fixed_sum), so a cost is the same bits on every CPU and
    # device; torch's own reductions add in an order set by the CPU's SIMD width.
    per_sample = frames[0].numel()
    block = frames.shape[0] if frames.is_cuda else max(1, _CPU_BLOCK_VALUES // per_sample)
    costs = []
    for chunk in frames.split(block):
        diff = (chunk - goal).flatten(1)  # (block, T*C*H*W)
        costs.append(fixed_sum(diff * diff, dim=1))  # (block,)
    return torch.cat(costs)  # (N,)


def classifier_cost(logits: Tensor) -> Tensor:
    """Classifier cost from per-frame success logits: ``-Σ_t logit``.

    Args:
        logits: ``(N, T)`` raw success logits of the predicted frames.

    Returns:
        ``(N,)`` costs (more confident success, lower cost).
    """
    if logits.ndim != 2:
        raise ValueError(f"logits must have shape (N, T), got {tuple(logits.shape)}")
    return -fixed_sum(logits, dim=1)


def _all_the_same(x: Tensor) -> bool:
    """Whether every ``(C, H, W)`` image of ``x (N, T, C, H, W)`` equals the first, bit for bit
    (one pixel column first, which rules out almost every batch of different images cheaply)."""
    first = x[:1, :1]
    return bool(
        torch.equal(x[..., 0], first[..., 0].expand_as(x[..., 0]))
        and torch.equal(x, first.expand_as(x))
    )


def _per_frame(
    fn: Callable[..., Tensor], frames: Tensor, *extra: Tensor, max_batch_size: int | None
) -> Tensor:
    """Applies an image function to all ``N·T`` frames in chunks; returns ``(N, T)``.

    When all ``N·T`` inputs are one image (the repeat-last-frame baseline predicts the context's
    last frame for every sample and step) and nothing needs a gradient, ``fn`` sees that image
    once and its value stands for every frame: every sample then has the same cost whatever
    ``fn``'s batch-size-dependent rounding, where thousands of copies (8,000 on the slide) cost
    seconds of a classifier per planning step.
    """
    n, t = frames.shape[:2]
    inputs = (frames, *extra)
    if (n * t > 1 and not any(x.requires_grad for x in inputs)
            and all(_all_the_same(x) for x in inputs)):
        value = fn(*(x[0, :1] for x in inputs)).reshape(-1)
        if value.shape[0] != 1:
            raise ValueError(
                f"a per-image function returned {value.shape[0]} values for 1 image; it "
                "must return one value per image"
            )
        return value.repeat(n * t).view(n, t)
    flat = [x.reshape(n * t, *x.shape[2:]) for x in inputs]  # (N*T, C, H, W) each
    chunk = max_batch_size or n * t
    out = [fn(*(x[i : i + chunk] for x in flat)) for i in range(0, n * t, chunk)]
    values = torch.cat([o.reshape(-1) for o in out])  # (N*T,)
    if values.shape[0] != n * t:
        raise ValueError(
            f"a per-image function returned {values.shape[0]} values for {n * t} images; it "
            "must return one value per image"
        )
    return values.view(n, t)


class PixelSSE:
    """Cost term: :func:`pixel_sse` to a fixed goal.

    Args:
        goal: ``(C, H, W)`` or ``(T, C, H, W)`` goal in ``[0, 1]``.
    """

    def __init__(self, goal: Tensor) -> None:
        self.goal = goal

    def __call__(self, frames: Tensor) -> Tensor:
        return pixel_sse(frames, self.goal)  # (N,)


class ClassifierCost:
    """Cost term: ``-Σ_t logit`` of a per-frame success classifier (SPEC §6).

    Args:
        classifier: ``images (M, C, H, W) -> logits (M,)`` (or ``(M, 1)``).
        max_batch_size: Most images per classifier call (``None``: all at once).
        exact: Call the classifier's ``exact_logits`` (logits that are the same bits on every
            CPU, :mod:`vp2.classifiers.exact`) instead of the classifier itself; for a
            classifier without that method, the classifier itself (its own arithmetic decides).
    """

    def __init__(
        self, classifier: FrameClassifier, max_batch_size: int | None = None, exact: bool = False
    ) -> None:
        self.classifier, self.max_batch_size, self.exact = classifier, max_batch_size, exact

    def __call__(self, frames: Tensor) -> Tensor:
        _check_frames(frames)
        fn = getattr(self.classifier, "exact_logits", self.classifier) if self.exact else (
            self.classifier)
        return classifier_cost(_per_frame(fn, frames, max_batch_size=self.max_batch_size))  # (N,)


class PerceptualCost:
    """Cost term: a perceptual distance (e.g. LPIPS) to the goal, summed over predicted frames.

    Any callable distance between image batches plugs in; the LPIPS network itself lives with
    the metrics.

    Args:
        distance: ``(images (M, C, H, W), goals (M, C, H, W)) -> (M,)``, images in ``[0, 1]``
            (a distance that wants ``[-1, 1]`` must rescale itself).
        goal: ``(C, H, W)`` or ``(T, C, H, W)`` goal in ``[0, 1]``.
        max_batch_size: Most images per distance call (``None``: all at once).
    """

    def __init__(
        self, distance: PerceptualDistance, goal: Tensor, max_batch_size: int | None = None
    ) -> None:
        self.distance = distance
        self.goal = goal
        self.max_batch_size = max_batch_size

    def __call__(self, frames: Tensor) -> Tensor:
        _check_frames(frames)
        goal = _goal_for(self.goal, frames).expand_as(frames)  # (N, T, C, H, W)
        per_frame = _per_frame(self.distance, frames, goal, max_batch_size=self.max_batch_size)
        return per_frame.sum(dim=1)  # (N,)


class WeightedCost:
    """Weighted sum of cost terms: ``cost = Σ_k w_k · term_k(frames)``.

    Example: the RoboDesk cost is
    ``WeightedCost([(0.5, PixelSSE(goal)), (10.0, ClassifierCost(classifier))])``.

    Args:
        terms: ``(weight, term)`` pairs.
    """

    def __init__(self, terms: Sequence[tuple[float, CostTerm]]) -> None:
        if not terms:
            raise ValueError("WeightedCost needs at least one term")
        self.terms = [(float(w), term) for w, term in terms]

    def breakdown(self, frames: Tensor) -> list[Tensor]:
        """The weighted cost of every term, ``[(N,), ...]`` in the order given (for logging)."""
        return [w * term(frames) for w, term in self.terms]

    def __call__(self, frames: Tensor) -> Tensor:
        parts = self.breakdown(frames)
        total = parts[0]
        for part in parts[1:]:  # in the terms' order, the same bits on every CPU
            total = total + part
        return total  # (N,)

    def score(self, frames: Tensor) -> Tensor:
        """The optimizer's score, ``-cost`` (higher is better)."""
        return -self(frames)  # (N,)


def tabletop_cost(goal: Tensor) -> WeightedCost:
    """SPEC §6 tabletop cost: the squared pixel error to the goal, summed over frames."""
    return WeightedCost([(spec.TABLETOP_PIXEL_WEIGHT, PixelSSE(goal))])


def robodesk_cost(
    goal: Tensor, classifier: FrameClassifier, max_batch_size: int | None = None
) -> WeightedCost:
    """SPEC §6 RoboDesk cost: ``0.5 × pixel SSE + 10 × (-Σ_t success logit)``."""
    return WeightedCost(
        [
            (spec.ROBODESK_PIXEL_WEIGHT, PixelSSE(goal)),
            (spec.ROBODESK_CLASSIFIER_WEIGHT, ClassifierCost(classifier, max_batch_size)),
        ]
    )


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
    classifiers: ClassifierRegistry | None = None,
    device: torch.device | None = None,
    exact: bool = False,
) -> tuple[WeightedCost, CostKind]:
    """The planning cost of a task (SPEC §6), in the form its registry entry names, and its kind.

    Args:
        task: Registered task name.
        goal: ``(3, H, W)`` goal image in [0, 1].
        mode: See :data:`CostMode`.
        classifiers: Where classifiers are looked up (default:
            :data:`vp2.classifiers.registry.CLASSIFIERS`).
        device: Device the classifier is loaded on (default: the goal's).
        exact: Score with the classifier's CPU-independent logits (:class:`ClassifierCost`);
            the simulator oracle's agent sets it, learned models keep float32 inference.

    Returns:
        The cost and its :data:`CostKind`.

    Raises:
        ValueError: for an unknown mode, or ``mode="spec"`` on a RoboDesk task without a
            registered classifier.
    """
    if mode not in COST_MODES:
        raise ValueError(f"unknown cost mode {mode!r}; choose one of {', '.join(COST_MODES)}")
    form = get_task(task)
    pixel_term = (form.pixel_weight, PixelSSE(goal))
    if form.cost == "pixel":
        return WeightedCost([pixel_term]), "pixel"
    if classifiers is None:
        # Imported on use: registering the shipped classifiers is not needed for the costs'
        # math, and `import vp2.planning` stays free of the classifiers package.
        from vp2.classifiers.registry import CLASSIFIERS

        classifiers = CLASSIFIERS
    classifier = None
    if mode != "pixel_only":
        classifier = classifiers.get(form.classifier, device or goal.device)
    if classifier is not None:
        classifier_term = (form.classifier_weight, ClassifierCost(classifier, exact=exact))
        return WeightedCost([pixel_term, classifier_term]), "pixel+classifier"
    if mode == "spec":
        raise ValueError(
            f"{task}: no success classifier is registered (vp2.classifiers.CLASSIFIERS), so the "
            "SPEC cost cannot be built; use cost mode 'auto' or 'pixel_only' to plan on pixels"
        )
    # The cost without its classifier term: the pixel term keeps its SPEC weight so that MPPI's
    # γ sees the same score scale as in the full cost.
    return WeightedCost([pixel_term]), "pixel_only"


def ensemble_disagreement(predictions: Tensor) -> Tensor:
    """Largest L1 deviation of an ensemble member from the ensemble mean, per sample.

    ``max_i ‖Iⁱ − mean_j Iʲ‖₁`` with the norm over frames, channels and pixels.

    Args:
        predictions: ``(M, N, T, C, H, W)`` predictions of ``M`` members.

    Returns:
        ``(N,)`` disagreements.
    """
    if predictions.ndim != 6:
        raise ValueError(
            f"predictions must have shape (M, N, T, C, H, W), got {tuple(predictions.shape)}"
        )
    deviation = (predictions - predictions.mean(dim=0, keepdim=True)).abs()
    return deviation.flatten(2).sum(dim=2).amax(dim=0)  # (M, N) -> (N,)


def choose_members(
    num_members: int, num_samples: int, generator: torch.Generator, per_sample: bool = True
) -> Tensor:
    """Random ensemble member for every sample: ``(N,)`` indices on the generator's device.

    Args:
        num_members: Ensemble size ``M``.
        num_samples: Number of samples ``N``.
        generator: Source of randomness.
        per_sample: Draw a member per sample (as the original code did); ``False`` draws one
            member for the whole batch.
    """
    size = num_samples if per_sample else 1
    members = torch.randint(num_members, (size,), generator=generator, device=generator.device)
    return members.expand(num_samples)


class EnsembleCost:
    """Cost of a randomly chosen ensemble member plus the disagreement penalty (SPEC §5).

    ``cost = term(I^{i_n})_n + λ · max_i ‖Iⁱ − mean‖₁`` with ``i_n`` drawn uniformly for every
    sample ``n``; the score is therefore the chosen member's score minus ``λ ×`` disagreement.

    Args:
        term: Cost on one member's frames, e.g. a :class:`WeightedCost`.
        generator: Source of the member choice.
        lam: Disagreement weight ``λ``.
        per_sample: See :func:`choose_members`.

    Attributes:
        last_members: ``(N,)`` the members drawn by the last call (``None`` before any).
    """

    def __init__(
        self,
        term: CostTerm,
        generator: torch.Generator,
        lam: float = ENSEMBLE_DISAGREEMENT_WEIGHT,
        per_sample: bool = True,
    ) -> None:
        self.term = term
        self.generator = generator
        self.lam = lam
        self.per_sample = per_sample
        self.last_members: Tensor | None = None

    def __call__(self, predictions: Tensor) -> Tensor:
        """Args: predictions ``(M, N, T, C, H, W)``. Returns ``(N,)`` costs."""
        penalty = ensemble_disagreement(predictions)  # (N,)
        num_members, num_samples = predictions.shape[:2]
        members = choose_members(num_members, num_samples, self.generator, self.per_sample)
        members = members.to(predictions.device)
        self.last_members = members
        chosen = predictions[members, torch.arange(num_samples, device=predictions.device)]
        return self.term(chosen) + self.lam * penalty  # (N,)

    def score(self, predictions: Tensor) -> Tensor:
        """The optimizer's score, ``-cost``."""
        return -self(predictions)  # (N,)
