"""MCVD's forward time with the SPADE modulation computed once per window vs once per step.

    .venv/bin/python -m benchmarks.speed.mcvd_conditioning_reuse --preset tiny --batch 50 \\
        --repeats 3

The conditioning map (context frames and the window's actions) is the same at every denoising
step of a window, so ``UNet.reusing_conditioning`` computes each SPADE norm's scale and shift
once per window. This script times ``predict`` both ways, interleaved in one process (the
"per step" side swaps the context manager for a no-op), checks that the frames are identical,
and prints a markdown row per preset with the ratio.
"""

from __future__ import annotations

import contextlib
import platform
import time

import torch

from benchmarks import common
from vp2.models.mcvd import MCVD, UNet
from vp2.models.registry import build_model

REUSE = UNet.reusing_conditioning


def timed(
    model: MCVD, context: torch.Tensor, actions: torch.Tensor, per_step: bool
) -> tuple[float, torch.Tensor]:
    """Seconds of one ``predict`` and its frames; ``per_step`` recomputes the modulation at
    every denoising step (the context manager swapped for a no-op)."""
    UNet.reusing_conditioning = (  # type: ignore[method-assign]
        (lambda self: contextlib.nullcontext()) if per_step else REUSE
    )
    try:
        start = time.perf_counter()
        out = model.predict(context, actions, generator=torch.Generator().manual_seed(1))
        return time.perf_counter() - start, out
    finally:
        UNet.reusing_conditioning = REUSE  # type: ignore[method-assign]


def main() -> None:
    p = common.argument_parser(__spec__.name, __doc__)
    p.add_argument("--preset", nargs="+", default=["tiny"])
    p.add_argument("--batch", type=int, default=50, help="candidates per predict call")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--sampling-steps", type=int, help="default: the preset's")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    print(
        f"# {time.strftime('%Y-%m-%d %H:%M')}  {platform.processor() or platform.machine()}  "
        f"threads={args.threads}  batch={args.batch}  torch {torch.__version__}"
    )
    print(
        "| preset | sampling steps | per step (s, median) | once per window (s, median) "
        "| speed-up | identical frames |"
    )
    print("|---|---|---|---|---|---|")
    for preset in args.preset:
        overrides = {} if args.sampling_steps is None else {"sampling_steps": args.sampling_steps}
        model = build_model("mcvd", preset, num_context=2, num_future=10, action_dim=5,
                            image_size=64, **overrides).eval()  # fmt: skip
        gen = torch.Generator().manual_seed(0)
        context = torch.rand(args.batch, 2, 3, 64, 64, generator=gen)
        actions = torch.rand(args.batch, 11, 5, generator=gen) * 2 - 1

        timed(model, context, actions, False)  # warm-up
        per_step, once, same = [], [], True
        for _ in range(args.repeats):
            t0, y0 = timed(model, context, actions, True)
            t1, y1 = timed(model, context, actions, False)
            per_step.append(t0)
            once.append(t1)
            same &= torch.equal(y0, y1)
        a, b = sorted(per_step)[len(per_step) // 2], sorted(once)[len(once) // 2]
        print(
            f"| {preset} | {model.config.sampling_steps} | {a:.2f} | {b:.2f} | "
            f"{a / b:.2f}x | {same} |"
        )


if __name__ == "__main__":
    main()
