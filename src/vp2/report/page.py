"""The HTML report of one or more benchmark runs (``vp2 report``, and every ``vp2 run``).

:func:`write_report` writes one self-contained HTML file: inline CSS, charts as inline SVG
(:mod:`vp2.report.charts`), trial GIFs embedded as ``data:`` URIs, no JavaScript and no
network access. It shows

* the runs: model label (from each run's ``config.yaml``), settings, departures from the SPEC
  protocol;
* success per task as grouped bars, one bar per model, error bars from the lowest to the
  highest control-run (seed) rate (the paper's Figure 3), and the same numbers as a table;
* the oracle-normalised score: by a simulator-oracle run among the inputs, else by the one a
  run names in its ``oracle`` setting, else by the shipped oracle
  (:mod:`vp2.oracle.shipped`), with how that was measured;
* the metrics-versus-control study (:mod:`vp2.report.study`) when ``metrics.json`` files
  are given;
* a gallery of trial videos per model and task (execution next to the goal image, and the
  chosen plan's predictions when the run saved them), capped, successes first.

The runs are read by :mod:`vp2.report.runs`, the sections drawn by :mod:`vp2.report.sections`.
``vp2 run`` and ``vp2 main`` give :func:`write_run_report` to the runner as its ``after_run``
hook: ``report.html`` in every run directory.
"""

from __future__ import annotations

import datetime
import logging
from collections.abc import Mapping, Sequence
from html import escape
from pathlib import Path
from typing import Any

from vp2.report.runs import PathLike, RunView, load_runs
from vp2.report.sections import (
    CSS,
    diagnosis_section,
    gallery,
    normalised_section,
    runs_table,
    success_chart,
    success_table,
)
from vp2.run.run_dir import RunDir
from vp2.utils.io import atomic_path

log = logging.getLogger(__name__)

#: Trials shown per model and task in the gallery.
DEFAULT_TRIALS_PER_TASK = 3
#: GIF bytes embedded at most (the rest of the gallery is left out, and the page says so).
DEFAULT_MAX_GALLERY_BYTES = 40_000_000


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
    gallery_html, shown, total = gallery(runs, trials_per_task, max_gallery_bytes)
    notes = [(r.label, w) for r in runs for w in r.summary.warnings]
    parts = [
        "<!DOCTYPE html><html lang=en><head><meta charset=utf-8>",
        f"<title>{escape(title)}</title><style>{CSS}</style></head><body>",
        f"<h1>{escape(title)}</h1>",
        f"<p class=sub>written {now} by vp2 {escape(vp2.__version__)}; {len(runs)} run(s)</p>",
        "<h2>Runs</h2>",
        runs_table(runs),
        "<h2>Success per task</h2>",
        "<p>Bars: mean success over control runs (seeds); error bars: lowest to highest seed.</p>",
        f'<figure class="chart">{success_chart(runs)}</figure>',
        success_table(runs),
        "<h2>Oracle-normalised score</h2>",
        normalised_section(runs),
        "<h2>Diagnosis</h2>",
        diagnosis_section(runs),
    ]
    if study_html:
        parts += ["<h2>Metrics versus control</h2>", study_html]
    parts += [
        "<h2>Trial videos</h2>",
        f"<p>{shown} of {total} trials with GIFs shown (at most {trials_per_task} per model "
        "and task).</p>",
        gallery_html,
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
    runs = load_runs(run_dirs, labels)
    study_html = None
    per_run = _metrics_by_run(run_dirs, metrics)
    if any(m for m in per_run):
        from vp2.report.study import load_entry, study

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


def write_run_report(run_dir: PathLike) -> None:
    """``report.html`` of one run directory: the runner's ``after_run`` hook of ``vp2 run`` and
    ``vp2 main``. A failure is logged, not raised: the report is a view of the run's results,
    which must never be lost to it."""
    try:
        write_report([run_dir], RunDir(run_dir).report_file)
    except Exception as exc:
        log.warning("could not write the HTML report of %s: %r", run_dir, exc)


# --------------------------------------------------------------------------- vp2 report


