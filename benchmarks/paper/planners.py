"""The paper's planner comparison (its appendix): MPPI, CEM, CEM-GD and L-BFGS planning with one
model on the tabletop, L-BFGS at each learning rate the paper swept, and the sampling-based
planners with the simulator oracle as well (docs/paper.md).

    python -m benchmarks.paper.planners --model MODEL --out outputs/paper/planners \\
        [--num-instances 3] [--seeds 0 1 2] [--workers 2]

``MODEL``: a differentiable tabletop model (any ``--model`` form), e.g. a tabletop SVG′.

Every setting is one resumable ``vp2 run`` under ``OUT/runs/<setting>`` (the same command
resumes an interrupted study and only runs what is missing); the table of success per task
(mean over seeds [min, max]) and the mean over tasks, one column per setting, is written to
``OUT/planners.md`` (with its bar chart, ``planners.svg``) and ``OUT/planners.json``. Each
optimizer keeps its own defaults (SPEC §5 and docs/planning.md: CEM's elites, CEM-GD's samples,
refinement and Adam steps, L-BFGS's calls); ``--num-samples`` sets the samples of the
sampling-based ones (SPEC: 200).
"""

from __future__ import annotations

from collections.abc import Sequence

from benchmarks.common import argument_parser, command_line
from benchmarks.paper import study
from benchmarks.paper.study import Column
from vp2.planning.config import PlannerConfig

#: L-BFGS step lengths the paper swept (its appendix).
LBFGS_LRS = (1e-3, 1e-2, 5e-2, 7e-2)
#: The planners that need no gradient, and so also plan with the simulator oracle.
SAMPLING = ("mppi", "cem")


def settings(model: str, lbfgs_lrs: Sequence[float], oracle: bool, grad_steps: int | None = None,
             num_samples_first: int | None = None) -> list[Column]:
    """The study's columns, in order: the model with MPPI, CEM, CEM-GD and L-BFGS at each rate;
    then, with ``oracle``, the simulator with the sampling-based planners. ``grad_steps`` and
    ``num_samples_first`` (CEM-GD's first-step samples) override the optimizers' defaults."""
    out = [Column("mppi", model, PlannerConfig(optimizer="mppi")),
           Column("cem", model, PlannerConfig(optimizer="cem")),
           Column("cem_gd", model, PlannerConfig(optimizer="cem_gd", grad_steps=grad_steps,
                                                 num_samples_first=num_samples_first))]
    out += [Column(f"lbfgs-lr{lr:g}", model,
                   PlannerConfig(optimizer="lbfgs", lr=lr, grad_steps=grad_steps))
            for lr in lbfgs_lrs]
    if oracle:
        out += [Column(f"oracle-{name}", "simulator", PlannerConfig(optimizer=name))
                for name in SAMPLING]
    return out


def parse_args(argv: Sequence[str] | None = None):
    parser = argument_parser(__spec__.name, __doc__)
    parser.add_argument("--model", required=True, help="a differentiable model (--model form)")
    study.add_run_arguments(parser, tasks=["tabletop"])
    parser.add_argument("--lbfgs-lrs", type=float, nargs="+", default=list(LBFGS_LRS))
    parser.add_argument("--grad-steps", type=int, default=None,
                        help="CEM-GD's most gradient steps, L-BFGS's step calls (default: "
                        "each optimizer's, the paper's)")
    parser.add_argument("--num-samples-first", type=int, default=None,
                        help="CEM-GD's samples on a trial's first step (default: its 500)")
    parser.add_argument("--no-oracle", action="store_true",
                        help="leave out the simulator oracle's columns")
    args = parser.parse_args(argv)
    study.check_run_arguments(parser, args)
    if any(lr <= 0 for lr in args.lbfgs_lrs):
        parser.error(f"--lbfgs-lrs must be positive, got {args.lbfgs_lrs}")
    return args


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    columns = settings(args.model, args.lbfgs_lrs, not args.no_oracle, args.grad_steps,
                       args.num_samples_first)
    study.run_study(args, columns, stem="planners", title=f"Planners with `{args.model}`",
                    command=command_line(__spec__.name, argv))


if __name__ == "__main__":
    main()
