"""Cost of the RoboDesk success classifiers per planning step: ours vs the paper's network.

One MPPI planning step scores 200 samples x 10 predicted frames, so the classifier term of the
RoboDesk cost (SPEC §6) runs the classifier on 2,000 frames of 64x64. This script times that
forward pass (no gradient) for our :class:`SuccessClassifier` and the paper's
:class:`PaperClassifier`, interleaved repeat by repeat in one run so that both see the same
machine load, and reports the medians and their ratio. With ``--metrics`` it also prints the
held-out table of ``metrics.json`` (written by ``vp2 train-classifier``).

Usage::

    .venv/bin/python -m benchmarks.speed.bench_classifiers [--repeats 5] [--threads 2] \\
        [--metrics src/vp2/assets/classifiers/metrics.json]

Results are recorded in docs/measurements.md (Success classifiers).
"""

from __future__ import annotations

import json
import os
import statistics
import time
from pathlib import Path

import torch

from benchmarks import common
from vp2.classifiers import (
    ASSETS_DIR,
    CLASSIFIER_TASKS,
    METRICS_FILE,
    build_classifier,
    load_classifier,
    multiply_adds,
)


def time_forward(model: torch.nn.Module, frames: torch.Tensor, chunk: int | None) -> float:
    """Seconds of one no-grad forward pass over ``frames`` (in chunks of ``chunk``)."""
    start = time.perf_counter()
    with torch.no_grad():
        for part in frames.split(chunk or len(frames)):
            model(part)
    return time.perf_counter() - start


def _fmt(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.1f}"


def print_metrics(path: Path) -> None:
    """The held-out table of a metrics.json: accuracy / precision / recall in %, per arch."""
    metrics = json.loads(path.read_text())
    archs = [a for a in ("ours", "paper") if a in metrics]
    print(f"\nheld-out frames, from {path} (accuracy / precision / recall, %):\n")
    header = " | ".join(
        f"{a} ({metrics[a][next(iter(metrics[a]))]['training']['steps']} steps)" for a in archs
    )
    print(f"| task | held-out frames (positive) | {header} |")
    print("|---|---|" + "---|" * len(archs))
    for task in CLASSIFIER_TASKS:
        name = task.split("/")[1]
        cells = []
        frames = ""
        for arch in archs:
            entry = metrics[arch].get(name)
            if entry is None:
                cells.append("-")
                continue
            m = entry["heldout"]
            frames = f"{m['frames']} ({m['positives']})"
            cells.append(f"{_fmt(m['accuracy'])} / {_fmt(m['precision'])} / {_fmt(m['recall'])}")
        print(f"| {name} | {frames} | " + " | ".join(cells) + " |")


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--repeats", type=int, default=5, help="timed repeats per network")
    parser.add_argument("--frames", type=int, default=2000, help="frames per planning step")
    parser.add_argument("--threads", type=int, default=None, help="torch intra-op threads")
    parser.add_argument(
        "--chunk",
        type=int,
        default=None,
        help="frames per forward call (default: all at once, as ClassifierCost)",
    )
    parser.add_argument(
        "--metrics",
        type=Path,
        default=None,
        help=f"also print this metrics.json (e.g. {ASSETS_DIR / METRICS_FILE})",
    )
    args = parser.parse_args()
    if args.threads is not None:
        torch.set_num_threads(args.threads)

    threads = torch.get_num_threads()
    common.print_header(__spec__.name, f"torch {torch.__version__}, {threads} threads")

    shipped = ASSETS_DIR / "push_red.pt"
    ours = load_classifier(shipped) if shipped.exists() else build_classifier("ours").eval()
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        paper = build_classifier("paper").eval()
    nets = {"ours": ours, "paper": paper}
    frames = torch.rand(args.frames, 3, 64, 64, generator=torch.Generator().manual_seed(0))
    for net in nets.values():  # warm-up
        time_forward(net, frames[:200], args.chunk)
    times: dict[str, list[float]] = {name: [] for name in nets}
    for _ in range(args.repeats):
        for name, net in nets.items():
            times[name].append(time_forward(net, frames, args.chunk))
    ratios = [p / o for p, o in zip(times["paper"], times["ours"], strict=True)]

    print(
        f"\n{args.frames} frames of 64x64 per call ({args.chunk or args.frames} per forward), "
        f"{args.repeats} interleaved repeats, seconds:\n"
    )
    print("| network | multiply-adds per frame | parameters | median | min | max |")
    print("|---|---|---|---|---|---|")
    for name, net in nets.items():
        network = getattr(net, "network", net)
        t = times[name]
        print(
            f"| {name} | {multiply_adds(network) / 1e6:.1f} M | "
            f"{sum(p.numel() for p in network.parameters()):,} | **{statistics.median(t):.3f}** | "
            f"{min(t):.3f} | {max(t):.3f} |"
        )
    print(
        f"\nratio paper / ours: median of per-repeat ratios **{statistics.median(ratios):.1f}x** "
        f"(min {min(ratios):.1f}x, max {max(ratios):.1f}x); ratio of medians "
        f"{statistics.median(times['paper']) / statistics.median(times['ours']):.1f}x"
    )
    print(f"load average after: {os.getloadavg()[0]:.2f}")
    if args.metrics is not None:
        print_metrics(args.metrics)


if __name__ == "__main__":
    main()
