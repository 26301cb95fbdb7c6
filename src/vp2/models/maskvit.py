"""MaskViT (Gupta et al. 2022), action-conditioned, and its per-frame VQ tokenizer.

The original code was never released; this is our reading of the paper (model-specs §5),
with the design choices stated here and in ``docs/models.md``.

**Tokenizer** (``maskvit_tokenizer``, trained first with ``vp2 train --model
maskvit_tokenizer``). A VQ-GAN-style convolutional autoencoder applied to each frame
independently: residual GroupNorm/SiLU blocks, ``len(channel_mult) - 1`` stride-2 stages
(64×64 -> 16×16 tokens by default), a codebook of ``codebook_size`` entries looked up by cosine
similarity (codes and encoder outputs are l2-normalised, which keeps the codebook in use
without restarts), straight-through gradients, and a sigmoid decoder. Its loss is
``MSE (+ perceptual) + ||sg(z) - e||² + commitment · ||z - sg(e)||²`` plus, after
``adv_start`` training steps, a PatchGAN hinge loss. The discriminator is trained inside the
same loss with the trainer's one optimiser: its hinge loss sees detached reconstructions, and
the generator's adversarial term calls the discriminator with detached weights
(``torch.func.functional_call``), so each term moves only its own side. As a
``VideoPredictor`` the tokenizer predicts "the last context frame through the codec" (a
deterministic persistence baseline that shows the quantisation floor).

**MaskViT** (``maskvit``). A bidirectional transformer over the tokens of all 12 frames
(2 context + 10 future). Blocks alternate *spatial* window attention (each frame's
``h × w`` tokens attend to each other: window ``1 × 16 × 16``) and *spatiotemporal* window
attention (``T × s × s`` windows, ``s = st_window = 4``). Each token's embedding is the sum
of its code embedding (or a learned ``[MASK]``), a spatial and a temporal position embedding
and its frame's action embedding: frame ``t`` gets ``Linear(a_{t-1})``, the action that
produced it (frame 0 gets a learned vector).

- Training: tokenise the clip with the frozen tokenizer; per clip draw a mask ratio
  ``r ~ U[mask_ratio_min, mask_ratio_max)`` and mask ``ceil(r · N)`` of the ``N`` future
  tokens at random; cross-entropy on the masked tokens. Context tokens are never masked.
- Inference: future tokens start fully masked. Each of ``decoding_iterations`` (5)
  iterations samples every masked token (Gumbel-max at ``temperature``), keeps the most
  confident and re-masks ``floor(N · cos(π/2 · (i + 1) / iterations))`` of them (MaskGIT's
  cosine schedule; confidence = log-probability plus Gumbel noise annealed to 0). Fixed
  tokens stay fixed. The tokens are decoded frame by frame.

**Loading the tokenizer.** ``MaskViTConfig.tokenizer_checkpoint`` names a trained
tokenizer's checkpoint (file or run directory) when a MaskViT is *built*:
``vp2 train --model maskvit --override tokenizer_checkpoint=runs/tok``. Its architecture and
weights are copied into the MaskViT (frozen: ``requires_grad = False``), and the MaskViT's
checkpoints record the tokenizer's architecture in ``tokenizer`` and its weights in the
state dict, with ``tokenizer_checkpoint`` cleared (the source path is kept in
``tokenizer_source``). A MaskViT checkpoint is therefore self-contained: ``load_model``
needs no tokenizer file. Without a checkpoint the tokenizer is randomly initialised (tests).

Gradients: decoding is discrete, so ``predict`` gives no gradient to the actions; plan with
sampling-based optimisers (MPPI, CEM).
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, ClassVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn
from torch.func import functional_call

from vp2.models.base import (
    NUM_CONTEXT,
    NUM_FUTURE,
    LossOutput,
    PerceptualLoss,
    TrainingDefaults,
    VideoPredictor,
    frame_losses,
)

# --------------------------------------------------------------------------- tokenizer


@dataclasses.dataclass
class MaskViTTokenizerConfig:
    """Architecture and loss settings of the per-frame VQ tokenizer.

    Attributes:
        action_dim: Action size (unused by the tokenizer; part of the model contract).
        image_size: Frame side; divisible by ``2 ** (len(channel_mult) - 1)``.
        channels: Channels of the first stage.
        channel_mult: Channel multipliers per stage; each stage but the last halves the side.
        num_res_blocks: Residual blocks per stage.
        codebook_size: Number of codes.
        code_dim: Size of a code vector.
        commitment: Weight of the commitment term.
        adv_weight: Weight of the generator's adversarial term (0 disables the GAN).
        adv_start: Training steps before the adversarial terms switch on.
        disc_channels: Channels of the PatchGAN discriminator's first layer.
        num_context: Context frames.
        num_future: Predicted frames.
    """

    action_dim: int = 5
    image_size: int = 64
    channels: int = 64
    channel_mult: tuple[int, ...] = (1, 2, 2)
    num_res_blocks: int = 2
    codebook_size: int = 1024
    code_dim: int = 32
    commitment: float = 0.25
    adv_weight: float = 0.1
    adv_start: int = 5_000
    disc_channels: int = 64
    num_context: int = NUM_CONTEXT
    num_future: int = NUM_FUTURE

    def __post_init__(self) -> None:
        self.channel_mult = tuple(int(c) for c in self.channel_mult)
        if self.image_size % self.downsample:
            raise ValueError(
                f"maskvit_tokenizer: image_size must be a multiple of {self.downsample}"
            )

    @property
    def downsample(self) -> int:
        return 2 ** (len(self.channel_mult) - 1)

    @property
    def token_side(self) -> int:
        return self.image_size // self.downsample


def _norm(channels: int) -> nn.GroupNorm:
    return nn.GroupNorm(math.gcd(32, channels), channels)


class _ResBlock(nn.Module):
    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.body = nn.Sequential(
            _norm(cin), nn.SiLU(), nn.Conv2d(cin, cout, 3, 1, 1),
            _norm(cout), nn.SiLU(), nn.Conv2d(cout, cout, 3, 1, 1),
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
        layers += [_ResBlock(cur, cur), _norm(cur), nn.SiLU(), nn.Conv2d(cur, c.code_dim, 1)]
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
        layers += [_norm(cur), nn.SiLU(), nn.Conv2d(cur, 3, 3, 1, 1)]
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
            nn.Conv2d(d, 2 * d, 4, 2, 1), _norm(2 * d), nn.LeakyReLU(0.2),
            nn.Conv2d(2 * d, 1, 4, 1, 1),
        )  # fmt: skip

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x * 2 - 1)


class MaskViTTokenizer(VideoPredictor):
    """Per-frame VQ tokenizer of MaskViT; see the module docstring."""

    name: ClassVar[str] = "maskvit_tokenizer"
    config_class: ClassVar[type] = MaskViTTokenizerConfig
    training_defaults: ClassVar[TrainingDefaults] = TrainingDefaults(
        optimizer="adam", lr=2e-4, betas=(0.5, 0.9), eps=1e-8, grad_clip=None
    )
    #: ``predict`` is deterministic (no sampling): the same inputs give the same frames.
    stochastic: ClassVar[bool] = False

    def __init__(self, config: MaskViTTokenizerConfig):
        super().__init__(config)
        self.encoder = _Encoder(config)
        self.decoder = _Decoder(config)
        self.codebook = nn.Parameter(torch.randn(config.codebook_size, config.code_dim))
        self.discriminator = PatchDiscriminator(config.disc_channels)
        self.register_buffer("train_steps", torch.zeros((), dtype=torch.long))

    def config_dict(self) -> dict[str, Any]:
        d = super().config_dict()
        d["channel_mult"] = list(d["channel_mult"])
        return d

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

    def compute_loss(
        self,
        frames: Tensor,
        actions: Tensor,
        generator: torch.Generator,
        perceptual: PerceptualLoss | None = None,
        perceptual_weight: float = 0.0,
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
        mse, rec, lp = frame_losses(recon_bt, frames, perceptual, perceptual_weight)
        loss = rec.mean() + vq
        metrics = {"mse": mse.mean().detach(), "vq": vq.detach()}
        if lp is not None:
            metrics["perceptual"] = lp.mean().detach()
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


# --------------------------------------------------------------------------- transformer


@dataclasses.dataclass
class MaskViTConfig:
    """Architecture, training and decoding settings of MaskViT.

    Attributes:
        action_dim: Action size ``A``.
        image_size: Frame side (the tokenizer's).
        dim: Transformer width.
        depth: Transformer blocks (alternating spatial and spatiotemporal attention).
        heads: Attention heads.
        mlp_ratio: MLP hidden size / ``dim``.
        st_window: Side ``s`` of the ``T × s × s`` spatiotemporal windows.
        mask_ratio_min: Lower end of the training mask ratio (of future tokens).
        mask_ratio_max: Upper end (exclusive).
        decoding_iterations: Iterations of the iterative decoding at inference.
        temperature: Sampling temperature of the tokens.
        confidence_noise: Scale of the Gumbel noise added to the confidences (annealed to 0).
        tokenizer: Tokenizer architecture (fields of :class:`MaskViTTokenizerConfig` other
            than ``action_dim``/``image_size``/``num_context``/``num_future``).
        tokenizer_checkpoint: A trained tokenizer to copy in when building (see module doc).
        tokenizer_source: Where the tokenizer came from (recorded, not read).
        num_context: Context frames.
        num_future: Predicted frames.
    """

    action_dim: int = 5
    image_size: int = 64
    dim: int = 512
    depth: int = 8
    heads: int = 8
    mlp_ratio: float = 4.0
    st_window: int = 4
    mask_ratio_min: float = 0.5
    mask_ratio_max: float = 1.0
    decoding_iterations: int = 5
    temperature: float = 1.0
    confidence_noise: float = 1.0
    tokenizer: dict[str, Any] = dataclasses.field(default_factory=dict)
    tokenizer_checkpoint: str | None = None
    tokenizer_source: str = ""
    num_context: int = NUM_CONTEXT
    num_future: int = NUM_FUTURE

    def __post_init__(self) -> None:
        self.tokenizer = dict(self.tokenizer)
        if not 0 <= self.mask_ratio_min < self.mask_ratio_max <= 1:
            raise ValueError("maskvit: need 0 <= mask_ratio_min < mask_ratio_max <= 1")
        if self.decoding_iterations < 1:
            raise ValueError("maskvit: decoding_iterations must be >= 1")
        if self.dim % self.heads:
            raise ValueError("maskvit: dim must be divisible by heads")

    def tokenizer_config(self) -> MaskViTTokenizerConfig:
        shared = {
            "action_dim": self.action_dim,
            "image_size": self.image_size,
            "num_context": self.num_context,
            "num_future": self.num_future,
        }
        return MaskViTTokenizerConfig(**{**self.tokenizer, **shared})


_SHARED_FIELDS = ("action_dim", "image_size", "num_context", "num_future")


class _Attention(nn.Module):
    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: Tensor) -> Tensor:
        """``(N, L, D)`` -> ``(N, L, D)``: full attention within each of the N windows."""
        n, length, d = x.shape
        q, k, v = self.qkv(x).view(n, length, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        out = F.scaled_dot_product_attention(q, k, v)  # (N, heads, L, d_h)
        return self.proj(out.transpose(1, 2).reshape(n, length, d))


class WindowBlock(nn.Module):
    """Pre-LN transformer block attending within spatial or spatiotemporal windows."""

    def __init__(self, dim: int, heads: int, mlp_ratio: float, spatial: bool, window: int):
        super().__init__()
        self.spatial, self.window = spatial, window
        self.norm1 = nn.LayerNorm(dim)
        self.attn = _Attention(dim, heads)
        self.norm2 = nn.LayerNorm(dim)
        hidden = int(dim * mlp_ratio)
        self.mlp = nn.Sequential(nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, dim))

    def _windows(self, x: Tensor) -> tuple[Tensor, tuple[int, ...]]:
        b, t, h, w, d = x.shape
        if self.spatial:
            return x.reshape(b * t, h * w, d), x.shape
        s = self.window
        x = x.view(b, t, h // s, s, w // s, s, d).permute(0, 2, 4, 1, 3, 5, 6)
        return x.reshape(b * (h // s) * (w // s), t * s * s, d), x.shape

    def _unwindows(self, x: Tensor, shape: tuple[int, ...]) -> Tensor:
        if self.spatial:
            b, t, h, w, d = shape
            return x.view(b, t, h, w, d)
        b, hs, ws, t, s1, s2, d = shape
        return x.view(shape).permute(0, 3, 1, 4, 2, 5, 6).reshape(b, t, hs * s1, ws * s2, d)

    def forward(self, x: Tensor) -> Tensor:
        """``(B, T, h, w, D)`` -> same."""
        win, shape = self._windows(self.norm1(x))
        x = x + self._unwindows(self.attn(win), shape)
        return x + self.mlp(self.norm2(x))


class MaskViT(VideoPredictor):
    """MaskViT with a frozen per-frame VQ tokenizer; see the module docstring."""

    name: ClassVar[str] = "maskvit"
    config_class: ClassVar[type] = MaskViTConfig
    training_defaults: ClassVar[TrainingDefaults] = TrainingDefaults(
        optimizer="adamw", lr=3e-4, betas=(0.9, 0.95), eps=1e-8, weight_decay=0.01, grad_clip=1.0
    )

    def __init__(self, config: MaskViTConfig):
        super().__init__(config)
        tok_config = config.tokenizer_config()
        state = None
        if config.tokenizer_checkpoint:
            tok_config, state = _read_tokenizer(config)
        self.tokenizer = MaskViTTokenizer(tok_config)
        if state is not None:
            self.tokenizer.load_state_dict(state)
        self.tokenizer.requires_grad_(False)
        side, frames = tok_config.token_side, config.num_context + config.num_future
        if side % config.st_window:
            raise ValueError(
                f"maskvit: st_window {config.st_window} must divide the token grid side {side}"
            )
        self.side, self.codebook_size = side, tok_config.codebook_size
        d = config.dim
        self.token_embed = nn.Embedding(self.codebook_size + 1, d)  # last index = [MASK]
        self.pos_space = nn.Parameter(torch.randn(side * side, d) * 0.02)
        self.pos_time = nn.Parameter(torch.randn(frames, d) * 0.02)
        self.action_embed = nn.Linear(config.action_dim, d)
        self.first_frame_embed = nn.Parameter(torch.zeros(d))
        self.blocks = nn.ModuleList(
            WindowBlock(d, config.heads, config.mlp_ratio, i % 2 == 0, config.st_window)
            for i in range(config.depth)
        )
        self.norm = nn.LayerNorm(d)
        self.head = nn.Linear(d, self.codebook_size)

    @property
    def mask_id(self) -> int:
        return self.codebook_size

    def config_dict(self) -> dict[str, Any]:
        d = super().config_dict()
        tok = self.tokenizer.config_dict()
        d["tokenizer"] = {k: v for k, v in tok.items() if k not in _SHARED_FIELDS}
        if d["tokenizer_checkpoint"]:
            d["tokenizer_source"] = str(d["tokenizer_checkpoint"])
            d["tokenizer_checkpoint"] = None
        return d

    def num_trainable_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters() if p.requires_grad)

    def train(self, mode: bool = True) -> MaskViT:
        super().train(mode)
        self.tokenizer.eval()  # frozen
        return self

    # ----------------------------------------------------------------- network

    def _tokenize(self, frames: Tensor) -> Tensor:
        """``(B, T, 3, H, W)`` -> ``(B, T, h, w)`` token indices."""
        b, t = frames.shape[:2]
        return self.tokenizer.tokenize(frames.flatten(0, 1)).unflatten(0, (b, t))

    def logits(self, tokens: Tensor, actions: Tensor) -> Tensor:
        """Tokens ``(B, T, h, w)`` (``mask_id`` where masked) and actions ``(B, T - 1, A)``
        -> features ``(B, T, h, w, dim)`` before the output head (see :meth:`head`)."""
        b, t, h, w = tokens.shape
        x = self.token_embed(tokens)  # (B, T, h, w, D)
        x = x + self.pos_space.view(1, 1, h, w, -1) + self.pos_time[:t].view(1, t, 1, 1, -1)
        act = self.action_embed(actions.to(x.dtype))  # (B, T - 1, D)
        act = torch.cat([self.first_frame_embed.expand(b, 1, -1), act], 1)  # (B, T, D)
        x = x + act[:, :, None, None]
        for block in self.blocks:
            x = block(x)
        return self.norm(x)

    # ----------------------------------------------------------------- training

    def compute_loss(
        self,
        frames: Tensor,
        actions: Tensor,
        generator: torch.Generator,
        perceptual: PerceptualLoss | None = None,
        perceptual_weight: float = 0.0,
    ) -> LossOutput:
        """Masked-token cross-entropy on the future tokens (see the module docstring).

        ``predictions``: frames 1 .. T-1 decoded from the visible tokens plus the argmax
        predictions at masked ones. The perceptual loss does not apply (token loss only).
        """
        cfg = self.config
        b, t = frames.shape[:2]
        c = cfg.num_context
        tokens = self._tokenize(frames)  # (B, T, h, w)
        future = tokens[:, c:].flatten(1)  # (B, N)
        n = future.shape[1]
        gen_device = generator.device
        ratio = cfg.mask_ratio_min + (cfg.mask_ratio_max - cfg.mask_ratio_min) * torch.rand(
            b, generator=generator, device=gen_device
        )
        count = (ratio * n).ceil().clamp(1, n).to(frames.device)  # (B,)
        scores = torch.rand(b, n, generator=generator, device=gen_device).to(frames.device)
        ranks = scores.argsort(1).argsort(1)  # a random permutation's rank of each token
        masked = ranks < count[:, None]  # (B, N)
        inp = tokens.clone()
        inp[:, c:] = torch.where(masked, self.mask_id, future).view_as(tokens[:, c:])
        feats = self.logits(inp, actions)[:, c:].flatten(1, 3)  # (B, N, D)
        logits = self.head(feats[masked])  # (M, K)
        loss = F.cross_entropy(logits.float(), future[masked])
        with torch.no_grad():
            filled = future.clone()
            filled[masked] = logits.argmax(-1)
            accuracy = (filled[masked] == future[masked]).float().mean()
            seq = torch.cat([tokens[:, 1:c].flatten(1), filled], 1).view(b, t - 1, self.side, -1)
            predictions = self.tokenizer.detokenize(seq.flatten(0, 1)).unflatten(0, (b, t - 1))
        metrics = {"ce": loss.detach(), "token_acc": accuracy, "mask_ratio": masked.float().mean()}
        return LossOutput(loss=loss, metrics=metrics, predictions=predictions)

    # ----------------------------------------------------------------- inference

    def _gumbel(self, shape: tuple[int, ...], like: Tensor, generator: torch.Generator) -> Tensor:
        u = torch.rand(shape, generator=generator, device=generator.device)
        neg_log = (-torch.log(u.clamp_min(1e-20))).clamp_min(1e-20)  # Exp(1) samples
        return (-torch.log(neg_log)).to(like)

    def _sample(
        self, feats: Tensor, unknown: Tensor, generator: torch.Generator, noise_scale: float
    ) -> tuple[Tensor, Tensor]:
        """Samples tokens at unknown positions; ``feats (B, N, D)`` -> ``(tokens (B, N),
        confidence (B, N))`` (``inf`` at known positions). The head runs in chunks of rows
        so that the ``(rows, codebook)`` logits stay small at batch 200."""
        b, n = unknown.shape
        tokens = torch.zeros(b, n, dtype=torch.long, device=feats.device)
        conf = torch.full((b, n), float("inf"), device=feats.device)
        rows = unknown.nonzero(as_tuple=True)
        chunk = max(1, (1 << 22) // self.codebook_size)
        temp = max(self.config.temperature, 1e-6)
        for i in range(0, rows[0].numel(), chunk):
            r = (rows[0][i : i + chunk], rows[1][i : i + chunk])
            logp = F.log_softmax(self.head(feats[r]).float() / temp, -1)  # (rows, K)
            pick = (logp + self._gumbel(tuple(logp.shape), logp, generator)).argmax(-1)
            score = logp.gather(1, pick[:, None])[:, 0]
            if noise_scale > 0:
                score = score + noise_scale * self._gumbel(tuple(score.shape), score, generator)
            tokens[r], conf[r] = pick, score
        return tokens, conf

    def _predict(
        self, context_frames: Tensor, actions: Tensor, generator: torch.Generator
    ) -> Tensor:
        cfg = self.config
        b, c, tf = context_frames.shape[0], cfg.num_context, cfg.num_future
        ctx = self._tokenize(context_frames)  # (B, C, h, w)
        n = tf * self.side * self.side
        future = torch.full((b, n), self.mask_id, dtype=torch.long, device=ctx.device)
        unknown = torch.ones(b, n, dtype=torch.bool, device=ctx.device)
        iters = cfg.decoding_iterations
        for i in range(iters):
            tokens = torch.cat([ctx, future.view(b, tf, self.side, self.side)], 1)
            feats = self.logits(tokens, actions)[:, c:].flatten(1, 3)  # (B, N, D)
            noise = cfg.confidence_noise * (1 - (i + 1) / iters)
            sampled, conf = self._sample(feats, unknown, generator, noise)
            future = torch.where(unknown, sampled, future)
            still = math.floor(n * math.cos(math.pi / 2 * (i + 1) / iters))
            unknown = torch.zeros_like(unknown)
            if still > 0:
                remask = conf.argsort(1)[:, :still]  # the least confident new tokens
                unknown.scatter_(1, remask, True)
                future = future.masked_fill(unknown, self.mask_id)
        frames = self.tokenizer.detokenize(future.view(b * tf, self.side, self.side))
        return frames.unflatten(0, (b, tf))


def _read_tokenizer(config: MaskViTConfig) -> tuple[MaskViTTokenizerConfig, dict[str, Tensor]]:
    """The architecture and weights of the tokenizer checkpoint ``config`` names."""
    from vp2.models.registry import read_checkpoint  # the registry imports this module

    path = Path(str(config.tokenizer_checkpoint))
    payload = read_checkpoint(path)
    name = payload["model"]["name"]
    if name != MaskViTTokenizer.name:
        raise ValueError(f"maskvit: {path} holds a {name!r} model, not a maskvit_tokenizer")
    saved = dict(payload["model"]["config"])
    if int(saved["image_size"]) != config.image_size:
        raise ValueError(
            f"maskvit: tokenizer {path} is for {saved['image_size']}px frames, "
            f"not {config.image_size}px"
        )
    saved.update({k: getattr(config, k) for k in _SHARED_FIELDS})
    return MaskViTTokenizerConfig(**saved), payload["model"]["state_dict"]
