"""What the paper's analyses share: a set of columns (a model planned with some planner), each one
resumable ``vp2 run`` under ``OUT/runs/<column>``, read back as success per task (mean over
seeds [min, max]), and drawn as grouped bars or as a curve over a numeric x (parameters,
trajectories). Used by ``benchmarks.paper.planners``, ``.ensemble`` and ``.scaling``.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from vp2.benchmark.runner import run_benchmark
from vp2.planning.config import PlannerConfig
from vp2.report.charts import bar_chart, line_chart, svg_file_text
from vp2.run.config import RunConfig
from vp2.run.run_dir import RunDir
from vp2.utils.io import atomic_path, write_json_atomic


@dataclasses.dataclass(frozen=True)
class Column:
    """One column of a study: a model (a ``--model`` form) planned with ``planner``; ``x`` places
    it on a curve (e.g. its parameters), ``group`` names the curve."""

    name: str
    model: str
    planner: PlannerConfig = dataclasses.field(default_factory=PlannerConfig)
    x: float | None = None
    group: str = ""


def add_run_arguments(parser: argparse.ArgumentParser, tasks: Sequence[str]) -> None:
    """The ``vp2 run`` settings every study shares."""
    parser.add_argument("--out", required=True)
    parser.add_argument("--tasks", nargs="+", default=list(tasks))
    parser.add_argument("--suite", default=None, help="a task suite file (default: the shipped)")
    parser.add_argument("--num-instances", type=int, default=3)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--num-samples", type=int, default=None,
                        help="planner samples (default: the SPEC's 200, 800 on slide and drawer)")
    parser.add_argument("--num-steps", type=int, default=15)
    parser.add_argument("--only", nargs="+", default=None, help="run only these columns")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--device", default=None)
    parser.add_argument("--stop-on-success", action="store_true",
                        help="end each trial at its first success (success is at any step, so "
                        "outcomes are unchanged; a study's simulator columns take far less time)")
    parser.add_argument("--no-gifs", action="store_true")
    parser.add_argument("--no-progress", action="store_true")


def check_run_arguments(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    if args.num_instances < 1 or not args.seeds or args.num_steps < 1:
        parser.error("--num-instances, --seeds and --num-steps need at least one each")


def run_config(args: argparse.Namespace, column: Column) -> RunConfig:
    planner = column.planner
    if args.num_samples is not None and planner.num_samples is None:
        planner = dataclasses.replace(planner, num_samples=args.num_samples)
    return RunConfig(
        model=column.model, out=str(Path(args.out) / "runs" / column.name), suite=args.suite,
        tasks=tuple(args.tasks), num_instances=args.num_instances, seeds=tuple(args.seeds),
        planner=planner, num_steps=args.num_steps, workers=args.workers, resume=True,
        stop_on_success=args.stop_on_success,
        save_gifs=not args.no_gifs, progress=not args.no_progress, device=args.device,
    )


def run_columns(args: argparse.Namespace, columns: Sequence[Column]) -> None:
    """Runs (or resumes) every column, or those of ``args.only``."""
    names = [c.name for c in columns]
    unknown = sorted(set(args.only or ()) - set(names))
    if unknown:
        raise SystemExit(f"--only: no column {', '.join(unknown)}; the columns are "
                         f"{', '.join(names)}")
    for column in columns:
        if args.only and column.name not in args.only:
            continue
        print(f"[{column.name}] {column.model}, {column.planner.optimizer}", flush=True)
        run_benchmark(run_config(args, column))


def summaries(out: Path, columns: Sequence[Column]) -> dict[str, dict[str, Any] | None]:
    """Each column's run summary (``None`` while its run has not finished one)."""
    found = {}
    for c in columns:
        path = RunDir(Path(out) / "runs" / c.name).summary_json
        found[c.name] = json.loads(path.read_text()) if path.is_file() else None
    return found


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.0f}"


def _task_row(summary: Mapping[str, Any] | None, task: str) -> dict[str, Any] | None:
    return next((r for r in (summary or {}).get("tasks", []) if r["task"] == task), None)


def tasks_of(found: Mapping[str, Mapping[str, Any] | None]) -> list[str]:
    tasks: list[str] = []
    for summary in found.values():
        for row in (summary or {}).get("tasks", []):
            if row["task"] not in tasks:
                tasks.append(row["task"])
    return tasks


def success_table(columns: Sequence[Column], found: Mapping[str, Any]) -> list[str]:
    """Markdown: a row per task and the mean over tasks, a column per study column; a cell is
    success % mean over seeds [min, max] (trials), "pending" before the run has a summary."""
    lines = ["| task | " + " | ".join(c.name for c in columns) + " |",
             "|---" * (len(columns) + 1) + "|"]
    for task in tasks_of(found):
        cells = []
        for c in columns:
            row = _task_row(found[c.name], task)
            cells.append("pending" if found[c.name] is None else "–" if row is None else
                         f"{_pct(row['mean'])} [{_pct(row['min'])}, {_pct(row['max'])}] "
                         f"({row['num_trials']})")
        lines.append(f"| {task} | " + " | ".join(cells) + " |")
    means = [found[c.name] or {} for c in columns]
    lines.append("| **mean over tasks** | " + " | ".join(
        f"**{_pct(m.get('mean'))}** [{_pct(m.get('min'))}, {_pct(m.get('max'))}]" for m in means
    ) + " |")
    return lines


def success_bars(columns: Sequence[Column], found: Mapping[str, Any]) -> str:
    """Grouped bars: a group per task (and the mean), a bar per column, seeds' min-max bars."""
    tasks = tasks_of(found)
    values, low, high = [], [], []
    for c in columns:
        rows = [_task_row(found[c.name], t) for t in tasks] + [found[c.name]]
        values.append([None if r is None else r["mean"] for r in rows])
        low.append([None if r is None else r["min"] for r in rows])
        high.append([None if r is None else r["max"] for r in rows])
    groups = [t.split("/")[-1] for t in tasks] + ["mean"]
    return bar_chart(groups, [c.name for c in columns], values, low, high)


def success_curve(columns: Sequence[Column], found: Mapping[str, Any], x_label: str,
                  extra: Mapping[str, Sequence[tuple[float, float]]] | None = None,
                  x_log: bool = False) -> str:
    """Mean success over tasks against each column's ``x``, a line per ``group``; the interval
    is the seeds' min to max. ``extra``: more series as ``(x, success)`` points without an
    interval (e.g. the paper's published numbers); ``x_log``: a logarithmic x axis."""
    series: dict[str, list[tuple[float, float, float, float]]] = {}
    for c in columns:
        summary = found[c.name]
        if summary is None or c.x is None or summary.get("mean") is None:
            continue
        series.setdefault(c.group or "success", []).append(
            (float(c.x), summary["mean"], summary["min"], summary["max"]))
    for label, points in (extra or {}).items():
        series[label] = [(float(x), float(y), float(y), float(y)) for x, y in points]
    return line_chart({k: sorted(v) for k, v in series.items()}, x_label=x_label,
                      y_label="success (mean over tasks)", x_log=x_log)


def run_study(args: argparse.Namespace, columns: Sequence[Column], *, stem: str, title: str,
              command: str, notes: Sequence[str] = (), x_label: str | None = None,
              extra: Mapping[str, Sequence[tuple[float, float]]] | None = None,
              x_log: bool = False) -> None:
    """Runs (or resumes) the columns, then publishes what their runs summarise
    (:func:`publish`)."""
    out = Path(args.out)
    run_columns(args, columns)
    publish(out, columns, summaries(out, columns), stem=stem, title=title, command=command,
            notes=notes, x_label=x_label, extra=extra, x_log=x_log)


def publish(out: Path, columns: Sequence[Column], found: Mapping[str, Any], *, stem: str,
            title: str, command: str, notes: Sequence[str] = (), x_label: str | None = None,
            extra: Mapping[str, Sequence[tuple[float, float]]] | None = None,
            x_log: bool = False) -> None:
    """Writes ``OUT/<stem>.md`` (title, command, the table, ``notes``, the picture),
    ``OUT/<stem>.svg`` (bars per task; with ``x_label``, the curve over the columns' ``x``,
    with the ``extra`` series) and ``OUT/<stem>.json`` (the columns with their summaries, and
    ``extra``), each atomically, and prints the table."""
    out = Path(out)
    lines = success_table(columns, found)
    svg = (success_bars(columns, found) if x_label is None
           else success_curve(columns, found, x_label, extra, x_log))
    with atomic_path(out / f"{stem}.svg") as tmp:
        tmp.write_text(svg_file_text(svg))
    page = [f"# {title}", "", f"Command: `{command}`", "",
            "Cell: success % mean over seeds [min, max] (trials).", "", *lines, "",
            *([*notes, ""] if notes else []), f"![{title}]({stem}.svg)", ""]
    with atomic_path(out / f"{stem}.md") as tmp:
        tmp.write_text("\n".join(page))
    record: dict[str, Any] = {"command": command, "columns": [
        {**dataclasses.asdict(c), "planner": dataclasses.asdict(c.planner),
         "summary": found[c.name]} for c in columns]}
    if extra:
        record["extra"] = {k: [list(p) for p in v] for k, v in extra.items()}
    write_json_atomic(out / f"{stem}.json", record)
    print("\n".join(lines))


def read_published(path: Path) -> tuple[str, list[Column], dict[str, Any]]:
    """A study's ``<stem>.json`` back as its command, columns and their summaries (to publish
    it again without its runs, e.g. on a machine that has only the committed evidence)."""
    record = json.loads(Path(path).read_text())
    columns, found = [], {}
    for entry in record["columns"]:
        fields = {k: v for k, v in entry.items() if k != "summary"}
        fields["planner"] = PlannerConfig(**fields["planner"])
        column = Column(**fields)
        columns.append(column)
        found[column.name] = entry["summary"]
    return record["command"], columns, found
