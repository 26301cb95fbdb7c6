"""Exact classifier inference: near the float32 forward, the same bits whatever the kernels."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import torch

from vp2.classifiers.checkpoint import load_classifier
from vp2.classifiers.exact import ExactLinear, box_downsample, exact_network
from vp2.classifiers.networks import FrameClassifierModule, build_classifier
from vp2.classifiers.registry import shipped_path


def _frames(n: int = 16, side: int = 64) -> torch.Tensor:
    g = torch.Generator().manual_seed(0)
    return (torch.rand(n, 3, side, side, generator=g) * 255).round() / 255


def test_exact_logits_stay_near_the_float32_forward():
    clf = load_classifier(shipped_path("push_red"))
    x = _frames()
    exact = clf.exact_logits(x)
    assert exact.dtype == torch.float32 and exact.shape == (16,)
    torch.testing.assert_close(exact, clf(x), rtol=0, atol=2e-5)
    # Batch-independent: a frame's logit does not depend on the others.
    assert torch.equal(clf.exact_logits(x[3:5]), exact[3:5])


def test_an_exact_layer_is_the_same_whatever_the_order_of_its_sum():
    layer = torch.nn.Linear(576, 4)
    exact = ExactLinear(layer)
    x = torch.randn(3, 576, dtype=torch.float64).relu()
    out = exact(x)
    perm = torch.randperm(576)
    shuffled = ExactLinear(layer)  # the same layer with its inputs summed in another order
    shuffled.w_int = exact.w_int[:, perm]
    assert torch.equal(shuffled(x[:, perm]), out)
    reverse = torch.zeros_like(out)  # and added one product at a time, backwards
    from vp2.classifiers.exact import _to_integers
    x_int, x_scale = _to_integers(x, exact.x_bits)
    for k in reversed(range(576)):
        reverse = reverse + x_int[:, k : k + 1] * exact.w_int[:, k]
    assert torch.equal(reverse * exact.w_scale * x_scale[:, None] + exact.bias, out)


def test_the_paper_network_runs_exactly_and_other_layers_are_refused():
    paper = FrameClassifierModule(build_classifier("paper"), "robodesk/push_red", {})
    x = _frames(2)
    torch.testing.assert_close(paper.exact_logits(x), paper(x), rtol=1e-4, atol=1e-4)
    with pytest.raises(ValueError, match="does not know layer BatchNorm2d"):
        exact_network(torch.nn.Sequential(torch.nn.Conv2d(3, 4, 3), torch.nn.BatchNorm2d(4)))


def test_box_downsample_and_the_sizes_it_refuses():
    x = _frames(2, 128).double()
    torch.testing.assert_close(box_downsample(x, 64),
                               torch.nn.functional.avg_pool2d(x, 2), rtol=1e-15, atol=1e-15)
    with pytest.raises(ValueError, match="multiple"):
        box_downsample(_frames(2, 96).double(), 64)


_SCRIPT = """
import torch
from vp2.classifiers.checkpoint import load_classifier
from vp2.classifiers.registry import shipped_path
torch.set_num_threads(1)
clf = load_classifier(shipped_path("push_red"))
g = torch.Generator().manual_seed(0)
x = (torch.rand(64, 3, 64, 64, generator=g) * 255).round() / 255
print(clf.exact_logits(x).numpy().tobytes().hex(), clf(x).numpy().tobytes().hex())
"""


def test_exact_logits_are_the_same_bits_under_other_kernels():
    runs = {}
    for name, env in {"own": {}, "onednn_sse41": {"ONEDNN_MAX_CPU_ISA": "SSE41"},
                      "aten_default": {"ATEN_CPU_CAPABILITY": "default",
                                       "MKL_ENABLE_INSTRUCTIONS": "SSE4_2"}}.items():
        proc = subprocess.run([sys.executable, "-c", _SCRIPT], env={**os.environ, **env},
                              capture_output=True, text=True, check=True)
        runs[name] = proc.stdout.split()
    assert {exact for exact, _ in runs.values()} == {runs["own"][0]}
    # The float32 forward is what differs (which is why the oracle plans with the exact one).
    assert runs["onednn_sse41"][1] != runs["own"][1]
