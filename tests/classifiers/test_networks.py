"""The classifier networks: shapes, the paper's size, resizing to the training size."""

from __future__ import annotations

import pytest
import torch

from vp2.classifiers.networks import (
    FrameClassifierModule,
    PaperClassifier,
    SuccessClassifier,
    build_classifier,
    multiply_adds,
)


@pytest.mark.parametrize("arch, cls", [("ours", SuccessClassifier), ("paper", PaperClassifier)])
def test_networks_map_frames_to_one_logit_each(arch, cls):
    net = build_classifier(arch, image_size=64)
    assert isinstance(net, cls)
    out = net(torch.rand(5, 3, 64, 64))
    assert out.shape == (5,) and out.dtype == torch.float32


def test_paper_network_is_the_papers_size_and_ours_is_80x_cheaper():
    paper, ours = build_classifier("paper"), build_classifier("ours")
    assert paper.head[1].in_features == 12288 and paper.head[1].out_features == 1024
    convs = [m for m in paper.modules() if isinstance(m, torch.nn.Conv2d)]
    assert len(convs) == 8 and all(c.stride == (1, 1) and c.kernel_size == (3, 3) for c in convs)
    assert sum(p.numel() for p in paper.parameters()) == 12_642_212
    # 3->32 and 32->3 at 64x64 plus six 32->32, plus the dense head.
    expected = 4096 * (32 * 27 + 6 * 32 * 288 + 3 * 288) + 12288 * 1024 + 1024
    assert multiply_adds(paper) == expected
    assert multiply_adds(paper) / multiply_adds(ours) > 70
    assert sum(p.numel() for p in ours.parameters()) < 100_000


def test_other_image_sizes_are_resized_for_the_network():
    module = FrameClassifierModule(build_classifier("ours", 64).eval(), "robodesk/push_red", {})
    x = torch.rand(2, 3, 64, 64)
    big = torch.nn.functional.interpolate(x, size=(128, 128), mode="nearest")
    torch.testing.assert_close(module(big), module(x), atol=1e-5, rtol=1e-5)
    with pytest.raises(ValueError, match="push_red classifier: images must have shape"):
        module(torch.rand(2, 64, 64))
