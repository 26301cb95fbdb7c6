"""Fixed-order sums, the reproducible softmax and weighted mean, and ``torch.randn``'s numbers
of its AVX2 kernels on any kernels."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import torch

from vp2.utils.fixedsum import fixed_sum, normal_float32, softmax_weights, weighted_mean


@pytest.mark.parametrize("n", [0, 1, 2, 3, 7, 16, 15 * 2**5])
def test_fixed_sum_is_the_sum_in_its_documented_order(n):
    x = torch.randn(n, 3, dtype=torch.float64)
    torch.testing.assert_close(fixed_sum(x, dim=0), x.sum(0), rtol=1e-12, atol=1e-12)
    if n == 3:  # odd: the last entry joins the first, then halves
        expected = (x[0] + x[2]) + x[1]
        assert torch.equal(fixed_sum(x, dim=0), expected)


def test_fixed_sum_depends_on_the_shape_alone_not_on_memory_layout():
    x = torch.rand(6, 1000)
    strided = x.T.contiguous().T  # same values, other strides
    assert torch.equal(fixed_sum(x, dim=1), fixed_sum(strided, dim=1))
    assert torch.equal(fixed_sum(x, dim=1)[2:4], fixed_sum(x[2:4], dim=1))  # batch-independent


def test_softmax_weights_and_weighted_mean():
    scores = torch.tensor([0.0, -10.0, -20.0])
    w = softmax_weights(scores, 0.1)
    torch.testing.assert_close(w, torch.softmax(0.1 * scores.double(), 0), rtol=1e-15, atol=0)
    values = torch.arange(6.0).view(3, 2)
    torch.testing.assert_close(weighted_mean(w, values), (w[:, None] * values.double()).sum(0)
                               .float())
    assert weighted_mean(w, values).dtype == torch.float32


_RANDN = """
import json, torch
from vp2.utils.fixedsum import normal_float32
out = {}
for size in (16, 400, 2500, 8000, 1 << 18):
    g1, g2 = torch.Generator().manual_seed(size), torch.Generator().manual_seed(size)
    ours = normal_float32(size, g2)
    out[size] = [torch.equal(torch.randn(size, generator=g1), ours),
                 torch.equal(g1.get_state(), g2.get_state()), ours.numpy().tobytes().hex()[:64]]
print(json.dumps(out))
"""


def _randn(capability: str) -> dict:
    env = {**os.environ, "ATEN_CPU_CAPABILITY": capability}
    proc = subprocess.run([sys.executable, "-c", _RANDN], env=env, capture_output=True,
                          text=True, check=True)
    return json.loads(proc.stdout.strip().splitlines()[-1])


#: The first 16 draws of ``normal_float32(size, seeded with size)``, as bytes: ATen's AVX2
#: normal kernel's numbers (recorded on an AVX2 machine, where torch.randn gives the same).
AVX2_DRAWS = {
    "16": "95e5adbefb2d45bf72d7e43fb60d1fbfa2888bbf3611a1bd4f21a53f76f853bf",
    "400": "61d41d3fe04a98bfa13ed93f568212bf436971bf7e929cbfb3c731bff6b1ed3e",
    "2500": "c41b083f93e5403fb4940d403d6bf9bff9e4d43fdbe519bf04d456bf6279c3bf",
    "8000": "d9cda43fee74753ee977323e21b0a73d9df762bd0df2aa3ee25aeabfee8a353e",
    "262144": "fb8994beb52d133fa0ba463f127532bfd95838bfe24ea73de9e7bc3d7dcc7e3e",
}


def test_normal_float32_is_randn_of_the_avx2_kernels_on_every_capability():
    avx2, default = _randn("avx2"), _randn("default")
    # The same numbers under either capability, and they are the AVX2 kernel's.
    assert {s: v[2] for s, v in avx2.items()} == AVX2_DRAWS
    assert {s: v[2] for s, v in default.items()} == AVX2_DRAWS
    assert all(v[1] for v in default.values())  # the generator advances as torch.randn's does
    if avx2 != default:  # a CPU with AVX2: torch.randn's own numbers, which differ by kernel
        for size, (same, same_state, _) in avx2.items():
            assert same and same_state, size
        assert not all(v[0] for v in default.values())


def test_normal_float32_small_sizes_keep_the_start_of_one_block():
    a = normal_float32(5, torch.Generator().manual_seed(1))
    b = normal_float32(16, torch.Generator().manual_seed(1))
    assert torch.equal(a, b[:5])
