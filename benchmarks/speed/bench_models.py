"""Forward (``predict``) time of every registered model variant, next to the paper's figures.

    .venv/bin/python -m benchmarks.speed.bench_models          # batch 200, 3 repeats
    .venv/bin/python -m benchmarks.speed.bench_models --batch 50 --repeats 1 \\
        --variants svg_prime:m2k2

One ``predict`` call = 2 context frames + 11 actions -> 10 frames of 64x64 (A = 5), the
planner's call. Each variant is warmed up with a batch of 2, then timed ``--repeats`` times at
``--batch``; the median is reported, and when ``--batch`` is not 200 also its linear
extrapolation to 200 (a lower bound: on a CPU time grows at least linearly). The paper's
figures are median times at batch 200 on one NVIDIA Titan RTX (VP² paper, Table 3).
"""

from __future__ import annotations

import datetime
import os
import statistics
import time

import torch

from benchmarks import common
from vp2.models import VideoPredictor, all_variants, build_model, parse_overrides

#: Paper, Table 3: median forward time (s) at batch 200 on one Titan RTX.
PAPER = {
    ("fitvid", "mini"): 0.29,
    ("fitvid", "small_encoder"): 0.48,
    ("svg_prime", "m0.5k0.5"): 0.52,
    ("svg_prime", "m1k1"): 1.21,
    ("svg_prime", "m2k2"): 3.58,
    # The MCVD paper model (100 sampling steps), VP² paper text: ">10x slower than any other".
    ("mcvd", "default"): 220.0,
}


def time_predict(model: VideoPredictor, batch: int, repeats: int) -> list[float]:
    """Wall-clock seconds of ``repeats`` calls of ``model.predict`` on a batch of ``batch``."""
    device = model.device
    g = torch.Generator().manual_seed(0)
    frames = torch.rand(batch, 2, 3, 64, 64, generator=g).to(device)  # (B, 2, 3, 64, 64)
    actions = (torch.rand(batch, 11, 5, generator=g) * 2 - 1).to(device)  # (B, 11, 5)
    model.predict(frames[:2], actions[:2])  # warm-up: allocator, kernel selection
    times = []
    for _ in range(repeats):
        if device.type == "cuda":
            torch.cuda.synchronize()
        start = time.perf_counter()
        model.predict(frames, actions)
        if device.type == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - start)
    return times


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--batch", type=int, default=200)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument("--device", default=None, help="default: cuda if available, else cpu")
    parser.add_argument(
        "--variants", nargs="*", default=None, help="name:preset (default: all registered)"
    )
    parser.add_argument(
        "--override",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="config override for every variant, e.g. sampling_steps=10 (MCVD) or "
        "decoding_iterations=3 (MaskViT)",
    )
    args = parser.parse_args()
    if args.threads:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device or ("cuda" if torch.cuda.is_available() else "cpu"))
    variants = [tuple(v.split(":")) for v in args.variants] if args.variants else all_variants()
    where = torch.cuda.get_device_name(device) if device.type == "cuda" else common.cpu_name()
    print(
        f"# {datetime.date.today()}  {where}  device={device}  "
        f"threads={torch.get_num_threads()}  cores={os.cpu_count()}  torch {torch.__version__}  "
        f"load={os.getloadavg()[0]:.1f}"
    )
    extrapolate = args.batch != 200
    head = f"| model | preset | params | batch {args.batch} (s) |"
    head += " batch 200 (s, x extrapolated) |" if extrapolate else ""
    head += " paper, Titan RTX, batch 200 (s) |"
    print(head)
    print("|---" * (head.count("|") - 1) + "|")
    for name, preset in variants:
        model = build_model(name, preset, action_dim=5, **parse_overrides(args.override)).to(device)
        params = model.num_parameters()
        times = time_predict(model, args.batch, args.repeats)
        del model
        median = statistics.median(times)
        label = preset + "".join(f" {o}" for o in args.override)
        row = f"| {name} | {label} | {params / 1e6:.2f}M | {median:.2f} |"
        if extrapolate:
            row += f" {median * 200 / args.batch:.1f} |"
        paper = PAPER.get((name, preset))
        row += f" {paper:.2f} |" if paper else " - |"
        print(row, flush=True)


if __name__ == "__main__":
    main()
