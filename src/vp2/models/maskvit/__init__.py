"""MaskViT (Gupta et al. 2022), action-conditioned, with its per-frame VQ tokenizer.

The original code was never released; this is our reading of the paper (model-specs §5),
with the design choices stated here and in ``docs/models.md``. The tokenizer
(``maskvit_tokenizer``, trained first) is in :mod:`vp2.models.maskvit.tokenizer`, the
transformer blocks in :mod:`vp2.models.maskvit.transformer`.

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

from vp2.models.base import (
    CONTRACT_FIELDS,
    LossOutput,
    ModelConfig,
    TrainingDefaults,
    VideoPredictor,
)
from vp2.models.checkpoint import read_model_checkpoint
from vp2.models.layers import FrameLoss, per_frame
from vp2.models.maskvit.tokenizer import MaskViTTokenizer, MaskViTTokenizerConfig
from vp2.models.maskvit.transformer import WindowBlock

__all__ = ["MaskViT", "MaskViTConfig", "MaskViTTokenizer", "MaskViTTokenizerConfig"]


@dataclasses.dataclass
class MaskViTConfig(ModelConfig):
    """Architecture, training and decoding settings of MaskViT.

    ``image_size`` is also the tokenizer's.

    Attributes:
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
    """

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

    def __post_init__(self) -> None:
        self.tokenizer = dict(self.tokenizer)
        if not 0 <= self.mask_ratio_min < self.mask_ratio_max <= 1:
            raise ValueError("maskvit: need 0 <= mask_ratio_min < mask_ratio_max <= 1")
        if self.decoding_iterations < 1:
            raise ValueError("maskvit: decoding_iterations must be >= 1")
        if self.dim % self.heads:
            raise ValueError("maskvit: dim must be divisible by heads")

    def tokenizer_config(self) -> MaskViTTokenizerConfig:
        shared = {k: getattr(self, k) for k in CONTRACT_FIELDS}
        return MaskViTTokenizerConfig(**{**self.tokenizer, **shared})


class MaskViT(VideoPredictor):
    """MaskViT with a frozen per-frame VQ tokenizer; see the module docstring."""

    name: ClassVar[str] = "maskvit"
    config_class: ClassVar[type] = MaskViTConfig
    #: AdamW 3e-4, betas (0.9, 0.95), eps 1e-8, weight decay 0.01, gradient clipping at 1.
    training_defaults: ClassVar[TrainingDefaults] = TrainingDefaults(
        optimizer="adamw", betas=(0.9, 0.95), weight_decay=0.01, grad_clip=1.0
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
        d["tokenizer"] = {k: v for k, v in tok.items() if k not in CONTRACT_FIELDS}
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
        return per_frame(self.tokenizer.tokenize, frames)

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

    def _compute_loss(
        self, frames: Tensor, actions: Tensor, generator: torch.Generator, frame_loss: FrameLoss
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
    path = Path(str(config.tokenizer_checkpoint))
    payload = read_model_checkpoint(path)
    name = payload["model"]["name"]
    if name != MaskViTTokenizer.name:
        raise ValueError(f"maskvit: {path} holds a {name!r} model, not a maskvit_tokenizer")
    saved = dict(payload["model"]["config"])
    if int(saved["image_size"]) != config.image_size:
        raise ValueError(
            f"maskvit: tokenizer {path} is for {saved['image_size']}px frames, "
            f"not {config.image_size}px"
        )
    saved.update({k: getattr(config, k) for k in CONTRACT_FIELDS})
    return MaskViTTokenizerConfig(**saved), payload["model"]["state_dict"]
