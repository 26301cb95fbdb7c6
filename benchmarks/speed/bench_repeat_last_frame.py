"""A repeat-last-frame planning step with its cost's one-image shortcut on and off, side by side
in one process (interleaved repeats, medians and the ratio).

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.speed.bench_repeat_last_frame \\
        [--repeats 5] [--tasks robodesk/open_slide robodesk/push_red]

The baseline predicts the context's last frame for every sample and step, so the RoboDesk
cost's classifier sees one image N x 10 times (8,000 on the slide and drawer at the SPEC's 800
samples). ``vp2.planning.costs`` classifies it once when every frame is that image ("on");
"off" patches the check out, so every frame goes through the classifier as before. The step is
``PlanningAgent.act`` with the task's SPEC sample count and the shipped classifier, on instance
#0 after one zero action; the chosen actions of both are compared as well.
"""

from __future__ import annotations

import contextlib
import os
import platform
import statistics
import time
from collections.abc import Iterator

import numpy as np
import torch

import vp2.planning.costs as costs
from benchmarks.common import argument_parser, suite_planning_step
from vp2.envs.tasks import get_task
from vp2.models.baselines import RepeatLastFrame


@contextlib.contextmanager
def shortcut(on: bool) -> Iterator[None]:
    original = costs._all_the_same
    if not on:
        costs._all_the_same = lambda x: False
    try:
        yield
    finally:
        costs._all_the_same = original


def _step(task: str):
    samples = get_task(task).num_samples
    step = suite_planning_step(task, RepeatLastFrame, samples)
    return (lambda: np.asarray(step()[0])), samples


def main() -> None:
    parser = argument_parser(__spec__.name, __doc__)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--tasks", nargs="+", default=["robodesk/open_slide", "robodesk/push_red"])
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, torch "
          f"{torch.__version__}, one torch thread, load average {os.getloadavg()[0]:.1f}\n")
    print("| task | samples | off (every frame) ms | on (one image) ms | on / off | same action |")
    print("|---|---|---|---|---|---|")
    for task in args.tasks:
        step, samples = _step(task)
        times: dict[bool, list[float]] = {False: [], True: []}
        actions: dict[bool, np.ndarray] = {}
        for _ in range(args.repeats):
            for on in (False, True):
                with shortcut(on):
                    start = time.perf_counter()
                    actions[on] = step()
                    times[on].append(1000 * (time.perf_counter() - start))
        off, on = statistics.median(times[False]), statistics.median(times[True])
        same = "yes" if np.array_equal(actions[False], actions[True]) else (
            f"no (max diff {np.abs(actions[False] - actions[True]).max():.1e})")
        print(f"| {task} | {samples} | {off:.0f} | {on:.0f} | {on / off:.2f}x | {same} |")


if __name__ == "__main__":
    main()
