"""The paper's ensemble experiment (its Figure 6): an ensemble of video prediction models planned
with SPEC §5's cost (a randomly chosen member's cost minus λ · the members' disagreement,
λ = 0.01) against each of its members alone, on the paper's three ensemble tasks (docs/paper.md).

    python -m benchmarks.paper.ensemble --members zoo:svg_prime-robodesk-120min \\
        svg_prime:outputs/paper/train/runs/svg-robodesk-mse-s1 ... --out outputs/paper/ensemble

Columns: ``ensemble`` (``--model 'ensemble(M1,M2,...)'``), then ``member-1`` ... one per member,
each a resumable ``vp2 run`` under ``OUT/runs/<column>`` with the same tasks, instances, seeds and
planner. Writes ``OUT/ensemble.md`` (success per task, mean over seeds [min, max]),
``OUT/ensemble.svg`` (the bars) and ``OUT/ensemble.json``. The paper: the ensemble is better on
the upright block, equal on the green button and slightly worse on the slide.
"""

from __future__ import annotations

from collections.abc import Sequence

from benchmarks.common import argument_parser, command_line
from benchmarks.paper import study
from benchmarks.paper.study import Column

#: The paper's ensemble tasks.
TASKS = ("robodesk/upright_block_off_table", "robodesk/push_green", "robodesk/open_slide")


def columns(members: Sequence[str]) -> list[Column]:
    """``ensemble`` of all ``members``, then each member alone."""
    return [Column("ensemble", f"ensemble({','.join(members)})")] + [
        Column(f"member-{i + 1}", spec) for i, spec in enumerate(members)
    ]


def parse_args(argv: Sequence[str] | None = None):
    parser = argument_parser(__spec__.name, __doc__)
    parser.add_argument("--members", nargs="+", required=True,
                        help="two or more --model forms (zoo names, checkpoints, FAMILY:PATH)")
    study.add_run_arguments(parser, tasks=TASKS)
    args = parser.parse_args(argv)
    study.check_run_arguments(parser, args)
    if len(args.members) < 2:
        parser.error(f"--members: an ensemble needs at least 2, got {len(args.members)}")
    if any("," in m or "(" in m for m in args.members):
        parser.error("--members: give each member as its own argument, not an ensemble(...) form")
    return args


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    members = [f"- `member-{i + 1}`: `{m}`" for i, m in enumerate(args.members)]
    study.run_study(args, columns(args.members), stem="ensemble",
                    title=f"An ensemble of {len(args.members)} against its members",
                    command=command_line(__spec__.name, argv), notes=["Members:", *members])


if __name__ == "__main__":
    main()
