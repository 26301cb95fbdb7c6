"""FitVid (Babaeizadeh et al. 2021), action-conditioned, as trained for VP².

Architecture (model-specs §2). A residual NVAE-style encoder (4 stages, ``32·2^i`` filters,
squeeze-excite blocks) maps each frame to a vector ``h`` (``g_dim``); LSTMs model the
dynamics on vectors; the decoder maps the predicted vector back through a dense layer to an
``8 × 8`` map and up through the reversed stages, adding the encoder's activations of the last
context frame after every block::

    h_{t-1} = enc(x_{t-1})                             (B, g)
    z_t ~ posterior(enc(x_t))  (training, and on context frames)
    z_t ~ prior(h_{t-1})       (predicted frames)      (B, z)
    x̂_t = dec(sigmoid(predictor([h_{t-1}, a_{t-1}, z_t])), skips)

Training (teacher forcing): ``loss = MSE(x̂, x) + β Σ_t KL(q_t || p_t)`` with the MSE a mean
over all predicted frames and pixels (as the original), KL summed over latent dimensions and
averaged over the batch. At inference the posterior runs on the context frames, then the prior
is sampled for each predicted frame, which is re-encoded as the next input.

Variants (``vp2.models.registry``): ``default`` (g 128, LSTM 256, ~10.4 M parameters),
``small_encoder`` (g 64, LSTM 128) and ``mini`` (g 32, LSTM 64, all filters / 4).
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from vp2.models.base import LossOutput, ModelConfig, TrainingDefaults, VideoPredictor
from vp2.models.layers import FrameLoss, context_skips, gaussian_kl, per_frame, reparameterize


@dataclasses.dataclass
class FitVidConfig(ModelConfig):
    """Architecture and loss settings of FitVid (defaults: the VP² "default" model).

    ``image_size`` must be divisible by ``2 ** (len(stage_sizes) - 1)``.

    Attributes:
        g_dim: Size of the frame encoding ``h``.
        rnn_size: LSTM width.
        z_dim: Latent size.
        num_base_filters: Filters of the first stage; stage ``i`` has ``base · 2^i``.
        stage_sizes: Residual blocks per encoder (and decoder) stage.
        first_block_channels: Channels of the decoder's first (dense) feature map.
        decoder_expand: Channel expansion inside decoder blocks.
        predictor_layers: LSTM layers of the frame predictor.
        latent_layers: LSTM layers of the prior and of the posterior.
        beta: KL weight in ``loss = MSE + beta · Σ_t KL_t`` (MSE: mean over all frames).
    """

    g_dim: int = 128
    rnn_size: int = 256
    z_dim: int = 10
    num_base_filters: int = 32
    stage_sizes: tuple[int, ...] = (1, 1, 1, 1)
    first_block_channels: int = 512
    decoder_expand: int = 1
    predictor_layers: int = 2
    latent_layers: int = 1
    beta: float = 1e-4

    @property
    def downsample(self) -> int:
        """How much the encoder shrinks a frame's side: 2 per stage after the first."""
        return 2 ** (len(self.stage_sizes) - 1)

    def __post_init__(self) -> None:
        # Checkpoints store plain lists; the architecture wants a hashable tuple.
        self.stage_sizes = tuple(int(s) for s in self.stage_sizes)
        if not self.stage_sizes or min(self.stage_sizes) < 1:
            raise ValueError(f"fitvid: stage_sizes must be >= 1 each, got {self.stage_sizes}")
        self.check_image_size("fitvid", self.downsample)


class SqueezeExcite(nn.Module):
    """Channel gating: global average pool -> C/16 (at least 4) -> ReLU -> C -> sigmoid."""

    def __init__(self, channels: int):
        super().__init__()
        hidden = max(channels // 16, 4)
        self.reduce = nn.Linear(channels, hidden)
        self.expand = nn.Linear(hidden, channels)

    def forward(self, x: Tensor) -> Tensor:
        w = self.expand(F.relu(self.reduce(x.mean(dim=(2, 3)))))  # (N, C)
        return x * torch.sigmoid(w)[:, :, None, None]


class _Shortcut(nn.Module):
    """1×1 conv + BN on the residual path when the shape changes."""

    def __init__(self, cin: int, cout: int, stride: int):
        super().__init__()
        self.conv = nn.Conv2d(cin, cout, 1, stride=stride, bias=False)
        self.norm = nn.BatchNorm2d(cout)

    def forward(self, x: Tensor) -> Tensor:
        return self.norm(self.conv(x))


class EncoderBlock(nn.Module):
    """``BN-SiLU-conv3x3-BN-SiLU-conv3x3-SE`` plus shortcut, then SiLU."""

    def __init__(self, cin: int, cout: int, stride: int):
        super().__init__()
        self.body = nn.Sequential(
            nn.BatchNorm2d(cin), nn.SiLU(),
            nn.Conv2d(cin, cout, 3, stride=stride, padding=1, bias=False),
            nn.BatchNorm2d(cout), nn.SiLU(),
            nn.Conv2d(cout, cout, 3, padding=1, bias=False),
            SqueezeExcite(cout),
        )  # fmt: skip
        self.shortcut = _Shortcut(cin, cout, stride) if (cin != cout or stride != 1) else None

    def forward(self, x: Tensor) -> Tensor:
        skip = x if self.shortcut is None else self.shortcut(x)
        return F.silu(skip + self.body(x))


class DecoderBlock(nn.Module):
    """``BN-conv1x1(×expand)-BN-SiLU-conv5x5-BN-SiLU-conv1x1-BN-SE`` plus shortcut, then SiLU.

    The last BN starts with ``gamma = 0`` so that every block starts as (nearly) the identity.
    """

    def __init__(self, cin: int, cout: int, expand: int, upsample: bool):
        super().__init__()
        mid = cout * expand
        self.upsample = upsample
        last_norm = nn.BatchNorm2d(cout)
        nn.init.zeros_(last_norm.weight)
        self.body = nn.Sequential(
            nn.BatchNorm2d(cin),
            nn.Conv2d(cin, mid, 1, bias=False), nn.BatchNorm2d(mid), nn.SiLU(),
            nn.Conv2d(mid, mid, 5, padding=2, bias=False), nn.BatchNorm2d(mid), nn.SiLU(),
            nn.Conv2d(mid, cout, 1, bias=False), last_norm,
            SqueezeExcite(cout),
        )  # fmt: skip
        self.shortcut = _Shortcut(cin, cout, 1) if cin != cout else None

    def forward(self, x: Tensor) -> Tensor:
        if self.upsample:
            x = F.interpolate(x, scale_factor=2, mode="nearest")
        skip = x if self.shortcut is None else self.shortcut(x)
        return F.silu(skip + self.body(x))


class Encoder(nn.Module):
    """Residual stages; returns ``h (N, g)`` and every block's output (the skips)."""

    def __init__(self, config: FitVidConfig):
        super().__init__()
        blocks, cin = [], 3
        for i, size in enumerate(config.stage_sizes):
            cout = config.num_base_filters * 2**i
            for j in range(size):
                blocks.append(EncoderBlock(cin, cout, stride=2 if i > 0 and j == 0 else 1))
                cin = cout
        self.blocks = nn.ModuleList(blocks)
        self.head = nn.Linear(cin, config.g_dim)

    def forward(self, x: Tensor) -> tuple[Tensor, list[Tensor]]:
        skips = []
        for block in self.blocks:
            x = block(x)
            skips.append(x)
        return self.head(x.mean(dim=(2, 3))), skips  # (N, g), [(N, C_i, H_i, W_i)]


class Decoder(nn.Module):
    """Dense layer to the first feature map, then the reversed stages with additive skips."""

    def __init__(self, config: FitVidConfig):
        super().__init__()
        self.side = config.image_size // config.downsample
        self.first_channels = config.first_block_channels
        self.dense = nn.Linear(config.g_dim, self.first_channels * self.side**2)
        blocks, cin = [], self.first_channels
        for i in reversed(range(len(config.stage_sizes))):
            cout = config.num_base_filters * 2**i
            first_stage = i == len(config.stage_sizes) - 1
            for j in range(config.stage_sizes[i]):
                blocks.append(
                    DecoderBlock(
                        cin, cout, config.decoder_expand, upsample=not first_stage and j == 0
                    )
                )
                cin = cout
        self.blocks = nn.ModuleList(blocks)
        self.out = nn.Conv2d(cin, 3, 3, padding=1, bias=False)

    def forward(self, h: Tensor, skips: list[Tensor]) -> Tensor:
        """``h (N, g)`` and the encoder's skips (in encoder order) -> ``(N, 3, H, W)``."""
        x = self.dense(h).view(-1, self.first_channels, self.side, self.side)
        for block, skip in zip(self.blocks, reversed(skips), strict=True):
            x = block(x) + skip
        return torch.sigmoid(self.out(x))


class GaussianLSTM(nn.Module):
    """``Linear embed -> nn.LSTM(L layers) -> Linear mu / logvar heads`` on vectors.

    Runs a whole sequence at once (teacher forcing) or one step at a time (inference).
    """

    def __init__(self, cin: int, hidden: int, cout: int, layers: int):
        super().__init__()
        self.embed = nn.Linear(cin, hidden)
        self.lstm = nn.LSTM(hidden, hidden, layers)
        self.mu = nn.Linear(hidden, cout)
        self.logvar = nn.Linear(hidden, cout)

    def forward(
        self, x: Tensor, state: tuple[Tensor, Tensor] | None = None
    ) -> tuple[Tensor, Tensor, tuple[Tensor, Tensor]]:
        """``x (S, B, cin)`` -> ``mu, logvar (S, B, cout)`` and the new LSTM state."""
        y, state = self.lstm(self.embed(x), state)
        return self.mu(y), self.logvar(y), state


class FitVid(VideoPredictor):
    """FitVid: a residual encoder and decoder around LSTMs on frame vectors.

    Architecture, loss and inference: see the module docstring.
    """

    name: ClassVar[str] = "fitvid"
    config_class: ClassVar[type] = FitVidConfig
    #: Adam 3e-4, betas (0.9, 0.999), eps 1e-8, gradient clipping at 100.
    training_defaults: ClassVar[TrainingDefaults] = TrainingDefaults(grad_clip=100.0)

    def __init__(self, config: FitVidConfig):
        super().__init__(config)
        g, z, a = config.g_dim, config.z_dim, config.action_dim
        self.encoder = Encoder(config)
        self.decoder = Decoder(config)
        self.predictor = GaussianLSTM(g + a + z, config.rnn_size, g, config.predictor_layers)
        self.prior = GaussianLSTM(g, config.rnn_size, z, config.latent_layers)
        self.posterior = GaussianLSTM(g, config.rnn_size, z, config.latent_layers)

    def _encode(self, frames: Tensor) -> tuple[Tensor, list[Tensor]]:
        """``(B, T, 3, H, W)`` -> ``h (T, B, g)`` (time-major, for ``nn.LSTM``) and skips
        ``(B, T, C_i, H_i, W_i)``."""
        h, skips = per_frame(self.encoder, frames)
        return h.transpose(0, 1), skips

    def _compute_loss(
        self, frames: Tensor, actions: Tensor, generator: torch.Generator, frame_loss: FrameLoss
    ) -> LossOutput:
        """See :meth:`VideoPredictor.compute_loss`. Under teacher forcing every LSTM input is
        known in advance, so each LSTM runs over the whole clip in one call."""
        b, t_total = frames.shape[:2]
        context = self.config.num_context
        h, skips = self._encode(frames)  # (T, B, g)
        mu_q, logvar_q, _ = self.posterior(h[1:])  # (T - 1, B, z)
        mu_p, logvar_p, _ = self.prior(h[:-1])
        z = reparameterize(mu_q, logvar_q, generator)
        inp = torch.cat([h[:-1], actions.transpose(0, 1).to(h.dtype), z], -1)  # (T - 1, B, g+a+z)
        h_pred = torch.sigmoid(self.predictor(inp)[0])  # (T - 1, B, g)
        step_skips = context_skips(skips, context)  # no target frame leaks into its own skips
        preds = self.decoder(h_pred.transpose(0, 1).flatten(0, 1), step_skips)
        preds = preds.unflatten(0, (b, t_total - 1))  # (B, T - 1, 3, H, W)
        losses = frame_loss(preds, frames[:, 1:])
        kl = torch.stack(
            [gaussian_kl(mu_q[i], logvar_q[i], mu_p[i], logvar_p[i]) for i in range(t_total - 1)]
        )  # (T - 1,)
        loss = losses.total.mean() + self.config.beta * kl.sum()
        return LossOutput(
            loss=loss, metrics=losses.metrics(kl=kl.sum().detach()), predictions=preds
        )

    def _predict(
        self, context_frames: Tensor, actions: Tensor, generator: torch.Generator
    ) -> Tensor:
        context = self.config.num_context
        h_ctx, skips = self._encode(context_frames)  # (C, B, g)
        last_skips = [s[:, -1] for s in skips]
        acts = actions.transpose(0, 1)  # (C + T - 1, B, A)
        prior_state = pred_state = None
        if context > 1:
            # Context: the posterior sees the true next frames; prior and predictor warm up.
            mu_q, logvar_q, _ = self.posterior(h_ctx[1:])
            _, _, prior_state = self.prior(h_ctx[:-1])
            z = reparameterize(mu_q, logvar_q, generator)
            inp = torch.cat([h_ctx[:-1], acts[: context - 1], z], -1)  # (C - 1, B, g+a+z)
            _, _, pred_state = self.predictor(inp)
        h_prev = h_ctx[-1:]  # (1, B, g)
        outputs = []
        for t in range(context, context + self.config.num_future):
            mu_p, logvar_p, prior_state = self.prior(h_prev, prior_state)
            z = reparameterize(mu_p, logvar_p, generator)
            mu, _, pred_state = self.predictor(
                torch.cat([h_prev, acts[t - 1 : t], z], -1), pred_state
            )
            frame = self.decoder(torch.sigmoid(mu[0]), last_skips)  # (B, 3, H, W)
            outputs.append(frame)
            if t + 1 < context + self.config.num_future:
                h_prev = self.encoder(frame)[0][None]
        return torch.stack(outputs, 1)  # (B, T, 3, H, W)
