"""Which clips a training step sees, and with which seeds.

Every source of randomness of a run is either restored from its checkpoint (the
posterior-noise generator) or a pure function of ``(seed, step)``: the data order
(:class:`StepBatchSampler`) and the validation noise. That is what makes a resumed run
bit-identical to an uninterrupted one without saving any sampler state.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Any

import numpy as np
import torch
from torch import Tensor
from torch.utils.data import DataLoader, Sampler

from vp2.data.loader import ClipDataset
from vp2.utils.tensors import images_to_float

log = logging.getLogger(__name__)


def seed_torch(seed: int) -> None:
    """Seeds torch's global generators (CPU and every CUDA device).

    vp2 code never draws from them (weights are initialised in a forked RNG, noise comes from
    explicit generators); this covers third-party operations that do. Called by
    :func:`~vp2.training.train`.
    """
    torch.manual_seed(seed)


def child_seed(seed: int, *keys: int) -> int:
    """A seed derived from ``seed`` and ``keys``, one key tuple per use: ``(0,)`` the model's
    weights, ``(2, i)`` validation batch ``i``'s noise, ``(3,)`` the training noise, ``(4,)`` the
    data order (whose sampler derives ``(1, epoch)`` from it)."""
    # 63 bits: torch.Generator.manual_seed takes any int, but keep it a positive int64.
    return int(np.random.SeedSequence([seed, *keys]).generate_state(1, np.uint64)[0]) >> 1


class StepBatchSampler(Sampler[list[int]]):
    """Batch indices for steps ``start .. stop - 1``, a pure function of ``(seed, step)``.

    Each epoch is a fresh permutation (seeded by ``seed`` and the epoch number) cut into
    ``len(dataset) // batch_size`` full batches, so a resumed run draws exactly the batches the
    uninterrupted run would have, without saving any sampler state.
    """

    def __init__(self, num_items: int, batch_size: int, seed: int, start: int, stop: int):
        if num_items < batch_size:
            raise ValueError(f"dataset has {num_items} clips, fewer than batch_size={batch_size}")
        self.num_items, self.batch_size, self.seed = num_items, batch_size, seed
        self.start, self.stop = start, stop
        self.per_epoch = num_items // batch_size

    def __len__(self) -> int:
        return max(0, self.stop - self.start)

    def __iter__(self) -> Iterator[list[int]]:
        epoch, perm = -1, None
        for step in range(self.start, self.stop):
            e, i = divmod(step, self.per_epoch)
            if e != epoch:
                g = torch.Generator().manual_seed(child_seed(self.seed, 1, e))
                epoch, perm = e, torch.randperm(self.num_items, generator=g)
            yield perm[i * self.batch_size : (i + 1) * self.batch_size].tolist()


def validation_batches(dataset: ClipDataset, count: int, batch_size: int) -> list[dict[str, Any]]:
    """``count`` batches of clips spread evenly over the validation set (fixed across steps);
    all its clips, with a warning, where it has fewer."""
    if count * batch_size > len(dataset):
        log.warning("--eval-batches %d x --batch-size %d: the validation split has %d clips; "
                    "validating on those %d", count, batch_size, len(dataset), len(dataset))
    n = min(len(dataset), count * batch_size)
    idx = np.linspace(0, len(dataset) - 1, n).round().astype(int)
    loader = DataLoader(torch.utils.data.Subset(dataset, idx.tolist()), batch_size=batch_size)
    return list(loader)


def batch_to_device(
    batch: dict[str, Tensor], device: torch.device, non_blocking: bool = False
) -> tuple[Tensor, Tensor]:
    """A loader batch as the model takes it: ``frames (B, T, 3, H, W)`` float in [0, 1] and
    ``actions (B, T - 1, A)`` float, on ``device``."""
    # Clips travel as uint8 (4x less to copy) and become [0, 1] floats on the device. Made
    # contiguous because ClipDataset's frames are a permuted (channels-last) view when loaded
    # in-process but contiguous when they come from a worker, and convolutions pick different
    # kernels (different rounding) for the two layouts: results must not depend on `workers`.
    frames = images_to_float(batch["frames"].to(device, non_blocking=non_blocking).contiguous())
    actions = batch["actions"].to(device, non_blocking=non_blocking).float()
    return frames, actions
