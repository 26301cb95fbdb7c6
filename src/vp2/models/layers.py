"""Building blocks and loss terms shared by the trainable models.

Latent sampling (:func:`sample_normal`, :func:`reparameterize`), the Gaussian KL, the
reconstruction loss of frames (:class:`FrameLoss`), SVG's skip-connection rule
(:func:`context_skips`), initialisation and channel-count helpers. Nothing here holds
parameters of its own: a module built here sits where its model puts it, so state-dict keys
are the model's.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any, NamedTuple

import torch
from torch import Tensor, nn

#: A perceptual distance ``perceptual(pred (N, 3, H, W), target (N, 3, H, W)) -> (N,)`` on
#: frames in [0, 1], e.g. LPIPS. Used as an optional extra training loss term.
PerceptualLoss = Callable[[Tensor, Tensor], Tensor]


# --------------------------------------------------------------------------- latents


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


# --------------------------------------------------------------------------- reconstruction


class FrameLosses(NamedTuple):
    """Per-frame reconstruction losses of a batch of clips, averaged over the batch."""

    mse: Tensor  # (T,) mean over the pixels of each frame, as nn.MSELoss
    total: Tensor  # (T,) mse + weight * perceptual
    perceptual: Tensor | None  # (T,), None without a perceptual term

    def metrics(self, **extra: Tensor) -> dict[str, Tensor]:
        """The scalars to log: ``mse``, then ``extra`` (already detached), then
        ``perceptual`` if the loss has that term."""
        out = {"mse": self.mse.mean().detach(), **extra}
        if self.perceptual is not None:
            out["perceptual"] = self.perceptual.mean().detach()
        return out


@dataclasses.dataclass(frozen=True)
class FrameLoss:
    """The reconstruction loss of frames: pixel MSE plus ``weight`` times an optional
    perceptual distance (:meth:`vp2.models.base.VideoPredictor.compute_loss` builds it from
    its ``perceptual`` arguments)."""

    perceptual: PerceptualLoss | None = None
    weight: float = 0.0

    def __call__(self, predictions: Tensor, targets: Tensor) -> FrameLosses:
        """Losses of ``predictions`` against ``targets``, both ``(B, T, 3, H, W)``."""
        predictions, targets = predictions.float(), targets.float()
        mse = ((predictions - targets) ** 2).mean(dim=(0, 2, 3, 4))  # (T,)
        if self.perceptual is None or self.weight == 0:
            return FrameLosses(mse, mse, None)
        b, t = predictions.shape[:2]
        dist = self.perceptual(predictions.flatten(0, 1), targets.flatten(0, 1))  # (B * T,)
        if dist.shape != (b * t,):
            raise ValueError(
                f"perceptual loss: expected shape ({b * t},) for {b * t} frames, "
                f"got {tuple(dist.shape)}"
            )
        per_frame = dist.float().view(b, t).mean(0)  # (T,)
        return FrameLosses(mse, mse + self.weight * per_frame, per_frame)


# --------------------------------------------------------------------------- architecture


def per_frame(fn: Callable[[Tensor], Any], frames: Tensor) -> Any:
    """``fn`` applied to every frame of ``frames (B, T, ...)`` in one batch of ``B T``.

    The frames are made contiguous first: memory layouts change the convolutions' rounding
    (a call must be a function of the values only), and a channels-last batch (e.g. a
    permuted uint8 clip) crashed oneDNN's backward in FitVid's encoder (torch 2.13 CPU).

    Returns:
        What ``fn`` returns, with every tensor in it (also inside tuples and lists) unfolded
        to ``(B, T, ...)``.
    """
    b, t = frames.shape[:2]

    def unfold(x: Any) -> Any:
        if isinstance(x, Tensor):
            return x.unflatten(0, (b, t))
        return type(x)(unfold(v) for v in x)

    return unfold(fn(frames.flatten(0, 1).contiguous()))


def context_skips(skips: list[Tensor], num_context: int) -> list[Tensor]:
    """The decoder skips for reconstructing frames ``1 .. T - 1`` under teacher forcing.

    SVG's rule: skips come from the last frame seen so far within the context -- frame
    ``t - 1`` while ``t - 1 < num_context``, then the last context frame -- so no target frame
    leaks into its own reconstruction.

    Args:
        skips: The encoder's activations of every frame, each ``(B, T, C_i, H_i, W_i)``.
        num_context: Context frames.

    Returns:
        Each skip at the source frame of each step, ``(B (T - 1), C_i, H_i, W_i)``.
    """
    t_total, device = skips[0].shape[1], skips[0].device
    src = torch.tensor([min(t - 1, num_context - 1) for t in range(1, t_total)], device=device)
    return [s.index_select(1, src).flatten(0, 1) for s in skips]


def group_norm(channels: int, affine: bool = True) -> nn.GroupNorm:
    """GroupNorm with 32 groups, or as many as divide ``channels`` (their gcd)."""
    return nn.GroupNorm(math.gcd(32, channels), channels, affine=affine)


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
