"""The report: views of finished benchmark runs (the last stage, after :mod:`vp2.benchmark`).

=================  ===========================================================================
page.py            write_report: one self-contained HTML page of runs; ``vp2 report``;
                   write_run_report, the runner's hook that writes ``report.html`` per run
runs.py            the runs a report shows: labelled, normalised by an oracle
sections.py        the page's charts, tables and gallery of trial videos
charts.py          grouped bars and scatter plots as inline SVG, no JavaScript
study.py           metrics versus control: the paper's Table 1 over several models
correlation.py     Spearman's ρ and Kendall's τ-b with p-values
study_output.py    the study as Markdown, JSON and SVG files
=================  ===========================================================================

Nothing here runs trials: the benchmark writes the run directories, and ``vp2 run`` / ``vp2
main`` hand :func:`write_run_report` to the runner. The study itself is
:func:`vp2.report.study.study` (not exported here: the name is its module's). See
``docs/report.md``.
"""

from vp2.report.page import render_report, write_report, write_run_report
from vp2.report.runs import RunView, load_runs
from vp2.report.study import StudyResult, load_entry
from vp2.report.study_output import write_study
from vp2.run.run_dir import REPORT_FILE

__all__ = [
    "REPORT_FILE",
    "RunView",
    "StudyResult",
    "load_entry",
    "load_runs",
    "render_report",
    "write_report",
    "write_run_report",
    "write_study",
]
