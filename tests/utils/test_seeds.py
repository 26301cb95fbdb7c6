"""``vp2.utils.seeds.check_seed``: what every config accepts as a seed."""

from __future__ import annotations

import re

import numpy as np
import pytest

from vp2.utils.seeds import check_seed


def test_non_negative_integers_pass():
    for seed in (0, 7, np.int64(3), np.uint32(2**32 - 1)):
        check_seed(seed)


@pytest.mark.parametrize("seed", [-1, np.int64(-2), 1.0, "3", True, None])
def test_anything_else_is_named(seed):
    with pytest.raises(ValueError, match="^" + re.escape(f"--seed must be a non-negative integer, got {seed!r}") + "$"):
        check_seed(seed, "--seed")
