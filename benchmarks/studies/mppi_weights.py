"""How selective is MPPI on the benchmark's cost scale? (oracle diagnosis)

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.studies.mppi_weights --task robodesk/push_red \\
        -n 50

At the first planning step of an instance, the simulator oracle predicts N candidate
sequences drawn by the SPEC sampler (correlated noise, σ per env); each cost term is
evaluated on them. Reported per term: the spread of the score over the candidates (std and
max − min) and, for the total score, MPPI's weights ``softmax(γ · score)`` summarised by the
effective sample size ``ESS = 1 / Σ w²`` (N: uniform weights, the plan is the mean of the noise;
1: greedy). With ESS close to N, MPPI makes no progress.
"""

from __future__ import annotations

import numpy as np
import torch

from benchmarks import common
from benchmarks.studies.scripted_plan_rank import first_step_candidates, predict_from_start
from vp2.classifiers.registry import CLASSIFIERS
from vp2.data.suite import TaskSuite
from vp2.planning.agent import frames_to_tensor
from vp2.planning.planner import PlannerConfig, build_cost, planner_settings


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--task", default="robodesk/push_red")
    parser.add_argument("--instance", type=int, default=0)
    parser.add_argument("-n", "--num-samples", type=int, default=50)
    parser.add_argument("--gammas", type=float, nargs="+", default=[0.05, 0.5, 5.0])
    args = parser.parse_args()
    torch.set_num_threads(1)
    inst = TaskSuite.load().get(args.task, args.instance)
    env_name = args.task.split("/")[0]
    settings = planner_settings(args.task, PlannerConfig(num_samples=args.num_samples))
    action_dim = 5 if env_name == "robodesk" else 4
    candidates = first_step_candidates(env_name, action_dim, args.num_samples)
    frames = predict_from_start(inst, candidates)
    goal = frames_to_tensor(inst.goal_image, torch.device("cpu"))
    print(f"{args.task} instance {args.instance}, {args.num_samples} candidates, "
          f"planner {settings}")
    for mode in ("pixel_only", "auto"):
        cost, kind = build_cost(args.task, goal, mode, CLASSIFIERS)
        terms = cost.breakdown(frames)
        for (weight, term), values in zip(cost.terms, terms, strict=True):
            v = values.double().numpy()
            print(f"  [{kind}] {weight:g} x {type(term).__name__}: mean {v.mean():.1f} "
                  f"std {v.std():.1f} range {v.max() - v.min():.1f}")
        score = cost.score(frames).double()
        for gamma in args.gammas:
            w = torch.softmax(gamma * score, dim=0)
            print(f"  [{kind}] gamma {gamma:g}: ESS {float(1 / (w ** 2).sum()):.1f} of "
                  f"{args.num_samples}, max weight {float(w.max()):.3f}")


if __name__ == "__main__":
    np.set_printoptions(precision=3)
    main()
