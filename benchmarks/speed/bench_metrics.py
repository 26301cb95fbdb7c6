"""Throughput of the perceptual metrics on this machine: FVD (I3D) and LPIPS, in clips/s.

    .venv/bin/python -m benchmarks.speed.bench_metrics --clips 16 --batch-size 8 --repeats 3

A clip is what ``vp2 metrics`` scores per held-out clip: 10 predicted and 10 true 64x64
frames. FVD per clip = the I3D logits of both 10-frame videos (resized to 224x224); the
final Fréchet distance of 1,000 x 400 features is timed separately (it runs once per
evaluation). LPIPS per clip = 10 frame pairs. MSE/PSNR/SSIM are timed for comparison.

The networks have the real architectures (I3D Inception-v1 with 400 logits, AlexNet / VGG16
trunks) but random weights: speed does not depend on the values, and the weight files are
not needed. ``--i3d-weights FILE`` loads the real I3D instead.
"""

from __future__ import annotations

import json
import platform
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from benchmarks import common
from vp2.metrics import (
    BACKBONES,
    I3D,
    LPIPS,
    FrechetVideoDistance,
    alexnet_features,
    fvd_from_features,
    mse,
    psnr,
    random_i3d,
    ssim,
    vgg16_features,
)


def _random_lpips(net: str, directory: Path) -> LPIPS:
    spec = BACKBONES[net]
    trunk, _ = alexnet_features() if net == "alex" else vgg16_features()
    torch.save(
        {f"features.{k}": v for k, v in trunk.state_dict().items()}, directory / spec.trunk_file
    )
    linear = {f"lin{k}.model.1.weight": torch.rand(1, c, 1, 1) for k, c in enumerate(spec.channels)}
    torch.save(linear, directory / spec.linear_file)
    return LPIPS(net, weights_dir=directory)


def _time(fn, repeats: int) -> list[float]:
    fn()  # warm-up (allocator, oneDNN primitive caches)
    out = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        out.append(time.perf_counter() - t)
    return out


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--clips", type=int, default=16, help="clips per timed run")
    parser.add_argument(
        "--batch-size", type=int, default=8, help="videos per I3D pass, clips per LPIPS pass"
    )
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--size", type=int, default=64, help="frame side of the clips")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--i3d-weights", type=Path, help="real I3D weights (default: random)")
    parser.add_argument("--fd-samples", type=int, default=1000, help="clips in the Fréchet timing")
    parser.add_argument("--out", type=Path, help="also write the numbers as JSON")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    gen = torch.Generator().manual_seed(0)
    pred = torch.rand(args.clips, 10, 3, args.size, args.size, generator=gen)
    true = torch.rand(args.clips, 10, 3, args.size, args.size, generator=gen)
    n = args.clips
    results: dict[str, dict] = {}

    def report(name: str, seconds: list[float], unit_count: int) -> None:
        med = statistics.median(seconds)
        results[name] = {
            "clips_per_s": unit_count / med,
            "s_per_clip": med / unit_count,
            "runs_s": [round(s, 3) for s in seconds],
        }
        print(
            f"{name:12s} {unit_count / med:8.2f} clips/s  ({med / unit_count * 1000:8.1f} ms/clip)"
        )

    with torch.no_grad():
        report(
            "mse+psnr+ssim",
            _time(lambda: (mse(pred, true), psnr(pred, true), ssim(pred, true)), args.repeats),
            n,
        )
        with tempfile.TemporaryDirectory() as tmp:
            for net in ("alex", "vgg"):
                lpips = _random_lpips(net, Path(tmp))

                def run_lpips(lpips=lpips) -> None:
                    for i in range(0, n, args.batch_size):
                        lpips(pred[i : i + args.batch_size], true[i : i + args.batch_size])

                report(f"lpips_{net}", _time(run_lpips, args.repeats), n)

        i3d = I3D.from_file(args.i3d_weights) if args.i3d_weights else random_i3d(0)
        fvd = FrechetVideoDistance(i3d, device="cpu", batch_size=args.batch_size)
        report(
            "fvd (i3d)", _time(lambda: (fvd.features(pred), fvd.features(true)), args.repeats), n
        )

    rng = np.random.default_rng(0)
    f1, f2 = rng.normal(size=(args.fd_samples, 400)), rng.normal(size=(args.fd_samples, 400))
    fd = _time(lambda: fvd_from_features(f1, f2), args.repeats)
    results["frechet_distance"] = {"seconds": statistics.median(fd), "samples": args.fd_samples}
    print(f"Fréchet distance of {args.fd_samples} x 400 features: {statistics.median(fd):.3f} s")

    info = {
        "machine": f"{platform.machine()}, {torch.get_num_threads()} torch thread(s)",
        "torch": torch.__version__,
        "clips": n,
        "batch_size": args.batch_size,
        "frame_size": args.size,
        "weights": "real I3D" if args.i3d_weights else "random (real architectures)",
    }
    print(json.dumps(info))
    if args.out:
        args.out.write_text(json.dumps({"info": info, "results": results}, indent=2) + "\n")


if __name__ == "__main__":
    main()
