"""Planner overhead and cost evaluation time per planning step.

Measures what planning costs apart from the video prediction model:

* optimizer overhead per planning step (sampling + distribution update), EXCLUDING the
  objective: the optimizer runs on a trivial objective that returns precomputed scores, the
  time of that objective alone is measured separately and subtracted;
* cost evaluation per planning step on 200 x 10 predicted 64x64 RGB frames: the tabletop pixel
  SSE, and the RoboDesk cost 0.5 x SSE + 10 x classifier term with the classifier logits
  precomputed (the classifier network itself is a model cost, not a planner cost).

Usage::

    .venv/bin/python -m benchmarks.speed.bench_planner [--repeats 50] [--threads 2] [--device cpu]

Prints a Markdown table of medians (and quartiles) in milliseconds. Results are recorded in
docs/planning.md.
"""

from __future__ import annotations

import os
import statistics
import time
from collections.abc import Callable

import torch

from benchmarks import common
from vp2.planning import (
    CEM,
    MPPI,
    ClassifierCost,
    Optimizer,
    PixelSSE,
    WeightedCost,
    pixel_sse,
)
from vp2.spec import SIGMA

HORIZON, ACTION_DIM, FRAMES, SIDE = 10, 5, 10, 64


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def time_ms(fn: Callable[[], object], repeats: int, device: torch.device) -> list[float]:
    """Wall time of ``fn`` in milliseconds, ``repeats`` times after 3 warm-up calls."""
    for _ in range(3):
        fn()
    _sync(device)
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        fn()
        _sync(device)
        times.append((time.perf_counter() - start) * 1e3)
    return times


def summary(times: list[float]) -> tuple[float, float, float]:
    """Median, 25th and 75th percentile."""
    q1, med, q3 = statistics.quantiles(times, n=4)
    return med, q1, q3


def bench_optimizer(
    optimizer: Optimizer, num_samples: int, calls_per_step: int, repeats: int, device: torch.device
) -> tuple[list[float], list[float]]:
    """Times of one planning step on a trivial objective, and of the objective calls alone."""
    scores = torch.zeros(num_samples, device=device)
    actions = torch.zeros(num_samples, HORIZON, ACTION_DIM, device=device)
    mean = torch.zeros(HORIZON, ACTION_DIM, device=device)
    generator = torch.Generator().manual_seed(0)

    def objective(candidates: torch.Tensor) -> torch.Tensor:
        return scores  # fixed scores: the objective costs (almost) nothing

    def objective_only() -> None:
        for _ in range(calls_per_step):
            objective(actions)

    def step() -> None:
        optimizer.optimize(objective, mean, generator)

    return time_ms(step, repeats, device), time_ms(objective_only, repeats, device)


def bench_optimizers(
    repeats: int, device: torch.device
) -> list[tuple[str, list[float], list[float]]]:
    """``(name, step times, objective-only times)`` per optimizer configuration."""
    sigma = SIGMA["robodesk"]
    configs = (
        ("MPPI 200 x 10 x 5, 1 iteration", MPPI(sigma, num_samples=200), 200, 1),
        ("MPPI 800 x 10 x 5, 1 iteration", MPPI(sigma, num_samples=800), 800, 1),
        ("CEM 200 x 10 x 5, 3 iterations", CEM(sigma, num_samples=200), 200, 3),
    )
    return [
        (name, *bench_optimizer(optimizer, n, calls, repeats, device))
        for name, optimizer, n, calls in configs
    ]


def bench_costs(repeats: int, device: torch.device) -> list[tuple[str, list[float]]]:
    """``(name, times)`` of the cost evaluations on 200 x 10 frames of 64x64."""
    generator = torch.Generator().manual_seed(0)
    frames = torch.rand(200, FRAMES, 3, SIDE, SIDE, generator=generator).to(device)
    goal = torch.rand(3, SIDE, SIDE, generator=generator).to(device)
    logits = torch.randn(200 * FRAMES, generator=generator).to(device)
    combined = WeightedCost([(0.5, PixelSSE(goal)), (10.0, ClassifierCost(lambda images: logits))])
    return [
        ("pixel SSE (tabletop cost)", time_ms(lambda: pixel_sse(frames, goal), repeats, device)),
        (
            "0.5 SSE + 10 classifier, logits precomputed (RoboDesk)",
            time_ms(lambda: combined.score(frames), repeats, device),
        ),
    ]


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--repeats", type=int, default=50, help="timed repeats (>= 20)")
    parser.add_argument("--threads", type=int, default=None, help="torch intra-op threads")
    parser.add_argument("--device", default="cpu", help="cpu or cuda")
    args = parser.parse_args()
    if args.repeats < 20:
        parser.error("--repeats must be >= 20")
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    device = torch.device(args.device)

    common.print_header(
        __spec__.name,
        f"torch {torch.__version__}, {torch.get_num_threads()} threads, device {device}"
        + (f" ({torch.cuda.get_device_name(device)})" if device.type == "cuda" else ""),
    )
    print(f"repeats: {args.repeats} (median [25%, 75%] and minimum, milliseconds)\n")

    print(
        "| planner step | step incl. trivial objective | objective alone"
        " | overhead, objective excluded | minimum |"
    )
    print("|---|---|---|---|---|")
    for name, step, objective in bench_optimizers(args.repeats, device):
        med, q1, q3 = summary(step)
        print(
            f"| {name} | {med:.3f} [{q1:.3f}, {q3:.3f}] | {summary(objective)[0]:.4f} | "
            f"**{med - summary(objective)[0]:.3f}** | {min(step):.3f} |"
        )

    print("\n| cost evaluation, 200 x 10 frames 64x64 | time | minimum |")
    print("|---|---|---|")
    for name, times in bench_costs(args.repeats, device):
        med, q1, q3 = summary(times)
        print(f"| {name} | **{med:.2f}** [{q1:.2f}, {q3:.2f}] | {min(times):.2f} |")
    print(f"\nload average after: {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
