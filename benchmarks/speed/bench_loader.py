"""Clip loader throughput (clips/s) with 0, 1 and 2 DataLoader workers.

    .venv/bin/python -m benchmarks.speed.bench_loader data/robodesk-20x-64px

Reads shuffled batches of 32 clips (12 frames of 64x64 + 11 actions) for a fixed number of
batches per setting and reports clips/s (the first batch, which pays worker start-up, is
excluded).
"""

from __future__ import annotations

import time

import torch
from torch.utils.data import DataLoader

from benchmarks import common
from vp2.data.loader import ClipDataset


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("dataset")
    parser.add_argument("--batches", type=int, default=60)
    parser.add_argument("--batch-size", type=int, default=32)
    args = parser.parse_args()
    print("| DataLoader workers | frames | clips/s |")
    print("|---|---|---|")
    for uint8 in (False, True):
        ds = ClipDataset(args.dataset, split="train", uint8=uint8)
        for workers in (0, 1, 2):
            loader = DataLoader(
                ds,
                batch_size=args.batch_size,
                shuffle=True,
                num_workers=workers,
                generator=torch.Generator().manual_seed(0),
                persistent_workers=workers > 0,
            )
            it = iter(loader)
            next(it)
            t0 = time.perf_counter()
            n = 0
            for _ in range(args.batches):
                try:
                    batch = next(it)
                except StopIteration:
                    it = iter(loader)
                    batch = next(it)
                n += batch["frames"].shape[0]
            rate = n / (time.perf_counter() - t0)
            print(f"| {workers} | {'uint8' if uint8 else 'float32'} | {rate:.0f} |")


if __name__ == "__main__":
    main()
