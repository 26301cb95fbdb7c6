"""``benchmarks.studies.diagnose_pictures``: the pictures of docs/diagnose.md."""

from __future__ import annotations

import base64
import io
import re

import numpy as np
import torch
from benchmarks.studies.diagnose_pictures import (
    FRAME_PX,
    SHOWN_FUTURE,
    conditioning_svg,
    measure_values,
    measures_svg,
    pick_clip,
)
from PIL import Image


def test_pick_clip_takes_the_clip_that_changes_most():
    frames = torch.zeros(3, 12, 3, 8, 8)
    frames[1, 2:, :, :4] = 0.5  # half the image changes after the 2 context frames
    frames[2, 2:, :, :1] = 1.0  # an eighth changes, more strongly
    assert pick_clip(frames, context=2) == 1


def test_conditioning_svg_shows_every_row_with_its_error_against_the_truth():
    truth = torch.zeros(10, 3, 64, 64)
    good = {"truth": truth, "context": torch.zeros(3, 64, 64),
            "true": truth + 0.1, "shuffled": truth + 0.3}  # fmt: skip
    bad = {"true": truth + 0.2, "shuffled": truth + 0.2}
    svg = conditioning_svg(good, bad, ("good", "bad"))
    assert svg.count("MSE ") == 4
    # (0.1)², (0.3)², (0.2)² twice, printed with 4 decimals
    assert re.findall(r"MSE (\d\.\d{4})", svg) == ["0.0100", "0.0900", "0.0400", "0.0400"]
    assert ">another clip&#x27;s actions<" in svg and ">good<" in svg and "true future" in svg
    data = re.search(r'href="data:image/png;base64,([^"]+)"', svg).group(1)
    image = np.asarray(Image.open(io.BytesIO(base64.b64decode(data))))
    gap = 4
    assert image.shape == (5 * (FRAME_PX + gap), (1 + len(SHOWN_FUTURE)) * (FRAME_PX + gap), 3)
    # Row 2 (the good model with shuffled actions) is 0.3 grey: 76.5 rounds to 76 (half to even).
    y = 2 * (FRAME_PX + gap) + 5
    assert image[y, FRAME_PX + gap + 5].tolist() == [76, 76, 76]
    assert image[5, 5].tolist() == [0, 0, 0]  # the context frame


def test_measure_values_and_the_strip_chart():
    report = {"planning": {"spread": {"num_samples": 50}, "instances": [
        {"rank": 1, "of": 51, "repeat_rho": 0.9, "ess": 10.0},
        {"rank": 51, "of": 51, "repeat_rho": None, "ess": 50.0},
    ]}}  # fmt: skip
    values = measure_values(report)
    assert values == {"rank": [0.0, 1.0], "rho": [0.9], "ess": [0.2, 1.0]}
    flat = {"rank": [1.0], "rho": [], "ess": [1.0]}
    svg = measures_svg([values, flat], ("good", "bad"))
    assert svg.count("<circle") == 2 + 1 + 2 + 1 + 0 + 1
    assert "median 0.50" in svg and "undefined" in svg
    assert svg.startswith("<svg") and svg.endswith("</svg>")
