"""The per-frame VQ tokenizer of MaskViT (``maskvit_tokenizer``).

Trained first with ``vp2 train --model maskvit_tokenizer``. A VQ-GAN-style convolutional
autoencoder applied to each frame independently: residual GroupNorm/SiLU blocks,
``len(channel_mult) - 1`` stride-2 stages (64×64 -> 16×16 tokens by default), a codebook of
``codebook_size`` entries looked up by cosine similarity (codes and encoder outputs are
l2-normalised, which keeps the codebook in use without restarts), straight-through gradients,
and a sigmoid decoder. Its loss is ``MSE (+ perceptual) + ||sg(z) - e||² + commitment ·
||z - sg(e)||²`` plus, after ``adv_start`` training steps, a PatchGAN hinge loss. The
discriminator is trained inside the same loss with the trainer's one optimiser: its hinge loss
sees detached reconstructions, and the generator's adversarial term calls the discriminator
with detached weights (``torch.func.functional_call``), so each term moves only its own side.
As a ``VideoPredictor`` the tokenizer predicts "the last context frame through the codec" (a
deterministic persistence baseline that shows the quantisation floor).
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.func import functional_call

from vp2.models.base import LossOutput, ModelConfig, TrainingDefaults, VideoPredictor
from vp2.models.layers import FrameLoss, group_norm


@dataclasses.dataclass
class MaskViTTokenizerConfig(ModelConfig):
    """Architecture and loss settings of the per-frame VQ tokenizer.

    ``image_size`` must be divisible by ``2 ** (len(channel_mult) - 1)``; ``action_dim`` is
    unused by the tokenizer (part of the model contract).

    Attributes:
        channels: Channels of the first stage.
        channel_mult: Channel multipliers per stage; each stage but the last halves the side.
        num_res_blocks: Residual blocks per stage.
        codebook_size: Number of codes.
        code_dim: Size of a code vector.
        commitment: Weight of the commitment term.
        adv_weight: Weight of the generator's adversarial term (0 disables the GAN).
        adv_start: Training steps before the adversarial terms switch on.
        disc_channels: Channels of the PatchGAN discriminator's first layer.
    """

    channels: int = 64
    channel_mult: tuple[int, ...] = (1, 2, 2)
    num_res_blocks: int = 2
    codebook_size: int = 1024
    code_dim: int = 32
    commitment: float = 0.25
    adv_weight: float = 0.1
    adv_start: int = 5_000
    disc_channels: int = 64

    def __post_init__(self) -> None:
        self.channel_mult = tuple(int(c) for c in self.channel_mult)
        self.check_image_size("maskvit_tokenizer", self.downsample)

    @property
    def downsample(self) -> int:
        return 2 ** (len(self.channel_mult) - 1)

    @property
    def token_side(self) -> int:
        return self.image_size // self.downsample


class _ResBlock(nn.Module):
    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.body = nn.Sequential(
            group_norm(cin), nn.SiLU(), nn.Conv2d(cin, cout, 3, 1, 1),
            group_norm(cout), nn.SiLU(), nn.Conv2d(cout, cout, 3, 1, 1),
        )  # fmt: skip
        self.shortcut = nn.Conv2d(cin, cout, 1) if cin != cout else nn.Identity()

    def forward(self, x: Tensor) -> Tensor:
        return self.shortcut(x) + self.body(x)


class _Encoder(nn.Module):
    def __init__(self, c: MaskViTTokenizerConfig):
        super().__init__()
        layers: list[nn.Module] = [nn.Conv2d(3, c.channels, 3, 1, 1)]
        cur = c.channels
        for i, mult in enumerate(c.channel_mult):
            for _ in range(c.num_res_blocks):
                layers.append(_ResBlock(cur, c.channels * mult))
                cur = c.channels * mult
            if i < len(c.channel_mult) - 1:
                layers.append(nn.Conv2d(cur, cur, 4, 2, 1))
        layers += [_ResBlock(cur, cur), group_norm(cur), nn.SiLU(), nn.Conv2d(cur, c.code_dim, 1)]
        self.net = nn.Sequential(*layers)

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x)


class _Decoder(nn.Module):
    def __init__(self, c: MaskViTTokenizerConfig):
        super().__init__()
        cur = c.channels * c.channel_mult[-1]
        layers: list[nn.Module] = [nn.Conv2d(c.code_dim, cur, 3, 1, 1), _ResBlock(cur, cur)]
        for i, mult in reversed(list(enumerate(c.channel_mult))):
            for _ in range(c.num_res_blocks):
                layers.append(_ResBlock(cur, c.channels * mult))
                cur = c.channels * mult
            if i > 0:
                layers += [
                    nn.Upsample(scale_factor=2, mode="nearest"),
                    nn.Conv2d(cur, cur, 3, 1, 1),
                ]
        layers += [group_norm(cur), nn.SiLU(), nn.Conv2d(cur, 3, 3, 1, 1)]
        self.net = nn.Sequential(*layers)

    def forward(self, z: Tensor) -> Tensor:
        return torch.sigmoid(self.net(z))


class PatchDiscriminator(nn.Module):
    """PatchGAN: three 4×4 convs (stride 2, 2, 1) to a map of real/fake logits."""

    def __init__(self, channels: int):
        super().__init__()
        d = channels
        self.net = nn.Sequential(
            nn.Conv2d(3, d, 4, 2, 1), nn.LeakyReLU(0.2),
            nn.Conv2d(d, 2 * d, 4, 2, 1), group_norm(2 * d), nn.LeakyReLU(0.2),
            nn.Conv2d(2 * d, 1, 4, 1, 1),
        )  # fmt: skip

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x * 2 - 1)


class MaskViTTokenizer(VideoPredictor):
    """Per-frame VQ tokenizer of MaskViT; see the module docstring."""

    name: ClassVar[str] = "maskvit_tokenizer"
    config_class: ClassVar[type] = MaskViTTokenizerConfig
    #: Adam 2e-4, betas (0.5, 0.9) (VQ-GAN's), eps 1e-8, no gradient clipping.
    training_defaults: ClassVar[TrainingDefaults] = TrainingDefaults(lr=2e-4, betas=(0.5, 0.9))
    #: ``predict`` is deterministic (no sampling): the same inputs give the same frames.
    stochastic: ClassVar[bool] = False

    def __init__(self, config: MaskViTTokenizerConfig):
        super().__init__(config)
        self.encoder = _Encoder(config)
        self.decoder = _Decoder(config)
        self.codebook = nn.Parameter(torch.randn(config.codebook_size, config.code_dim))
        self.discriminator = PatchDiscriminator(config.disc_channels)
        self.register_buffer("train_steps", torch.zeros((), dtype=torch.long))

    def _codes(self) -> Tensor:
        return F.normalize(self.codebook, dim=1)  # (K, D)

    def quantize(self, z: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Encoder output ``(N, D, h, w)`` -> ``(z_q with straight-through gradient,
        indices (N, h, w), codebook + commitment loss)``."""
        z = F.normalize(z, dim=1)
        codes = self._codes()
        flat = z.permute(0, 2, 3, 1).reshape(-1, z.shape[1])  # (N h w, D)
        indices = (flat @ codes.t()).argmax(1)
        zq = codes[indices].view(z.shape[0], z.shape[2], z.shape[3], -1).permute(0, 3, 1, 2)
        vq = (zq - z.detach()).square().mean() + self.config.commitment * (
            z - zq.detach()
        ).square().mean()
        return z + (zq - z).detach(), indices.view(z.shape[0], z.shape[2], z.shape[3]), vq

    @torch.no_grad()
    def tokenize(self, frames: Tensor) -> Tensor:
        """``(N, 3, H, W)`` in [0, 1] -> token indices ``(N, h, w)``."""
        return self.quantize(self.encoder(frames.contiguous()))[1]

    def detokenize(self, indices: Tensor) -> Tensor:
        """Token indices ``(N, h, w)`` -> frames ``(N, 3, H, W)`` in [0, 1]."""
        zq = self._codes()[indices].permute(0, 3, 1, 2)  # (N, D, h, w)
        return self.decoder(zq)

    def _compute_loss(
        self, frames: Tensor, actions: Tensor, generator: torch.Generator, frame_loss: FrameLoss
    ) -> LossOutput:
        """Reconstruction of every frame of the clips (``predictions`` = frames 1 .. T-1)."""
        training = self.training and torch.is_grad_enabled()
        if training:
            self.train_steps += 1
        b, t = frames.shape[:2]
        flat = frames.flatten(0, 1).contiguous()  # (B T, 3, H, W)
        zq, _, vq = self.quantize(self.encoder(flat))
        recon = self.decoder(zq)
        recon_bt = recon.unflatten(0, (b, t))
        losses = frame_loss(recon_bt, frames)
        loss = losses.total.mean() + vq
        metrics = losses.metrics(vq=vq.detach())
        cfg = self.config
        if cfg.adv_weight > 0 and int(self.train_steps) > cfg.adv_start:
            frozen = {k: v.detach() for k, v in self.discriminator.named_parameters()}
            g_adv = -functional_call(self.discriminator, frozen, (recon,)).mean()
            d_loss = (
                F.relu(1 - self.discriminator(flat)).mean()
                + F.relu(1 + self.discriminator(recon.detach())).mean()
            )
            loss = loss + cfg.adv_weight * g_adv + d_loss
            metrics.update(g_adv=g_adv.detach(), d_loss=d_loss.detach())
        return LossOutput(loss=loss, metrics=metrics, predictions=recon_bt[:, 1:].clamp(0, 1))

    def _predict(
        self, context_frames: Tensor, actions: Tensor, generator: torch.Generator
    ) -> Tensor:
        last = self.detokenize(self.tokenize(context_frames[:, -1]))  # (B, 3, H, W)
        return last[:, None].expand(-1, self.config.num_future, -1, -1, -1).contiguous()
