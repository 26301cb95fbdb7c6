"""The video prediction model interface and its boundary checks.

Every model the benchmark can plan with -- a trained network, the simulator oracle, an
ensemble -- implements :class:`VideoPredictionModel`. The planner calls
:meth:`VideoPredictionModel.predict` once per batch of candidate action sequences; nothing
else about a model is visible to it.

Trainable networks subclass :class:`VideoPredictor`, which adds the training loss used by
:mod:`vp2.training`, and whose ``predict`` validates every call (:func:`check_inputs`,
:func:`check_output`) so that a wrong shape, dtype or value range fails at the boundary with
a message naming the model and the field. Other implementations get the same checks by being
wrapped in :class:`CheckedModel`.
"""

from __future__ import annotations

import abc
import contextlib
import dataclasses
import inspect
import math
from collections.abc import Callable, Iterator
from typing import Any, ClassVar, Protocol, runtime_checkable

import torch
from torch import Tensor, nn

#: Context frames the benchmark gives a model (SPEC §4).
NUM_CONTEXT = 2
#: Frames a model predicts per call (SPEC §4).
NUM_FUTURE = 10

#: A perceptual distance ``perceptual(pred (N, 3, H, W), target (N, 3, H, W)) -> (N,)`` on
#: frames in [0, 1], e.g. LPIPS. Used as an optional extra training loss term.
PerceptualLoss = Callable[[Tensor, Tensor], Tensor]

# Float rounding (e.g. uint8 / 255 on another device, or a clamp in half precision) may land a
# hair outside the nominal range; anything beyond this is a caller bug.
_RANGE_TOLERANCE = 1e-5
#: ``max_batch_size`` of a model that does not declare one (the planner's 200 samples in one
#: call; 800-sample tasks are split in four).
DEFAULT_MAX_BATCH_SIZE = 200
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


#: Attribute set on an exception raised inside a model's ``predict`` (by :class:`CheckedModel`
#: and :class:`VideoPredictor`), naming the call, e.g. ``"DriftModel.predict"``.
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


def _grad_enabled(grad: bool | None, *inputs: Tensor) -> bool:
    if grad is None:
        return torch.is_grad_enabled() and any(x.requires_grad for x in inputs)
    return grad


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


class CheckedModel:
    """Wraps any :class:`VideoPredictionModel` so that every ``predict`` call is checked.

    For implementations that do not derive from :class:`VideoPredictor` (plugins, the
    simulator oracle, ensembles); a :class:`VideoPredictor` already checks its calls. Use
    :func:`checked`, which wraps once. The wrapper also completes the interface:

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
                f"{', '.join(missing)} (docs/benchmark.md, \"Plugins\")"
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

    def predict(
        self,
        context_frames: Tensor,
        actions: Tensor,
        *,
        generator: torch.Generator | None = None,
        grad: bool | None = None,
    ) -> Tensor:
        check_inputs(self, context_frames, actions)
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
        try:
            with mode:
                out = self.model.predict(context_frames, actions, **kwargs)
        except Exception as exc:
            _mark_model_call(exc, f"{self.name}.predict")
            raise
        check_output(self, out, context_frames.shape[0])
        return out


def checked(model: Any) -> VideoPredictionModel:
    """``model`` with checked ``predict`` calls and the interface's defaults: a
    :class:`VideoPredictor` or :class:`CheckedModel` as it is, anything else wrapped in a
    :class:`CheckedModel` (once).

    Raises:
        TypeError: if the model lacks one of :data:`REQUIRED_ATTRIBUTES`.
    """
    if isinstance(model, (VideoPredictor, CheckedModel)):
        return model
    return CheckedModel(model)


def unwrap(model: Any) -> Any:
    """The model inside a :class:`CheckedModel` (anything else as it is)."""
    return model.model if isinstance(model, CheckedModel) else model


def gradient_problem(model: VideoPredictionModel, device: str | torch.device = "cpu") -> str | None:
    """Why ``model`` cannot give gradients of its predictions with respect to the actions,
    or ``None`` if it can (what the gradient-based planners ``cem_gd`` and ``lbfgs`` need).

    A model may say so itself with ``differentiable = False``; otherwise one batch-1
    ``predict`` call with ``grad=True`` on grey frames and zero actions (on ``device``) must
    return frames whose gradient reaches the actions.
    """
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


# --------------------------------------------------------------------------- trainable models


@dataclasses.dataclass
class LossOutput:
    """What a training step of a :class:`VideoPredictor` returns.

    Attributes:
        loss: Scalar to minimise.
        metrics: Detached scalars to log (``mse``, ``kl``, ...).
        predictions: ``(B, T - 1, 3, H, W)`` reconstructions of frames ``1 .. T - 1``.
    """

    loss: Tensor
    metrics: dict[str, Tensor]
    predictions: Tensor


@dataclasses.dataclass
class TrainingDefaults:
    """Optimiser settings of a model's original training recipe (model-specs)."""

    optimizer: str = "adam"  # "adam" or "adamw"
    lr: float = 3e-4
    betas: tuple[float, float] = (0.9, 0.999)
    eps: float = 1e-8
    weight_decay: float = 0.0
    grad_clip: float | None = None  # max global gradient norm; None = no clipping


class VideoPredictor(nn.Module, abc.ABC):
    """Base class of the trainable models: checked ``predict``, training loss, config.

    Subclasses set the class attributes ``name`` (registered name), ``config_class`` (a
    dataclass whose instance fully determines the architecture; it has ``action_dim``,
    ``image_size``, ``num_context`` and ``num_future`` fields) and ``training_defaults``,
    and implement :meth:`_predict` and :meth:`compute_loss`. Missing pieces are reported when
    the subclass is defined, not when it is first used.

    ``predict`` always runs the network in eval mode (BatchNorm running statistics), so the
    planner's results do not depend on a forgotten ``model.eval()``; the previous mode is
    restored afterwards. On CUDA it runs under autocast (``inference_autocast``).
    """

    name: ClassVar[str]
    config_class: ClassVar[type]
    training_defaults: ClassVar[TrainingDefaults]

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if inspect.isabstract(cls):
            return
        problems = []
        if not isinstance(getattr(cls, "name", None), str) or not cls.name:
            problems.append("class attribute `name` (a non-empty str)")
        config_class = getattr(cls, "config_class", None)
        if not (isinstance(config_class, type) and dataclasses.is_dataclass(config_class)):
            problems.append("class attribute `config_class` (a dataclass)")
        else:
            fields = {f.name for f in dataclasses.fields(config_class)}
            need = {"action_dim", "image_size", "num_context", "num_future"} - fields
            if need:
                problems.append(f"config_class fields {sorted(need)}")
        if not isinstance(getattr(cls, "training_defaults", None), TrainingDefaults):
            problems.append("class attribute `training_defaults` (a TrainingDefaults)")
        if problems:
            raise TypeError(f"VideoPredictor subclass {cls.__name__} lacks " + "; ".join(problems))

    def __init__(self, config: Any):
        super().__init__()
        if not isinstance(config, self.config_class):
            raise TypeError(f"{self.name} needs a {self.config_class.__name__}, got {config!r}")
        self.config = config
        #: The largest batch one ``predict`` call should get (see the interface).
        self.max_batch_size: int = 200
        #: Seed of the default generator used when ``predict`` gets none.
        self.sample_seed: int = 0
        #: Autocast dtype for ``predict`` on CUDA (``None`` = full precision).
        self.inference_autocast: torch.dtype | None = (
            torch.bfloat16
            if torch.cuda.is_available() and torch.cuda.is_bf16_supported()
            else torch.float16
        )

    # The interface's attributes, read from the config so that they cannot disagree with it.
    @property
    def num_context(self) -> int:
        return self.config.num_context

    @property
    def num_future(self) -> int:
        return self.config.num_future

    @property
    def action_dim(self) -> int:
        return self.config.action_dim

    @property
    def image_size(self) -> int:
        return self.config.image_size

    @property
    def device(self) -> torch.device:
        return next(self.parameters()).device

    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters())

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
        device = self.device
        if generator is None:
            generator = torch.Generator(device).manual_seed(self.sample_seed)
        dtype = next(self.parameters()).dtype
        # Contiguous: convolutions round differently for other memory layouts, and a call
        # must be a function of the values only.
        frames = context_frames.to(device=device, dtype=dtype).contiguous()  # (B, C, 3, H, W)
        acts = actions.to(device=device, dtype=dtype)  # (B, C + T - 1, A)
        grad_mode = (
            torch.enable_grad()
            if _grad_enabled(grad, context_frames, actions)
            else (torch.no_grad())
        )
        try:
            with grad_mode, self._eval_mode(), self._autocast(device, self.inference_autocast):
                out = self._predict(frames, acts, generator)  # (B, T, 3, H, W)
        except Exception as exc:
            _mark_model_call(exc, f"{self.name}.predict")
            raise
        out = out.float().to(context_frames.device)
        check_output(self, out, context_frames.shape[0])
        return out

    @contextlib.contextmanager
    def _eval_mode(self) -> Iterator[None]:
        was_training = self.training
        self.eval()
        try:
            yield
        finally:
            self.train(was_training)

    @staticmethod
    def _autocast(
        device: torch.device, dtype: torch.dtype | None
    ) -> contextlib.AbstractContextManager:
        # Mixed precision only on CUDA: CPU autocast is slower than float32 for these convs.
        if device.type == "cuda" and dtype is not None:
            return torch.autocast("cuda", dtype=dtype)
        return contextlib.nullcontext()

    @abc.abstractmethod
    def _predict(
        self, context_frames: Tensor, actions: Tensor, generator: torch.Generator
    ) -> Tensor:
        """The network's rollout on checked inputs already on the model's device.

        Args:
            context_frames: ``(B, num_context, 3, H, W)``.
            actions: ``(B, num_context + num_future - 1, A)``.
            generator: Noise source on the model's device.

        Returns:
            ``(B, num_future, 3, H, W)`` frames in [0, 1].
        """

    @abc.abstractmethod
    def compute_loss(
        self,
        frames: Tensor,
        actions: Tensor,
        generator: torch.Generator,
        perceptual: PerceptualLoss | None = None,
        perceptual_weight: float = 0.0,
    ) -> LossOutput:
        """The training objective on a clip, with teacher forcing.

        Args:
            frames: ``(B, T, 3, H, W)`` clip in [0, 1] (``T = num_context + num_future``).
            actions: ``(B, T - 1, A)``; ``actions[:, k]`` produced ``frames[:, k + 1]``.
            generator: Noise for posterior samples, on the model's device.
            perceptual: Optional perceptual distance added to the reconstruction loss.
            perceptual_weight: Its weight (the paper used 1 and 10 with LPIPS).
        """

    def config_dict(self) -> dict[str, Any]:
        """The architecture config as plain data (for checkpoints)."""
        return dataclasses.asdict(self.config)


# --------------------------------------------------------------------------- shared pieces


def sample_normal(shape: tuple[int, ...], like: Tensor, generator: torch.Generator) -> Tensor:
    """Standard normal noise of ``shape`` with ``like``'s device and dtype, from ``generator``.

    Drawn on the generator's device (a CPU generator can drive a CUDA model) and moved.
    """
    eps = torch.randn(shape, generator=generator, device=generator.device, dtype=torch.float32)
    return eps.to(device=like.device, dtype=like.dtype)


def reparameterize(mu: Tensor, logvar: Tensor, generator: torch.Generator) -> Tensor:
    """A sample of ``N(mu, exp(logvar))``, differentiable in ``mu`` and ``logvar``."""
    return mu + torch.exp(0.5 * logvar) * sample_normal(tuple(mu.shape), mu, generator)


def gaussian_kl(mu_q: Tensor, logvar_q: Tensor, mu_p: Tensor, logvar_p: Tensor) -> Tensor:
    """``KL(N(mu_q, var_q) || N(mu_p, var_p))`` summed over all but the batch dim, batch mean.

    Computed in float32: under fp16 autocast ``exp(logvar)`` overflows easily.
    """
    mu_q, logvar_q, mu_p, logvar_p = (t.float() for t in (mu_q, logvar_q, mu_p, logvar_p))
    kl = 0.5 * (logvar_p - logvar_q + (logvar_q.exp() + (mu_q - mu_p) ** 2) / logvar_p.exp() - 1)
    return kl.flatten(1).sum(1).mean()


def frame_losses(
    predictions: Tensor,
    targets: Tensor,
    perceptual: PerceptualLoss | None,
    perceptual_weight: float,
) -> tuple[Tensor, Tensor, Tensor | None]:
    """Per-frame reconstruction losses, averaged over the batch.

    Args:
        predictions: ``(B, T, 3, H, W)``.
        targets: ``(B, T, 3, H, W)``.
        perceptual: Optional perceptual distance on frames.
        perceptual_weight: Its weight.

    Returns:
        ``(mse (T,), total (T,), perceptual (T,) or None)`` where ``total = mse + weight *
        perceptual``. MSE is the mean over pixels of each frame, as ``nn.MSELoss``.
    """
    predictions, targets = predictions.float(), targets.float()
    mse = ((predictions - targets) ** 2).mean(dim=(0, 2, 3, 4))  # (T,)
    if perceptual is None or perceptual_weight == 0:
        return mse, mse, None
    b, t = predictions.shape[:2]
    dist = perceptual(predictions.flatten(0, 1), targets.flatten(0, 1))  # (B * T,)
    if dist.shape != (b * t,):
        raise ValueError(
            f"perceptual loss: expected shape ({b * t},) for {b * t} frames, got {tuple(dist.shape)}"
        )
    per_frame = dist.float().view(b, t).mean(0)  # (T,)
    return mse, mse + perceptual_weight * per_frame, per_frame


def init_normal_(module: nn.Module, std: float = 0.02) -> None:
    """DCGAN-style init used by SVG: conv/linear weights ``N(0, std)``, biases 0, BN
    ``gamma ~ N(1, std)``. Deterministic under the caller's ``torch.manual_seed``/fork."""
    for m in module.modules():
        if isinstance(m, (nn.Conv2d, nn.ConvTranspose2d, nn.Linear)):
            nn.init.normal_(m.weight, 0.0, std)
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.BatchNorm2d):
            nn.init.normal_(m.weight, 1.0, std)
            nn.init.zeros_(m.bias)


def scaled(channels: float) -> int:
    """A fractional channel count rounded to an integer >= 1 (size multipliers M, K)."""
    return max(1, int(math.floor(channels + 0.5)))
