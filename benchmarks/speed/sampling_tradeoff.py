"""Speed against quality: MCVD sampling steps and MaskViT decoding iterations.

    OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.speed.sampling_tradeoff \\
        --model mcvd:runs/zoo2/mcvd_tiny --values 2 5 10 25 50 100 --clips 48
    OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.speed.sampling_tradeoff \\
        --model maskvit:runs/zoo2/maskvit_tiny --values 1 2 3 5 8 12 --clips 48

One trained checkpoint, one fixed, seeded set of held-out clips (2 context + 10 future frames,
the same clips for every value), one sampling seed. For each value of the inference setting
(``sampling_steps`` for MCVD, ``decoding_iterations`` for MaskViT; ``--field`` for others) the
model predicts the 10 frames; reported: MSE, PSNR, SSIM (×100) against the true frames, the
MSE on the pixels that change (true value moves by > 0.05 from the last context frame: the
static background dilutes the plain MSE) and the prediction time per clip. The values run
interleaved with the timing repeated ``--repeats`` times (median), so machine noise hits all.
"""

from __future__ import annotations

import platform
import statistics
import time

import torch

from benchmarks import common
from vp2.diagnose.measures import held_out_clips
from vp2.metrics.image import psnr, ssim
from vp2.run.model_spec import resolve_model

FIELDS = {"mcvd": "sampling_steps", "maskvit": "decoding_iterations"}


def quality(pred: torch.Tensor, true: torch.Tensor, last_context: torch.Tensor) -> dict:
    err = (pred - true).square()
    moving = ((true - last_context).abs().amax(dim=2, keepdim=True) > 0.05).expand_as(err)
    flat_p, flat_t = pred.flatten(0, 1), true.flatten(0, 1)
    return {
        "mse": float(err.mean()),
        "moving_mse": float(err[moving].mean()) if moving.any() else float("nan"),
        "psnr": float(psnr(flat_p, flat_t).mean()),
        "ssim": 100 * float(ssim(flat_p, flat_t).mean()),
    }


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--model", required=True, help="NAME:CHECKPOINT (a training run dir)")
    parser.add_argument("--values", type=int, nargs="+", required=True)
    parser.add_argument("--field", help="config field to vary (default: by model name)")
    parser.add_argument("--data", default="data/robodesk-20x-64px")
    parser.add_argument("--clips", type=int, default=48)
    parser.add_argument("--batch-size", type=int, default=16)
    parser.add_argument("--repeats", type=int, default=1, help="timing repeats (median)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    name = args.model.partition(":")[0]
    field = args.field or FIELDS.get(name)
    if field is None:
        parser.error(f"--field is required for {name!r} (known: {FIELDS})")

    frames, actions = held_out_clips(args.data, args.clips, args.seed, context=2, future=10)
    env = "tabletop" if actions.shape[-1] == 4 else "robodesk"

    def predict(value: int) -> tuple[torch.Tensor, float]:
        # The checkpoint loaded with an inference override, as `vp2 run --model-arg` does.
        model = resolve_model(
            args.model, {field: value}, env=env, action_dim=actions.shape[-1], device="cpu"
        )
        outs, t0 = [], time.perf_counter()
        with torch.no_grad():
            for b in range(0, len(frames), args.batch_size):
                sl = slice(b, b + args.batch_size)
                gen = torch.Generator().manual_seed(args.seed + b)
                outs.append(model.predict(frames[sl, :2], actions[sl], generator=gen))
        return torch.cat(outs), (time.perf_counter() - t0) / len(frames)

    times: dict[int, list[float]] = {v: [] for v in args.values}
    results: dict[int, dict] = {}
    for _ in range(args.repeats):
        for v in args.values:
            pred, per_clip = predict(v)
            times[v].append(per_clip)
            results[v] = quality(pred, frames[:, 2:], frames[:, 1:2])

    print(
        f"{args.model}: {len(frames)} held-out clips of {args.data} (seed {args.seed}), "
        f"{platform.machine()} CPU, {args.threads} thread(s)"
    )
    print(f"| {field} | s per clip | MSE | MSE, changing pixels | PSNR | SSIM ×100 |")
    print("|---|---|---|---|---|---|")
    for v in args.values:
        r = results[v]
        print(
            f"| {v} | {statistics.median(times[v]):.3f} | {r['mse']:.5f} | "
            f"{r['moving_mse']:.5f} | {r['psnr']:.2f} | {r['ssim']:.1f} |"
        )


if __name__ == "__main__":
    main()
