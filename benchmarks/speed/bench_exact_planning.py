"""The CPU-independent planning arithmetic against the float32 arithmetic it replaced, side by
side in one process (interleaved repeats, medians and ratios).

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.speed.bench_exact_planning \\
        [--repeats 7] [--oracle-samples 20]

Rows: the sampler's noise (200 x 10 x 5), MPPI's update (weights and weighted mean, 200), the
pixel SSE on 200 x 10 frames, the shipped push_red classifier on 2,000 frames (float32 forward
against ``exact_logits``), a model-based MPPI step on precomputed frames (sampling, the RoboDesk
cost with the float32 classifier, the update: what a learned model's step adds around its
predictions), and one simulator-oracle planning step on robodesk/push_red. "before" is the
previous arithmetic, patched back in for the measurement (``legacy``): ``torch.randn``,
``linalg.vector_norm``, ``torch.softmax`` and a matrix-vector product, the float32 classifier.
"""

from __future__ import annotations

import contextlib
import os
import platform
import statistics
import time
from collections.abc import Callable, Iterator

import torch

import vp2.planning.agent as agent_mod
import vp2.planning.costs as costs
import vp2.planning.optimizers.mppi as mppi
import vp2.planning.samplers as samplers
from benchmarks.common import argument_parser, suite_planning_step
from vp2.classifiers.checkpoint import load_classifier
from vp2.classifiers.registry import shipped_path
from vp2.models.simulator import SimulatorModel
from vp2.planning import MPPI, robodesk_cost
from vp2.spec import SIGMA


def _old_normal(shape, generator, like):
    return torch.randn(
        tuple(shape), generator=generator, device=generator.device, dtype=like.dtype
    ).to(like.device)


def _old_pixel_sse(frames, goal):
    goal = costs._goal_for(goal, frames)
    block = max(1, costs._CPU_BLOCK_VALUES // frames[0].numel())
    return torch.cat(
        [
            torch.linalg.vector_norm((c - goal).flatten(1), dim=1).square()
            for c in frames.split(block)
        ]
    )


def _old_weights(scores, gamma):
    return torch.softmax(gamma * scores.float(), dim=0)


def _old_mean(weights, samples):
    return (weights.float() @ samples.flatten(1)).view(samples.shape[1:])


@contextlib.contextmanager
def legacy() -> Iterator[None]:
    """The previous arithmetic in place of the CPU-independent one."""
    build = agent_mod.build_cost
    saved = [
        (samplers, "standard_normal", _old_normal),
        (costs, "pixel_sse", _old_pixel_sse),
        (mppi, "mppi_weights", _old_weights),
        (mppi, "weighted_mean", _old_mean),
        (agent_mod, "build_cost", lambda *a, **k: build(*a, **{**k, "exact": False})),
    ]
    old = [(m, n, getattr(m, n)) for m, n, _ in saved]
    for m, n, f in saved:
        setattr(m, n, f)
    try:
        yield
    finally:
        for m, n, f in old:
            setattr(m, n, f)


def _oracle_step(samples: int) -> Callable[[], object]:
    return suite_planning_step("robodesk/push_red", SimulatorModel, samples)


def main() -> None:
    p = argument_parser(__spec__.name, __doc__)
    p.add_argument("--repeats", type=int, default=7)
    p.add_argument("--oracle-samples", type=int, default=20)
    p.add_argument("--oracle-repeats", type=int, default=3)
    p.add_argument(
        "--device",
        default="cpu",
        help="where frames, costs and the classifier "
        "live (the oracle step always runs on the CPU; 0 oracle samples skip it)",
    )
    args = p.parse_args()
    torch.set_num_threads(1)
    dev = torch.device(args.device)
    g = torch.Generator().manual_seed(0)
    n, h, a = 200, 10, 5
    mean = torch.zeros(h, a, device=dev)
    sampler = samplers.CorrelatedNoiseSampler()
    std = samplers.broadcast_std(torch.tensor(SIGMA["robodesk"]), mean)
    frames = ((torch.rand(n, h, 3, 64, 64, generator=g) * 255).round() / 255).to(dev)
    goal = frames[0, 0]
    scores = (-torch.rand(n, generator=g) * 1e3).to(dev)
    acts = torch.rand(n, h, a, generator=g).to(dev)
    clf = load_classifier(shipped_path("push_red"), dev)
    flat = frames.flatten(0, 1)
    cost = robodesk_cost(goal, clf)
    planner = MPPI(SIGMA["robodesk"], num_samples=n)

    def mppi_update() -> object:
        return mppi.weighted_mean(mppi.mppi_weights(scores, 0.05), acts)

    rows: dict[str, Callable[[], object]] = {
        "sampler noise 200x10x5": lambda: sampler.sample(mean, std, n, g),
        "MPPI weights + mean, 200": mppi_update,
        "pixel SSE, 200x10 frames": lambda: costs.pixel_sse(frames, goal),
        "classifier, 2000 frames": lambda: clf(flat),
        "model-based MPPI step (frames precomputed)": lambda: planner.optimize(
            lambda x: cost.score(frames), mean, g
        ),
    }
    exact_clf = {"classifier, 2000 frames": lambda: clf.exact_logits(flat)}
    times: dict[tuple[str, str], list[float]] = {}
    jobs = list(rows.items())
    if args.oracle_samples:
        jobs.append(
            (
                f"oracle planning step, push_red, {args.oracle_samples} samples",
                _oracle_step(args.oracle_samples),
            )
        )
    for name, fn in jobs:
        reps = args.oracle_repeats if name.startswith("oracle") else args.repeats
        fn()  # warm-up (the oracle's env, the classifier's exact copy)
        with legacy():
            fn()
        exact_clf.get(name, fn)()
        for _ in range(reps):
            for label in ("before", "after"):
                ctx = legacy() if label == "before" else contextlib.nullcontext()
                call = exact_clf.get(name, fn) if label == "after" else fn
                with ctx:
                    start = time.perf_counter()
                    call()
                    if dev.type == "cuda":
                        torch.cuda.synchronize(dev)
                    times.setdefault((name, label), []).append(time.perf_counter() - start)
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"torch {torch.__version__}, ATen {torch.backends.cpu.get_cpu_capability()}, "
        f"1 thread, load {os.getloadavg()[0]:.1f}, device {dev}"
        + (f" ({torch.cuda.get_device_name(dev)})" if dev.type == "cuda" else "")
    )
    print("| step | before ms | after ms | after / before |\n|---|---|---|---|")
    for name, _ in jobs:
        b = statistics.median(times[(name, "before")]) * 1e3
        a_ = statistics.median(times[(name, "after")]) * 1e3
        print(f"| {name} | {b:.1f} | {a_:.1f} | {a_ / b:.2f}x |")


if __name__ == "__main__":
    main()
