"""The video prediction model interface and its boundary checks.

Every model the benchmark can plan with -- a trained network, the simulator oracle, an
ensemble -- implements :class:`VideoPredictionModel`. The planner calls
:meth:`VideoPredictionModel.predict` once per batch of candidate action sequences; nothing
else about a model is visible to it.

Every ``predict`` call is validated (:func:`check_inputs`, :func:`check_output`) so that a
wrong shape, dtype or value range fails at the boundary with a message naming the model and
the field. :class:`CheckedPredictor` runs those checks around a subclass's call; the trainable
networks (:class:`vp2.models.base.VideoPredictor`) derive from it, and any other
implementation gets the same checks by being wrapped in :class:`CheckedModel` (:func:`checked`).
"""

from __future__ import annotations

import abc
import contextlib
import inspect
import math
from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

import torch
from torch import Tensor, nn

from vp2 import spec

# Float rounding (e.g. uint8 / 255 on another device, or a clamp in half precision) may land a
# hair outside the nominal range; anything beyond this is a caller bug.
_RANGE_TOLERANCE = 1e-5
#: ``max_batch_size`` of a model that does not declare one (the planner's 200 samples in one
#: call; 800-sample tasks are split in four).
DEFAULT_MAX_BATCH_SIZE = spec.NUM_SAMPLES
_FLOAT_DTYPES = (torch.float16, torch.bfloat16, torch.float32, torch.float64)


@runtime_checkable
class VideoPredictionModel(Protocol):
    """An action-conditioned video prediction model, as the planner sees it.

    Attributes:
        name: Registered model name (e.g. ``"svg_prime"``), used in messages and results.
        num_context: Context frames per call: 2 (SPEC §4).
        num_future: Frames predicted per call: 10 (SPEC §4).
        action_dim: ``A``, the action size (4 tabletop, 5 RoboDesk).
        image_size: ``H = W`` of input and output frames (64 in the benchmark).
        max_batch_size: The largest batch one ``predict`` call should get (memory). Callers
            with more samples (e.g. 800 for ``open_slide``) split them, see
            :func:`predict_in_chunks`.

    ``predict(context_frames, actions, *, generator=None, grad=None)``:

    - ``context_frames``: ``(B, num_context, 3, H, W)`` floating point in [0, 1], the most
      recent observations, oldest first.
    - ``actions``: ``(B, num_context + num_future - 1, A)`` = ``(B, 11, A)`` floating point in
      [-1, 1]. ``actions[:, k]`` is executed in frame ``k`` and produces frame ``k + 1``
      (context frames are ``0 .. num_context - 1``): ``actions[:, 0]`` is the last executed
      action, which produced the last context frame, and ``actions[:, 1:]`` are the 10
      candidate actions whose outcomes are predicted.
    - ``generator``: source of the model's sampling noise (stochastic models). ``None`` uses
      a fresh generator with the model's fixed default seed, so a call is a deterministic
      function of its inputs.
    - ``grad``: ``None`` (default) records gradients only if grad mode is on and an input
      requires grad (gradient-based planners pass actions with ``requires_grad=True``);
      ``False`` always runs under ``torch.no_grad()``; ``True`` always records them.
    - Returns ``(B, num_future, 3, H, W)`` = ``(B, 10, 3, H, W)`` float32 in [0, 1], on the
      device of ``context_frames``: frames ``num_context .. num_context + num_future - 1``.

    A model treats batch elements independently (the planner differentiates summed scores).

    Only ``num_context``, ``num_future``, ``action_dim``, ``image_size`` and
    ``predict(context_frames, actions)`` are required of a plugin: :class:`CheckedModel`
    supplies ``name`` (the class name) and ``max_batch_size``
    (:data:`DEFAULT_MAX_BATCH_SIZE`), and passes ``generator`` and ``grad`` only to a
    ``predict`` that declares them (for one that does not declare ``grad``, ``grad=False``
    runs it under ``torch.no_grad()``).
    """

    name: str
    num_context: int
    num_future: int
    action_dim: int
    image_size: int
    max_batch_size: int

    def predict(
        self,
        context_frames: Tensor,
        actions: Tensor,
        *,
        generator: torch.Generator | None = None,
        grad: bool | None = None,
    ) -> Tensor: ...


# --------------------------------------------------------------------------- boundary checks


class ModelContractError(ValueError):
    """A ``predict`` call that broke the interface: which model, which field, expected vs got.

    ``field`` is ``context_frames``, ``actions`` or ``output`` (or an interface attribute such
    as ``action_dim``). A ``ValueError``, so existing handlers keep working.
    """

    def __init__(self, model: str, field: str, expected: str, got: str, call: str = "predict"):
        super().__init__(f"{model}.{call}: {field}: expected {expected}, got {got}")
        self.model, self.field, self.expected, self.got, self.call = (
            model, field, expected, got, call
        )

    def __reduce__(self) -> tuple[Any, ...]:  # picklable across worker processes
        return (type(self), (self.model, self.field, self.expected, self.got, self.call))


def _fail(model: str, field: str, expected: str, got: str) -> ModelContractError:
    return ModelContractError(model, field, expected, got)


#: Attribute set on an exception raised inside a model's ``predict`` (by
#: :meth:`CheckedPredictor.predict`), naming the call, e.g. ``"DriftModel.predict"``.
MODEL_CALL_ATTR = "vp2_model_call"


def _mark_model_call(exc: BaseException, call: str) -> None:
    with contextlib.suppress(AttributeError, TypeError):
        setattr(exc, MODEL_CALL_ATTR, call)


def model_failure(exc: BaseException) -> dict[str, str] | None:
    """What a failure at the model boundary is about, or ``None`` for any other error.

    A boundary failure is a :class:`ModelContractError` (a checked input or output) or an
    exception raised inside the model's ``predict``. Returns ``{"model", "field", "expected",
    "got"}`` (plain strings, for the runner's records and its fail-fast).
    """
    if isinstance(exc, ModelContractError):
        return {
            "model": exc.model,
            "field": f"{exc.call} {exc.field}",
            "expected": exc.expected,
            "got": exc.got,
        }
    call = getattr(exc, MODEL_CALL_ATTR, None)
    if isinstance(call, str):
        model, _, method = call.rpartition(".")
        return {
            "model": model,
            "field": f"{method}() call",
            "expected": "no exception",
            "got": f"{type(exc).__name__}: {exc}",
        }
    return None


def _check_tensor(
    model: str,
    field: str,
    x: Any,
    shape: tuple[int | None, ...],
    shape_text: str,
    low: float,
    high: float,
) -> None:
    if not isinstance(x, Tensor):
        raise _fail(model, field, f"a torch.Tensor of shape {shape_text}", type(x).__name__)
    if x.dim() != len(shape) or any(
        s is not None and s != d for s, d in zip(shape, x.shape, strict=True)
    ):
        raise _fail(model, field, f"shape {shape_text}", f"{tuple(x.shape)}")
    if x.dtype not in _FLOAT_DTYPES:
        hint = " (divide uint8 images by 255)" if x.dtype == torch.uint8 else ""
        raise _fail(model, field, f"a floating point dtype{hint}", str(x.dtype))
    if x.numel() == 0:
        return
    with torch.no_grad():
        # One device sync per tensor: min/max are NaN/inf exactly when some value is.
        lo, hi = torch.stack([x.min(), x.max()]).float().tolist()
        if not (math.isfinite(lo) and math.isfinite(hi)):
            bad = int((~torch.isfinite(x)).sum())
            raise _fail(model, field, "finite values", f"{bad} NaN/inf values")
    if lo < low - _RANGE_TOLERANCE or hi > high + _RANGE_TOLERANCE:
        raise _fail(model, field, f"values in [{low:g}, {high:g}]", f"range [{lo:.4g}, {hi:.4g}]")


def check_inputs(model: VideoPredictionModel, context_frames: Any, actions: Any) -> None:
    """Checks a ``predict`` call's inputs against the model's declared contract.

    Raises:
        ValueError: naming the model, the field (``context_frames`` or ``actions``), what was
            expected and what was given.
    """
    c, size, a = model.num_context, model.image_size, model.action_dim
    _check_tensor(
        model.name,
        "context_frames",
        context_frames,
        (None, c, 3, size, size),
        f"(B, {c}, 3, {size}, {size})",
        0.0,
        1.0,
    )
    steps = model.num_context + model.num_future - 1
    _check_tensor(model.name, "actions", actions, (None, steps, a), f"(B, {steps}, {a})", -1.0, 1.0)
    if actions.shape[0] != context_frames.shape[0]:
        raise _fail(
            model.name,
            "actions",
            f"batch size {context_frames.shape[0]} (as context_frames)",
            f"{actions.shape[0]}",
        )


def check_output(model: VideoPredictionModel, output: Any, batch_size: int) -> None:
    """Checks a ``predict`` call's result; a diverged network fails here, not in the cost.

    Raises:
        ValueError: naming the model and the field ``output``.
    """
    t, size = model.num_future, model.image_size
    _check_tensor(
        model.name,
        "output",
        output,
        (batch_size, t, 3, size, size),
        f"({batch_size}, {t}, 3, {size}, {size})",
        0.0,
        1.0,
    )
    if output.dtype != torch.float32:
        raise _fail(model.name, "output", "dtype torch.float32", str(output.dtype))


#: The attributes a model must have; everything else of the interface has a default.
REQUIRED_ATTRIBUTES: tuple[str, ...] = (
    "num_context", "num_future", "action_dim", "image_size", "predict"
)


def _declared_keywords(fn: Callable[..., Any]) -> frozenset[str]:
    """Which of ``generator``/``grad`` ``fn`` accepts (all, if it takes ``**kwargs``)."""
    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):  # no signature (a builtin): pass only the required ones
        return frozenset()
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params):
        return frozenset({"generator", "grad"})
    names = {
        p.name
        for p in params
        if p.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    }
    return frozenset(names & {"generator", "grad"})


class CheckedPredictor(abc.ABC):
    """Base of the implementations whose ``predict`` checks every call.

    ``predict`` validates the inputs (:func:`check_inputs`), runs the subclass's
    :meth:`_checked_call`, marks an exception raised there as a failure of this model
    (:func:`model_failure`), and validates the output (:func:`check_output`). Subclasses:
    :class:`vp2.models.base.VideoPredictor` (the trainable networks) and
    :class:`CheckedModel` (any other implementation); :func:`checked` leaves them as they are.
    """

    name: str

    def predict(
        self,
        context_frames: Tensor,
        actions: Tensor,
        *,
        generator: torch.Generator | None = None,
        grad: bool | None = None,
    ) -> Tensor:
        """Predicts the next ``num_future`` frames; see :class:`VideoPredictionModel`."""
        check_inputs(self, context_frames, actions)
        try:
            out = self._checked_call(context_frames, actions, generator, grad)
        except Exception as exc:
            _mark_model_call(exc, f"{self.name}.predict")
            raise
        check_output(self, out, context_frames.shape[0])
        return out

    @abc.abstractmethod
    def _checked_call(
        self, frames: Tensor, actions: Tensor, generator: torch.Generator | None, grad: bool | None
    ) -> Tensor:
        """The prediction itself, on ``frames`` (the context frames) and ``actions`` that passed
        :func:`check_inputs`; ``generator`` and ``grad`` as given to ``predict``."""


class CheckedModel(CheckedPredictor):
    """Wraps any :class:`VideoPredictionModel` so that every ``predict`` call is checked.

    For implementations that do not derive from :class:`vp2.models.base.VideoPredictor`
    (plugins, the simulator oracle, ensembles); a ``VideoPredictor`` already checks its calls.
    Use :func:`checked`, which wraps once. The wrapper also completes the interface:

    - ``name`` defaults to the class name, ``max_batch_size`` to
      :data:`DEFAULT_MAX_BATCH_SIZE`;
    - ``generator`` and ``grad`` are passed only to a ``predict`` that declares them (or
      ``**kwargs``), decided once here from its signature; for one without ``grad``,
      ``grad=False`` runs it under ``torch.no_grad()`` and ``grad=True`` under
      ``torch.enable_grad()``.

    Every other attribute is read from and written to the wrapped model.

    Raises:
        TypeError: if the model lacks one of :data:`REQUIRED_ATTRIBUTES`.
    """

    _OWN = frozenset({"model", "_keywords"})

    def __init__(self, model: VideoPredictionModel):
        missing = [attr for attr in REQUIRED_ATTRIBUTES if not hasattr(model, attr)]
        if missing:
            raise TypeError(
                f"{type(model).__name__} does not implement VideoPredictionModel: missing "
                f"{', '.join(missing)} (docs/evaluation.md, \"Plugins\")"
            )
        object.__setattr__(self, "model", model)
        object.__setattr__(self, "_keywords", _declared_keywords(model.predict))

    def __getattr__(self, attr: str) -> Any:
        return getattr(self.__dict__["model"], attr)

    def __setattr__(self, attr: str, value: Any) -> None:
        if attr in self._OWN:
            object.__setattr__(self, attr, value)
        else:
            setattr(self.model, attr, value)

    @property
    def name(self) -> str:
        name = getattr(self.model, "name", None)
        return name if isinstance(name, str) and name else type(self.model).__name__

    @property
    def max_batch_size(self) -> int:
        size = getattr(self.model, "max_batch_size", None)
        return DEFAULT_MAX_BATCH_SIZE if size is None else int(size)

    @max_batch_size.setter
    def max_batch_size(self, value: int) -> None:
        self.model.max_batch_size = value

    def _checked_call(
        self, frames: Tensor, actions: Tensor, generator: torch.Generator | None, grad: bool | None
    ) -> Tensor:
        kwargs: dict[str, Any] = {}
        if "generator" in self._keywords:
            kwargs["generator"] = generator
        if "grad" in self._keywords:
            kwargs["grad"] = grad
            mode: contextlib.AbstractContextManager = contextlib.nullcontext()
        elif grad is None:
            mode = contextlib.nullcontext()
        else:
            mode = torch.enable_grad() if grad else torch.no_grad()
        with mode:
            return self.model.predict(frames, actions, **kwargs)


def checked(model: Any) -> VideoPredictionModel:
    """``model`` with checked ``predict`` calls and the interface's defaults: a
    :class:`CheckedPredictor` (a :class:`vp2.models.base.VideoPredictor` or a
    :class:`CheckedModel`) as it is, anything else wrapped in a :class:`CheckedModel` (once).

    Raises:
        TypeError: if the model lacks one of :data:`REQUIRED_ATTRIBUTES`.
    """
    if isinstance(model, CheckedPredictor):
        return model
    return CheckedModel(model)


def unwrap(model: Any) -> Any:
    """The model inside a :class:`CheckedModel` (anything else as it is)."""
    return model.model if isinstance(model, CheckedModel) else model


def gradient_problem(model: VideoPredictionModel, device: str | torch.device = "cpu") -> str | None:
    """Why ``model`` cannot give gradients of its predictions with respect to the actions,
    or ``None`` if it can (what the gradient-based planners ``cem_gd`` and ``lbfgs`` need).

    A model may say so itself with ``differentiable = False``, or answer itself with a
    ``gradient_problem(device)`` method (an ensemble asks each member); otherwise one batch-1
    ``predict`` call with ``grad=True`` on grey frames and zero actions (on ``device``) must
    return frames whose gradient reaches the actions.
    """
    own = getattr(unwrap(model), "gradient_problem", None)
    if callable(own):
        return own(device)
    model = checked(model)
    if getattr(model, "differentiable", None) is False:
        return "declares differentiable = False"
    size, steps = model.image_size, model.num_context + model.num_future - 1
    frames = torch.full((1, model.num_context, 3, size, size), 0.5, device=device)
    actions = torch.zeros(1, steps, model.action_dim, device=device, requires_grad=True)
    try:
        with torch.enable_grad():
            out = model.predict(frames, actions, grad=True)
            if not out.requires_grad:
                return "returned predictions without a gradient (grad_fn is None)"
            (grad,) = torch.autograd.grad(out.float().sum(), actions, allow_unused=True)
    except Exception as exc:
        return f"raised {type(exc).__name__}: {exc} when asked for gradients"
    if grad is None:
        return "returned predictions that do not depend on the actions"
    return None


def predict_in_chunks(
    model: VideoPredictionModel,
    context_frames: Tensor,
    actions: Tensor,
    *,
    generator: torch.Generator | None = None,
    grad: bool | None = None,
    chunk_size: int | None = None,
) -> Tensor:
    """``model.predict`` on a batch of any size, in chunks of at most ``model.max_batch_size``.

    With ``generator=None`` one generator seeded with the model's ``sample_seed`` is shared by
    all chunks, so chunks do not repeat each other's noise, and the first chunk gets the same
    noise as an unchunked ``predict`` call.

    Args:
        model: The model.
        context_frames: ``(N, num_context, 3, H, W)`` in [0, 1].
        actions: ``(N, num_context + num_future - 1, A)`` in [-1, 1].
        generator: Sampling noise for stochastic models.
        grad: As in :meth:`VideoPredictionModel.predict`.
        chunk_size: Overrides ``model.max_batch_size`` (e.g. smaller, to save memory).

    Returns:
        ``(N, num_future, 3, H, W)`` predicted frames.
    """
    size = chunk_size or getattr(model, "max_batch_size", None) or DEFAULT_MAX_BATCH_SIZE
    if size <= 0:
        raise ValueError(f"chunk size must be > 0, got {size}")
    n = context_frames.shape[0]
    if n <= size:
        return model.predict(context_frames, actions, generator=generator, grad=grad)
    if generator is None:
        seed = getattr(model, "sample_seed", 0)
        generator = torch.Generator(_model_device(model)).manual_seed(seed)
    parts = [
        model.predict(
            context_frames[i : i + size], actions[i : i + size], generator=generator, grad=grad
        )
        for i in range(0, n, size)
    ]
    return torch.cat(parts)  # (N, num_future, 3, H, W)


def _model_device(model: Any) -> torch.device:
    model = unwrap(model)
    if isinstance(model, nn.Module):
        for p in model.parameters():
            return p.device
    return torch.device("cpu")
