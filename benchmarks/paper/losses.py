"""The paper's Table 1: models of one family trained with different losses (MSE,
MSE + LPIPS × 1, MSE + LPIPS × 10) planned on the table's three RoboDesk tasks or the tabletop's
four pushes (``--env``), each column's metrics beside its success (docs/paper.md).

    python -m benchmarks.paper.losses --out outputs/paper/table1 --num-instances 1 \\
        --num-samples 50 --no-gifs
    python -m benchmarks.paper.losses --env tabletop --out outputs/paper/table1-tabletop \\
        --num-instances 1 --num-samples 50 --no-gifs

Columns (``--column LABEL=MODEL``, repeatable; default the environment's six zoo variants of
``benchmarks.paper.train_variants``, :data:`VARIANTS` or :data:`TABLETOP_VARIANTS`), each a
resumable ``vp2 run`` under
``OUT/runs/<label>``. A column's metrics are read from ``OUT/metrics/<label>.json`` (a
``vp2 metrics --out`` result) where it exists. Writes ``OUT/losses.md`` (success per task,
mean over seeds [min, max], then FVD, LPIPS and SSIM per column), ``OUT/losses.svg`` (the bars)
and ``OUT/losses.json``.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path

from benchmarks.common import argument_parser, command_line
from benchmarks.paper import study
from benchmarks.paper.study import Column

#: Table 1's RoboDesk tasks.
TASKS = ("robodesk/push_red", "robodesk/upright_block_off_table", "robodesk/open_slide")
#: Table 1's tabletop row: the four pushes, reported as one mean.
TABLETOP_TASKS = ("tabletop/push_large_cube", "tabletop/push_small_cube", "tabletop/push_cylinder",
                  "tabletop/push_sphere")
#: label -> model: SVG' and FitVid, each with MSE, + LPIPS-VGG x 1 and x 10 (the zoo's entries).
VARIANTS: dict[str, str] = {
    "svg-mse": "zoo:svg_prime-robodesk-mse-s0",
    "svg-lpips1": "zoo:svg_prime-robodesk-lpips1",
    "svg-lpips10": "zoo:svg_prime-robodesk-lpips10",
    "fitvid-mse": "zoo:fitvid-robodesk-mse",
    "fitvid-lpips1": "zoo:fitvid-robodesk-lpips1",
    "fitvid-lpips10": "zoo:fitvid-robodesk-lpips10",
}
#: The same six on the tabletop (trained on its default dataset).
TABLETOP_VARIANTS: dict[str, str] = {
    "svg-mse": "zoo:svg_prime-tabletop-mse",
    "svg-lpips1": "zoo:svg_prime-tabletop-lpips1",
    "svg-lpips10": "zoo:svg_prime-tabletop-lpips10",
    "fitvid-mse": "zoo:fitvid-tabletop-mse",
    "fitvid-lpips1": "zoo:fitvid-tabletop-lpips1",
    "fitvid-lpips10": "zoo:fitvid-tabletop-lpips10",
}
#: env -> (default tasks, default columns)
ENVS: dict[str, tuple[tuple[str, ...], dict[str, str]]] = {
    "robodesk": (TASKS, VARIANTS), "tabletop": (TABLETOP_TASKS, TABLETOP_VARIANTS)}
#: The metrics shown, as ``vp2 metrics`` displays them: key -> column title.
METRICS = {"fvd": "FVD", "lpips_alex_x100": "LPIPS-Alex ×100", "ssim_x100": "SSIM ×100"}


def parse_column(text: str) -> tuple[str, str]:
    """``LABEL=MODEL`` -> ``(label, model)``.

    Raises:
        ValueError: no ``=``, or an empty side.
    """
    label, sep, model = text.partition("=")
    if not sep or not label or not model:
        raise ValueError(f"--column {text!r}: expected LABEL=MODEL, e.g. svg-mse=zoo:NAME")
    return label, model


def metrics_table(out: Path, labels: Sequence[str]) -> list[str]:
    """Markdown: a row per column with its ``OUT/metrics/<label>.json`` display values
    ("not measured" where the file is missing)."""
    lines = ["| column | " + " | ".join(METRICS.values()) + " | clips |",
             "|---" * (len(METRICS) + 2) + "|"]
    for label in labels:
        path = out / "metrics" / f"{label}.json"
        if not path.is_file():
            lines.append(f"| {label} | " + " | ".join(["not measured"] * len(METRICS)) + " | – |")
            continue
        data = json.loads(path.read_text())
        shown = data.get("display", {})
        cells = [f"{shown[k]:.1f}" if k in shown else "–" for k in METRICS]
        lines.append(f"| {label} | " + " | ".join(cells) + f" | {data.get('num_clips', '–')} |")
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    parser = argument_parser(__spec__.name, __doc__)
    parser.add_argument("--env", choices=sorted(ENVS), default="robodesk",
                        help="whose Table 1 half: its default tasks and the zoo's six variants "
                        "trained on it (default: robodesk)")
    parser.add_argument("--column", action="append", default=None, metavar="LABEL=MODEL",
                        help="a model to plan (default: the environment's six zoo variants)")
    study.add_run_arguments(parser, tasks=())
    args = parser.parse_args(argv)
    study.check_run_arguments(parser, args)
    env_tasks, env_variants = ENVS[args.env]
    if not args.tasks:
        args.tasks = list(env_tasks)
    try:
        pairs = ([parse_column(c) for c in args.column] if args.column
                 else list(env_variants.items()))
    except ValueError as exc:
        parser.error(str(exc))
    labels = [label for label, _ in pairs]
    if len(set(labels)) != len(labels):
        parser.error(f"--column: a label given twice ({', '.join(labels)})")
    columns = [Column(label, model) for label, model in pairs]
    notes = ["Metrics on held-out clips (`vp2 metrics`, `OUT/metrics/<column>.json`):", "",
             *metrics_table(Path(args.out), labels), "", "Columns:",
             *[f"- `{c.name}`: `{c.model}`" for c in columns]]
    study.run_study(args, columns, stem="losses",
                    title=f"Table 1 ({args.env}): losses, control and metrics",
                    command=command_line(__spec__.name, argv), notes=notes)


if __name__ == "__main__":
    main()
