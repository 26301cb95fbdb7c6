"""``results.md`` of ``benchmarks.comparison.model_comparison``, from the files its stages wrote.

:func:`results_markdown` reads only the comparison's output folder: ``comparison.json`` (the
settings and the command), ``train/<model>.json``, ``conditioning/<family>.json``, ``diagnose/<name>.json``,
``metrics/<name>/metrics.json``, ``runs/<name>/summary.json``, ``study/study.json`` and
``report.png``. So the page can be rebuilt from a copied folder, and no number in it comes
from anywhere else. Its sections are written by
:mod:`benchmarks.comparison.model_comparison_sections`; this module puts them together.
"""

from __future__ import annotations

import datetime
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.comparison.model_comparison_sections import (
    budget_lines,
    conditioning_lines,
    diagnosis_lines,
    metrics_lines,
    study_lines,
    success_lines,
)
from vp2.run.run_dir import REPORT_FILE, RunDir


def _trials_on_disk(run_dir: Path) -> int:
    path = RunDir(run_dir).trials_file
    return len(path.read_text().splitlines()) if path.is_file() else 0


def results_markdown(
    out: Path,
    screenshot_note: str | None,
    pending: Sequence[str] = (),
    image: str = "report.png",
    notes: str | None = None,
    written: str | None = None,
) -> str:
    """The page: budget, success per task, normalised means, action conditioning, metrics,
    the study and the report's screenshot (``screenshot_note``: why there is none; ``image``:
    its link from where the page is written). ``pending``: runs not finished yet (the page
    then says so at the top, and their columns say "pending"). ``notes``: the link, from where
    the page is written, to the Markdown file that reads the numbers; the page gets a
    "Reading" section after the study that points there. ``written``: the time it names
    (default: now), so that two copies of one page agree."""
    s = json.loads((out / "comparison.json").read_text())
    written = written or datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")
    lines = [
        "# Model comparison: five families at one training budget, judged by control",
        "",
        f"Written {written} "
        f"by `python -m benchmarks.comparison.model_comparison` (vp2 {s['vp2_version']}, torch "
        f"{s['torch_version']}); every number below is read from the files under `{out}`"
        f"{records_note(s)}.",
        "",
        "Rebuild (the same command resumes an interrupted build; on a finished folder it only "
        "rewrites the study, the report and this page):",
        "",
        "```bash",
        s["command"],
        "```",
        "",
    ]
    lines += pending_lines(out, pending)
    lines += body_lines(out, s)
    if notes:
        lines += ["", *reading_lines(notes)]
    lines += ["", "## The report", ""]
    if screenshot_note is None:
        lines += [
            f"`{REPORT_FILE}` is the `vp2 report` page of every run above; its top:",
            "",
            f"![vp2 report]({image})",
        ]
    else:
        lines.append(
            f"`{REPORT_FILE}` is the `vp2 report` page of every run above ({screenshot_note})."
        )
    return "\n".join(lines) + "\n"


def pending_lines(out: Path, pending: Sequence[str]) -> list[str]:
    """The "Incomplete" paragraph naming the runs not finished yet (none: no lines)."""
    if not pending:
        return []
    counts = ", ".join(
        f"{name} ({_trials_on_disk(out / 'runs' / name)} trials on disk)" for name in pending
    )
    return [
        f"**Incomplete**: the runs of {counts} are not finished; their columns, the study and "
        "the report leave them out until they are. The command above resumes them.",
        "",
    ]


def body_lines(out: Path, s: dict[str, Any]) -> list[str]:
    """The page's sections from the budget to the study, for the comparison in ``out``."""
    return [
        *budget_lines(out, s),
        *success_lines(out, s),
        *conditioning_lines(out, s),
        *diagnosis_lines(out, s),
        *metrics_lines(out, s),
        *study_lines(out / "study" / "study.json"),
    ]


#: The part headings of a comparison over both environments.
ENV_TITLES = {"robodesk": "RoboDesk", "tabletop": "Tabletop"}


def combined_markdown(
    outs: Sequence[Path], images: dict[Path, str | None], notes: str | None = None
) -> str:
    """The page of a comparison with a part per environment (``outs``: each environment's
    output folder, named after it): the command once, then per environment its sections, a
    level down, and its report's screenshot (``images``: its link from the page, ``None``:
    none). Pending runs are read from the folders (runs without a ``summary.json``)."""
    first = json.loads((outs[0] / "comparison.json").read_text())
    names = [ENV_TITLES.get(o.name, o.name) for o in outs]
    lines = [
        "# Model comparison: the zoo on " + " and ".join(names) + ", judged by control",
        "",
        f"Written {datetime.datetime.now(datetime.timezone.utc).isoformat(timespec='seconds')} "
        f"by `python -m benchmarks.comparison.model_comparison` (vp2 {first['vp2_version']}, "
        f"torch {first['torch_version']}), one part per environment; every number below is read "
        "from the files under the part's folder.",
        "",
        "Rebuild (the same command resumes an interrupted build; on a finished folder it only "
        "rewrites the studies, the reports and this page):",
        "",
        "```bash",
        first["command"],
        "```",
    ]
    for out, name in zip(outs, names, strict=True):
        s = json.loads((out / "comparison.json").read_text())
        pending = [n for n in s["run_names"] if not RunDir(out / "runs" / n).summary_json.is_file()]
        lines += ["", f"## {name}", "",
                  f"Dataset `{s['data']}`, tasks {', '.join(s['tasks'])}; files under `{out}`"
                  f"{records_note(s)}.", ""]
        lines += pending_lines(out, pending)
        lines += [("#" + line) if line.startswith("## ") else line for line in body_lines(out, s)]
        image = images.get(out)
        lines += ["", f"### The report ({name})", ""]
        lines.append(f"![vp2 report, {name}]({image})" if image else
                     f"`{out / REPORT_FILE}` is the `vp2 report` page of this part's runs.")
    if notes:
        lines += ["", *reading_lines(notes)]
    return "\n".join(lines) + "\n"


def records_note(s: dict[str, Any]) -> str:
    """Where the build keeps its evidence (``--records``), as a clause; empty if nowhere."""
    if not s.get("records"):
        return ""
    return (f" (their compact copy, kept in the repository: `{s['records']}`; "
            "`benchmarks/comparison/records.py`)")


def relative_link(target: Path, page: Path) -> str:
    """The Markdown link from ``page`` to ``target`` (both relative to the working directory,
    or both absolute)."""
    return Path(os.path.relpath(target, page.parent)).as_posix()


def reading_lines(notes: str) -> list[str]:
    """The "Reading" section: a pointer to the notes file (``notes``: its link)."""
    return [
        "## Reading",
        "",
        f"What these numbers say is written apart from this generated page: [{notes}]({notes}).",
    ]
