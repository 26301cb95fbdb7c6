"""Is an oracle failure the cost's or the search's? The scripted plan against MPPI's samples.

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.studies.scripted_plan_rank \\
        --tasks robodesk/push_red robodesk/flat_block_off_table --instances 0 1 2 3 4 \\
        -n 50 --classifiers src/vp2/assets/classifiers runs/classifiers-new

Every suite instance stores the scripted actions that reach its goal from its initial state
(at most 12, SPEC §2). At the first planning step the simulator oracle predicts ``n``
candidates drawn by the SPEC sampler (correlated noise, σ per env, seed 0) **and** the scripted
plan (its first 10 actions, padded with zeros). Each is scored by the planning cost (SPEC §6:
0.5 × pixel SSE + the weighted classifier logits) under every ``--classifiers`` directory.

Read per instance:

* the scripted plan's **rank** among the ``n + 1`` (1 = best). Rank 1 with a clear margin:
  the cost points the right way and MPPI's samples do not find that direction (search-bound:
  samples, σ, horizon). A poor rank: the cost prefers something else (cost-bound: the pixel
  term or the classifier);
* the margin of each cost term between the scripted plan and the best sample.

One line per instance and classifier set is printed; ``--json`` also writes them.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import torch

from benchmarks import common
from vp2.classifiers.registry import (
    ASSETS_DIR,
    ClassifierRegistry,
    register_shipped_classifiers,
)
from vp2.data.suite import TaskSuite
from vp2.models.simulator import SimulatorModel
from vp2.planning.agent import frames_to_tensor
from vp2.planning.planner import build_cost
from vp2.planning.samplers import CorrelatedNoiseSampler
from vp2.spec import NUM_FUTURE as HORIZON
from vp2.spec import SIGMA
from vp2.utils.io import write_json_atomic


def scripted_plan(actions: np.ndarray, horizon: int) -> torch.Tensor:
    """The first ``horizon`` scripted actions, zero-padded to ``horizon``."""
    plan = np.zeros((horizon, actions.shape[1]))
    k = min(horizon, len(actions))
    plan[:k] = actions[:k]
    return torch.as_tensor(plan, dtype=torch.float32)


def first_step_candidates(env_name: str, action_dim: int, n: int) -> torch.Tensor:
    """``(n, HORIZON, A)`` float32: the SPEC sampler's draws at a first planning step (seed 0)."""
    return CorrelatedNoiseSampler().sample(
        torch.zeros(HORIZON, action_dim), SIGMA[env_name], n, torch.Generator().manual_seed(0)
    ).float()


def predict_from_start(inst, plans: torch.Tensor) -> torch.Tensor:
    """The simulator oracle's ``(N, HORIZON, 3, 64, 64)`` frames of ``plans`` from the
    instance's initial state (after the zero context action, as at a trial's first plan)."""
    n, _, action_dim = plans.shape
    model = SimulatorModel(action_dim)
    try:
        model.set_simulator_state(inst.env_meta, inst.init_state)
        actions = torch.cat([torch.zeros(n, 1, action_dim), plans], dim=1)
        with torch.no_grad():
            return model.predict(torch.zeros(n, 2, 3, 64, 64), actions)
    finally:
        model.close()


def rank_of_last(scores: np.ndarray) -> int:
    """1-based rank of ``scores[-1]`` among all (higher is better; ties count against it)."""
    return int((scores[:-1] >= scores[-1]).sum()) + 1


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--tasks", nargs="+", default=["robodesk/push_red"])
    parser.add_argument("--instances", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    parser.add_argument("-n", "--num-samples", type=int, default=50)
    parser.add_argument(
        "--classifiers",
        nargs="+",
        default=[str(ASSETS_DIR)],
        help="classifier directories to score with (vp2 train-classifier --out; "
        "default: the shipped ones)",
    )
    parser.add_argument("--json", type=Path, help="also write the rows here")
    args = parser.parse_args()
    torch.set_num_threads(1)
    registries = {}
    for directory in args.classifiers:
        registry = ClassifierRegistry()
        if not register_shipped_classifiers(registry, directory):
            parser.error(f"--classifiers {directory}: no classifier files (<task>.pt) there")
        registries[directory] = registry
    suite = TaskSuite.load()
    rows = []
    for task in args.tasks:
        env_name = task.split("/")[0]
        for index in args.instances:
            inst = suite.get(task, index)
            action_dim = inst.actions.shape[1]
            candidates = first_step_candidates(env_name, action_dim, args.num_samples)
            plans = torch.cat([candidates, scripted_plan(inst.actions, HORIZON)[None]])
            n = len(plans)
            start = time.perf_counter()
            frames = predict_from_start(inst, plans)
            seconds = time.perf_counter() - start
            goal = frames_to_tensor(inst.goal_image, torch.device("cpu"))
            for directory, registry in registries.items():
                cost, kind = build_cost(task, goal, "auto", registry)
                with torch.no_grad():
                    terms = [t.double().numpy() for t in cost.breakdown(frames)]
                    score = cost.score(frames).double().numpy()
                best = int(np.argmax(score[:-1]))
                row = {
                    "task": task,
                    "instance": index,
                    "scripted_actions": len(inst.actions),
                    "classifiers": directory,
                    "cost": kind,
                    "samples": args.num_samples,
                    "rank": rank_of_last(score),
                    "of": n,
                    "score_scripted": float(score[-1]),
                    "score_best_sample": float(score[best]),
                    "terms_scripted": [float(t[-1]) for t in terms],
                    "terms_best_sample": [float(t[best]) for t in terms],
                    # every candidate's terms (the scripted plan last), for re-weighting
                    "terms_all": [[round(float(x), 3) for x in t] for t in terms],
                    "term_names": [f"{w:g} x {type(term).__name__}" for w, term in cost.terms],
                    "predict_seconds": round(seconds, 1),
                }
                rows.append(row)
                margins = ", ".join(
                    f"{name}: {s - b:+.1f}"
                    for name, s, b in zip(
                        row["term_names"],
                        row["terms_scripted"],
                        row["terms_best_sample"],
                        strict=True,
                    )
                )
                print(
                    f"{task}#{index} ({len(inst.actions)} scripted) [{directory}] rank "
                    f"{row['rank']}/{n}, score scripted {score[-1]:.1f} vs best sample "
                    f"{score[best]:.1f} (cost terms, scripted - best: {margins})",
                    flush=True,
                )
    if args.json:
        write_json_atomic(
            args.json, {"command": vars(args) | {"json": str(args.json)}, "rows": rows}
        )


if __name__ == "__main__":
    main()
