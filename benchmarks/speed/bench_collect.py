"""Collection throughput (trajectories/min) with 1 and 2 workers, side by side in one run.

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.speed.bench_collect --env robodesk -n 4

Each configuration collects the same trajectories into a fresh temporary directory; the
runs alternate (1, 2, 1, 2, ...) so machine noise hits both alike. Reported: median
trajectories/min per worker count and the speed-up ratio.
"""

from __future__ import annotations

import platform
import statistics
import tempfile
import time
from pathlib import Path

from benchmarks import common
from vp2.data.collect import CollectionConfig, collect
from vp2.data.policies import stream_names


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--env", default="robodesk", choices=["robodesk", "tabletop"])
    parser.add_argument("-n", type=int, default=4, help="trajectories per stream")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--image-size", type=int, default=64)
    args = parser.parse_args()
    streams = stream_names(args.env)
    config = CollectionConfig(
        env=args.env,
        trajectories_per_stream=args.n,
        streams=streams,
        image_size=args.image_size,
        chunk_size=max(1, args.n * len(streams) // 8),
    )
    rates: dict[int, list[float]] = {1: [], 2: []}
    for _ in range(args.repeats):
        for workers in (1, 2):
            with tempfile.TemporaryDirectory() as tmp:
                t0 = time.perf_counter()
                collect(config, Path(tmp) / "ds", workers=workers, progress=False)
                rates[workers].append(60 * config.total / (time.perf_counter() - t0))
    r1, r2 = statistics.median(rates[1]), statistics.median(rates[2])
    print(
        f"machine: {platform.processor() or platform.machine()}, {args.env}, "
        f"{config.total} trajectories x {args.repeats} repeats, {args.image_size}px"
    )
    print("| workers | trajectories/min (median) | runs |")
    print("|---|---|---|")
    for w, r in ((1, r1), (2, r2)):
        print(f"| {w} | {r:.1f} | {', '.join(f'{x:.1f}' for x in rates[w])} |")
    print(f"speed-up 2 vs 1 workers: {r2 / r1:.2f}x")


if __name__ == "__main__":
    main()
