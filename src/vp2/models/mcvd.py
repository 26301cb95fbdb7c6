"""MCVD (Voleti et al. 2022): masked conditional video diffusion, action-conditioned for VP².

Architecture (model-specs §4). A DDPM whose noise-prediction network is a U-Net over a
window of ``W = 5`` future frames stacked as channels (``3W``, frames in [-1, 1]). The
conditioning -- the 2 context frames (6 channels) and the ``W + 1`` actions of the window,
flattened and tiled over the image (``(W + 1)·A`` channels) -- is not concatenated to the
noisy input: it enters every residual block through SPADE normalisation,
``GroupNorm(x) · (1 + γ(c)) + β(c)`` with ``γ, β`` small convs on the conditioning map
resized to the block's resolution::

    c      = [x_{s}, x_{s+1}, tile(a_s .. a_{s+W})]          (B, 6 + (W+1)A, H, W)
    ε̂      = UNet(x_noisy (B, 3W, H, W), t, c)
    loss   = 0.5 ||ε - ε̂||²  (summed over a window, batch mean)

``a_s`` produced the last context frame, ``a_{s+1} .. a_{s+W}`` produce the window's frames.
Prediction: 5 frames from the 2 context frames, then the last 2 predicted frames become the
context of the next window (10 frames in 2 windows). Sampling is ancestral DDPM sampling on
``sampling_steps`` evenly spaced timesteps of the 1000-step chain (the posterior of the
strided chain), with the predicted ``x_0`` clipped to [-1, 1] at every step.

Training follows the original recipe where the trainer allows it: Adam 2e-4, gradient clip
1, EMA of the weights (decay 0.999) used at inference. The EMA lives in buffers of this
module (``ema_*``) and is updated at the start of every training-mode ``compute_loss`` with
the weights the optimiser produced in the previous step, so the trainer needs no hook and
checkpoints (and resumed runs) carry it. The decay is warmed up as ``min(decay, (1 + n) /
(10 + n))`` after ``n`` updates, so short runs get a useful average. The original's
1000-step learning-rate warmup is not applied (the trainer has no schedule).
"""

from __future__ import annotations

import contextlib
import dataclasses
import logging
import math
from collections.abc import Iterator
from typing import ClassVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.func import functional_call

from vp2.models.base import LossOutput, ModelConfig, TrainingDefaults, VideoPredictor
from vp2.models.layers import FrameLoss, group_norm, sample_normal

log = logging.getLogger(__name__)


@dataclasses.dataclass
class MCVDConfig(ModelConfig):
    """Architecture, diffusion and sampling settings of MCVD (defaults: the paper's model).

    ``image_size`` must be divisible by ``2 ** (len(channel_mult) - 1)``, and ``num_future``
    by ``window``.

    Attributes:
        window: Frames predicted per diffusion sample (5); ``num_future`` must be a
            multiple of it.
        base_channels: U-Net channels at full resolution. Keep it >= ``2 · 3W`` (30): the
            output head is ``conv(SiLU(GroupNorm(h)))`` on these channels and must reproduce
            the ``3W`` input noise channels at high ``t``; with about one channel each, the
            SiLU caps the explained variance at corr(x, SiLU(x))² = 0.80, and a base of 16
            trained on RoboDesk stalled at ε-MSE 0.20 for ``t >= 300`` (a base of 32 reached
            0.13 in a third of the steps; docs/findings/cpu-training.md). Smaller values log a warning.
        channel_mult: Channel multipliers per resolution level.
        num_res_blocks: Residual blocks per level on the way down (``+ 1`` on the way up).
        attn_resolutions: Feature-map sides with self-attention (plus the middle).
        spade_hidden: Hidden channels of each SPADE conditioning branch.
        dropout: Dropout in residual blocks.
        num_timesteps: Length of the diffusion chain.
        beta_start: First noise variance (linear schedule).
        beta_end: Last noise variance.
        sampling_steps: Denoising steps at inference (<= ``num_timesteps``).
        ema_decay: Decay of the weight average used at inference.
        use_ema: Predict with the EMA weights (else the raw ones).
        cond_mask_prob: Probability of hiding the context frames of a training sample (the
            "masked" conditioning of MCVD, which also trains unconditional generation);
            0 trains prediction only.
    """

    window: int = 5
    base_channels: int = 64
    channel_mult: tuple[int, ...] = (1, 2, 3, 4)
    num_res_blocks: int = 2
    attn_resolutions: tuple[int, ...] = (32, 16, 8)
    spade_hidden: int = 128
    dropout: float = 0.1
    num_timesteps: int = 1000
    beta_start: float = 1e-4
    beta_end: float = 0.02
    sampling_steps: int = 100
    ema_decay: float = 0.999
    use_ema: bool = True
    cond_mask_prob: float = 0.0

    def __post_init__(self) -> None:
        self.channel_mult = tuple(int(c) for c in self.channel_mult)
        self.attn_resolutions = tuple(int(r) for r in self.attn_resolutions)
        if self.num_future % self.window:
            raise ValueError(
                f"mcvd: num_future ({self.num_future}) must be a multiple of window ({self.window})"
            )
        if self.window < self.num_context:
            raise ValueError("mcvd: window must be >= num_context (autoregression)")
        self.check_image_size("mcvd", 2 ** (len(self.channel_mult) - 1))
        if self.base_channels < self.min_base_channels:
            log.warning(
                "mcvd: base_channels=%d < %d (2 x 3 x window): the U-Net's output SiLU cannot "
                "pass the noise through and training is likely to stall near eps-MSE 0.2; "
                "use base_channels >= %d",
                self.base_channels, self.min_base_channels, self.min_base_channels,
            )
        if not 1 <= self.sampling_steps <= self.num_timesteps:
            raise ValueError(
                f"mcvd: sampling_steps must be in [1, {self.num_timesteps}], "
                f"got {self.sampling_steps}"
            )

    @property
    def min_base_channels(self) -> int:
        """Two channels per noise channel of a window (see ``base_channels``)."""
        return 2 * 3 * self.window

    @property
    def cond_channels(self) -> int:
        return 3 * self.num_context + (self.window + 1) * self.action_dim


def timestep_embedding(t: Tensor, dim: int) -> Tensor:
    """Sinusoidal embedding ``(N,)`` -> ``(N, dim)`` (Transformer/DDPM)."""
    half = dim // 2
    freqs = torch.exp(-math.log(10_000) * torch.arange(half, device=t.device) / max(half - 1, 1))
    args = t.float()[:, None] * freqs[None]
    return torch.cat([args.sin(), args.cos()], 1)


class SPADENorm(nn.Module):
    """``GroupNorm(x) · (1 + γ(c)) + β(c)``, with the conditioning map resized to ``x``."""

    def __init__(self, channels: int, cond_channels: int, hidden: int):
        super().__init__()
        self.norm = group_norm(channels, affine=False)
        self.shared = nn.Sequential(nn.Conv2d(cond_channels, hidden, 3, 1, 1), nn.SiLU())
        self.gamma = nn.Conv2d(hidden, channels, 3, 1, 1)
        self.beta = nn.Conv2d(hidden, channels, 3, 1, 1)
        #: Set by :meth:`UNet.reusing_conditioning`: keep the last modulation (``cached``:
        #: ``(cond, scale, shift)``) and reuse it while ``cond`` is the same tensor.
        self.reusing = False
        self.cached: tuple[Tensor, Tensor, Tensor] | None = None

    def modulation(self, cond: Tensor, size: torch.Size) -> tuple[Tensor, Tensor]:
        """``(1 + γ(c), β(c))`` at the spatial ``size``: a function of ``cond`` alone."""
        if cond.shape[-2:] != size:
            cond = F.interpolate(cond, size=size, mode="nearest")
        h = self.shared(cond)
        return 1 + self.gamma(h), self.beta(h)

    def forward(self, x: Tensor, cond: Tensor) -> Tensor:
        if self.reusing and self.cached is not None and self.cached[0] is cond:
            _, scale, shift = self.cached
        else:
            scale, shift = self.modulation(cond, x.shape[-2:])
            if self.reusing:
                self.cached = (cond, scale, shift)
        return self.norm(x) * scale + shift


class ResBlock(nn.Module):
    """SPADE-norm -> swish -> conv -> + time -> SPADE-norm -> swish -> dropout -> conv;
    ``(shortcut + h) / sqrt(2)``."""

    def __init__(self, cin: int, cout: int, temb: int, config: MCVDConfig):
        super().__init__()
        self.norm1 = SPADENorm(cin, config.cond_channels, config.spade_hidden)
        self.conv1 = nn.Conv2d(cin, cout, 3, 1, 1)
        self.time = nn.Linear(temb, cout)
        self.norm2 = SPADENorm(cout, config.cond_channels, config.spade_hidden)
        self.dropout = nn.Dropout(config.dropout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1)
        self.shortcut = nn.Conv2d(cin, cout, 1) if cin != cout else nn.Identity()

    def forward(self, x: Tensor, temb: Tensor, cond: Tensor) -> Tensor:
        h = self.conv1(F.silu(self.norm1(x, cond)))
        h = h + self.time(F.silu(temb))[:, :, None, None]
        h = self.conv2(self.dropout(F.silu(self.norm2(h, cond))))
        return (self.shortcut(x) + h) / math.sqrt(2)


class AttnBlock(nn.Module):
    """Single-head self-attention over positions; ``(x + attn) / sqrt(2)``."""

    def __init__(self, channels: int):
        super().__init__()
        self.norm = group_norm(channels)
        self.qkv = nn.Conv2d(channels, 3 * channels, 1)
        self.proj = nn.Conv2d(channels, channels, 1)

    def forward(self, x: Tensor) -> Tensor:
        b, c, h, w = x.shape
        q, k, v = self.qkv(self.norm(x)).flatten(2).transpose(1, 2).chunk(3, -1)  # (B, HW, C)
        out = F.scaled_dot_product_attention(q, k, v)  # (B, HW, C)
        return (x + self.proj(out.transpose(1, 2).reshape(b, c, h, w))) / math.sqrt(2)


class UNet(nn.Module):
    """The noise-prediction network ``(x_noisy, t, cond) -> ε̂`` (DDPM U-Net with SPADE)."""

    def __init__(self, config: MCVDConfig):
        super().__init__()
        ch, channels = config.base_channels, 3 * config.window
        temb = 4 * ch
        self.base = ch
        self.time_mlp = nn.Sequential(nn.Linear(ch, temb), nn.SiLU(), nn.Linear(temb, temb))
        self.stem = nn.Conv2d(channels, ch, 3, 1, 1)
        self.down = nn.ModuleList()
        skips, cur, side = [ch], ch, config.image_size
        for level, mult in enumerate(config.channel_mult):
            for _ in range(config.num_res_blocks):
                block = nn.ModuleList([ResBlock(cur, ch * mult, temb, config)])
                cur = ch * mult
                if side in config.attn_resolutions:
                    block.append(AttnBlock(cur))
                self.down.append(block)
                skips.append(cur)
            if level < len(config.channel_mult) - 1:
                self.down.append(nn.ModuleList([nn.Conv2d(cur, cur, 3, 2, 1)]))
                skips.append(cur)
                side //= 2
        self.mid1 = ResBlock(cur, cur, temb, config)
        self.mid_attn = AttnBlock(cur)
        self.mid2 = ResBlock(cur, cur, temb, config)
        self.up = nn.ModuleList()
        for level, mult in reversed(list(enumerate(config.channel_mult))):
            for _ in range(config.num_res_blocks + 1):
                block = nn.ModuleList([ResBlock(cur + skips.pop(), ch * mult, temb, config)])
                cur = ch * mult
                if side in config.attn_resolutions:
                    block.append(AttnBlock(cur))
                self.up.append(block)
            if level > 0:
                self.up.append(nn.ModuleList([nn.Upsample(scale_factor=2, mode="nearest"),
                                              nn.Conv2d(cur, cur, 3, 1, 1)]))  # fmt: skip
                side *= 2
        self.out_norm = group_norm(cur)
        self.out = nn.Conv2d(cur, channels, 3, 1, 1)

    @contextlib.contextmanager
    def reusing_conditioning(self) -> Iterator[None]:
        """Within it, each SPADE norm computes its modulation once per conditioning tensor
        (the same object) and reuses it: the denoising steps of a window share ``cond``, so
        its convolutions (most of the U-Net's at the small presets) run once per window
        instead of once per step. Same values, more memory (a scale and shift per norm);
        the weights must not change inside it."""
        norms = [m for m in self.modules() if isinstance(m, SPADENorm)]
        for m in norms:
            m.reusing = True
        try:
            yield
        finally:
            for m in norms:
                m.reusing, m.cached = False, None

    def forward(self, x: Tensor, t: Tensor, cond: Tensor) -> Tensor:
        """``x (B, 3W, H, W)``, ``t (B,)`` timesteps, ``cond (B, Cc, H, W)`` -> ``ε̂``."""
        temb = self.time_mlp(timestep_embedding(t, self.base))
        h = self.stem(x)
        hs = [h]
        for block in self.down:
            if isinstance(block[0], ResBlock):
                h = block[0](h, temb, cond)
                if len(block) > 1:
                    h = block[1](h)
            else:  # strided conv: downsample
                h = block[0](h)
            hs.append(h)
        h = self.mid2(self.mid_attn(self.mid1(h, temb, cond)), temb, cond)
        for block in self.up:
            if isinstance(block[0], ResBlock):
                h = block[0](torch.cat([h, hs.pop()], 1), temb, cond)
                if len(block) > 1:
                    h = block[1](h)
            else:  # upsample + conv
                h = block[1](block[0](h))
        return self.out(F.silu(self.out_norm(h)))


class MCVD(VideoPredictor):
    """Action-conditioned MCVD: a DDPM whose SPADE U-Net denoises windows of 5 frames.

    The weights' EMA (buffers ``ema_*``) predicts; see the module docstring.
    """

    name: ClassVar[str] = "mcvd"
    config_class: ClassVar[type] = MCVDConfig
    #: Adam 2e-4, betas (0.9, 0.999), eps 1e-8, gradient clipping at 1.
    training_defaults: ClassVar[TrainingDefaults] = TrainingDefaults(lr=2e-4, grad_clip=1.0)

    def __init__(self, config: MCVDConfig):
        super().__init__(config)
        self.unet = UNet(config)
        betas = torch.linspace(
            config.beta_start, config.beta_end, config.num_timesteps, dtype=torch.float64
        )
        # Schedules are functions of the config: non-persistent (not in checkpoints).
        self.register_buffer(
            "alphas_cumprod", torch.cumprod(1 - betas, 0).float(), persistent=False
        )
        self._ema_names = {
            n: "ema_" + n.replace(".", "__") for n, _ in self.unet.named_parameters()
        }
        for name, p in self.unet.named_parameters():
            self.register_buffer(self._ema_names[name], p.detach().clone())
        self.register_buffer("ema_updates", torch.zeros((), dtype=torch.long))

    def num_parameters(self) -> int:
        """Trainable weights (the EMA copy is a buffer and not counted)."""
        return sum(p.numel() for p in self.unet.parameters())

    # ----------------------------------------------------------------- EMA

    @torch.no_grad()
    def update_ema(self) -> None:
        """One EMA step towards the current weights (called by ``compute_loss`` in training)."""
        n = int(self.ema_updates)
        decay = min(self.config.ema_decay, (1 + n) / (10 + n))
        for name, p in self.unet.named_parameters():
            getattr(self, self._ema_names[name]).lerp_(p.detach(), 1 - decay)
        self.ema_updates += 1

    def ema_parameters(self) -> dict[str, Tensor]:
        return {name: getattr(self, buf) for name, buf in self._ema_names.items()}

    def _denoiser(self, x: Tensor, t: Tensor, cond: Tensor) -> Tensor:
        if self.config.use_ema:
            return functional_call(self.unet, self.ema_parameters(), (x, t, cond))
        return self.unet(x, t, cond)

    # ----------------------------------------------------------------- conditioning

    def _condition(self, context: Tensor, actions: Tensor) -> Tensor:
        """Context ``(B, C, 3, H, W)`` in [-1, 1] and the window's actions ``(B, W + 1, A)``
        -> conditioning map ``(B, 3C + (W + 1)A, H, W)``."""
        side = context.shape[-1]
        tiled = actions.flatten(1)[:, :, None, None].expand(-1, -1, side, side)
        return torch.cat([context.flatten(1, 2), tiled.to(context.dtype)], 1)

    # ----------------------------------------------------------------- training

    def _compute_loss(
        self, frames: Tensor, actions: Tensor, generator: torch.Generator, frame_loss: FrameLoss
    ) -> LossOutput:
        """The DDPM objective on one random window per clip.

        For each clip a window start ``s`` is drawn: context frames ``s, s + 1``, targets
        ``s + 2 .. s + 1 + W``, actions ``s .. s + W``. ``predictions`` holds the one-step
        estimates of ``x_0`` for the window's frames, placed at their time indices, and the
        true frames elsewhere (a diffusion model has no cheap full reconstruction). The
        perceptual loss does not apply (the model never decodes a frame in training).
        """
        if self.training and torch.is_grad_enabled():
            self.update_ema()
        cfg = self.config
        b, t_total = frames.shape[:2]
        c, w = cfg.num_context, cfg.window
        span = c + w
        if t_total < span:
            raise ValueError(f"mcvd: clips of {t_total} frames are shorter than {span}")
        gen_device = generator.device
        start = torch.randint(0, t_total - span + 1, (b,), generator=generator, device=gen_device)
        step = torch.randint(0, cfg.num_timesteps, (b,), generator=generator, device=gen_device)
        start, step = start.to(frames.device), step.to(frames.device)
        idx = start[:, None] + torch.arange(span, device=frames.device)  # (B, C + W)
        clip = frames.gather(1, idx[:, :, None, None, None].expand(-1, -1, *frames.shape[2:]))
        clip = clip * 2 - 1  # (B, C + W, 3, H, W) in [-1, 1]
        acts = actions.gather(1, idx[:, : w + 1, None].expand(-1, -1, actions.shape[-1]))
        context, target = clip[:, :c], clip[:, c:].flatten(1, 2)  # (B, 3W, H, W)
        if cfg.cond_mask_prob > 0:
            keep = torch.rand(b, generator=generator, device=gen_device) >= cfg.cond_mask_prob
            context = context * keep.to(context)[:, None, None, None, None]
        noise = sample_normal(tuple(target.shape), target, generator)
        ab = self.alphas_cumprod[step][:, None, None, None].to(target.dtype)
        noisy = ab.sqrt() * target + (1 - ab).sqrt() * noise
        eps = self.unet(noisy, step, self._condition(context, acts))
        per_sample = 0.5 * (eps.float() - noise.float()).square().flatten(1).sum(1)
        loss = per_sample.mean()
        x0 = ((noisy - (1 - ab).sqrt() * eps) / ab.sqrt()).clamp(-1, 1)
        predictions = frames[:, 1:].clone()
        window_frames = ((x0.detach().unflatten(1, (w, 3)) + 1) / 2).to(predictions.dtype)
        pos = (idx[:, c:] - 1)[:, :, None, None, None].expand_as(window_frames)
        predictions.scatter_(1, pos, window_frames)
        metrics = {
            "eps_mse": (eps.detach().float() - noise.float()).square().mean(),
            "x0_mse": ((x0.detach().float() - target.float()) / 2).square().mean(),
        }
        return LossOutput(loss=loss, metrics=metrics, predictions=predictions)

    # ----------------------------------------------------------------- sampling

    def sampling_timesteps(self) -> list[int]:
        """The ``sampling_steps`` timesteps visited, from ``num_timesteps - 1`` down to 0."""
        n, s = self.config.num_timesteps, self.config.sampling_steps
        steps = torch.linspace(n - 1, 0, s).round().long().tolist()
        return sorted(set(steps), reverse=True)

    def sample_window(self, context: Tensor, actions: Tensor, generator: torch.Generator) -> Tensor:
        """One window: context ``(B, C, 3, H, W)`` in [-1, 1], actions ``(B, W + 1, A)`` ->
        ``(B, W, 3, H, W)`` in [-1, 1]."""
        cfg = self.config
        b, side = context.shape[0], context.shape[-1]
        cond = self._condition(context, actions)
        x = sample_normal((b, 3 * cfg.window, side, side), context, generator)
        steps = self.sampling_timesteps()
        with self.unet.reusing_conditioning():
            return self._denoise(x, cond, steps, generator).unflatten(1, (cfg.window, 3))

    def _denoise(
        self, x: Tensor, cond: Tensor, steps: list[int], generator: torch.Generator
    ) -> Tensor:
        """The strided ancestral chain from ``x`` at ``steps[0]`` down to ``x_0``."""
        b = x.shape[0]
        for i, t in enumerate(steps):
            ab_t = self.alphas_cumprod[t].to(x.dtype)
            ab_prev = self.alphas_cumprod[steps[i + 1]].to(x.dtype) if i + 1 < len(steps) else None
            eps = self._denoiser(x, torch.full((b,), t, device=x.device, dtype=torch.long), cond)
            x0 = ((x - (1 - ab_t).sqrt() * eps) / ab_t.sqrt()).clamp(-1, 1)
            if ab_prev is None:
                x = x0
                break
            # Posterior q(x_prev | x_t, x0) of the strided chain.
            beta = 1 - ab_t / ab_prev
            mean = (ab_prev.sqrt() * beta * x0 + (1 - beta).sqrt() * (1 - ab_prev) * x) / (1 - ab_t)
            var = beta * (1 - ab_prev) / (1 - ab_t)
            x = mean + var.sqrt() * sample_normal(tuple(x.shape), x, generator)
        return x

    def _predict(
        self, context_frames: Tensor, actions: Tensor, generator: torch.Generator
    ) -> Tensor:
        cfg = self.config
        c, w = cfg.num_context, cfg.window
        history = context_frames * 2 - 1  # (B, C, 3, H, W)
        outputs = []
        for k in range(cfg.num_future // w):
            # Frames so far: 0 .. C - 1 + k W; actions[j] produced frame j + 1.
            first = k * w  # index of the window's first context frame
            window = self.sample_window(
                history[:, -c:], actions[:, first : first + w + 1], generator
            )
            outputs.append(window)
            history = torch.cat([history, window], 1)
        return ((torch.cat(outputs, 1) + 1) / 2).clamp(0, 1)
