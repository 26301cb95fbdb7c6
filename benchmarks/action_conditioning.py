"""Does a model use its actions? Prediction error under true vs shuffled actions, held-out clips.

    .venv/bin/python benchmarks/action_conditioning.py \
        --model svg_prime:src/vp2/assets/models/svg_prime_tiny_robodesk.pt \
        --data data/robodesk-20x-64px --clips 128 --samples 3

For a fixed, seeded set of validation clips (2 context + 10 future frames), the model
predicts the 10 frames from the true 11 actions and from the same actions of another clip
(a random derangement of the clips, the context kept). A model that uses its actions has a
lower error under the true ones. Reported: per-frame MSE and the error on the frames that
change (pixels whose true value moves by more than 0.05 between the last context frame and the
target frame; the static background dilutes the plain MSE), each averaged over ``--samples``
sampling seeds, and their ratio shuffled / true.
"""

from __future__ import annotations

import argparse

import numpy as np
import torch

from vp2.benchmark.plugins import build_model
from vp2.data.loader import ClipDataset


def _derangement(n: int, rng: np.random.Generator) -> np.ndarray:
    while True:
        perm = rng.permutation(n)
        if not np.any(perm == np.arange(n)):
            return perm


def evaluate(model, frames: torch.Tensor, actions: torch.Tensor, samples: int) -> dict:
    context, future = frames[:, :2], frames[:, 2:]
    moving = (future - context[:, -1:]).abs().amax(dim=2, keepdim=True) > 0.05  # (B, 10, 1, H, W)
    perm = torch.from_numpy(_derangement(len(frames), np.random.default_rng(0)))
    out = {"true": [], "shuffled": [], "true_moving": [], "shuffled_moving": []}
    for s in range(samples):
        for name, acts in (("true", actions), ("shuffled", actions[perm])):
            pred = model.predict(context, acts, generator=torch.Generator().manual_seed(s))
            err = (pred - future).square()
            out[name].append(float(err.mean()))
            mask = moving.expand_as(err)
            out[f"{name}_moving"].append(float(err[mask].mean()))
    return {k: float(np.mean(v)) for k, v in out.items()} | {"moving_fraction": float(moving.float().mean())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", required=True, help="model spec (as vp2 run --model)")
    parser.add_argument("--data", required=True, help="dataset directory")
    parser.add_argument("--clips", type=int, default=128)
    parser.add_argument("--samples", type=int, default=3, help="sampling seeds")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    data = ClipDataset(args.data, split="valid")
    idx = np.random.default_rng(0).choice(len(data), size=min(args.clips, len(data)), replace=False)
    items = [data[int(i)] for i in sorted(idx)]
    frames = torch.stack([it["frames"] for it in items])
    actions = torch.stack([it["actions"] for it in items]).float()
    env = "tabletop" if actions.shape[-1] == 4 else "robodesk"
    model = build_model(args.model, {}, env=env, action_dim=actions.shape[-1], device="cpu")
    with torch.no_grad():
        r = evaluate(model, frames, actions, args.samples)
    print(f"{len(items)} held-out clips of {args.data}, {args.samples} sampling seeds")
    print("| actions | MSE per pixel | MSE on changing pixels |")
    print("|---|---|---|")
    print(f"| true | {r['true']:.5f} | {r['true_moving']:.5f} |")
    print(f"| shuffled | {r['shuffled']:.5f} | {r['shuffled_moving']:.5f} |")
    print(f"| ratio shuffled / true | {r['shuffled'] / r['true']:.3f} | "
          f"{r['shuffled_moving'] / r['true_moving']:.3f} |")
    print(f"changing pixels: {100 * r['moving_fraction']:.1f}% of all")


if __name__ == "__main__":
    main()
