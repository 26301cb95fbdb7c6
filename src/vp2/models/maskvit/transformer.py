"""The transformer blocks of MaskViT: pre-LN blocks attending within windows of tokens.

Blocks alternate *spatial* window attention (each frame's ``h × w`` tokens attend to each
other) and *spatiotemporal* window attention (``T × s × s`` windows over all frames).
"""

from __future__ import annotations

import torch.nn.functional as F
from torch import Tensor, nn


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
