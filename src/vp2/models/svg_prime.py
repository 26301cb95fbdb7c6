"""SVG′: stochastic video generation with convolutional LSTMs (Villegas et al. 2019, VP² variant).

Architecture (model-specs §1). Frames are encoded by the first VGG blocks into an 8×8 feature
map ``h`` (``g_dim`` channels); a learned prior, a posterior and a frame predictor, all
convolutional LSTMs at 8×8, model the dynamics; the decoder mirrors the encoder with U-Net
skips taken from the last context frame. The action that leads to the next frame is tiled to
an ``A × 8 × 8`` map and concatenated with ``h`` and the latent ``z``::

    h_{t-1} = enc(x_{t-1})                              (B, g, 8, 8)
    z_t ~ posterior(enc(x_t))   (training, and on context frames)
    z_t ~ prior(h_{t-1})        (predicted frames)      (B, z, 8, 8)
    x̂_t = dec(predictor([h_{t-1}, tile(a_{t-1}), z_t]), skips)

Size multipliers: ``m`` (the paper's M) scales the LSTM width (``rnn_size * m``), ``k`` (K)
the encoder/decoder channels; both may be fractional.

Training (full teacher forcing): ``loss = Σ_t [MSE(x̂_t, x_t) + β KL(q_t || p_t)]`` over the
``T - 1`` transitions of a clip, MSE a per-frame pixel mean and KL summed over the latent map
and averaged over the batch. At inference the posterior runs on the context frames, then the
prior is sampled for each predicted frame, which is re-encoded as the next input.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from vp2.models.base import LossOutput, ModelConfig, TrainingDefaults, VideoPredictor
from vp2.models.layers import (
    FrameLoss,
    context_skips,
    gaussian_kl,
    init_normal_,
    per_frame,
    reparameterize,
    scaled,
)


@dataclasses.dataclass
class SVGPrimeConfig(ModelConfig):
    """Architecture and loss settings of SVG′ (defaults: the paper's M = K = 1 model).

    ``image_size`` must be a multiple of 8 (the LSTMs run at ``image_size / 8``).

    Attributes:
        rnn_size: LSTM channels before scaling by ``m`` (512 in the paper).
        m: LSTM size multiplier (the paper's M).
        k: Encoder/decoder channel multiplier (the paper's K).
        g_dim: Channels of the encoded frame ``h``.
        z_dim: Channels of the latent map ``z``.
        predictor_layers: ConvLSTM layers of the frame predictor.
        latent_layers: ConvLSTM layers of the prior and of the posterior.
        beta: KL weight in ``loss = Σ_t [MSE_t + beta · KL_t]``.
    """

    rnn_size: int = 512
    m: float = 1.0
    k: float = 1.0
    g_dim: int = 128
    z_dim: int = 10
    predictor_layers: int = 2
    latent_layers: int = 1
    beta: float = 1e-4

    def __post_init__(self) -> None:
        self.check_image_size("svg_prime", 8)
        if self.m <= 0 or self.k <= 0:
            raise ValueError(f"svg_prime: m and k must be > 0, got m={self.m}, k={self.k}")

    @property
    def hidden(self) -> int:
        """LSTM channels: ``rnn_size · m``, rounded."""
        return scaled(self.rnn_size * self.m)


def _vgg_layer(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1), nn.BatchNorm2d(cout), nn.LeakyReLU(0.2, inplace=True)
    )


def _up(x: Tensor) -> Tensor:
    return F.interpolate(x, scale_factor=2, mode="nearest")


class Encoder(nn.Module):
    """First three VGG blocks, then a 3×3 conv to ``g_dim`` at 1/8 resolution."""

    def __init__(self, k: float, g_dim: int):
        super().__init__()
        c1, c2, c3 = scaled(64 * k), scaled(128 * k), scaled(256 * k)
        self.block1 = nn.Sequential(_vgg_layer(3, c1), _vgg_layer(c1, c1))
        self.block2 = nn.Sequential(_vgg_layer(c1, c2), _vgg_layer(c2, c2))
        self.block3 = nn.Sequential(_vgg_layer(c2, c3), _vgg_layer(c3, c3), _vgg_layer(c3, c3))
        self.out = nn.Conv2d(c3, g_dim, 3, padding=1)

    def forward(self, x: Tensor) -> tuple[Tensor, list[Tensor]]:
        s1 = self.block1(x)  # (N, 64K, H, W)
        s2 = self.block2(F.max_pool2d(s1, 2))  # (N, 128K, H/2, W/2)
        s3 = self.block3(F.max_pool2d(s2, 2))  # (N, 256K, H/4, W/4)
        h = self.out(F.max_pool2d(s3, 2))  # (N, g, H/8, W/8)
        return h, [s1, s2, s3]


class Decoder(nn.Module):
    """Mirror of :class:`Encoder`; concatenates the skips at each resolution."""

    def __init__(self, k: float, g_dim: int):
        super().__init__()
        c1, c2, c3 = scaled(64 * k), scaled(128 * k), scaled(256 * k)
        self.inp = nn.Conv2d(g_dim, c3, 3, padding=1)
        self.block3 = nn.Sequential(_vgg_layer(2 * c3, c3), _vgg_layer(c3, c3), _vgg_layer(c3, c2))
        self.block2 = nn.Sequential(_vgg_layer(2 * c2, c2), _vgg_layer(c2, c1))
        self.block1 = _vgg_layer(2 * c1, c1)
        self.out = nn.ConvTranspose2d(c1, 3, 3, padding=1)

    def forward(self, h: Tensor, skips: list[Tensor]) -> Tensor:
        s1, s2, s3 = skips
        x = _up(self.inp(h))  # (N, 256K, H/4, W/4)
        x = _up(self.block3(torch.cat([x, s3], 1)))  # (N, 128K, H/2, W/2)
        x = _up(self.block2(torch.cat([x, s2], 1)))  # (N, 64K, H, W)
        x = self.block1(torch.cat([x, s1], 1))  # (N, 64K, H, W)
        return torch.sigmoid(self.out(x))  # (N, 3, H, W)


class ConvLSTMCell(nn.Module):
    """One convolutional LSTM layer: a single 3×3 conv on ``[x, h]`` gives the four gates."""

    def __init__(self, cin: int, hidden: int):
        super().__init__()
        self.hidden = hidden
        self.gates = nn.Conv2d(cin + hidden, 4 * hidden, 3, padding=1)

    def forward(self, x: Tensor, state: tuple[Tensor, Tensor] | None) -> tuple[Tensor, Tensor]:
        if state is None:
            zeros = x.new_zeros(x.shape[0], self.hidden, *x.shape[2:])
            state = (zeros, zeros)
        h, c = state
        i, f, o, g = self.gates(torch.cat([x, h], 1)).chunk(4, 1)
        c = torch.sigmoid(f) * c + torch.sigmoid(i) * torch.tanh(g)
        h = torch.sigmoid(o) * torch.tanh(c)
        return h, c


class ConvLSTM(nn.Module):
    """``conv3x3 -> L ConvLSTM layers -> conv3x3 head(s)``, stepped one frame at a time.

    With ``gaussian=True`` (prior, posterior) the heads give ``mu`` and ``logvar``; otherwise
    (frame predictor) one head followed by ``tanh``.
    """

    def __init__(self, cin: int, hidden: int, cout: int, layers: int, gaussian: bool):
        super().__init__()
        self.embed = nn.Conv2d(cin, hidden, 3, padding=1)
        self.cells = nn.ModuleList(ConvLSTMCell(hidden, hidden) for _ in range(layers))
        self.gaussian = gaussian
        self.mu = nn.Conv2d(hidden, cout, 3, padding=1)
        self.logvar = nn.Conv2d(hidden, cout, 3, padding=1) if gaussian else None

    def forward(
        self, x: Tensor, states: list[tuple[Tensor, Tensor]] | None
    ) -> tuple[Tensor, Tensor | None, list[tuple[Tensor, Tensor]]]:
        """One step: returns ``(mu or output, logvar or None, new states)``."""
        y = self.embed(x)
        new_states = []
        for i, cell in enumerate(self.cells):
            h, c = cell(y, None if states is None else states[i])
            new_states.append((h, c))
            y = h
        if self.gaussian:
            return self.mu(y), self.logvar(y), new_states
        return torch.tanh(self.mu(y)), None, new_states


class SVGPrime(VideoPredictor):
    """SVG′ with size multipliers.

    A VGG encoder and decoder with U-Net skips around convolutional LSTMs at 1/8 resolution;
    see the module docstring.
    """

    name: ClassVar[str] = "svg_prime"
    config_class: ClassVar[type] = SVGPrimeConfig
    #: Adam 3e-4, betas (0.9, 0.999), eps 1e-8, no gradient clipping.
    training_defaults: ClassVar[TrainingDefaults] = TrainingDefaults()

    def __init__(self, config: SVGPrimeConfig):
        super().__init__(config)
        g, z, a, hidden = config.g_dim, config.z_dim, config.action_dim, config.hidden
        self.encoder = Encoder(config.k, g)
        self.decoder = Decoder(config.k, g)
        self.predictor = ConvLSTM(g + a + z, hidden, g, config.predictor_layers, gaussian=False)
        self.prior = ConvLSTM(g, hidden, z, config.latent_layers, gaussian=True)
        self.posterior = ConvLSTM(g, hidden, z, config.latent_layers, gaussian=True)
        init_normal_(self)

    @staticmethod
    def _tile(action: Tensor, like: Tensor) -> Tensor:
        return action[:, :, None, None].expand(-1, -1, *like.shape[2:])  # (B, A, h, w)

    def _compute_loss(
        self, frames: Tensor, actions: Tensor, generator: torch.Generator, frame_loss: FrameLoss
    ) -> LossOutput:
        """See :meth:`VideoPredictor.compute_loss`; teacher forcing over all ``T - 1`` steps."""
        t_total, context = frames.shape[1], self.config.num_context
        h, skips = per_frame(self.encoder, frames)  # (B, T, g, h, w)
        pred_state = prior_state = post_state = None
        h_preds, kls = [], []
        for t in range(1, t_total):
            mu_q, logvar_q, post_state = self.posterior(h[:, t], post_state)
            mu_p, logvar_p, prior_state = self.prior(h[:, t - 1], prior_state)
            z = reparameterize(mu_q, logvar_q, generator)  # (B, z, h, w)
            inp = torch.cat([h[:, t - 1], self._tile(actions[:, t - 1], z), z], 1)
            h_pred, _, pred_state = self.predictor(inp, pred_state)
            h_preds.append(h_pred)
            kls.append(gaussian_kl(mu_q, logvar_q, mu_p, logvar_p))
        step_skips = context_skips(skips, context)  # SVG's rule: no target leaks in
        preds = self.decoder(torch.stack(h_preds, 1).flatten(0, 1), step_skips)
        preds = preds.unflatten(0, frames.shape[:1] + (t_total - 1,))  # (B, T - 1, 3, H, W)
        losses = frame_loss(preds, frames[:, 1:])
        kl = torch.stack(kls)  # (T - 1,)
        loss = losses.total.sum() + self.config.beta * kl.sum()
        metrics = losses.metrics(kl=kl.sum().detach())
        return LossOutput(loss=loss, metrics=metrics, predictions=preds)

    def _predict(
        self, context_frames: Tensor, actions: Tensor, generator: torch.Generator
    ) -> Tensor:
        context = self.config.num_context
        h_ctx, skips = per_frame(self.encoder, context_frames)  # (B, C, g, h, w)
        last_skips = [s[:, -1] for s in skips]
        pred_state = prior_state = post_state = None
        # Context: the posterior sees the true next frame; prior and predictor states warm up.
        for t in range(1, context):
            mu_q, logvar_q, post_state = self.posterior(h_ctx[:, t], post_state)
            _, _, prior_state = self.prior(h_ctx[:, t - 1], prior_state)
            z = reparameterize(mu_q, logvar_q, generator)
            inp = torch.cat([h_ctx[:, t - 1], self._tile(actions[:, t - 1], z), z], 1)
            _, _, pred_state = self.predictor(inp, pred_state)
        h_prev = h_ctx[:, -1]
        outputs = []
        for t in range(context, context + self.config.num_future):
            mu_p, logvar_p, prior_state = self.prior(h_prev, prior_state)
            z = reparameterize(mu_p, logvar_p, generator)
            inp = torch.cat([h_prev, self._tile(actions[:, t - 1], z), z], 1)
            h_pred, _, pred_state = self.predictor(inp, pred_state)
            frame = self.decoder(h_pred, last_skips)  # (B, 3, H, W)
            outputs.append(frame)
            if t + 1 < context + self.config.num_future:
                h_prev, _ = self.encoder(frame)
        return torch.stack(outputs, 1)  # (B, T, 3, H, W)
