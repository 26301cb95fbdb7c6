"""The metrics-versus-control study: do perceptual metrics rank models as control does?

Input: several evaluated models, each an *entry* ``(label, run_dir, metrics_json)``: a
benchmark run directory (``vp2 run``, its ``trials.jsonl``) and the ``metrics.json`` that
``vp2 metrics`` wrote for the same model (one per environment; an entry may list several).

Output (:class:`StudyResult`):

* the table of the paper's Table 1 per scope (each task, each environment's mean over its
  tasks when the study spans several environments, and all tasks): per model FVD,
  LPIPS-Alex ×100, SSIM ×100 and success (mean over seeds with min and max);
* per scope and metric, the rank correlation between the metric and success across models:
  Spearman's ρ (average ranks for ties) and Kendall's τ-b (tie-corrected), with p-values, from
  ``scipy.stats``. With fewer than 3 models, or a metric or success that is the same for every
  model, a rank correlation says nothing: the value is ``None`` and the note says why;
* a scatter plot (inline SVG) per metric and environment-level scope.

A metric of the environment of each task is used for that task (``metrics.json`` records its
``env``); the "all tasks" scope uses an entry's metric only if the entry has exactly one
metrics file, since FVDs of different environments do not average into anything meaningful.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections.abc import Iterable, Sequence
from html import escape
from pathlib import Path
from typing import Any

from vp2.report.charts import scatter_plot
from vp2.report.correlation import Correlation, rank_correlation
from vp2.run.results import is_ok, summarize
from vp2.run.run_dir import RunDir
from vp2.utils.io import json_safe

#: Scope of all tasks of the study.
ALL_TASKS = "all tasks"
#: Key of metrics that apply to every environment (a ``metrics.json`` without ``env``).
ANY_ENV = "*"


@dataclasses.dataclass(frozen=True)
class StudyMetric:
    """A column of the study.

    Attributes:
        key: Short name (``fvd``, ``lpips``, ``ssim``).
        label: Column title.
        source: Key in ``metrics.json``'s ``metrics`` (raw values).
        scale: Displayed value = raw value × scale (the paper's ×100 for LPIPS and SSIM).
        lower_is_better: Whether a better model has a lower value; then a metric that agrees
            with control correlates *negatively* with success.
    """

    key: str
    label: str
    source: str
    scale: float
    lower_is_better: bool

    @property
    def expected_sign(self) -> str:
        return "−" if self.lower_is_better else "+"


STUDY_METRICS: tuple[StudyMetric, ...] = (
    StudyMetric("fvd", "FVD", "fvd", 1.0, True),
    StudyMetric("lpips", "LPIPS ×100", "lpips_alex", 100.0, True),
    StudyMetric("ssim", "SSIM ×100", "ssim", 100.0, False),
)


@dataclasses.dataclass
class StudyEntry:
    """One evaluated model.

    Attributes:
        label: Name in the tables and plots.
        run_dir: Its benchmark run directory.
        records: The run's trial records.
        metrics: Environment (or :data:`ANY_ENV`) -> raw metric values of that ``metrics.json``.
        metrics_files: The files read.
        outside: The note on trials in the run directory that its config does not cover,
            which are not counted (:meth:`~vp2.run.run_dir.RunDir.split_trials`).
    """

    label: str
    run_dir: Path
    records: list[dict[str, Any]]
    metrics: dict[str, dict[str, float]]
    metrics_files: list[Path]
    outside: str | None = None

    def metric(self, source: str, env: str | None) -> float | None:
        """The raw value of ``source`` for environment ``env`` (``None``: all tasks)."""
        if env is None:
            if len(self.metrics) != 1:
                return None
            (values,) = self.metrics.values()
        else:
            values = self.metrics.get(env, self.metrics.get(ANY_ENV, {}))
        value = values.get(source)
        return float(value) if value is not None and math.isfinite(value) else None


def load_entry(
    label: str,
    run_dir: str | os.PathLike[str],
    metrics_json: str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
) -> StudyEntry:
    """Reads an entry's trial records and metrics file(s).

    Raises:
        FileNotFoundError: a run directory without ``trials.jsonl`` or a missing metrics file.
        ValueError: two metrics files of the same environment.
    """
    run = RunDir(run_dir)
    run.check_is_run()
    files = [metrics_json] if isinstance(metrics_json, (str, os.PathLike)) else metrics_json
    metrics: dict[str, dict[str, float]] = {}
    paths = []
    for file in files:
        path = Path(file)
        if path.is_dir():
            path = path / "metrics.json"
        data = json.loads(path.read_text())
        env = data.get("env") or ANY_ENV
        if env in metrics:
            raise ValueError(f"entry {label!r}: two metrics files for environment {env!r}")
        metrics[env] = {k: v for k, v in data.get("metrics", {}).items() if v is not None}
        paths.append(path)
    records, note = run.counted_trials()
    return StudyEntry(label, run.path, records, metrics, paths, note)


# --------------------------------------------------------------------------- the study


@dataclasses.dataclass
class StudyRow:
    """One model in one scope: its metrics (displayed scale) and success."""

    label: str
    metrics: dict[str, float | None]
    success: float | None
    success_min: float | None
    success_max: float | None
    num_trials: int


@dataclasses.dataclass
class StudyResult:
    """What :func:`study` returns.

    Attributes:
        labels: The models, in entry order.
        scopes: Tasks (first-seen order), then environment means (when several
            environments), then :data:`ALL_TASKS`.
        rows: Scope -> one :class:`StudyRow` per model.
        correlations: One per scope and metric.
        notes: Things a reader must know (missing metrics, tasks some models lack).
    """

    labels: list[str]
    scopes: list[str]
    rows: dict[str, list[StudyRow]]
    correlations: list[Correlation]
    notes: list[str]

    def correlation(self, scope: str, metric: str) -> Correlation:
        """The correlation of ``metric`` in ``scope``."""
        for c in self.correlations:
            if c.scope == scope and c.metric == metric:
                return c
        raise KeyError((scope, metric))

    @property
    def plot_scopes(self) -> list[str]:
        """Scopes that get scatter plots: environment means and all tasks."""
        return [s for s in self.scopes if s == ALL_TASKS or s.endswith(_ENV_SUFFIX)]

    def scatter_svgs(self) -> dict[tuple[str, str], str]:
        """``(metric key, scope) -> <svg>``: each model's metric against its success."""
        out = {}
        for scope in self.plot_scopes:
            for m in STUDY_METRICS:
                points = [
                    (r.label, r.metrics[m.key], r.success)
                    for r in self.rows[scope]
                    if r.metrics[m.key] is not None and r.success is not None
                ]
                if not points:
                    continue
                c = self.correlation(scope, m.key)
                out[(m.key, scope)] = scatter_plot(
                    points,  # type: ignore[arg-type]
                    x_label=f"{m.label} ({'lower' if m.lower_is_better else 'higher'} is better)",
                    title=f"{scope}: {m.label} vs success, {_corr_text(c)}",
                )
        return out

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def to_markdown(self) -> str:
        """The tables and correlations as Markdown."""
        lines = ["# Metrics versus control", ""]
        for scope in self.scopes:
            lines += [f"## {scope}", "", _MD_HEAD, _MD_RULE]
            lines += [_md_row(r) for r in self.rows[scope]]
            lines.append("")
        lines += [
            "## Rank correlation with success (across models)",
            "",
            "A metric that ranks models as control does correlates positively with success if "
            "higher is better (SSIM) and negatively if lower is better (FVD, LPIPS).",
            "",
            "| scope | metric | models | Spearman ρ (p) | Kendall τ-b (p) | agreeing sign | note |",
            "|---|---|---|---|---|---|---|",
        ]
        lines += ["| " + " | ".join(_correlation_cells(c)) + " |" for c in self.correlations]
        if self.notes:
            lines += ["", "Notes:"] + [f"- {n}" for n in self.notes]
        return "\n".join(lines) + "\n"

    def to_html(self) -> str:
        """The tables, correlations and scatter plots as an HTML fragment (for the report)."""
        parts = []
        for scope in self.scopes:
            parts.append(f'<h3>{escape(scope)}</h3><div class="wide"><table><thead><tr><th>model</th>')
            parts += [
                f"<th>{escape(m.label)} {'↓' if m.lower_is_better else '↑'}</th>"
                for m in STUDY_METRICS
            ]
            parts.append("<th>success % mean [min, max]</th><th>trials</th></tr></thead><tbody>")
            for r in self.rows[scope]:
                cells = "".join(
                    f'<td class="num">{_num(r.metrics[m.key])}</td>' for m in STUDY_METRICS
                )
                parts.append(
                    f"<tr><td>{escape(r.label)}</td>{cells}"
                    f'<td class="num">{_success(r)}</td><td class="num">{r.num_trials}</td></tr>'
                )
            parts.append("</tbody></table></div>")
        parts.append(
            "<h3>Rank correlation with success (across models)</h3><p>A metric that ranks "
            "models as control does correlates positively with success where higher is better "
            "(SSIM) and negatively where lower is better (FVD, LPIPS).</p>"
            '<div class="wide"><table><thead><tr><th>scope</th><th>metric</th><th>models</th>'
            "<th>Spearman ρ (p)</th><th>Kendall τ-b (p)</th><th>agreeing sign</th>"
            "<th>note</th></tr></thead><tbody>"
        )
        for c in self.correlations:
            cells = zip(_CORRELATION_TD, _correlation_cells(c), strict=True)
            parts.append("<tr>" + "".join(f"<td{td}>{escape(x)}</td>" for td, x in cells) + "</tr>")
        parts.append("</tbody></table></div>")
        svgs = self.scatter_svgs()
        if svgs:
            parts.append('<div class="scatters">')
            parts += [f'<figure class="scatter">{svg}</figure>' for svg in svgs.values()]
            parts.append("</div>")
        if self.notes:
            parts.append("<ul class=notes>")
            parts += [f"<li>{escape(n)}</li>" for n in self.notes]
            parts.append("</ul>")
        return "".join(parts)


_ENV_SUFFIX = " (mean of tasks)"
_MD_HEAD = (
    "| model | "
    + " | ".join(f"{m.label} {'↓' if m.lower_is_better else '↑'}" for m in STUDY_METRICS)
    + " | success % mean [min, max] | trials |"
)
_MD_RULE = "|---" * (len(STUDY_METRICS) + 3) + "|"


def _num(value: float | None) -> str:
    if value is None:
        return "n/a"
    return f"{value:.1f}" if abs(value) >= 10 else f"{value:.2f}"


def _pct(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.1f}"


def _success(r: StudyRow) -> str:
    if r.success is None:
        return "n/a"
    return f"{_pct(r.success)} [{_pct(r.success_min)}, {_pct(r.success_max)}]"


def _rp(value: float | None, p: float | None) -> str:
    if value is None:
        return "undefined"
    return f"{value:+.3f} ({p:.2g})" if p is not None and math.isfinite(p) else f"{value:+.3f}"


#: Attributes of the correlation table's cells (numbers right-aligned).
_CORRELATION_TD = ("", "", ' class="num"', ' class="num"', ' class="num"', "", "")


def _correlation_cells(c: Correlation) -> tuple[str, ...]:
    """A row of the correlation table: scope, metric, models, Spearman ρ (p), Kendall τ-b (p),
    the sign of a metric that agrees with control, note."""
    metric = next(m for m in STUDY_METRICS if m.key == c.metric)
    return (c.scope, metric.label, str(c.n), _rp(c.spearman, c.spearman_p),
            _rp(c.kendall, c.kendall_p), metric.expected_sign, c.note)


def _corr_text(c: Correlation) -> str:
    if c.spearman is None:
        return f"ρ undefined ({c.note})"
    return f"ρ = {c.spearman:+.2f}, τ = {c.kendall:+.2f}, n = {c.n}"


def _md_row(r: StudyRow) -> str:
    cells = " | ".join(_num(r.metrics[m.key]) for m in STUDY_METRICS)
    return f"| {r.label} | {cells} | {_success(r)} | {r.num_trials} |"


def _row(entry: StudyEntry, records: list[dict[str, Any]], env: str | None) -> StudyRow:
    finished = [r for r in records if is_ok(r)]
    metrics = {}
    for m in STUDY_METRICS:
        raw = entry.metric(m.source, env)
        metrics[m.key] = None if raw is None else raw * m.scale
    if not finished:
        return StudyRow(entry.label, metrics, None, None, None, 0)
    s = summarize(records)
    return StudyRow(
        entry.label,
        metrics,
        json_safe(s.mean),
        json_safe(s.min),
        json_safe(s.max),
        len(finished),
    )


def study(
    entries: Iterable[
        StudyEntry
        | tuple[
            str,
            str | os.PathLike[str],
            str | os.PathLike[str] | Sequence[str | os.PathLike[str]],
        ]
    ],
) -> StudyResult:
    """Tables and rank correlations of metrics versus control success.

    Args:
        entries: :class:`StudyEntry` objects or ``(label, run_dir, metrics_json)`` tuples
            (``metrics_json``: a file, a directory holding ``metrics.json``, or a list of
            them, one per environment).

    Returns:
        The :class:`StudyResult`.

    Raises:
        ValueError: no entries, or two entries with the same label.
    """
    loaded = [e if isinstance(e, StudyEntry) else load_entry(*e) for e in entries]
    if not loaded:
        raise ValueError("the study needs at least one entry")
    labels = [e.label for e in loaded]
    if len(set(labels)) != len(labels):
        raise ValueError(f"entry labels must be distinct, got {labels}")
    tasks: list[str] = []
    for e in loaded:
        for r in e.records:
            if r["task"] not in tasks:
                tasks.append(r["task"])
    envs = list(dict.fromkeys(t.split("/")[0] for t in tasks))
    notes = []
    scopes: list[tuple[str, list[str], str | None]] = [(t, [t], t.split("/")[0]) for t in tasks]
    if len(envs) > 1:
        scopes += [
            (f"{env}{_ENV_SUFFIX}", [t for t in tasks if t.startswith(env + "/")], env)
            for env in envs
        ]
    scopes.append((ALL_TASKS, tasks, envs[0] if len(envs) == 1 else None))

    rows: dict[str, list[StudyRow]] = {}
    correlations = []
    for scope, scope_tasks, env in scopes:
        rows[scope] = [
            _row(e, [r for r in e.records if r["task"] in scope_tasks], env) for e in loaded
        ]
        for m in STUDY_METRICS:
            pairs = [
                (r.metrics[m.key], r.success)
                for r in rows[scope]
                if r.metrics[m.key] is not None and r.success is not None
            ]
            rho, rho_p, tau, tau_p, note = rank_correlation(
                [p[0] for p in pairs],
                [p[1] for p in pairs],  # type: ignore[misc]
            )
            correlations.append(Correlation(scope, m.key, len(pairs), rho, rho_p, tau, tau_p, note))
    for e in loaded:
        if e.outside:
            notes.append(f"{e.label}: {e.outside}")
        missing = [t for t in tasks if not any(r["task"] == t and is_ok(r) for r in e.records)]
        if missing:
            notes.append(f"{e.label}: no finished trials on {missing}")
        lacking = [
            m.label for m in STUDY_METRICS if all(e.metric(m.source, env) is None for env in envs)
        ]
        if lacking:
            notes.append(
                f"{e.label}: no {', '.join(lacking)} in {[str(p) for p in e.metrics_files]}"
            )
    if len(envs) > 1:
        notes.append(
            "the 'all tasks' rows use a model's metrics only if it has a single metrics file; "
            "compare the per-environment rows instead"
        )
    return StudyResult(labels, [s[0] for s in scopes], rows, correlations, notes)
