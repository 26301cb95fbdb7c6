"""The base class of the trainable video prediction networks.

:class:`VideoPredictor` is a :class:`~vp2.models.contract.CheckedPredictor` (every ``predict``
call is checked against :class:`~vp2.models.contract.VideoPredictionModel`) and an
``nn.Module`` with the training loss used by :mod:`vp2.training`. A subclass declares its
registered name, its config dataclass and its original training recipe
(:class:`TrainingDefaults`), and implements the network's rollout (``_predict``) and loss
(``_compute_loss``). Layers and loss terms shared by the models are in
:mod:`vp2.models.layers`.
"""

from __future__ import annotations

import abc
import contextlib
import dataclasses
import inspect
from collections.abc import Iterator
from typing import Any, ClassVar

import torch
from torch import Tensor, nn

from vp2 import spec
from vp2.models.contract import DEFAULT_MAX_BATCH_SIZE, CheckedPredictor
from vp2.models.layers import FrameLoss, PerceptualLoss


@dataclasses.dataclass
class ModelConfig:
    """The fields every model config has: the interface's sizes, which
    :class:`VideoPredictor` reads from its config. A model's config dataclass derives from
    this one and adds its architecture, loss and inference settings.

    Attributes:
        action_dim: Action size ``A`` (4 tabletop, 5 RoboDesk).
        image_size: Frame side ``H = W``; a model may need a multiple of some factor.
        num_context: Context frames per call (SPEC §4).
        num_future: Predicted frames per call (SPEC §4).
    """

    action_dim: int = 5
    image_size: int = 64
    num_context: int = spec.NUM_CONTEXT
    num_future: int = spec.NUM_FUTURE

    def check_image_size(self, model: str, factor: int) -> None:
        """Raises ``ValueError`` (naming ``model``) unless ``image_size`` is a multiple of
        ``factor``; for a config's ``__post_init__``."""
        if self.image_size % factor:
            raise ValueError(
                f"{model}: image_size must be a multiple of {factor}, got {self.image_size}"
            )


#: The interface's sizes: the fields of :class:`ModelConfig`, which every model config has.
CONTRACT_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(ModelConfig))


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
    """Optimiser settings of a model's original training recipe (model-specs).

    The defaults -- Adam 3e-4, betas (0.9, 0.999), eps 1e-8, no weight decay, no gradient
    clipping -- are the recipe of SVG′ and Struct-VRNN; other models state what differs.
    """

    optimizer: str = "adam"  # "adam" or "adamw"
    lr: float = 3e-4
    betas: tuple[float, float] = (0.9, 0.999)
    eps: float = 1e-8
    weight_decay: float = 0.0
    grad_clip: float | None = None  # max global gradient norm; None = no clipping


class VideoPredictor(nn.Module, CheckedPredictor):
    """Base class of the trainable models: checked ``predict``, training loss, config.

    Subclasses set the class attributes ``name`` (registered name), ``config_class`` (a
    dataclass whose instance fully determines the architecture; it has the
    :data:`CONTRACT_FIELDS`, e.g. by deriving from :class:`ModelConfig`) and
    ``training_defaults``, and implement :meth:`_predict` and :meth:`_compute_loss`. Missing
    pieces are reported when the subclass is defined, not when it is first used.

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
            need = set(CONTRACT_FIELDS) - fields
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
        self.max_batch_size: int = DEFAULT_MAX_BATCH_SIZE
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

    def _checked_call(
        self, frames: Tensor, actions: Tensor, generator: torch.Generator | None, grad: bool | None
    ) -> Tensor:
        """The network's rollout in eval mode (under autocast on CUDA), in float32 on the
        device of ``frames``; called by ``predict`` between the checks."""
        device = self.device
        if generator is None:
            generator = torch.Generator(device).manual_seed(self.sample_seed)
        dtype = next(self.parameters()).dtype
        # Contiguous: convolutions round differently for other memory layouts, and a call
        # must be a function of the values only.
        context = frames.to(device=device, dtype=dtype).contiguous()  # (B, C, 3, H, W)
        acts = actions.to(device=device, dtype=dtype)  # (B, C + T - 1, A)
        grad_mode = torch.enable_grad() if _grad_enabled(grad, frames, actions) else torch.no_grad()
        with grad_mode, self._eval_mode(), self._autocast(device, self.inference_autocast):
            out = self._predict(context, acts, generator)  # (B, T, 3, H, W)
        return out.float().to(frames.device)

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

    def compute_loss(
        self,
        frames: Tensor,
        actions: Tensor,
        generator: torch.Generator,
        perceptual: PerceptualLoss | None = None,
        perceptual_weight: float = 0.0,
    ) -> LossOutput:
        """The training objective on a clip, with teacher forcing (the trainer's step).

        Args:
            frames: ``(B, T, 3, H, W)`` clip in [0, 1] (``T = num_context + num_future``).
            actions: ``(B, T - 1, A)``; ``actions[:, k]`` produced ``frames[:, k + 1]``.
            generator: Noise for posterior samples, on the model's device.
            perceptual: Optional perceptual distance added to the reconstruction loss.
            perceptual_weight: Its weight (the paper used 1 and 10 with LPIPS).
        """
        frame_loss = FrameLoss(perceptual, perceptual_weight)
        return self._compute_loss(frames, actions, generator, frame_loss)

    @abc.abstractmethod
    def _compute_loss(
        self, frames: Tensor, actions: Tensor, generator: torch.Generator, frame_loss: FrameLoss
    ) -> LossOutput:
        """The model's objective; ``frame_loss`` is its reconstruction loss of frames (pixel
        MSE plus the perceptual term, if any). Arguments as in :meth:`compute_loss`."""

    def config_dict(self) -> dict[str, Any]:
        """The architecture config as plain data (for checkpoints): tuples become lists."""
        config = dataclasses.asdict(self.config)
        return {k: list(v) if isinstance(v, tuple) else v for k, v in config.items()}


def _grad_enabled(grad: bool | None, *inputs: Tensor) -> bool:
    if grad is None:
        return torch.is_grad_enabled() and any(x.requires_grad for x in inputs)
    return grad
