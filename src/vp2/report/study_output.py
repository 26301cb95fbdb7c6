"""``vp2 study``: the metrics-versus-control study of several models, as files.

Writes ``study.md``, ``study.json`` and a scatter plot per metric and scope (SVG) of
:func:`vp2.report.study.study`.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

from vp2.report.charts import svg_file_text
from vp2.report.study import StudyResult
from vp2.utils.io import atomic_path, json_safe, write_json_atomic


def slug(text: str) -> str:
    """A file-name-safe form of a scope or label."""
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-.") or "x"


def write_study(result: StudyResult, out_dir: str | os.PathLike[str]) -> list[Path]:
    """Writes ``study.md``, ``study.json`` and one ``scatter_<metric>_<scope>.svg`` per plot
    into ``out_dir``; returns the files."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    written = [out / "study.md", out / "study.json"]
    with atomic_path(written[0]) as tmp:
        tmp.write_text(result.to_markdown())
    write_json_atomic(written[1], json_safe(result.to_dict()))
    for (metric, scope), svg in result.scatter_svgs().items():
        path = out / f"scatter_{metric}_{slug(scope)}.svg"
        with atomic_path(path) as tmp:
            tmp.write_text(svg_file_text(svg))
        written.append(path)
    return written


