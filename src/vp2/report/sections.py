"""The sections of the report page: charts, tables, the gallery of trial videos."""

from __future__ import annotations

import base64
import math
from collections.abc import Sequence
from html import escape
from pathlib import Path
from typing import Any

from vp2.oracle.shipped import NO_SHIPPED_ORACLE
from vp2.report.charts import bar_chart
from vp2.report.runs import RunView
from vp2.run.results import is_ok
from vp2.utils.io import json_safe


def _pct(value: float | None) -> str:
    return "n/a" if value is None or math.isnan(value) else f"{100 * value:.1f}"


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
        row_v.append(json_safe(r.summary.mean))
        row_l.append(json_safe(r.summary.min))
        row_h.append(json_safe(r.summary.max))
        values.append(row_v)
        low.append(row_l)
        high.append(row_h)
    return bar_chart(groups, [r.label for r in runs], values, low, high)


def _mean_range(mean: float | None, low: float | None, high: float | None) -> str:
    """``mean [min, max]`` in %, which may wrap before the bracket (never inside it)."""
    return f'{_pct(mean)} <span class="nw">[{_pct(low)}, {_pct(high)}]</span>'


def success_table(runs: Sequence[RunView]) -> str:
    """Success per task and model: mean [min, max] over seeds, and the totals."""
    tasks = task_order(runs)
    # Labels may break after an underscore and task names after their environment, so that
    # the columns of many runs fit the page.
    head = "".join(f"<th>{escape(r.label).replace('_', '_<wbr>')}</th>" for r in runs)
    rows = []
    for task in tasks:
        cells = []
        for r in runs:
            t = next((t for t in r.summary.tasks if t.task == task), None)
            if t is None:
                cells.append('<td class="num">n/a</td>')
                continue
            notes = [f"{len(t.per_seed)} seeds", f"{t.num_trials} trials"]
            notes += [] if t.normalised is None else [f"{t.normalised:.2f}×"]
            sub = " · ".join(f'<span class="nw">{n}</span>' for n in notes)
            cells.append(
                f'<td class="num">{_mean_range(t.mean, t.min, t.max)}<span class="sub">{sub}</span></td>'
            )
        name = escape(task).replace("/", "/<wbr>")
        rows.append(f"<tr><td>{name}</td>{''.join(cells)}</tr>")
    envs = list(dict.fromkeys(t.split("/")[0] for t in tasks))
    for env in envs:
        cells = "".join(f'<td class="num">{_pct(r.summary.env_means.get(env))}</td>' for r in runs)
        rows.append(f"<tr class=total><td>{escape(env)} (mean of tasks)</td>{cells}</tr>")
    cells = "".join(
        f'<td class="num">{_mean_range(r.summary.mean, r.summary.min, r.summary.max)}</td>'
        for r in runs
    )
    rows.append(f"<tr class=total><td>all tasks</td>{cells}</tr>")
    return (
        '<div class="wide"><table class="success"><thead><tr><th>task</th>'
        f"{head}</tr></thead><tbody>{''.join(rows)}</tbody></table></div>"
        '<p class="sub">success % mean over control runs (seeds) [min, max]; '
        "× = the task's ratio to the oracle's mean</p>"
    )


def normalised_section(runs: Sequence[RunView]) -> str:
    """Each run's oracle-normalised score and where the oracle came from."""
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
        elif r.oracle_note:
            items.append(
                f"<li><b>{escape(r.label)}</b>: not available "
                f"<span class=sub>({escape(r.oracle_note)})</span></li>"
            )
        else:
            items.append(f"<li><b>{escape(r.label)}</b>: not available (no oracle)</li>")
    missing = (
        f"<p class=warn>{escape(NO_SHIPPED_ORACLE)}.</p>"
        if any(not r.is_oracle and r.oracle_source is None and r.oracle_note is None
               for r in runs)
        else ""
    )
    return (
        "<p>Mean success over tasks divided by the simulator oracle's on the same tasks (a "
        "ratio of means), [min, max] over seeds. The oracle: a simulator-oracle run given to "
        "<code>vp2 report</code>, else the run's <code>--oracle RUN_DIR</code>, else the "
        "shipped oracle's table of the run's planner samples and render spec (named with the "
        "score).</p>"
        f"{missing}<ul>{''.join(items)}</ul>"
    )


def runs_table(runs: Sequence[RunView]) -> str:
    """One row per run: model, directory, settings, trials, departures from the SPEC."""
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
            f'<td class="num" title="seeds {escape(", ".join(map(str, seeds)))}">{len(seeds)}</td>'
            f"<td>{deviations}</td></tr>"
        )
    return (
        '<div class="wide"><table class="runs"><thead><tr><th>model</th><th>run directory</th>'
        "<th>agent</th><th>planner</th><th>trials</th><th>errors</th><th>seeds</th>"
        "<th>not the SPEC protocol</th></tr></thead>"
        f"<tbody>{''.join(rows)}</tbody></table></div>"
    )


def _data_uri(path: Path) -> str:
    return "data:image/gif;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _trial_rank(record: dict[str, Any]) -> tuple[int, float, int, int]:
    scores = record.get("scores") or []
    best = scores[-1] if scores and scores[-1] is not None else -math.inf
    return (0 if record.get("success") else 1, -best, int(record["instance"]), int(record["seed"]))


def gallery(runs: Sequence[RunView], per_task: int, max_bytes: int) -> tuple[str, int, int]:
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


#: The page's style sheet (inline: the report opens without a network).
CSS = """
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
.diag-blind,.diag-inverted{color:#a40;font-weight:bold} .diag-inconclusive{color:#a40} .diag-uses{color:#070}
code{background:#f3f3f3;padding:0 3px} .wide{max-width:100%;overflow-x:auto}
table.runs{table-layout:auto;width:100%} table.runs code{word-break:break-all}
figure.chart svg,figure.scatter svg{max-width:100%;height:auto}
table.success{font-size:.9em} table.success td.num{white-space:normal} .nw{white-space:nowrap}
"""


def _env_success(run: RunView, env: str) -> str:
    mean = run.summary.env_means.get(env)
    return "–" if mean is None else f"{100 * mean:.0f}%"


def diagnosis_section(runs: Sequence[RunView]) -> str:
    """Each run's diagnosis (``vp2 diagnose`` or the run's pre-check) beside its success."""
    rows = []
    for r in runs:
        for d in r.diagnosis:
            env = str(d.get("env"))
            c = d.get("conditioning")
            if c and c.get("ratio") is not None:
                ci = c.get("ci") or [None, None]
                cond = (
                    f"{c['ratio']:.3f} [{ci[0]:.3f}, {ci[1]:.3f}] on {c.get('clips')} clips"
                    if None not in ci else f"{c['ratio']:.3f}"
                )
                cond_cell = (
                    f'<td class="diag-{escape(str(c.get("status")))}" '
                    f'title="{escape(str(c.get("text") or ""))}">{escape(cond)}</td>'
                )
            else:
                cond_cell = "<td>not measured</td>"
            sp = d.get("scripted")
            scripted = (
                f"median rank {sp.get('median_rank')} of {sp.get('of')}, top 10% on "
                f"{100 * (sp.get('top_fraction') or 0):.0f}%" if sp else "not measured"
            )
            ag = d.get("agreement")
            agreement = (
                f"ρ {ag['median_rho']:+.2f}, its best in the top 10% on "
                f"{100 * (ag.get('best_in_top_fraction') or 0):.0f}%"
                if ag and ag.get("median_rho") is not None else "not measured"
            )  # fmt: skip
            pred = d.get("predicted")
            pred_cell = (
                f"{100 * pred:.0f}%" if pred is not None
                else escape(str(d.get("predicted_reason") or "–"))
            )
            rows.append(
                f"<tr><td><b>{escape(r.label)}</b></td><td>{escape(env)}</td>"
                f"<td>{escape(str(d.get('source')))}</td>{cond_cell}<td>{escape(scripted)}</td>"
                f"<td>{escape(agreement)}</td>"
                f'<td class="num">{pred_cell}</td>'
                f'<td class="num">{_env_success(r, env)}</td></tr>'
            )
    intro = (
        "<p>What the model's cheap measurements said before planning (<code>vp2 run</code>'s "
        "pre-check on held-out clips, or <code>vp2 diagnose --model M --out RUN_DIR</code>), "
        "beside the success it then measured. Action conditioning: error with shuffled / "
        "true actions, 95% interval; an interval reaching 1 means the predictions ignore the "
        "actions (what each measure means: docs/diagnose.md in the vp2 repository).</p>"
    )
    if not rows:
        return intro.replace(
            "</p>",
            " No run directory here holds a diagnosis (the pre-check runs for learned models "
            "only).</p>",
            1,
        )
    return (
        intro
        + '<div class="wide"><table class="diagnosis"><thead><tr><th>model</th><th>env</th>'
        "<th>from</th><th>action conditioning</th><th>scripted plan</th>"
        "<th>agreement with the simulator</th>"
        "<th>predicted success</th><th>measured success</th></tr></thead>"
        f"<tbody>{''.join(rows)}</tbody></table></div>"
    )
