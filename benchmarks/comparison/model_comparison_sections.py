"""The sections of ``results.md`` (:mod:`benchmarks.comparison.model_comparison_results`), one
function each, from the budget to the study: each reads the files one stage of the comparison
wrote under its output folder, and nothing else."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from vp2.diagnose.score import load_predictor, predicted_score
from vp2.diagnose.verdicts import TOP_FRACTION
from vp2.report.study import ALL_TASKS, STUDY_METRICS
from vp2.run.run_dir import RunDir

#: The metrics table's columns: key in ``metrics.json``, title, scale, format.
METRIC_COLUMNS = (
    ("mse", "MSE", 1, ".5f"),
    ("psnr", "PSNR (dB)", 1, ".2f"),
    ("ssim", "SSIM ×100", 100, ".2f"),
    ("lpips_alex", "LPIPS-Alex ×100", 100, ".2f"),
    ("lpips_vgg", "LPIPS-VGG ×100", 100, ".2f"),
    ("fvd", "FVD", 1, ".1f"),
)


def _read(path: Path) -> Any:
    return json.loads(path.read_text()) if path.is_file() else None


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.0f}"


def _num(x: float | None) -> str:
    return "–" if x is None else f"{x:.2f}"


def _success(mean: float | None, low: float | None, high: float | None) -> str:
    return f"{_pct(mean)} [{_pct(low)}, {_pct(high)}]"


def budget_lines(out: Path, s: dict[str, Any]) -> list[str]:
    if not s["families"]:
        intro = (
            "No family is trained by this comparison: every model comes from elsewhere. A zoo "
            "model's row gives the training budget, steps and device its card records "
            "(`vp2 zoo list`)."
        )
    else:
        intro = (
            f"Dataset `{s['data']}`, batch {s['batch_size']}, seed 0. Every family got "
            f"**{s['budget_minutes']:g} minutes** of training wall time (`vp2 train "
            "--max-minutes`: optimisation steps with their data loading, summed over resumed "
            "sessions; validation and checkpoint writing left out. MaskViT's budget is split "
            "1/3 tokenizer, 2/3 transformer). Steps reached depend on the device and its load."
        )
    lines = [
        "## Training budget",
        "",
        intro,
        "",
        "| family | model (preset) | parameters | budget (min) | minutes used | steps reached "
        "| device | threads |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for family in s["families"]:
        for stage in s["family_stages"][family]:
            r = _read(out / "train" / f"{stage['model']}.json")
            overrides = "".join(f" {k}={v}" for k, v in stage["overrides"])
            name = f"{stage['model']} ({stage['preset']}{overrides})"
            if r is None:
                lines.append(f"| {family} | {name} | – | – | – | – | – | – |")
                continue
            params = "–" if r.get("parameters") is None else f"{r['parameters'] / 1e6:.2f} M"
            steps = f"{r['step']:,}" + ("" if r["budget_reached"] else " (budget not reached)")
            lines.append(
                f"| {family} | {name} | {params} | {r['budget_minutes']:.3g} | "
                f"{r['train_minutes']:.3g} | {steps} | {r['device']} | {r['threads'] or '–'} |"
            )
    for label, spec in s.get("extra_models", {}).items():
        card = _read(out / "zoo" / f"{label}.json")
        if card is None:
            lines.append(f"| {label} | `{spec}` | – | not trained here | – | – | – | – |")
            continue
        budget = card["budget"]
        minutes = budget.get("core_minutes") or budget.get("max_minutes") or budget.get(
            "wall_minutes"
        )
        lines.append(
            f"| {label} | `{spec}` ({card['family']}, {card['preset'] or 'default preset'}) | "
            f"{card['parameters'] / 1e6:.2f} M | {_budget(minutes)} (zoo card) | – | "
            f"{card['steps']:,} | {card['device'] or '–'} | – |"
        )
    return [*lines, ""]


def _budget(minutes: float | None) -> str:
    return "not recorded" if minutes is None else f"{minutes:.3g}"


def success_lines(out: Path, s: dict[str, Any]) -> list[str]:
    names = s["run_names"]
    summaries = {name: _read(RunDir(out / "runs" / name).summary_json) for name in names}
    tasks: list[str] = []
    for summary in summaries.values():
        for row in summary["tasks"] if summary else []:
            if row["task"] not in tasks:
                tasks.append(row["task"])
    # The oracle column and the note are those of one table, the first run's: an agent without
    # planner samples (random) is normalised by another table (the SPEC count's), named below.
    source = next(
        (x["oracle_source"] for x in summaries.values() if x and x.get("oracle_source")), None
    )
    oracle: dict[str, float] = {}
    others: dict[str, list[str]] = {}
    for name, summary in summaries.items():
        if not summary or not summary.get("oracle_source"):
            continue
        if summary["oracle_source"] != source:
            others.setdefault(summary["oracle_source"], []).append(name)
            continue
        for row in summary["tasks"]:
            if row.get("oracle_mean") is not None:
                oracle.setdefault(row["task"], row["oracle_mean"])
    fewer = "".join(
        f" ({name}: seed{'s' if len(seeds) > 1 else ''} {', '.join(map(str, seeds))} only, "
        "`--seeds-for`)"
        for name, seeds in s.get("seeds_for", [])
    )
    lines = [
        "## Success per task",
        "",
        f"`vp2 run` on {', '.join(s['tasks'])}: the first {s['num_instances']} instance(s) of "
        f"each task, seeds {', '.join(map(str, s['seeds']))}{fewer}, MPPI with {s['num_samples']} "
        f"planner samples (SPEC: 200, 800 for open_slide/open_drawer), {s['num_steps']} control "
        "steps. Cell: success % mean over seeds [min, max] (trials). The shipped oracle's column "
        "is its own measurement (how: the first note), not a run of this comparison.",
        "",
        "| task | " + " | ".join(names) + " | oracle (shipped) |",
        "|---" * (len(names) + 2) + "|",
    ]
    for task in tasks:
        cells = []
        for name in names:
            if summaries[name] is None:
                cells.append("pending")
                continue
            row = next((r for r in summaries[name]["tasks"] if r["task"] == task), None)
            cells.append(
                "–" if row is None
                else f"{_success(row['mean'], row['min'], row['max'])} ({row['num_trials']})"
            )  # fmt: skip
        lines.append(f"| {task} | " + " | ".join(cells) + f" | {_pct(oracle.get(task))} |")
    means, normalised = [], []
    for x in summaries.values():
        x = x or {}
        means.append(f"**{_pct(x.get('mean'))}** [{_pct(x.get('min'))}, {_pct(x.get('max'))}]")
        normalised.append(
            "–" if x.get("normalised") is None
            else f"**{x['normalised']:.2f}** [{_num(x.get('normalised_min'))}, "
            f"{_num(x.get('normalised_max'))}]"
        )  # fmt: skip
    oracle_mean = sum(oracle.values()) / len(oracle) if oracle else None
    lines.append("| **mean over tasks** | " + " | ".join(means) + f" | {_pct(oracle_mean)} |")
    lines.append("| **oracle-normalised mean** | " + " | ".join(normalised) + " | 1 |")
    lines += ["", f"- normalised by the {source}" if source else "- not oracle-normalised"]
    lines += [f"- {', '.join(names)}: normalised by the {other} instead (its oracle-normalised "
              "mean; the oracle column is the first table's)" for other, names in others.items()]
    warnings = sorted({w for x in summaries.values() if x for w in x.get("warnings", [])})
    return lines + [f"- {w}" for w in warnings] + [""]


def conditioning_lines(out: Path, s: dict[str, Any]) -> list[str]:
    lines = [
        "## Action conditioning (held-out clips)",
        "",
        "Prediction MSE under each clip's true actions and under another clip's, measured as "
        f"`vp2 diagnose` measures it (up to {s['conditioning_clips']} clips of the valid split, "
        f"{s['conditioning_samples']} sampling seed(s), seed 0: the clips and the ratio of the "
        "diagnosis and of a zoo card). A ratio shuffled / true above 1: the model uses its "
        "actions. Intervals: 95% bootstrap over clips and over the clips' trajectories (whole "
        "trajectories resampled: the clips of one trajectory are not independent draws); wins: "
        "clips where the true actions gave the lower error (all pixels); p: two-sided sign "
        "test on those pairs.",
        "",
        "| family | ratio, all pixels [95% CI] | 95% CI over trajectories | "
        "ratio, changing pixels [95% CI] | wins | p |",
        "|---|---|---|---|---|---|",
    ]
    for family in [*s["families"], *s.get("extra_models", {})]:
        r = _read(out / "conditioning" / f"{family}.json")
        if r is None or "moving" not in r:  # absent, or a record of an older layout
            lines.append(f"| {family} | – | – | – | – | – |")
            continue
        m = r["moving"]
        t = ("–" if "trajectory_ci" not in r else
             f"[{r['trajectory_ci'][0]:.3f}, {r['trajectory_ci'][1]:.3f}] "
             f"({r['trajectories']} trajectories)")
        lines.append(
            f"| {family} | {r['ratio']:.3f} [{r['ci'][0]:.3f}, {r['ci'][1]:.3f}] | {t} | "
            f"{m['ratio']:.3f} [{m['ci'][0]:.3f}, {m['ci'][1]:.3f}] | "
            f"{r['wins']}/{r['clips']} | {r['sign_p']:.2g} |"
        )
    return [*lines, ""]


def control_seconds(run_dir: Path) -> tuple[float, int]:
    """Wall seconds of a run's trials (each trial's ``timings.total_s``) and how many trials."""
    path = RunDir(run_dir).trials_file
    if not path.is_file():
        return 0.0, 0
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    rows = [r for r in rows if r.get("error") is None and (r.get("timings") or {}).get("total_s")]
    return sum(r["timings"]["total_s"] for r in rows), len(rows)


def diagnosis_lines(out: Path, s: dict[str, Any]) -> list[str]:
    """``vp2 diagnose`` of every model beside its measured success; empty when no model of the
    comparison was diagnosed (a build from before the stage existed)."""
    names = s["metrics_names"]
    records = {name: _read(out / "diagnose" / f"{name}.json") for name in names}
    if not any(records.values()):
        return []
    first = next(r for r in records.values() if r)["settings"]
    lines = [
        "## Diagnosis beside control",
        "",
        f"`vp2 diagnose` of each model ({first['clips']} held-out clips, the first "
        f"{first['instances_per_task']} instance(s) of each {first['env']} task probed at their "
        f"first planning step, {first['num_samples']} planner samples): its verdict on the "
        "actions, where the instance's scripted plan ranks under the model's cost, whether the "
        "ranking repeats across the model's noise, and its predicted success (docs/diagnose.md), "
        "beside the success the control runs above measured. Time: diagnose against all of "
        "this comparison's control trials of the model, same machine.",
        "",
        f"| model | actions | scripted plan in the top {TOP_FRACTION:.0%} | ranking repeats (median ρ) | "
        "predicted success | measured success | time: diagnose / control |",
        "|---|---|---|---|---|---|---|",
    ]
    rescored, asset = False, None
    for name in names:
        record = records[name]
        if record is None:
            lines.append(f"| {name} | pending | | | | | |")
            continue
        r = record["report"]
        verdict = r["verdicts"]["action_conditioning"]["text"]
        plan = r["planning"].get("scripted_plan") or {}
        in_top = (
            f"{round(plan['top_fraction'] * plan['instances'])}/{plan['instances']} "
            f"(median rank {plan['median_rank']:g} of {plan['of']})"
            if plan.get("instances") else "–"
        )  # fmt: skip
        rho = (r["planning"].get("repeatability") or {}).get("median_rho")
        predicted, mark = r.get("predicted_control_score"), ""
        if predicted is None:  # a report made before vp2 shipped a predictor for its env
            asset = asset or load_predictor()
            predicted, _ = predicted_score(r, asset)
            mark = "†" if predicted is not None else ""
            rescored = rescored or bool(mark)
        summary = _read(RunDir(out / "runs" / name).summary_json)
        measured = _pct(summary.get("mean")) if summary else "pending"
        seconds, trials = control_seconds(out / "runs" / name)
        time_cell = f"{r['timing']['total_s']:.0f} s / " + (
            f"{seconds:.0f} s ({trials} trial{'' if trials == 1 else 's'})" if trials else "–"
        )
        lines.append(
            f"| {name} | {verdict} | {in_top} | {_num(rho)} | "
            f"{_pct(predicted) + '%' + mark if predicted is not None else '–'} | "
            f"{measured + '%' if summary else measured} | {time_cell} |"
        )
    if rescored:
        lines += [
            "",
            "†: the report predates the predictor vp2 now ships for this environment; the "
            "score is what that predictor gives the report's measures.",
        ]
    return [*lines, ""]


def metrics_lines(out: Path, s: dict[str, Any]) -> list[str]:
    lines = [
        "## Perceptual metrics (held-out clips)",
        "",
        "`vp2 metrics` on a seeded sample of the valid split (the same clips for every model).",
        "",
        "| model | " + " | ".join(c[1] for c in METRIC_COLUMNS) + " | clips |",
        "|---" * (len(METRIC_COLUMNS) + 2) + "|",
    ]
    skipped: set[str] = set()
    for name in s["metrics_names"]:
        result = _read(out / "metrics" / name / "metrics.json")
        if result is None:
            continue
        values = result["metrics"]
        skipped |= set(result["skipped"])
        cells = [
            "n/a" if values.get(k) is None else f"{values[k] * scale:{fmt}}"
            for k, _, scale, fmt in METRIC_COLUMNS
        ]
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {result['num_clips']} |")
    notes = []
    if skipped:
        notes.append(
            f"n/a: {', '.join(sorted(skipped))} skipped, the weight files are not on this "
            "machine (docs/metrics.md says where they go)"
        )
    if not s["lpips"] or not s["fvd"]:
        notes.append("n/a: LPIPS or FVD not asked for (`--lpips`, `--no-fvd` or `--smoke`)")
    return lines + ([""] + [f"- {n}" for n in notes] if notes else []) + [""]


def _metric(x: float | None) -> str:
    """One decimal, as the metrics table prints FVD and SSIM ×100 (``49.99`` reads ``50.0``,
    never ``50`` beside ``2.72``)."""
    return "n/a" if x is None else f"{x:.1f}"


def study_lines(path: Path) -> list[str]:
    data = _read(path)
    lines = ["## Metrics versus control (`vp2 study`)", ""]
    if data is None:
        return [*lines, "(no study)"]
    labels = {m.key: m.label for m in STUDY_METRICS}
    lines += [
        f"All tasks (`{path.parent.name}/study.md` has the table of every task, "
        "`scatter_*.svg` the plots):",
        "",
        "| model | " + " | ".join(labels.values()) + " | success % mean [min, max] | trials |",
        "|---" * (len(labels) + 3) + "|",
    ]
    for row in data["rows"][ALL_TASKS]:
        cells = [_metric(row["metrics"][k]) for k in labels]
        success = (
            "n/a" if row["success"] is None
            else _success(row["success"], row["success_min"], row["success_max"])
        )  # fmt: skip
        lines.append(
            f"| {row['label']} | " + " | ".join(cells) + f" | {success} | {row['num_trials']} |"
        )

    def rp(value: float | None, p: float | None) -> str:
        if value is None:
            return "undefined"
        return f"{value:+.3f}" + ("" if p is None else f" (p {p:.2g})")

    lines += [
        "",
        "Rank correlation across models between each metric and success (a metric that agrees "
        "with control correlates negatively for FVD and LPIPS, positively for SSIM):",
        "",
        "| scope | metric | models | Spearman ρ | Kendall τ-b | note |",
        "|---|---|---|---|---|---|",
    ]
    # A metric no model has (its weights are not on the machine) is one line, not a row of
    # "undefined" per scope.
    measured = {c["metric"] for c in data["correlations"] if c["n"]}
    absent = [labels[k] for k in labels if k not in measured]
    for c in data["correlations"]:
        if c["metric"] not in measured:
            continue
        lines.append(
            f"| {c['scope']} | {labels[c['metric']]} | {c['n']} | "
            f"{rp(c['spearman'], c['spearman_p'])} | {rp(c['kendall'], c['kendall_p'])} | "
            f"{c['note']} |"
        )
    if absent:
        lines += ["", f"Left out: {', '.join(absent)}, which no model has (see the metrics table)."]
    notes = data.get("notes", [])
    return lines + ([""] + [f"- {n}" for n in notes] if notes else [])
