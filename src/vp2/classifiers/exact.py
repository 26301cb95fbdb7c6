"""Classifier inference whose logits are the same bits on every CPU (and device).

Why: a convolution or a linear layer in float32 adds its products in an order (and with or
without fused multiply-adds) that the library picks per CPU: oneDNN by instruction set
(``ONEDNN_MAX_CPU_ISA``), the BLAS by kernel, ATen by capability. The logits of the success
classifier, which the RoboDesk planning cost sums, then differ in their last bits from one
machine to the next, and the simulator oracle's plans with them.

How: each convolution and linear layer runs as one float64 matrix product of **integers**:

* its weights are rounded once, per output channel, to ``w_bits`` significant bits
  (``W = Wi · 2^a`` with ``|Wi| <= 2^w_bits``);
* its input is rounded, per frame, to ``x_bits`` bits relative to the frame's largest value
  (``X = Xi · 2^b``, ``|Xi| <= 2^x_bits``; ``b`` from the frame's maximum, which does not
  depend on any order);
* ``w_bits + x_bits + ceil(log2 K) <= 53`` for the ``K`` products of an output, so every
  product and every partial sum is an integer below ``2^53``: float64 holds each exactly, and
  the sum is the same whatever the order, blocking, threading or FMA of the kernel;
* the result is scaled back by ``2^(a + b)`` (exact) and the bias added (one rounding).

ReLU, residual additions and flattening are element-wise, hence correctly rounded everywhere.
The logit is rounded to float32 at the end. With ``K <= 576`` (ours) the layers keep 21-24
bits, float32's precision, so the logits stay within about ``1e-6`` of float32 inference.
"""

from __future__ import annotations

import copy
import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from vp2.utils.fixedsum import fixed_sum

#: Bits of a float64 significand: integers up to ``2^53`` are exact.
_SIGNIFICAND_BITS = 53
#: Layers that are element-wise or pure data movement, exact as they are.
_ELEMENTWISE = (nn.ReLU, nn.Flatten, nn.Identity, nn.Sequential, nn.ModuleList)


def _bits(k: int) -> tuple[int, int]:
    """``(w_bits, x_bits)`` for ``k`` products per output."""
    spare = _SIGNIFICAND_BITS - max(0, math.ceil(math.log2(k)))
    return spare // 2, spare - spare // 2


def _powers_of_two(exponents: Tensor) -> Tensor:
    """``2^e`` for integer ``e``, exactly (``torch.ldexp`` goes through ``pow``)."""
    return torch.tensor([math.ldexp(1.0, int(e)) for e in exponents.tolist()], dtype=torch.float64)


def _to_integers(x: Tensor, bits: int) -> tuple[Tensor, Tensor]:
    """``x (M, ...)`` as integers ``Xi`` (float64, ``|Xi| <= 2^bits``) and the per-row power of
    two ``s`` with ``x ≈ Xi · s``; ``Xi = round(x / s)`` with ``s`` set by the row's maximum."""
    low, high = torch.aminmax(x.detach().flatten(1), dim=1)  # exact: extremes
    top = torch.maximum(high, -low).to("cpu", torch.float64)
    _, exponent = torch.frexp(top)  # top < 2^exponent
    inverse = _powers_of_two(bits - exponent).to(x.device)  # (M,): 1/s, exact
    shape = (-1, *([1] * (x.ndim - 1)))
    return (x * inverse.view(shape)).round_(), _powers_of_two(exponent - bits).to(x.device)


class ExactLinear(nn.Module):
    """A :class:`torch.nn.Linear` (or a 2-D convolution, through ``unfold``) computed as an
    integer float64 product; see the module's docstring."""

    def __init__(self, layer: nn.Linear | nn.Conv2d) -> None:
        super().__init__()
        weight = layer.weight.detach().double().flatten(1)  # (out, K)
        if isinstance(layer, nn.Conv2d):
            if layer.groups != 1 or layer.padding_mode != "zeros" or isinstance(layer.padding,
                                                                                 str):
                raise ValueError("exact inference supports plain convolutions only "
                                 "(groups=1, numeric zero padding)")
            self.unfold = dict(kernel_size=layer.kernel_size, stride=layer.stride,
                               padding=layer.padding, dilation=layer.dilation)
        else:
            self.unfold = None
        self.w_bits, self.x_bits = _bits(weight.shape[1])
        w_int, w_scale = _to_integers(weight, self.w_bits)
        self.register_buffer("w_int", w_int)  # (out, K) integers
        self.register_buffer("w_scale", w_scale)  # (out,) powers of two
        bias = layer.bias.detach().double() if layer.bias is not None else None
        self.register_buffer("bias", bias)

    def forward(self, x: Tensor) -> Tensor:
        x_int, x_scale = _to_integers(x, self.x_bits)  # (M, ...), (M,)
        if self.unfold is None:  # (M, K) @ (K, out)
            out = (x_int @ self.w_int.T).mul_(self.w_scale * x_scale[:, None])  # (M, out)
            return out if self.bias is None else out.add_(self.bias)
        side = [(s + 2 * p - d * (k - 1) - 1) // st + 1 for s, p, d, k, st in zip(
            x.shape[-2:], *(self.unfold[n] for n in ("padding", "dilation", "kernel_size",
                                                     "stride")), strict=True)]
        cols = F.unfold(x_int, **self.unfold)  # (M, K, L): copies, exact
        out = self.w_int @ cols  # (M, out, L) integers
        out.mul_(self.w_scale[:, None] * x_scale[:, None, None])  # exact: powers of two
        if self.bias is not None:
            out.add_(self.bias[:, None])
        return out.view(x.shape[0], -1, *side)


def exact_network(network: nn.Module) -> nn.Module:
    """A float64 copy of ``network`` with every convolution and linear layer an
    :class:`ExactLinear`; its ``forward`` (ReLUs, residual sums, flattening) is unchanged.

    Raises:
        ValueError: for a layer that is neither linear nor element-wise (e.g. a batch norm).
    """
    exact = copy.deepcopy(network).double()
    _replace(exact)
    return exact.eval().requires_grad_(False)


def _replace(module: nn.Module) -> None:
    for name, child in module.named_children():
        if isinstance(child, (nn.Linear, nn.Conv2d)):
            setattr(module, name, ExactLinear(child))
        elif list(child.children()) or isinstance(child, _ELEMENTWISE):
            _replace(child)
        else:
            raise ValueError(
                f"exact classifier inference does not know layer {type(child).__name__}; it "
                "supports Conv2d, Linear and element-wise layers (ReLU, Flatten)"
            )


def box_downsample(images: Tensor, size: int) -> Tensor:
    """``(M, C, S, S) -> (M, C, size, size)``: the mean of each ``f × f`` block (``S = f ·
    size``), added in a fixed order; the exact path's ``F.interpolate(mode="area")``."""
    side = images.shape[-1]
    if side % size or images.shape[-2] != side:
        raise ValueError(
            f"exact classifier inference takes square frames of {size} pixels or a multiple, "
            f"got {tuple(images.shape[-2:])}; render the frames at {size}x{size}"
        )
    f = side // size
    blocks = images.reshape(*images.shape[:2], size, f, size, f).permute(0, 1, 2, 4, 3, 5)
    return fixed_sum(blocks.reshape(*blocks.shape[:4], f * f), dim=-1) / (f * f)
