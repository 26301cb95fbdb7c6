"""The HTML report of one or more benchmark runs (``vp2 report``, and every ``vp2 run``).

:func:`write_report` writes one self-contained HTML file: inline CSS, charts as inline SVG
(:mod:`vp2.benchmark.charts`), trial GIFs embedded as ``data:`` URIs, no JavaScript and no
network access. It shows

* the runs: model label (from each run's ``config.yaml``), settings, departures from the SPEC
  protocol;
* success per task as grouped bars, one bar per model, error bars from the lowest to the
  highest control-run (seed) rate (the paper's Figure 3), and the same numbers as a table;
* the oracle-normalised score: by a simulator-oracle run among the inputs, else by the one a
  run names in its ``oracle`` setting, else by the shipped oracle
  (:mod:`vp2.benchmark.shipped_oracle`), with how that was measured;
* the metrics-versus-control study (:mod:`vp2.benchmark.study`) when ``metrics.json`` files
  are given;
* a gallery of trial videos per model and task (execution next to the goal image, and the
  chosen plan's predictions when the run saved them), capped, successes first.

The runner calls it at the end of every run (``report.html`` in the run directory).
"""

from __future__ import annotations

import argparse
import base64
import dataclasses
import datetime
import logging
import math
import os
from collections.abc import Mapping, Sequence
from html import escape
from pathlib import Path
from typing import Any

import yaml

from vp2.benchmark.charts import bar_chart
from vp2.benchmark.results import Summary, is_ok, read_trials, summarize
from vp2.benchmark.shipped_oracle import (
    NO_SHIPPED_ORACLE,
    is_oracle_config,
    load_shipped_oracle,
    summarize_run,
)

log = logging.getLogger(__name__)

#: File name of the report inside a run directory.
REPORT_FILE = "report.html"
#: Trials shown per model and task in the gallery.
DEFAULT_TRIALS_PER_TASK = 3
#: GIF bytes embedded at most (the rest of the gallery is left out, and the page says so).
DEFAULT_MAX_GALLERY_BYTES = 40_000_000

PathLike = str | os.PathLike[str]


@dataclasses.dataclass
class RunView:
    """A run directory as the report sees it.

    Attributes:
        run_dir: The directory.
        label: Model label (unique among the report's runs).
        config: The ``config`` mapping of ``config.yaml`` (empty if the file is missing).
        deviations: Its departures from the SPEC protocol.
        records: Trial records.
        summary: Scores, normalised when an oracle run is known.
        is_oracle: Whether the run is a simulator-oracle run.
        oracle_source: Where the normalisation came from (``None``: not normalised).
    """

    run_dir: Path
    label: str
    config: dict[str, Any]
    deviations: list[str]
    records: list[dict[str, Any]]
    summary: Summary
    is_oracle: bool
    oracle_source: str | None = None


def model_label(config: Mapping[str, Any]) -> str:
    """A run's model as the report names it: the model spec, or the random baseline."""
    if config.get("agent") == "random":
        return "random actions"
    spec = str(config.get("model") or "unknown model")
    args = config.get("model_args") or {}
    if args:
        spec += " (" + ", ".join(f"{k}={v}" for k, v in sorted(args.items())) + ")"
    return spec


def _read_config(run_dir: Path) -> tuple[dict[str, Any], list[str]]:
    path = run_dir / "config.yaml"
    if not path.is_file():
        return {}, []
    data = yaml.safe_load(path.read_text()) or {}
    return dict(data.get("config") or {}), list(data.get("spec_deviations") or [])


def load_runs(
    run_dirs: Sequence[PathLike], labels: Sequence[str | None] | None = None
) -> list[RunView]:
    """Reads the runs, labels them uniquely and normalises their scores.

    ``labels``: one per run directory (``None`` or empty: the model spec, :func:`model_label`).

    An oracle run among ``run_dirs`` normalises every other run; otherwise a run's own
    ``oracle`` setting is used if that directory exists, else the shipped oracle.

    Raises:
        FileNotFoundError: a directory that is not a run (no ``trials.jsonl``).
    """
    if labels is not None and len(labels) != len(run_dirs):
        raise ValueError(
            f"{len(labels)} label(s) for {len(run_dirs)} run director(ies): give one per run "
            "('-' keeps a run's default label)"
        )
    runs = []
    for i, d in enumerate(run_dirs):
        run_dir = Path(d)
        if not (run_dir / "trials.jsonl").is_file():
            raise FileNotFoundError(f"{run_dir}: no trials.jsonl (not a vp2 run directory)")
        config, deviations = _read_config(run_dir)
        records = read_trials(run_dir)
        is_oracle = is_oracle_config(config)
        runs.append(
            RunView(
                run_dir,
                (labels[i] if labels else None) or model_label(config),
                config,
                deviations,
                records,
                summarize(records),
                is_oracle,
            )
        )
    counts: dict[str, int] = {}
    for r in runs:
        counts[r.label] = counts.get(r.label, 0) + 1
    for r in runs:
        if counts[r.label] > 1:
            r.label = f"{r.label} [{r.run_dir.name}]"
    oracle = next((r for r in runs if r.is_oracle), None)
    shipped = None
    if any(not r.is_oracle for r in runs) and oracle is None:
        shipped = load_shipped_oracle()
    for r in runs:
        if r.is_oracle:
            continue
        if oracle is not None:
            r.oracle_source = f"oracle run {oracle.label} ({oracle.run_dir})"
            r.summary = summarize(r.records, oracle.records, oracle_source=r.oracle_source)
        elif r.config.get("oracle") and Path(r.config["oracle"]).exists():
            r.summary = summarize_run(r.records, oracle_run=r.config["oracle"])
            r.oracle_source = r.summary.oracle_source
        else:
            # Without a shipped oracle the section says so once, not every run's notes.
            r.summary = summarize_run(r.records, shipped=shipped, note_missing=False)
            r.oracle_source = r.summary.oracle_source
    return runs


# --------------------------------------------------------------------------- sections


def _pct(value: float | None) -> str:
    return "n/a" if value is None or math.isnan(value) else f"{100 * value:.1f}"


def _nan_to_none(value: float | None) -> float | None:
    return None if value is None or math.isnan(value) else value


def task_order(runs: Sequence[RunView]) -> list[str]:
    """Every task of the runs, in first-seen order."""
    tasks: list[str] = []
    for r in runs:
        for t in r.summary.tasks:
            if t.task not in tasks:
                tasks.append(t.task)
    return tasks


def success_chart(runs: Sequence[RunView]) -> str:
    """Grouped bars: tasks (and all tasks) on x, one bar per model, error bars min..max over
    seeds."""
    tasks = task_order(runs)
    groups = [*tasks, "all tasks"]
    values, low, high = [], [], []
    for r in runs:
        by_task = {t.task: t for t in r.summary.tasks}
        row_v, row_l, row_h = [], [], []
        for task in tasks:
            t = by_task.get(task)
            row_v.append(None if t is None else t.mean)
            row_l.append(None if t is None else t.min)
            row_h.append(None if t is None else t.max)
        row_v.append(_nan_to_none(r.summary.mean))
        row_l.append(_nan_to_none(r.summary.min))
        row_h.append(_nan_to_none(r.summary.max))
        values.append(row_v)
        low.append(row_l)
        high.append(row_h)
    return bar_chart(groups, [r.label for r in runs], values, low, high)


def _success_table(runs: Sequence[RunView]) -> str:
    tasks = task_order(runs)
    head = "".join(f"<th>{escape(r.label)}</th>" for r in runs)
    rows = []
    for task in tasks:
        cells = []
        for r in runs:
            t = next((t for t in r.summary.tasks if t.task == task), None)
            if t is None:
                cells.append('<td class="num">n/a</td>')
                continue
            ratio = "" if t.normalised is None else f" · {t.normalised:.2f}×"
            cells.append(
                f'<td class="num">{_pct(t.mean)} [{_pct(t.min)}, {_pct(t.max)}]'
                f'<span class="sub">{len(t.per_seed)} seeds · {t.num_trials} trials{ratio}</span></td>'
            )
        rows.append(f"<tr><td>{escape(task)}</td>{''.join(cells)}</tr>")
    envs = list(dict.fromkeys(t.split("/")[0] for t in tasks))
    for env in envs:
        cells = "".join(f'<td class="num">{_pct(r.summary.env_means.get(env))}</td>' for r in runs)
        rows.append(f"<tr class=total><td>{escape(env)} (mean of tasks)</td>{cells}</tr>")
    cells = "".join(
        f'<td class="num">{_pct(r.summary.mean)} [{_pct(r.summary.min)}, {_pct(r.summary.max)}]</td>'
        for r in runs
    )
    rows.append(f"<tr class=total><td>all tasks</td>{cells}</tr>")
    return (
        '<table class="success"><thead><tr><th>task</th>'
        f"{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"
        '<p class="sub">success % mean over control runs (seeds) [min, max]; '
        "× = the task's ratio to the oracle's mean</p>"
    )


def _normalised_section(runs: Sequence[RunView]) -> str:
    items = []
    for r in runs:
        s = r.summary
        if r.is_oracle:
            items.append(f"<li><b>{escape(r.label)}</b>: the oracle (1.000 by definition)</li>")
        elif s.normalised is not None:
            items.append(
                f'<li><b>{escape(r.label)}</b>: <span class="score">{s.normalised:.3f}</span> '
                f"[{s.normalised_min:.3f}, {s.normalised_max:.3f}] "
                f"<span class=sub>(oracle: {escape(r.oracle_source or '')})</span></li>"
            )
        elif r.oracle_source:
            items.append(
                f"<li><b>{escape(r.label)}</b>: not available (no task the oracle has for its "
                "instances, see the notes)</li>"
            )
        else:
            items.append(f"<li><b>{escape(r.label)}</b>: not available (no oracle)</li>")
    missing = (
        f"<p class=warn>{escape(NO_SHIPPED_ORACLE)}.</p>"
        if any(not r.is_oracle and r.oracle_source is None for r in runs)
        else ""
    )
    return (
        "<p>Mean success over tasks divided by the simulator oracle's on the same tasks (a "
        "ratio of means), [min, max] over seeds. The oracle: a simulator-oracle run given to "
        "<code>vp2 report</code>, else the run's <code>--oracle RUN_DIR</code>, else the "
        "shipped oracle.</p>"
        f"{missing}<ul>{''.join(items)}</ul>"
    )


def _runs_table(runs: Sequence[RunView]) -> str:
    rows = []
    for r in runs:
        c = r.config
        finished = sum(is_ok(x) for x in r.records)
        errors = len(r.records) - finished
        seeds = sorted({int(x["seed"]) for x in r.records})
        agent = c.get("agent", "?")
        planner = (
            f"{c.get('optimizer', '?')}, {c.get('num_samples') or 'SPEC'} samples, "
            f"{c.get('num_steps', '?')} steps, cost {c.get('cost', '?')}"
            if agent == "planning"
            else f"{c.get('num_steps', '?')} steps"
        )
        deviations = "<br>".join(escape(d) for d in r.deviations) or "none"
        rows.append(
            f"<tr><td><b>{escape(r.label)}</b></td><td><code>{escape(str(r.run_dir))}</code></td>"
            f"<td>{escape(str(agent))}</td><td>{escape(planner)}</td>"
            f'<td class="num">{finished}</td><td class="num">{errors}</td>'
            f"<td>{escape(', '.join(map(str, seeds)))}</td><td>{deviations}</td></tr>"
        )
    return (
        "<table><thead><tr><th>model</th><th>run directory</th><th>agent</th><th>planner</th>"
        "<th>trials</th><th>errors</th><th>seeds</th><th>not the SPEC protocol</th></tr></thead>"
        f"<tbody>{''.join(rows)}</tbody></table>"
    )


def _data_uri(path: Path) -> str:
    return "data:image/gif;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _trial_rank(record: dict[str, Any]) -> tuple[int, float, int, int]:
    scores = record.get("scores") or []
    best = scores[-1] if scores and scores[-1] is not None else -math.inf
    return (0 if record.get("success") else 1, -best, int(record["instance"]), int(record["seed"]))


def _gallery(runs: Sequence[RunView], per_task: int, max_bytes: int) -> tuple[str, int, int]:
    """The gallery HTML, the number of trials shown and of those with a GIF."""
    used = shown = 0
    total_with_gif = 0
    parts = []
    budget_hit = False
    for r in runs:
        parts.append(f"<h3>{escape(r.label)}</h3>")
        by_task: dict[str, list[dict[str, Any]]] = {}
        for rec in r.records:
            if is_ok(rec) and rec.get("gif"):
                by_task.setdefault(rec["task"], []).append(rec)
        if not by_task:
            parts.append("<p class=sub>no trial GIFs in this run (run with GIFs on)</p>")
        for task, records in by_task.items():
            total_with_gif += len(records)
            chosen = sorted(records, key=_trial_rank)[:per_task]
            items = []
            for rec in chosen:
                gif = r.run_dir / rec["gif"]
                plan = r.run_dir / rec["plan_gif"] if rec.get("plan_gif") else None
                if not gif.is_file():
                    continue
                size = gif.stat().st_size + (plan.stat().st_size if plan and plan.is_file() else 0)
                if used + size > max_bytes:
                    budget_hit = True
                    break
                used += size
                shown += 1
                first = rec.get("first_success_step")
                outcome = (
                    f"success (first at step {first})"
                    if rec.get("success")
                    else f"failure after {rec.get('num_steps', '?')} steps"
                )
                caption = f"instance {rec['instance']}, seed {rec['seed']}: {outcome}"
                html = (
                    f'<figure class="trial {"ok" if rec.get("success") else "fail"}">'
                    f'<img class="exec" src="{_data_uri(gif)}" '
                    f'alt="{escape(caption)}: execution | goal">'
                    f"<figcaption>{escape(caption)}<br><span class=sub>execution | goal image"
                    "</span></figcaption>"
                )
                if plan is not None and plan.is_file():
                    html += (
                        f'<img class="plan" src="{_data_uri(plan)}" alt="{escape(caption)}: plan">'
                        "<figcaption class=sub>the chosen plan's 10 predicted frames | goal, "
                        "one frame per planning step</figcaption>"
                    )
                items.append(html + "</figure>")
            parts.append(
                f"<h4>{escape(task)} <span class=sub>showing {len(items)} of {len(records)} "
                "trials: successes first, then by the best planning score</span></h4>"
                f'<div class="gallery">{"".join(items)}</div>'
            )
    if budget_hit:
        parts.append(
            f"<p class=warn>The gallery stopped at {max_bytes / 1e6:.0f} MB of GIFs; the "
            "remaining trials are in each run's gifs/ folder.</p>"
        )
    return "".join(parts), shown, total_with_gif


_CSS = """
body{font-family:system-ui,sans-serif;margin:24px auto;max-width:1400px;padding:0 16px;color:#222}
h1{font-size:1.6em;margin-bottom:0} h2{border-bottom:1px solid #ccc;padding-bottom:4px;margin-top:32px}
table{border-collapse:collapse;margin:8px 0 16px} th,td{border:1px solid #ddd;padding:4px 8px;
vertical-align:top;text-align:left} th{background:#f3f3f3} td.num{text-align:right;white-space:nowrap}
tr.total td{font-weight:bold;background:#fafafa} .sub{color:#777;font-size:.85em;display:block}
h4 .sub{display:inline;font-weight:normal} .score{font-size:1.3em;font-weight:bold}
.gallery{display:flex;flex-wrap:wrap;gap:12px} figure{margin:0;padding:6px;border:1px solid #ddd;
border-radius:4px;max-width:100%} figure.ok{border-color:#2a9d4b} figure.fail{border-color:#c44}
img{image-rendering:pixelated;display:block;max-width:100%} img.plan{margin-top:6px}
.warn{color:#a40} .scatters{display:flex;flex-wrap:wrap;gap:8px} ul.notes{color:#555}
code{background:#f3f3f3;padding:0 3px}
"""


def render_report(
    runs: Sequence[RunView],
    study_html: str | None = None,
    *,
    trials_per_task: int = DEFAULT_TRIALS_PER_TASK,
    max_gallery_bytes: int = DEFAULT_MAX_GALLERY_BYTES,
    title: str | None = None,
) -> str:
    """The report page for loaded runs (``study_html``: the study fragment, if any)."""
    import vp2

    title = title or "vp2 report: " + ", ".join(r.label for r in runs)
    now = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    gallery, shown, total = _gallery(runs, trials_per_task, max_gallery_bytes)
    notes = [(r.label, w) for r in runs for w in r.summary.warnings]
    parts = [
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8>",
        f"<title>{escape(title)}</title><style>{_CSS}</style></head><body>",
        f"<h1>{escape(title)}</h1>",
        f"<p class=sub>written {now} by vp2 {escape(vp2.__version__)}; {len(runs)} run(s)</p>",
        "<h2>Runs</h2>",
        _runs_table(runs),
        "<h2>Success per task</h2>",
        "<p>Bars: mean success over control runs (seeds); error bars: lowest to highest seed.</p>",
        f'<figure class="chart">{success_chart(runs)}</figure>',
        _success_table(runs),
        "<h2>Oracle-normalised score</h2>",
        _normalised_section(runs),
    ]
    if study_html:
        parts += ["<h2>Metrics versus control</h2>", study_html]
    parts += [
        "<h2>Trial videos</h2>",
        f"<p>{shown} of {total} trials with GIFs shown (at most {trials_per_task} per model "
        "and task).</p>",
        gallery,
    ]
    if notes:
        parts.append("<h2>Notes</h2><ul class=notes>")
        parts += [f"<li><b>{escape(label)}</b>: {escape(w)}</li>" for label, w in notes]
        parts.append("</ul>")
    parts.append("</body></html>\n")
    return "".join(parts)


def _metrics_by_run(
    run_dirs: Sequence[PathLike],
    metrics: Sequence[PathLike | Sequence[PathLike] | None] | Mapping[str, Any] | None,
) -> list[Any]:
    if metrics is None:
        return [None] * len(run_dirs)
    if isinstance(metrics, Mapping):
        by_dir = {str(Path(k)): v for k, v in metrics.items()}
        return [by_dir.get(str(Path(d))) for d in run_dirs]
    metrics = list(metrics)
    if len(metrics) != len(run_dirs):
        raise ValueError(
            f"give one metrics file per run directory, in the same order ({len(run_dirs)} runs, "
            f"{len(metrics)} metrics files); use a mapping to give them for some runs only"
        )
    return metrics


def write_report(
    run_dirs: Sequence[PathLike],
    out_path: PathLike,
    metrics: Sequence[PathLike | Sequence[PathLike] | None] | Mapping[str, Any] | None = None,
    *,
    trials_per_task: int = DEFAULT_TRIALS_PER_TASK,
    max_gallery_bytes: int = DEFAULT_MAX_GALLERY_BYTES,
    title: str | None = None,
    labels: Sequence[str | None] | None = None,
) -> Path:
    """Writes the HTML report of ``run_dirs`` to ``out_path`` (atomically); returns it.

    Args:
        run_dirs: Benchmark run directories, one model each (several runs of one model get
            their directory name added to the label). A simulator-oracle run among them
            normalises the others.
        out_path: The HTML file.
        metrics: ``metrics.json`` files (``vp2 metrics``) for the study: one per run in the
            same order (``None`` for a run without; a list for several environments), or a
            mapping run directory -> file(s). The study section appears when any is given.
        trials_per_task: Gallery trials per model and task.
        max_gallery_bytes: Cap on the embedded GIF bytes.
        title: Page title (default: the model labels).
        labels: Model labels, one per run directory (``None``: the model spec).
    """
    from vp2.utils.io import atomic_path

    runs = load_runs(run_dirs, labels)
    study_html = None
    per_run = _metrics_by_run(run_dirs, metrics)
    if any(m for m in per_run):
        from vp2.benchmark.study import load_entry, study

        entries = [
            load_entry(r.label, r.run_dir, m) for r, m in zip(runs, per_run, strict=True) if m
        ]
        study_html = study(entries).to_html()
    html = render_report(
        runs,
        study_html,
        trials_per_task=trials_per_task,
        max_gallery_bytes=max_gallery_bytes,
        title=title,
    )
    out = Path(out_path)
    with atomic_path(out) as tmp:
        tmp.write_text(html, encoding="utf-8")
    return out


# --------------------------------------------------------------------------- vp2 report


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 report`` arguments to ``p`` (a sub-parser) and returns it."""
    p.add_argument("run_dirs", nargs="+", type=Path, metavar="RUN_DIR", help="vp2 run directories")
    p.add_argument(
        "--out",
        type=Path,
        default=Path("report.html"),
        metavar="FILE",
        help="HTML file (default: %(default)s)",
    )
    p.add_argument(
        "--metrics",
        nargs="+",
        metavar="M.json",
        help="vp2 metrics JSON per RUN_DIR, in the same order ('-' for a run without; "
        "several environments: comma-separated); adds the metrics-versus-control study",
    )
    p.add_argument(
        "--trials-per-task",
        type=int,
        default=DEFAULT_TRIALS_PER_TASK,
        help="gallery trials per model and task (default: %(default)s)",
    )
    p.add_argument(
        "--labels",
        nargs="+",
        metavar="LABEL",
        help="model label per RUN_DIR, in the same order ('-' keeps the default: the model spec)",
    )
    p.add_argument("--title", help="page title")
    return p


def run_from_args(args: argparse.Namespace) -> int:
    """Runs ``vp2 report`` from parsed arguments."""
    metrics = None
    if args.metrics:
        metrics = [None if m == "-" else [x for x in m.split(",") if x] for m in args.metrics]
    out = write_report(
        args.run_dirs,
        args.out,
        metrics,
        trials_per_task=args.trials_per_task,
        title=args.title,
        labels=None if args.labels is None else [None if x == "-" else x for x in args.labels],
    )
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB)")
    return 0
