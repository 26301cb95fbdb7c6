"""FVD of several models with one FrechetVideoDistance (true clips' I3D features remembered)
against one per model, side by side in one process.

    .venv/bin/python -m benchmarks.speed.fvd_reference_cache --data data/robodesk-500x-64px \\
        --clips 32

Scores ``repeat_last_frame`` ``--models`` times each way on the same held-out clips (LPIPS
off) and prints the summed FVD seconds (``seconds["fvd"]`` of ``vp2 metrics``: the I3D on
predicted and true clips), their ratio, and whether the FVD values are identical.
Needs the I3D weights (docs/metrics.md).
"""

from __future__ import annotations

import torch

from benchmarks import common
from vp2.metrics.evaluate import DEFAULT_BATCH_SIZE, evaluate_model
from vp2.metrics.fvd import FrechetVideoDistance


def main() -> None:
    p = common.argument_parser(__spec__.name, __doc__)
    p.add_argument("--data", required=True)
    p.add_argument("--clips", type=int, default=32)
    p.add_argument("--models", type=int, default=3, help="evaluations per way")
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    torch.set_num_threads(args.threads)

    def score(fvd: FrechetVideoDistance) -> tuple[float, float]:
        r = evaluate_model(
            "repeat_last_frame",
            args.data,
            num_clips=args.clips,
            lpips_nets=(),
            device="cpu",
            progress=False,
            fvd_metric=fvd,
        )
        return r["seconds"]["fvd"], r["metrics"]["fvd"]

    shared = FrechetVideoDistance(device="cpu", batch_size=DEFAULT_BATCH_SIZE)
    each, once, values = 0.0, 0.0, set()
    for _ in range(args.models):  # interleaved, so that load changes hit both ways alike
        s, v = score(FrechetVideoDistance(device="cpu", batch_size=DEFAULT_BATCH_SIZE))
        each += s
        values.add(v)
        s, v = score(shared)
        once += s
        values.add(v)
    print(
        f"{args.models} models x {args.clips} clips, {args.threads} thread(s): FVD seconds "
        f"one FVD per model {each:.1f}, one shared {once:.1f}, ratio {each / once:.2f}; "
        f"FVD values identical: {len(values) == 1}"
    )


if __name__ == "__main__":
    main()
