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

``--paper-point LABEL X Y`` draws a published number beside the curves (success ``Y`` at ``X``,
e.g. the paper's Table 1 SVG′ on the tabletop, 0.80, at its model's parameters or its 50,000
trajectories); ``--log-x`` spaces decades evenly. ``--replot`` runs nothing: it draws
``OUT/scaling.*`` again from ``OUT/scaling.json`` (the committed evidence is enough) with the
given ``--paper-point`` and ``--log-x``::

    python -m benchmarks.paper.scaling --x parameters --out results/paper/size --replot \
        --log-x --paper-point "paper, M = K = 1" 8.3e7 0.80
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

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


def paper_points(items: Sequence[Sequence[str]] | None) -> dict[str, list[tuple[float, float]]]:
    """``--paper-point LABEL X Y`` items as series: label -> [(x, y)]."""
    out: dict[str, list[tuple[float, float]]] = {}
    for label, x, y in items or ():
        try:
            point = (float(x), float(y))
        except ValueError:
            raise ValueError(f"--paper-point {label}: X and Y must be numbers, got {x!r} "
                             f"{y!r}") from None
        if not 0 <= point[1] <= 1:
            raise ValueError(f"--paper-point {label}: Y is a success fraction in [0, 1], got "
                             f"{y} (write 80% as 0.80)")
        out.setdefault(label, []).append(point)
    return out


def parse_args(argv: Sequence[str] | None = None):
    parser = argument_parser(__spec__.name, __doc__)
    parser.add_argument("--x", choices=sorted(X_LABELS), required=True,
                        help="what the points' X is")
    parser.add_argument("--point", nargs=4, action="append", default=[],
                        metavar=("FAMILY", "NAME", "MODEL", "X"))
    parser.add_argument("--paper-point", nargs=3, action="append", default=[],
                        metavar=("LABEL", "X", "Y"),
                        help="a published success fraction Y at X, drawn beside the curves")
    parser.add_argument("--log-x", action="store_true", help="a logarithmic x axis")
    parser.add_argument("--replot", action="store_true",
                        help="run nothing: draw OUT/scaling.* again from OUT/scaling.json")
    study.add_run_arguments(parser, tasks=["tabletop"])
    args = parser.parse_args(argv)
    study.check_run_arguments(parser, args)
    try:
        args.paper = paper_points(args.paper_point)
        args.columns = columns(args.point)
    except ValueError as exc:
        parser.error(str(exc))
    if args.replot and args.point:
        parser.error("--replot draws the points of OUT/scaling.json; leave out --point")
    if not args.replot and not args.point:
        parser.error("give at least one --point FAMILY NAME MODEL X (or --replot)")
    return args


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    title = f"Control against {X_LABELS[args.x]}"
    paper = [f"- {label}: {', '.join(f'{y:.0%} at {x:g}' for x, y in pts)} (published)"
             for label, pts in args.paper.items()]
    out = Path(args.out)
    if args.replot:
        record = out / "scaling.json"
        if not record.is_file():
            raise SystemExit(f"--replot: no {record}; run the study first (without --replot)")
        command, cols, found = study.read_published(record)
    else:
        command, cols = command_line(__spec__.name, argv), args.columns
        study.run_columns(args, cols)
        found = study.summaries(out, cols)
    points = [f"- `{c.name}`: `{c.model}` at {c.x:g} {args.x}" for c in cols]
    study.publish(out, cols, found, stem="scaling", title=title, command=command,
                  notes=points + paper, x_label=X_LABELS[args.x], extra=args.paper,
                  x_log=args.log_x)


if __name__ == "__main__":
    main()
