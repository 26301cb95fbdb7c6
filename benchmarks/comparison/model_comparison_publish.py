"""Stages e. to g. of the model comparison: the study (``vp2 study``), the report (``vp2 report``)
and its screenshot, and ``results.md`` (:mod:`benchmarks.comparison.model_comparison_results`),
of the runs finished so far; and ``--publish-only``, which rebuilds them from what is on disk."""

from __future__ import annotations

import dataclasses
import datetime
import json
import shutil
from pathlib import Path

from benchmarks.comparison import records as evidence
from benchmarks.comparison.model_comparison_results import relative_link, results_markdown
from benchmarks.comparison.model_comparison_settings import Settings, StageLog
from vp2.report.page import write_report
from vp2.report.study import study
from vp2.report.study_output import write_study
from vp2.run.run_dir import REPORT_FILE, RunDir
from vp2.utils.io import atomic_path


def screenshot(html: Path, png: Path, width: int = 1200) -> str | None:
    """A PNG of the report down to its trial videos (headless Chromium over the DevTools pipe
    of ``tests/report/headless.py``); returns why not, or ``None`` when written."""
    try:
        from tests.report.headless import Browser, find_chromium
    except ImportError as exc:
        return f"no screenshot: tests/report/headless.py could not be imported ({exc})"
    executable = find_chromium()
    if executable is None:
        return "no screenshot: Chromium is not on PATH"
    try:
        with Browser(executable, width=width, height=1000) as browser:
            browser.open(html)
            # The page above the gallery: the runs, success chart and table, normalised
            # scores and the study (the GIF gallery below would make it megabytes).
            height = browser.evaluate(
                "(() => { const h = [...document.querySelectorAll('h2')]"
                ".find(e => e.textContent === 'Trial videos');"
                " return h ? h.getBoundingClientRect().top + window.scrollY"
                " : document.body.scrollHeight; })()"
            )
            image = browser.screenshot(
                {"x": 0, "y": 0, "width": width, "height": min(height, 12000)}
            )
    except (OSError, RuntimeError, TimeoutError) as exc:
        return f"no screenshot: Chromium failed ({exc!r})"
    with atomic_path(png) as tmp:
        tmp.write_bytes(image)
    return None


def publish_found(s: Settings) -> Path:
    """``--publish-only``: the study, report and page of the runs finished under ``s.out``
    (those with a ``summary.json``), for the families and extra models the build recorded in
    ``comparison.json``; nothing is trained, measured or planned, and the recorded command
    stays the build's."""
    recorded = s.out / "comparison.json"
    if not recorded.is_file():
        raise ValueError(f"--publish-only: {recorded} does not exist; run the comparison first")
    if s.records is not None:
        evidence.restore(s.records, s.out)
    build = json.loads(recorded.read_text())
    s = dataclasses.replace(
        s,
        families=tuple(build["families"]),
        extras=tuple((k, v) for k, v in build.get("extra_models", {}).items()),
    )
    order = s.run_order()
    run_dirs = {n: s.out / "runs" / n for n in order}
    run_dirs = {n: d for n, d in run_dirs.items() if RunDir(d).summary_json.is_file()}
    if not run_dirs:
        raise ValueError(f"--publish-only: no finished run under {s.out / 'runs'}")
    metrics_files = {n: s.out / "metrics" / n / "metrics.json" for n in s.predictor_names()}
    metrics_files = {n: p for n, p in metrics_files.items() if p.is_file()}
    pending = [n for n in order if n not in run_dirs]
    return publish(s, run_dirs, metrics_files, StageLog(s.out), pending)


def _notes_link(s: Settings, page: Path) -> str | None:
    """The link from ``page`` to the ``--notes`` file, ``None`` without one."""
    return None if s.notes is None else relative_link(s.notes, page)


def publish(
    s: Settings,
    run_dirs: dict[str, Path],
    metrics_files: dict[str, Path],
    stage_log: StageLog,
    pending: list[str],
) -> Path:
    """The study, the report (and its screenshot) and ``results.md`` of the runs finished so
    far (``run_dirs``); ``pending`` names the runs not yet finished. Returns ``results.md``."""
    study_dir = s.out / "study"
    entries = [(n, run_dirs[n], path) for n, path in metrics_files.items() if n in run_dirs]
    if entries:
        write_study(study(entries), study_dir)
        stage_log.add("study", "all", "written", entries=len(entries))
    else:  # runs finished beside a build still measuring metrics (--publish-only meanwhile)
        shutil.rmtree(study_dir, ignore_errors=True)
        stage_log.add("study", "all", "waits", why="no finished run has its metrics yet")
    labels = [n for n in s.table_names() if n in run_dirs]
    report = write_report(
        [run_dirs[n] for n in labels],
        s.out / REPORT_FILE,
        metrics={str(run_dirs[n]): path for n, path in metrics_files.items() if n in run_dirs},
        labels=labels,
        title="vp2 model comparison: " + ", ".join(labels),
    )
    shot_note = screenshot(report, s.out / "report.png")
    stage_log.add("report", "all", "written", screenshot=shot_note or "report.png")
    path = s.out / "results.md"
    written = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    with atomic_path(path) as tmp:
        tmp.write_text(results_markdown(s.out, shot_note, pending, notes=_notes_link(s, path),
                                        written=written))
    if s.docs is not None:  # the published copy, its screenshot beside it
        image = s.docs.with_name(s.docs.stem + "-report.png")
        if shot_note is None:
            with atomic_path(image) as tmp:
                tmp.write_bytes((s.out / "report.png").read_bytes())
        with atomic_path(s.docs) as tmp:
            notes = _notes_link(s, s.docs)
            tmp.write_text(results_markdown(s.out, shot_note, pending, image.name, notes,
                                            written))
    stage_log.add("results", "all", "written", pending=pending)
    return path
