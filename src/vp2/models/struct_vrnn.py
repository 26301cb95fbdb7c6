"""Struct-VRNN (Minderer et al. 2019): keypoints as the state of a variational RNN.

Architecture (model-specs §3). A convolutional detector (RGB plus two coordinate channels)
turns each frame into ``K`` heatmaps at a quarter of the image side; each map gives a
keypoint ``(x, y, intensity)``: the expected coordinates under the normalised map and its
mean activation relative to the strongest keypoint. Keypoints are rendered back into
Gaussian maps, and a decoder turns ``[G(k_t), appearance(x_0), G(k_0), coords]`` into a
residual added to the first frame ``x_0``. The dynamics run on keypoint vectors only::

    k_t = detect(x_t)                                   (B, K, 3)
    e_t = LSTM([k_{t-1}, a_{t-1}])                      deterministic core, 2 layers
    z_t ~ posterior(e_t, k_t)  (training)
    z_t ~ prior(e_t)           (predicted frames)        (B, z)
    k̂_t = tanh(head([e_t, z_t]))                        (B, K, 3)
    x̂_t = x_0 + decode(G(k̂_t), appearance(x_0), G(k_0))

The action that produced frame ``t`` (``a_{t-1}``) enters the step that predicts ``k_t``, in
training and at inference alike: the original inference code fed the actions one step late
(model-specs §3), which we do not reproduce.

Training on a clip: ``loss = w_rec · MSE(decode(k_t), x_t)`` (every frame from its own
detected keypoints) ``+ w_coord · MSE(k̂_t, sg(k_t)) + w_kl · Σ_t KL(q_t || p_t)``. The
keypoints the dynamics learn from are detached: the detector is shaped by reconstruction
only, so the dynamics cannot make its job easier by collapsing the keypoints.
"""

from __future__ import annotations

import dataclasses
from typing import ClassVar

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from vp2.models.base import LossOutput, ModelConfig, TrainingDefaults, VideoPredictor
from vp2.models.layers import FrameLoss, gaussian_kl, per_frame, reparameterize


@dataclasses.dataclass
class StructVRNNConfig(ModelConfig):
    """Architecture and loss settings of Struct-VRNN (defaults: the paper's model).

    ``image_size`` must be a multiple of 4 (keypoint maps are ``image_size / 4``).

    Attributes:
        num_keypoints: ``K``.
        filters: Channels of the first detector stage (then ×2, ×4).
        decoder_filters: Channels of the decoder's first conv (then /2, /4).
        keypoint_sigma: Std of the rendered Gaussian maps, in coordinates in [-1, 1].
        rnn_size: Width of the dynamics LSTM and of the prior/posterior MLPs.
        rnn_layers: LSTM layers of the deterministic core.
        z_dim: Latent size.
        recon_weight: Weight of the image reconstruction MSE.
        coord_weight: Weight of the keypoint prediction MSE.
        kl_weight: Weight of the KL term (the paper found 1e-4 best for control).
    """

    num_keypoints: int = 64
    filters: int = 32
    decoder_filters: int = 256
    keypoint_sigma: float = 0.1
    rnn_size: int = 512
    rnn_layers: int = 2
    z_dim: int = 16
    recon_weight: float = 10.0
    coord_weight: float = 1.0
    kl_weight: float = 1e-3

    def __post_init__(self) -> None:
        self.check_image_size("struct_vrnn", 4)


def coordinate_grid(size: int, like: Tensor) -> Tensor:
    """``(2, size, size)`` channels ``x`` and ``y`` in [-1, 1] (pixel centres)."""
    lin = (torch.arange(size, device=like.device, dtype=like.dtype) + 0.5) / size * 2 - 1
    y, x = torch.meshgrid(lin, lin, indexing="ij")
    return torch.stack([x, y])


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1), nn.LeakyReLU(0.2))


class FeatureExtractor(nn.Module):
    """The detector/appearance trunk: coordinate channels + 3 stages of convs, /4 spatially.

    ``f, 2f, 4f`` channels: conv(5->f), 2x conv(f->f); stride-2 conv(f->2f), 2x conv(2f->2f);
    stride-2 conv(2f->4f), 2x conv(4f->4f).
    """

    def __init__(self, filters: int):
        super().__init__()
        f = filters
        self.net = nn.Sequential(
            _conv(5, f), _conv(f, f), _conv(f, f),
            _conv(f, 2 * f, 2), _conv(2 * f, 2 * f), _conv(2 * f, 2 * f),
            _conv(2 * f, 4 * f, 2), _conv(4 * f, 4 * f), _conv(4 * f, 4 * f),
        )  # fmt: skip
        self.out_channels = 4 * f

    def forward(self, x: Tensor) -> Tensor:
        """``(N, 3, H, W)`` -> ``(N, 4f, H/4, W/4)``."""
        coords = coordinate_grid(x.shape[-1], x).expand(x.shape[0], -1, -1, -1)
        return self.net(torch.cat([x, coords], 1))


class KeypointDetector(nn.Module):
    """Frames -> ``K`` keypoints ``(x, y, intensity)`` with ``x, y`` in [-1, 1]."""

    def __init__(self, filters: int, num_keypoints: int):
        super().__init__()
        self.features = FeatureExtractor(filters)
        self.heatmaps = nn.Conv2d(self.features.out_channels, num_keypoints, 3, 1, 1)

    def forward(self, x: Tensor) -> Tensor:
        """``(N, 3, H, W)`` -> ``(N, K, 3)``."""
        maps = F.softplus(self.heatmaps(self.features(x)))  # (N, K, h, w)
        grid = coordinate_grid(maps.shape[-1], maps)  # (2, h, w)
        weights = maps / (maps.sum(dim=(2, 3), keepdim=True) + 1e-6)
        xy = (weights[:, :, None] * grid).sum(dim=(3, 4))  # (N, K, 2)
        mean = maps.mean(dim=(2, 3))  # (N, K)
        intensity = mean / (mean.amax(dim=1, keepdim=True) + 1e-6)
        return torch.cat([xy, intensity[..., None]], -1)


def gaussian_maps(keypoints: Tensor, size: int, sigma: float) -> Tensor:
    """``(N, K, 3)`` keypoints -> ``(N, K, size, size)`` Gaussian blobs scaled by intensity.

    Intensities are clamped to [0, 1] (the dynamics' tanh head may predict a negative one).
    """
    grid = coordinate_grid(size, keypoints)  # (2, s, s)
    dx = grid[0] - keypoints[..., 0, None, None]  # (N, K, s, s)
    dy = grid[1] - keypoints[..., 1, None, None]
    blobs = torch.exp(-(dx**2 + dy**2) / (2 * sigma**2))
    return blobs * keypoints[..., 2, None, None].clamp(0, 1)


class ImageDecoder(nn.Module):
    """``[G(k_t), appearance(x_0), G(k_0), coords]`` -> residual image at full size."""

    def __init__(self, config: StructVRNNConfig, appearance_channels: int):
        super().__init__()
        k, d = config.num_keypoints, config.decoder_filters
        self.first = _conv(2 * k + appearance_channels + 2, d)
        self.stage1 = nn.Sequential(_conv(d, d // 2), _conv(d // 2, d // 2))
        self.stage2 = nn.Sequential(_conv(d // 2, d // 4), _conv(d // 4, d // 4))
        self.out = nn.Conv2d(d // 4, 3, 3, 1, 1)

    def forward(self, maps: Tensor, appearance: Tensor, first_maps: Tensor) -> Tensor:
        coords = coordinate_grid(maps.shape[-1], maps).expand(maps.shape[0], -1, -1, -1)
        x = self.first(torch.cat([maps, appearance, first_maps, coords], 1))
        x = self.stage1(F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False))
        x = self.stage2(F.interpolate(x, scale_factor=2, mode="bilinear", align_corners=False))
        return self.out(x)


def _mlp(cin: int, hidden: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(cin, hidden), nn.ReLU(), nn.Linear(hidden, cout))


class KeypointDynamics(nn.Module):
    """The VRNN on flattened keypoints (``3K``): LSTM core, Gaussian prior/posterior, head."""

    def __init__(self, config: StructVRNNConfig):
        super().__init__()
        kdim, hidden, z = 3 * config.num_keypoints, config.rnn_size, config.z_dim
        self.z_dim = z
        self.embed = nn.Linear(kdim + config.action_dim, hidden)
        self.core = nn.LSTM(hidden, hidden, config.rnn_layers, batch_first=True)
        self.prior = _mlp(hidden, hidden, 2 * z)
        self.posterior = _mlp(hidden + kdim, hidden, 2 * z)
        self.head = _mlp(hidden + z, hidden, kdim)

    def step_core(
        self, keypoints: Tensor, actions: Tensor, state: tuple[Tensor, Tensor] | None = None
    ) -> tuple[Tensor, tuple[Tensor, Tensor]]:
        """``k (B, S, 3K)``, ``a (B, S, A)`` -> core outputs ``e (B, S, hidden)``."""
        return self.core(F.relu(self.embed(torch.cat([keypoints, actions], -1))), state)

    def predict_keypoints(self, e: Tensor, z: Tensor) -> Tensor:
        return torch.tanh(self.head(torch.cat([e, z], -1)))


class StructVRNN(VideoPredictor):
    """Struct-VRNN: keypoints detected in every frame, a variational RNN on the keypoints,
    and a decoder that renders them back onto the first frame; see the module docstring."""

    name: ClassVar[str] = "struct_vrnn"
    config_class: ClassVar[type] = StructVRNNConfig
    #: Adam 3e-4, betas (0.9, 0.999), eps 1e-8, no gradient clipping.
    training_defaults: ClassVar[TrainingDefaults] = TrainingDefaults()

    def __init__(self, config: StructVRNNConfig):
        super().__init__(config)
        self.detector = KeypointDetector(config.filters, config.num_keypoints)
        self.appearance = FeatureExtractor(config.filters)
        self.decoder = ImageDecoder(config, self.appearance.out_channels)
        self.dynamics = KeypointDynamics(config)

    # ----------------------------------------------------------------- pieces

    def _detect(self, frames: Tensor) -> Tensor:
        """``(B, T, 3, H, W)`` -> ``(B, T, K, 3)``."""
        return per_frame(self.detector, frames)

    def _render(self, keypoints: Tensor, first_keypoints: Tensor, first_frame: Tensor) -> Tensor:
        """Keypoints ``(B, T, K, 3)``, ``k_0 (B, K, 3)`` and ``x_0 (B, 3, H, W)`` -> frames
        ``(B, T, 3, H, W)`` (unclamped: ``x_0`` plus the decoder's residual)."""
        b, t = keypoints.shape[:2]
        side = self.config.image_size // 4
        sigma = self.config.keypoint_sigma
        appearance = self.appearance(first_frame)  # (B, C, h, w)
        first_maps = gaussian_maps(first_keypoints, side, sigma)  # (B, K, h, w)
        maps = gaussian_maps(keypoints.flatten(0, 1), side, sigma)  # (B*T, K, h, w)
        rep = lambda x: x[:, None].expand(-1, t, *x.shape[1:]).flatten(0, 1)  # noqa: E731
        residual = self.decoder(maps, rep(appearance), rep(first_maps))
        return rep(first_frame).unflatten(0, (b, t)) + residual.unflatten(0, (b, t))

    @staticmethod
    def _latent(params: Tensor) -> tuple[Tensor, Tensor]:
        mu, logvar = params.chunk(2, -1)
        return mu, logvar

    # ----------------------------------------------------------------- training

    def _compute_loss(
        self, frames: Tensor, actions: Tensor, generator: torch.Generator, frame_loss: FrameLoss
    ) -> LossOutput:
        """See :meth:`VideoPredictor.compute_loss` and the module docstring.

        ``predictions`` are frames ``1 .. T - 1`` decoded from their detected keypoints.
        """
        cfg = self.config
        keypoints = self._detect(frames)  # (B, T, K, 3)
        recon = self._render(keypoints, keypoints[:, 0], frames[:, 0])  # (B, T, 3, H, W)
        losses = frame_loss(recon, frames)

        k = keypoints.detach().flatten(2)  # (B, T, 3K)
        e, _ = self.dynamics.step_core(k[:, :-1], actions.to(k.dtype))  # (B, T - 1, hidden)
        mu_p, logvar_p = self._latent(self.dynamics.prior(e))
        mu_q, logvar_q = self._latent(self.dynamics.posterior(torch.cat([e, k[:, 1:]], -1)))
        z = reparameterize(mu_q, logvar_q, generator)
        k_hat = self.dynamics.predict_keypoints(e, z)  # (B, T - 1, 3K)
        coord = ((k_hat.float() - k[:, 1:].float()) ** 2).mean()
        kl = gaussian_kl(mu_q.flatten(1), logvar_q.flatten(1), mu_p.flatten(1), logvar_p.flatten(1))
        loss = (
            cfg.recon_weight * losses.total.mean() + cfg.coord_weight * coord + cfg.kl_weight * kl
        )
        metrics = losses.metrics(coord=coord.detach(), kl=kl.detach())
        return LossOutput(loss=loss, metrics=metrics, predictions=recon[:, 1:].clamp(0, 1))

    # ----------------------------------------------------------------- inference

    def rollout_keypoints(
        self, context_frames: Tensor, actions: Tensor, generator: torch.Generator | None = None
    ) -> tuple[Tensor, Tensor]:
        """The dynamics' keypoints of the future frames ``(B, T, K, 3)`` and the first context
        frame's ``(B, K, 3)``; latents sampled from the prior with ``generator``, or its mean
        when ``generator`` is ``None`` (no sampling noise)."""
        context = self.config.num_context
        observed = self._detect(context_frames).flatten(2)  # (B, C, 3K)
        # Warm the core up on the context transitions (k_{t-1}, a_{t-1}) -> k_t.
        _, state = self.dynamics.step_core(observed[:, :-1], actions[:, : context - 1])
        k_prev, predicted = observed[:, -1:], []
        for t in range(context, context + self.config.num_future):
            e, state = self.dynamics.step_core(k_prev, actions[:, t - 1 : t], state)
            mu, logvar = self._latent(self.dynamics.prior(e))
            z = mu if generator is None else reparameterize(mu, logvar, generator)
            k_prev = self.dynamics.predict_keypoints(e, z)
            predicted.append(k_prev)
        keypoints = torch.cat(predicted, 1).unflatten(-1, (-1, 3))  # (B, T, K, 3)
        return keypoints, observed[:, 0].unflatten(-1, (-1, 3))

    def _predict(
        self, context_frames: Tensor, actions: Tensor, generator: torch.Generator
    ) -> Tensor:
        keypoints, first = self.rollout_keypoints(context_frames, actions, generator)
        return self._render(keypoints, first, context_frames[:, 0]).clamp(0, 1)
