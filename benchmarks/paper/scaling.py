"""The paper's scaling experiments (its Figures 4 and 5): control against model size (parameters)
or training data (trajectories), a curve per model family (docs/paper.md).

    python -m benchmarks.paper.scaling --x parameters --out outputs/paper/size \\
        --point svg_prime m0.125 svg_prime:outputs/paper/size/train/m0.125 1.65e6 \\
        --point svg_prime m0.25 svg_prime:outputs/paper/size/train/m0.25 6.1e6 ...
    python -m benchmarks.paper.scaling --x trajectories --out outputs/paper/data \\
        --point svg_prime n100 svg_prime:RUN_100 100 --point svg_prime n1000 svg_prime:RUN_1000 1000

A ``--point FAMILY NAME MODEL X`` is one model (a ``--model`` form) at ``X`` on the curve of
``FAMILY``; each is one resumable ``vp2 run`` under ``OUT/runs/<FAMILY>-<NAME>`` on the tabletop
(the paper's), 3 instances per task and 3 seeds by default. Writes ``OUT/scaling.md`` (success per
task, mean over seeds [min, max]; the curve), ``OUT/scaling.svg`` (mean success over tasks
against X, the seeds' range as bars) and ``OUT/scaling.json``. The paper: no strong trend with
size (6 M to 300 M parameters); gains from hundreds to thousands of trajectories, then a plateau.
"""

from __future__ import annotations

import re
from collections.abc import Sequence

from benchmarks.common import argument_parser, command_line
from benchmarks.paper import study
from benchmarks.paper.study import Column

X_LABELS = {"parameters": "parameters", "trajectories": "training trajectories"}
NAME = re.compile(r"[A-Za-z0-9_.-]+")


def columns(points: Sequence[Sequence[str]]) -> list[Column]:
    """A column per ``(family, name, model, x)``, named ``family-name``."""
    out = []
    for family, name, model, x in points:
        if not (NAME.fullmatch(family) and NAME.fullmatch(name)):
            raise ValueError(f"--point {family} {name}: use letters, digits, '.', '_' and '-' "
                             "in FAMILY and NAME (they name a folder)")
        try:
            value = float(x)
        except ValueError:
            raise ValueError(f"--point {family} {name}: X must be a number, got {x!r}") from None
        out.append(Column(f"{family}-{name}", model, x=value, group=family))
    names = [c.name for c in out]
    if len(set(names)) != len(names):
        raise ValueError(f"--point: each FAMILY NAME once, got {names}")
    return out


def parse_args(argv: Sequence[str] | None = None):
    parser = argument_parser(__spec__.name, __doc__)
    parser.add_argument("--x", choices=sorted(X_LABELS), required=True,
                        help="what the points' X is")
    parser.add_argument("--point", nargs=4, action="append", required=True,
                        metavar=("FAMILY", "NAME", "MODEL", "X"))
    study.add_run_arguments(parser, tasks=["tabletop"])
    args = parser.parse_args(argv)
    study.check_run_arguments(parser, args)
    try:
        args.columns = columns(args.point)
    except ValueError as exc:
        parser.error(str(exc))
    return args


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    points = [f"- `{c.name}`: `{c.model}` at {c.x:g} {args.x}" for c in args.columns]
    study.run_study(args, args.columns, stem="scaling",
                    title=f"Control against {X_LABELS[args.x]}",
                    command=command_line(__spec__.name, argv), notes=points,
                    x_label=X_LABELS[args.x])


if __name__ == "__main__":
    main()
