"""Torch sums, means and normal draws that give the same bits on every CPU (and any device).

Why this module exists: a torch reduction (``sum``, ``linalg.vector_norm``, ``softmax``, a
matrix-vector product) adds in an order that depends on the SIMD width of the kernel ATen picks
for the CPU (``ATEN_CPU_CAPABILITY``: default, AVX2, AVX-512) or on the BLAS library's kernel,
and ``exp``/``log`` are vectorised differently per capability; so the last bits of a planning
cost, of MPPI's weights and of its weighted mean depend on the machine. Element-wise ``+ - *
/`` and ``sqrt`` are correctly rounded at every SIMD width, so sums made of them alone, in an
order fixed by the shape, are reproducible everywhere (:func:`fixed_sum`). Transcendentals go
through Python's ``math`` (the C library, as :mod:`vp2.utils.fixedmath` explains).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import math
from collections.abc import Callable

import numpy as np
import torch
from torch import Tensor


def fixed_sum(x: Tensor, dim: int = -1) -> Tensor:
    """``x.sum(dim)`` added pairwise in an order fixed by the size of ``dim`` alone.

    The slice is halved again and again (``x[:h] + x[h:]``, element-wise); an odd slice first
    adds its last entry to its first. About ``log2(n)`` element-wise passes; differentiable.
    """
    x = x.movedim(dim, 0)
    if x.shape[0] == 0:
        return torch.zeros(x.shape[1:], dtype=x.dtype, device=x.device)
    while x.shape[0] > 1:
        n = x.shape[0]
        if n % 2:
            x = torch.cat([(x[0] + x[n - 1])[None], x[1 : n - 1]])
            n -= 1
        half = n // 2
        x = x[:half] + x[half:]
    return x[0]


def softmax_weights(scores: Tensor, scale: float) -> Tensor:
    """``softmax(scale · scores)`` in float64, reproducible: ``exp`` of the C library, each
    weight's share from a correctly rounded sum (``math.fsum``). ``(N,)`` on the scores' device.
    """
    z = [scale * s for s in scores.detach().to("cpu", torch.float64).tolist()]
    top = max(z)
    e = [math.exp(v - top) for v in z]
    total = math.fsum(e)
    return torch.tensor([v / total for v in e], dtype=torch.float64, device=scores.device)


def weighted_mean(weights: Tensor, values: Tensor) -> Tensor:
    """``Σ_n weights[n] · values[n]`` (``weights (N,)`` summing to 1, ``values (N, ...)``) in
    float64 with :func:`fixed_sum`, returned in ``values``' dtype."""
    w = weights.to(values.device, torch.float64).reshape(-1, *([1] * (values.ndim - 1)))
    return fixed_sum(w * values.double(), dim=0).to(values.dtype)


_TWO_PI = 2.0 * math.pi


def _libm_float(name: str) -> Callable[[float], float]:
    fn = getattr(ctypes.CDLL(ctypes.util.find_library("m")), name)
    fn.restype, fn.argtypes = ctypes.c_float, [ctypes.c_float]
    return fn


_LOGF, _COSF, _SINF = (_libm_float(name) for name in ("logf", "cosf", "sinf"))


def normal_float32(size: int, generator: torch.Generator) -> Tensor:
    """``size`` float32 ``N(0, 1)`` draws from a CPU generator, the same on every CPU: the
    numbers ``torch.randn(size, generator=generator)`` gives where ATen runs its default or
    AVX-512 kernels.

    ``torch.randn`` of float32 runs Box-Muller on the generator's uniforms in blocks of 16
    (``u1 = 1 - u[j]``, ``u2 = u[j + 8]``, ``r = sqrt(-2 logf(u1))``, ``θ = 2π u2``; values
    ``r cosf(θ)`` and ``r sinf(θ)``; a size that is not a multiple of 16 draws 16 more uniforms
    and redoes its last 16 values) with the C library's ``logf``/``cosf``/``sinf``, except that
    ATen's AVX2 kernels use their own vectorised ``log``/``cos``/``sin``, which round otherwise.
    Here the same uniforms (``torch.rand``, the same stream) go through the same steps, with the
    C library's functions called one value at a time and the rest in float32 element-wise; the
    generator ends in the state ``torch.randn`` leaves it in. Sizes under 16, where
    ``torch.randn`` takes another algorithm, draw one block and keep its start.
    """
    n = max(size, 16)
    u = torch.rand(n, generator=generator, dtype=torch.float32)
    full = n - n % 16
    out = _box_muller(u[:full].view(-1, 2, 8)).reshape(-1)
    if full < n:  # the last 16 values again, from 16 new uniforms
        last = _box_muller(torch.rand(16, generator=generator, dtype=torch.float32).view(1, 2, 8))
        out = torch.cat([out[: n - 16], last.reshape(-1)])
    return out[:size]


def _box_muller(u: Tensor) -> Tensor:
    """``u (B, 2, 8)`` uniforms in [0, 1) -> ``(B, 2, 8)`` normals (``[:, 0]`` cos, ``[:, 1]``
    sin), as ATen's ``normal_fill_16``. NumPy does the float32 arithmetic: its ``sqrt`` is the
    correctly rounded instruction, torch's float32 ``sqrt`` is not (about one value in six
    differs in the last bit)."""
    v = u.numpy()
    u1 = (np.float32(1) - v[:, 0]).ravel().tolist()  # exact: (0, 1] for the log
    theta = (_TWO_PI * v[:, 1].astype(np.float64)).astype(np.float32).ravel().tolist()
    radius = np.sqrt(np.float32(-2) * np.fromiter(map(_LOGF, u1), np.float32, len(u1)))
    cos = radius * np.fromiter(map(_COSF, theta), np.float32, len(theta))
    sin = radius * np.fromiter(map(_SINF, theta), np.float32, len(theta))
    return torch.from_numpy(np.stack([cos, sin]).reshape(2, -1, 8).transpose(1, 0, 2).copy())
