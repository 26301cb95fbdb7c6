"""Torch sums, means and normal draws that give the same bits on every CPU (and any device).

Why this module exists: a torch reduction (``sum``, ``linalg.vector_norm``, ``softmax``, a
matrix-vector product) adds in an order that depends on the SIMD width of the kernel ATen picks
for the CPU (``ATEN_CPU_CAPABILITY``: default, AVX2, AVX-512) or on the BLAS library's kernel,
and ``exp``/``log`` are vectorised differently per capability; so the last bits of a planning
cost, of MPPI's weights and of its weighted mean depend on the machine. Element-wise ``+ - *
/`` are correctly rounded at every SIMD width, so sums made of them alone, in an order fixed by
the shape, are reproducible everywhere (:func:`fixed_sum`). (Torch's float32 ``sqrt`` is not
correctly rounded, about one value in six differs in its last bit from the instruction's;
NumPy's is.) ``exp`` goes through Python's ``math`` (the C library, as
:mod:`vp2.utils.fixedmath` explains); the normal draws replay ATen's AVX2 kernel in NumPy
(:func:`normal_float32`).
"""

from __future__ import annotations

import math

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


def normal_float32(size: int, generator: torch.Generator) -> Tensor:
    """``size`` float32 ``N(0, 1)`` draws from a CPU generator, the same on every CPU: the
    numbers ``torch.randn(size, generator=generator)`` gives where ATen runs its AVX2 kernels
    (the capability torch picks on today's x86-64 CPUs, Intel's and AMD's, AVX-512 ones
    included, and the one the committed oracle records were planned with).

    ``torch.randn`` of float32 runs Box-Muller on the generator's uniforms in blocks of 16
    (``u1 = 1 - u[j]``, ``u2 = u[j + 8]``, ``r = sqrt(-2 log u1)``, ``θ = 2π u2``; values
    ``r cos θ`` and ``r sin θ``; a size that is not a multiple of 16 draws 16 more uniforms and
    redoes its last 16 values). Its AVX2 kernel takes ``log`` and ``sin``/``cos`` from
    ``avx_mathfun.h`` (Cephes polynomials in float32, some steps fused into multiply-adds by
    the compiler); its default kernel calls the C library's ``logf``/``cosf``/``sinf``, which
    round otherwise. Here the same uniforms (``torch.rand``, the same stream) go through the
    AVX2 kernel's steps in NumPy float32 element-wise operations, its fused steps as exactly
    rounded multiply-adds (:func:`_fma32`); the generator ends in the state ``torch.randn``
    leaves it in. Sizes under 16, where ``torch.randn`` takes another algorithm, draw one
    block and keep its start.
    """
    n = max(size, 16)
    u = torch.rand(n, generator=generator, dtype=torch.float32).numpy()
    full = n - n % 16
    out = _box_muller(u[:full])
    if full < n:  # the last 16 values again, from 16 new uniforms
        last = _box_muller(torch.rand(16, generator=generator, dtype=torch.float32).numpy())
        out = np.concatenate([out[: n - 16], last])
    return torch.from_numpy(out[:size].copy())


_F32 = np.float32
# avx_mathfun.h's constants (Cephes).
_LOG_P = [7.0376836292e-2, -1.1514610310e-1, 1.1676998740e-1, -1.2420140846e-1,
          1.4249322787e-1, -1.6668057665e-1, 2.0000714765e-1, -2.4999993993e-1, 3.3333331174e-1]
_LOG_Q1, _LOG_Q2 = -2.12194440e-4, 0.693359375
_FOUR_OVER_PI = 1.27323954473516
_DP = (-0.78515625, -2.4187564849853515625e-4, -3.77489497744594108e-8)
_COS_P = (2.443315711809948e-5, -1.388731625493765e-3, 4.166664568298827e-2)
_SIN_P = (-1.9515295891e-4, 8.3321608736e-3, -1.6666654611e-1)


def _fma32(a: np.ndarray, b: np.ndarray | float, c: np.ndarray | float) -> np.ndarray:
    """``a · b + c`` of float32 values rounded once to float32, as an FMA instruction does.

    The product is exact in float64 (24 + 24 bits); the float64 sum's rounding error comes
    from TwoSum, and a sum that sits exactly halfway between two float32 values is moved one
    float64 step towards the error before the final rounding, so nothing rounds twice."""
    p = np.asarray(a, np.float64) * np.float64(b)
    c64 = np.asarray(c, np.float64)
    s = p + c64
    bp = s - c64
    err = (p - bp) + (c64 - (s - bp))
    halfway = (s.astype(_F32).astype(np.float64) != s) & (err != 0)
    halfway &= np.abs(s - s.astype(_F32).astype(np.float64)) == np.abs(
        np.nextafter(s.astype(_F32), np.copysign(np.inf, s - s.astype(_F32))).astype(np.float64)
        - s.astype(_F32).astype(np.float64)) / 2
    s = np.where(halfway, np.nextafter(s, s + err), s)
    return s.astype(_F32)


def _log(x: np.ndarray) -> np.ndarray:
    """``log256_ps`` for ``x`` in (0, 1] (normal numbers)."""
    bits = x.view(np.int32)
    e = ((bits >> 23) - 0x7F).astype(_F32) + _F32(1)
    m = ((bits & ~0x7F800000) | 0x3F000000).view(_F32)  # the significand in [0.5, 1)
    small = m < _F32(0.707106781186547524)
    e = e - small.astype(_F32)
    m = (m - _F32(1)) + np.where(small, m, _F32(0))
    z = m * m
    y = np.full_like(m, _LOG_P[0])
    for coef in _LOG_P[1:]:
        y = _fma32(y, m, _F32(coef))
    y = _fma32(y * m, z, e * _F32(_LOG_Q1))
    y = y - z * _F32(0.5)
    return (m + y) + e * _F32(_LOG_Q2)


def _sincos(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``sincos256_ps`` for ``x >= 0``: ``(sin x, cos x)``."""
    j = ((x * _F32(_FOUR_OVER_PI)).astype(np.int32) + 1) & ~1  # truncation, as cvttps
    y = j.astype(_F32)
    for dp in _DP:  # the reduction, x - y·π/4 in three parts
        x = _fma32(y, _F32(dp), x)
    z = x * x
    c = np.full_like(x, _COS_P[0])
    for coef in _COS_P[1:]:
        c = _fma32(c, z, _F32(coef))
    c = _fma32(c * z, z, -(z * _F32(0.5))) + _F32(1)
    s = np.full_like(x, _SIN_P[0])
    for coef in _SIN_P[1:]:
        s = _fma32(s, z, _F32(coef))
    s = _fma32(s * z, x, x)
    first = (j & 2) == 0  # the octant's polynomials
    sin, cos = np.where(first, s, c), np.where(first, c, s)
    sin = np.where((j & 4) != 0, -sin, sin)
    cos = np.where((~(j - 2) & 4) != 0, -cos, cos)
    return sin, cos


def _box_muller(u: np.ndarray) -> np.ndarray:
    """Uniforms in [0, 1), a multiple of 16, -> normals, block by block as ATen's
    ``normal_fill_16_AVX2`` (mean 0, std 1)."""
    blocks = u.reshape(-1, 2, 8)
    radius = np.sqrt(_F32(-2) * _log(_F32(1) - blocks[:, 0]))  # correctly rounded sqrt
    sin, cos = _sincos(_F32(2.0 * math.pi) * blocks[:, 1])
    return np.stack([radius * cos, radius * sin], axis=1).reshape(-1)
