"""Does a model use its actions? Prediction error under true vs shuffled actions, held-out clips.

    .venv/bin/python -m benchmarks.studies.action_conditioning \\
        --model svg_prime:src/vp2/assets/models/svg_prime_tiny_robodesk.pt \\
        --data data/robodesk-20x-64px --clips 128 --samples 3

For a fixed, seeded set of validation clips (2 context + 10 future frames), the model
predicts the 10 frames from the true 11 actions and from the same actions of another clip
(a random derangement of the clips, the context kept). A model that uses its actions has a
lower error under the true ones. Reported: per-frame MSE and the error on the frames that
change (pixels whose true value moves by more than 0.05 between the last context frame and the
target frame; the static background dilutes the plain MSE), each averaged over ``--samples``
sampling seeds, and their ratio shuffled / true.

Whether the difference is more than noise: per clip the MSE under its true and under the
shuffled actions (averaged over the sampling seeds) form a pair. Reported with the ratio: a 95%
bootstrap interval over clips (the clips resampled with replacement, 2,000 times, ratio of the
resampled means), the share of clips whose true-action error is lower, and the two-sided sign
test's p-value on those pairs (exact binomial). A model that ignores its actions has a ratio
whose interval contains 1 and wins about half of the clips.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import torch

from benchmarks import common
from vp2.benchmark.model_spec import resolve_model
from vp2.data.loader import ClipDataset


def held_out_clips(
    data: str | Path, clips: int, seed: int = 0
) -> tuple[torch.Tensor, torch.Tensor]:
    """A seeded sample of up to ``clips`` clips of the dataset's valid split, in index order:
    ``frames`` ``(N, 12, 3, H, W)`` in [0, 1] and ``actions`` ``(N, 11, A)`` float32."""
    dataset = ClipDataset(data, split="valid")
    rng = np.random.default_rng(seed)
    idx = rng.choice(len(dataset), size=min(clips, len(dataset)), replace=False)
    items = [dataset[int(i)] for i in sorted(idx)]
    frames = torch.stack([it["frames"] for it in items])
    return frames, torch.stack([it["actions"] for it in items]).float()


def derangement(n: int, rng: np.random.Generator) -> np.ndarray:
    """A random permutation of ``range(n)`` that moves every element."""
    while True:
        perm = rng.permutation(n)
        if not np.any(perm == np.arange(n)):
            return perm


def evaluate(model, frames: torch.Tensor, actions: torch.Tensor, samples: int) -> dict:
    """Per-clip errors (numpy, averaged over ``samples`` seeds) under true and shuffled actions."""
    context, future = frames[:, :2], frames[:, 2:]
    moving = (future - context[:, -1:]).abs().amax(dim=2, keepdim=True) > 0.05  # (B, 10, 1, H, W)
    perm = torch.from_numpy(derangement(len(frames), np.random.default_rng(0)))
    out = {"true": [], "shuffled": [], "true_moving": [], "shuffled_moving": []}
    mask = moving.float()
    for s in range(samples):
        for name, acts in (("true", actions), ("shuffled", actions[perm])):
            pred = model.predict(context, acts, generator=torch.Generator().manual_seed(s))
            err = (pred - future).square()  # (B, 10, C, H, W)
            out[name].append(err.mean(dim=(1, 2, 3, 4)).numpy())
            moving_err = (err * mask).sum(dim=(1, 2, 3, 4)) / (
                mask.sum(dim=(1, 2, 3, 4)) * err.shape[2]).clamp(min=1)
            out[f"{name}_moving"].append(moving_err.numpy())
    per_clip = {k: np.mean(v, axis=0) for k, v in out.items()}
    per_clip["moving_fraction"] = float(moving.float().mean())
    return per_clip


def ratio_statistics(true: np.ndarray, shuffled: np.ndarray, resamples: int = 2000,
                     seed: int = 0) -> dict:
    """Ratio of mean errors shuffled / true with a bootstrap interval, win share, sign test."""
    n = len(true)
    idx = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
    boot = shuffled[idx].mean(axis=1) / true[idx].mean(axis=1)
    wins = int(np.sum(true < shuffled))
    ties = int(np.sum(true == shuffled))
    m = n - ties
    k = min(wins, m - wins)
    # Two-sided exact sign test: P(X <= k) + P(X >= m - k) for X ~ Binomial(m, 1/2).
    tail = sum(math.comb(m, j) for j in range(k + 1)) / 2.0**m if m else 1.0
    return {
        "ratio": float(shuffled.mean() / true.mean()),
        "ci": (float(np.quantile(boot, 0.025)), float(np.quantile(boot, 0.975))),
        "wins": wins,
        "n": n,
        "sign_p": min(1.0, 2.0 * tail),
    }


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--model", required=True, help="model spec (as vp2 run --model)")
    parser.add_argument("--data", required=True, help="dataset directory")
    parser.add_argument("--clips", type=int, default=128)
    parser.add_argument("--samples", type=int, default=3, help="sampling seeds")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    frames, actions = held_out_clips(args.data, args.clips)
    env = "tabletop" if actions.shape[-1] == 4 else "robodesk"
    model = resolve_model(args.model, {}, env=env, action_dim=actions.shape[-1], device="cpu")
    with torch.no_grad():
        r = evaluate(model, frames, actions, args.samples)
    overall = ratio_statistics(r["true"], r["shuffled"])
    moving = ratio_statistics(r["true_moving"], r["shuffled_moving"])
    print(f"{len(frames)} held-out clips of {args.data}, {args.samples} sampling seeds")
    print("| actions | MSE per pixel | MSE on changing pixels |")
    print("|---|---|---|")
    print(f"| true | {r['true'].mean():.5f} | {r['true_moving'].mean():.5f} |")
    print(f"| shuffled | {r['shuffled'].mean():.5f} | {r['shuffled_moving'].mean():.5f} |")
    print(f"| ratio shuffled / true | {overall['ratio']:.3f} | {moving['ratio']:.3f} |")
    print("| 95% bootstrap interval | {:.3f}-{:.3f} | {:.3f}-{:.3f} |".format(*overall["ci"], *moving["ci"]))
    print(f"| clips where true < shuffled | {overall['wins']}/{overall['n']} | "
          f"{moving['wins']}/{moving['n']} |")
    print(f"| sign test p (two-sided) | {overall['sign_p']:.2g} | {moving['sign_p']:.2g} |")
    print(f"changing pixels: {100 * r['moving_fraction']:.1f}% of all")

if __name__ == "__main__":
    main()
