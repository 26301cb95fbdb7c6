"""Does `vp2 diagnose` predict control? The predictor fitted and validated leave-one-model-out.

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.studies.diagnose_validation \\
        --models benchmarks/studies/diagnose_models.json --out outputs/diagnose-validation \\
        [--write-asset]

``--models`` is a JSON file listing the models with control runs, per environment::

    {"models": [
      {"label": "shipped_svg_prime", "env": "robodesk",
       "model": "svg_prime:src/vp2/assets/models/svg_prime_tiny_robodesk.pt",
       "control": ["outputs/comparison/runs/shipped_svg_prime"],
       "metrics": "outputs/comparison/metrics/shipped_svg_prime/metrics.json"},
      ...]}

(``"report": PATH`` names a diagnose report made elsewhere, e.g. by the model comparison;
``"fit": false`` keeps a model out of every fit: one whose control runs follow another protocol,
such as a study's few tasks, predicted by the predictor fitted on the environment's other
models.) A top-level ``"common_trials"`` names, per environment, trials every model should have
(``{"robodesk": {"tasks": [...], "instances": [0], "seeds": [0, 1, 2]}}``): each model whose
runs hold them all is scored on exactly those, fitted or not, and the held-out predictions are
ranked against that success too (the one protocol all of them share).

For each model it runs ``vp2 diagnose`` (default settings; the report is kept under
``<out>/reports/<label>.json`` and reused), reads the control success (every trial of the run
directories in ``control`` on the model's environment) and the perceptual metrics (SSIM, LPIPS,
FVD of ``vp2 metrics``, where given). Then, per environment with at least 5 models (an
environment with fewer borrows the predictor of the environment with the most models, rescaled
by the two environments' oracle success in the shipped oracle table of the diagnoses' planner
budget, :func:`vp2.diagnose.score.transfer`; its models are all held out from that
fit, so their predictions are validated as they are, given at least 3):

* the **held-out predictions**: each model's score from the predictor
  (:mod:`vp2.diagnose.score`) fitted on the *other* models, its ridge penalty chosen
  by those models alone (nested leave-one-out, :func:`~vp2.diagnose.score.choose_ridge`);
  beside it the same with the penalty fixed at 1;
* **Spearman** of the held-out predictions with measured success, beside the Spearman of SSIM,
  −LPIPS and −FVD with success on the same models (signed so that +1 means "the better metric
  goes with more success");
* ``validation.md`` / ``validation.json`` under ``--out``; with ``--write-asset`` the predictor
  fitted on all the models, with these figures, becomes ``src/vp2/assets/diagnose_predictor.json``
  (what ``vp2 diagnose`` then reports as the predicted control score).
"""

from __future__ import annotations

import datetime
import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from benchmarks import common
from benchmarks.comparison.records import save_run
from vp2.diagnose.measures import spearman
from vp2.diagnose.score import (
    FEATURES,
    FORMAT,
    RIDGE,
    choose_ridge,
    features,
    fit,
    leave_one_out,
    predict,
    transfer,
)
from vp2.run.run_dir import read_trials
from vp2.utils.io import json_safe, write_json_atomic

ASSET = Path(__file__).resolve().parents[2] / "src" / "vp2" / "assets" / "diagnose_predictor.json"
#: Fewest models an environment needs for a held-out figure.
MIN_MODELS = 3
#: Fewest models an environment needs to fit its own predictor (six weights; with fewer it
#: borrows another environment's, :func:`vp2.diagnose.score.transfer`).
MIN_FIT = 5


def oracle_rates(num_samples: int, asset: Path | None = None) -> tuple[str, dict[str, float]]:
    """``(table name, {env: success fraction})``: the shipped oracle table whose every task
    was measured at ``num_samples`` planner samples, its successes pooled per environment.

    Raises:
        ValueError: if no shipped table is at that budget.
    """
    from vp2.oracle.shipped import load_shipped_oracle

    shipped = load_shipped_oracle(asset)
    for table in shipped.tables if shipped else ():
        if table.tasks and all(t.num_samples == num_samples for t in table.tasks.values()):
            return table.name, table.env_rates()
    tables = shipped.table_list() if shipped else "no oracle asset"
    raise ValueError(f"no shipped oracle table at {num_samples} samples ({tables})")


#: A trial of a control run: (task, instance, seed).
TrialKey = tuple[str, int, int]


def control_trials(run_dirs: Sequence[str], env: str) -> dict[TrialKey, bool]:
    """Whether each finished ``env`` trial of the run directories succeeded, by (task,
    instance, seed); a trial two of the runs hold is counted once (a trial is the same trial
    in every run: the same model, instance and seed replan the same actions).

    Raises:
        ValueError: no such trial, or one trial recorded as solved in one run and failed in
            another.
    """
    found: dict[TrialKey, bool] = {}
    for d in run_dirs:
        for t in read_trials(d):
            if not str(t.get("task", "")).startswith(f"{env}/") or t.get("error"):
                continue
            key = (str(t["task"]), int(t["instance"]), int(t["seed"]))
            if found.setdefault(key, bool(t["success"])) != bool(t["success"]):
                raise ValueError(
                    f"{key[0]}#{key[1]} seed {key[2]} is recorded both solved and failed in "
                    f"{list(run_dirs)}: these runs are not of one model; list one of them"
                )
    if not found:
        raise ValueError(f"no {env} trials in {list(run_dirs)}: run `vp2 run` first")
    return found


def control_success(run_dirs: Sequence[str], env: str) -> tuple[float, int]:
    """Success fraction and trial count over the ``env`` trials of the run directories."""
    return success_of(control_trials(run_dirs, env))


def success_of(trials: Mapping[TrialKey, bool]) -> tuple[float, int]:
    """Success fraction and count of :func:`control_trials`' outcomes."""
    return sum(trials.values()) / len(trials), len(trials)


def common_keys(spec: Mapping[str, Sequence[Any]]) -> list[TrialKey]:
    """The trials of a ``common_trials`` entry: every task × instance × seed."""
    return [(t, int(i), int(s)) for t in spec["tasks"] for i in spec["instances"]
            for s in spec["seeds"]]  # fmt: skip


def common_validation(
    rows: Sequence[Mapping[str, Any]], predicted: Mapping[str, float],
    keys: Sequence[TrialKey], trials: Mapping[str, Mapping[TrialKey, bool]],
) -> dict[str, Any]:
    """Every model of ``rows`` whose control holds all of ``keys``, scored on exactly those:
    its success there, its held-out prediction (``predicted``) and the Spearman of each
    predictor with that success; the others listed with how many of the trials they lack."""
    on = [r for r in rows if all(k in trials[r["label"]] for k in keys)]
    scored = {r["label"] for r in on}
    models = [{**r, "success": sum(trials[r["label"]][k] for k in keys) / len(keys),
               "trials": len(keys)} for r in on]  # fmt: skip
    return {
        "trials": [list(k) for k in keys],
        "models": len(models),
        "success": {m["label"]: m["success"] for m in models},
        "predicted": {m["label"]: predicted[m["label"]] for m in models},
        "fitted": {m["label"]: m["fit"] for m in models},
        "missing": {r["label"]: sum(k not in trials[r["label"]] for k in keys)
                    for r in rows if r["label"] not in scored},  # fmt: skip
        "spearman": _spearman_table(models, [predicted[m["label"]] for m in models]),
    }


def perceptual(path: str | None) -> dict[str, float | None]:
    """SSIM, LPIPS (AlexNet) and FVD from a ``vp2 metrics`` file (``None`` where absent)."""
    if not path:
        return {"ssim": None, "lpips": None, "fvd": None}
    metrics = json.loads(Path(path).read_text()).get("metrics", {})
    return {
        "ssim": metrics.get("ssim"),
        "lpips": metrics.get("lpips_alex"),
        "fvd": metrics.get("fvd"),
    }


def diagnose_report(entry: Mapping[str, Any], out: Path) -> dict[str, Any]:
    """The model's diagnose report: read from the entry's ``report`` file (e.g. the one a
    model comparison keeps in ``results/comparison``), else from ``<out>/reports/<label>.json``,
    else measured there."""
    if entry.get("report"):
        return json.loads(Path(entry["report"]).read_text())
    path = out / "reports" / f"{entry['label']}.json"
    if path.is_file():
        return json.loads(path.read_text())
    from vp2.diagnose.model import DiagnoseConfig, diagnose_model, write_report

    report = diagnose_model(DiagnoseConfig(model=entry["model"], env=entry["env"]))
    write_report(path, report)
    return report


def compact_run(run_dir: Path, dest: Path) -> int:
    """Copies a control run into ``dest`` as ``results/`` keeps one: its ``config.yaml`` and
    one compact record per trial (:func:`benchmarks.comparison.records.compact_trial`: outcome,
    actions, wall time; no scores or GIFs). Returns the trials copied."""
    copied = save_run(Path(run_dir), Path(dest))
    if not copied:
        raise SystemExit(f"--compact {run_dir}: no trials there")
    return copied


def _signed_spearman(values: Sequence[float | None], success: Sequence[float], sign: float):
    pairs = [(sign * v, s) for v, s in zip(values, success, strict=True) if v is not None]
    if len(pairs) < MIN_MODELS:
        return None, len(pairs)
    a, b = np.array(pairs).T
    return spearman(a, b), len(pairs)


def _spearman_table(models: Sequence[Mapping[str, Any]], held_out: Sequence[float],
                    extra: Mapping[str, tuple[float | None, int]] | None = None):
    success = [m["success"] for m in models]
    table = {"predicted (held out)": _signed_spearman(held_out, success, 1.0), **(extra or {})}
    for key, sign in (("ssim", 1.0), ("lpips", -1.0), ("fvd", -1.0)):
        table[key] = _signed_spearman([m[key] for m in models], success, sign)
    for name in FEATURES:  # each measure alone, as it is: nothing fitted
        table[f"{name} alone"] = _signed_spearman(
            [m["features"][name] for m in models], success, 1.0
        )
    return {k: {"rho": v[0], "models": v[1]} for k, v in table.items()}


def validate(
    rows: Sequence[Mapping[str, Any]],
    rates: tuple[str, Mapping[str, float]] | None = None,
    common: Mapping[str, Sequence[TrialKey]] | None = None,
    control: Mapping[str, Mapping[TrialKey, bool]] | None = None,
) -> dict[str, Any]:
    """Per environment: held-out predictions and the Spearman of each predictor with success.

    Args:
        rows: One per model: ``label``, ``env``, ``features``, ``success``, ``trials``,
            ``ssim``, ``lpips``, ``fvd``, and ``fit`` (default true: a model with
            ``fit`` false is in no fit and no figure of the fitted models; the predictor
            fitted on the others predicts it, under ``unfitted``).
        rates: ``(table, {env: oracle success})`` (:func:`oracle_rates`) for the environments
            with fewer than :data:`MIN_FIT` models; ``None``: those are skipped.
        common: Per environment, the trials every model is also scored on
            (:func:`common_validation`, under ``common``); needs ``control``.
        control: Each model's control trials by label (:func:`control_trials`).
    """
    result: dict[str, Any] = {}
    envs = sorted({r["env"] for r in rows if r.get("fit", True)})
    few = [e for e in envs if sum(r["env"] == e and r.get("fit", True) for r in rows) < MIN_FIT]
    for env in envs:
        models = [r for r in rows if r["env"] == env and r.get("fit", True)]
        if env in few:
            continue
        feats = [m["features"] for m in models]
        success = [m["success"] for m in models]
        trials = [m["trials"] for m in models]
        held_out = leave_one_out(feats, success, trials, ridge="auto")  # nested choice
        fixed = leave_one_out(feats, success, trials, ridge=RIDGE)
        spearman_table = _spearman_table(models, held_out, {
            f"predicted (held out), ridge fixed at {RIDGE:g}": _signed_spearman(fixed, success, 1.0)
        })  # fmt: skip
        predictor = fit(feats, success, trials, choose_ridge(feats, success, trials))
        rho = spearman_table["predicted (held out)"]["rho"]
        predictor.update(
            models_fitted=len(models),
            validation={"held_out_spearman": rho, "models": len(models)},
        )
        result[env] = {
            "models": len(models),
            "held_out": {m["label"]: p for m, p in zip(models, held_out, strict=True)},
            "spearman": spearman_table,
            "predictor": predictor,
        }
    fitted = [e for e in envs if "predictor" in result.get(e, {})]
    source = max(fitted, key=lambda e: (result[e]["models"], e), default=None)
    for env in few:
        models = [r for r in rows if r["env"] == env and r.get("fit", True)]
        if source is None:
            why = "no environment with a fitted predictor"
        elif rates is None:
            why = "no oracle rates given"
        elif env not in rates[1]:
            why = f"no oracle rate for {env}"
        else:
            why = None
        if why:
            result[env] = {"models": len(models),
                           "skipped": f"fewer than {MIN_FIT} models to fit, and {why}"}  # fmt: skip
            continue
        predictor = transfer(result[source]["predictor"], source, env, rates[0])
        held_out = [predict(predictor, m["features"], rates[1]) for m in models]
        spearman_table = _spearman_table(models, held_out)
        predictor["validation"] = {
            "held_out_spearman": spearman_table["predicted (held out)"]["rho"],
            "models": len(models),
        }
        result[env] = {
            "models": len(models),
            "transferred_from": source,
            "oracle_rates": {source: rates[1][source], env: rates[1][env]},
            "held_out": {m["label"]: p for m, p in zip(models, held_out, strict=True)},
            "spearman": spearman_table,
            "predictor": predictor,
        }
    for env, res in result.items():
        if "predictor" not in res:
            continue
        unfitted = [r for r in rows if r["env"] == env and not r.get("fit", True)]
        env_rates = rates[1] if "transfer" in res["predictor"] and rates else None
        if unfitted:
            res["unfitted"] = {r["label"]: predict(res["predictor"], r["features"], env_rates)
                               for r in unfitted}  # fmt: skip
        if common and env in common:
            if control is None:
                raise ValueError("common trials need each model's control trials")
            predicted = {**res["held_out"], **res.get("unfitted", {})}
            res["common"] = common_validation(
                [{"fit": True, **r} for r in rows if r["env"] == env], predicted,
                common[env], control)
    return result


def validation_markdown(
    rows: Sequence[Mapping[str, Any]], result: Mapping[str, Any], command: str
) -> str:
    lines = ["# Diagnose against control", "", f"Command: `{command}`", ""]
    for env, res in result.items():
        lines += [f"## {env}", ""]
        if "skipped" in res:
            lines += [f"Not validated: {res['skipped']} ({res['models']}).", ""]
            continue
        if "transferred_from" in res:
            moved = res["predictor"]["transfer"]
            src, rates = moved["from"], res["oracle_rates"]
            lines += [
                f"Fewer than {MIN_FIT} models: the {src} predictor, its prediction times the "
                f"oracles' success ratio {env}/{src} in table `{moved['table']}` "
                f"({rates[env]:.3f}/{rates[src]:.3f} = {rates[env] / rates[src]:.3f}). None of these "
                "models was fitted on: every prediction is held out.",
                "",
            ]
        lines += [
            "| model | measured success | trials | predicted (held out) | SSIM | LPIPS | FVD | "
            + " | ".join(FEATURES)
            + " |",
            "|---|---|---|---|---|---|---|" + "---|" * len(FEATURES),
        ]
        for r in (r for r in rows if r["env"] == env and r.get("fit", True)):
            cells = [
                r["label"], f"{100 * r['success']:.0f}%", str(r["trials"]),
                f"{100 * res['held_out'][r['label']]:.0f}%",
                *("–" if r[k] is None else f"{r[k]:.4g}" for k in ("ssim", "lpips", "fvd")),
                *(f"{r['features'][f]:.3g}" for f in FEATURES),
            ]  # fmt: skip
            lines.append("| " + " | ".join(cells) + " |")
        lines += [
            "",
            "Spearman with measured success (+1: the better value goes with more success):",
            "",
        ]
        lines += _spearman_lines(res["spearman"])
        if res.get("unfitted"):
            lines += _unfitted_lines([r for r in rows if r["label"] in res["unfitted"]], res)
        if res.get("common"):
            lines += _common_lines(rows, res["common"])
    return "\n".join(lines)


def _spearman_lines(table: Mapping[str, Mapping[str, Any]]) -> list[str]:
    lines = ["| predictor | Spearman | models |", "|---|---|---|"]
    for name, v in table.items():
        rho = "–" if v["rho"] is None else f"{v['rho']:+.2f}"
        lines.append(f"| {name} | {rho} | {v['models']} |")
    return lines + [""]


def _unfitted_lines(rows: Sequence[Mapping[str, Any]], res: Mapping[str, Any]) -> list[str]:
    lines = [
        "Models in no fit (their control follows another protocol), predicted by the predictor "
        "fitted on the models above:", "",
        "| model | measured success | trials | predicted | SSIM | LPIPS | FVD |",
        "|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    for r in rows:
        lines.append("| " + " | ".join([
            r["label"], f"{100 * r['success']:.0f}%", str(r["trials"]),
            f"{100 * res['unfitted'][r['label']]:.0f}%",
            *("–" if r[k] is None else f"{r[k]:.4g}" for k in ("ssim", "lpips", "fvd")),
        ]) + " |")  # fmt: skip
    return lines + [""]


def _common_lines(rows: Sequence[Mapping[str, Any]], common: Mapping[str, Any]) -> list[str]:
    tasks = sorted({t for t, _, _ in common["trials"]})
    seeds = sorted({s for _, _, s in common["trials"]})
    instances = sorted({i for _, i, _ in common["trials"]})
    lines = [
        f"### Every model on the same {len(common['trials'])} trials", "",
        f"The trials every model's runs hold: instance(s) {', '.join(map(str, instances))} of "
        f"{', '.join(tasks)}, seeds {', '.join(map(str, seeds))}. Success on exactly those; "
        "the prediction is held out (a fitted model's from the fit without it).", "",
        "| model | fitted on | success on these trials | predicted (held out) | SSIM | LPIPS | FVD |",
        "|---|---|---|---|---|---|---|",
    ]  # fmt: skip
    by_label = {r["label"]: r for r in rows}
    for label, success in common["success"].items():
        r = by_label[label]
        lines.append("| " + " | ".join([
            label, "yes" if common["fitted"][label] else "no",
            f"{round(success * len(common['trials']))} of {len(common['trials'])}",
            f"{100 * common['predicted'][label]:.0f}%",
            *("–" if r[k] is None else f"{r[k]:.4g}" for k in ("ssim", "lpips", "fvd")),
        ]) + " |")  # fmt: skip
    if common["missing"]:
        lines += ["", "Not on these trials (trials lacking): " + ", ".join(
            f"{label} ({n})" for label, n in common["missing"].items()) + "."]
    lines += ["", "Spearman with success on these trials:", ""]
    return lines + _spearman_lines(common["spearman"])


def _rates_for(
    rows: Sequence[Mapping[str, Any]], reports: Sequence[Mapping[str, Any]]
) -> tuple[str, dict[str, float]] | None:
    """The oracle rates a transfer uses, when some environment has fewer than :data:`MIN_FIT`
    models: the shipped table at the diagnoses' planner budget (one budget for all)."""
    envs = [r["env"] for r in rows]
    if all(envs.count(e) >= MIN_FIT for e in envs):
        return None
    budgets = {(r.get("settings") or {}).get("num_samples") for r in reports}
    if len(budgets) != 1 or None in budgets:
        raise SystemExit(
            f"the diagnose reports were measured at planner budgets {sorted(map(str, budgets))}; "
            "a transfer between environments needs them all at one budget"
        )
    return oracle_rates(int(budgets.pop()))


def main(argv: Sequence[str] | None = None) -> None:
    parser = common.argument_parser(__spec__.name, __doc__ or "")
    parser.add_argument("--models", type=Path, help="JSON list of models (see above)")
    parser.add_argument("--out", type=Path, default=Path("outputs/diagnose-validation"))
    parser.add_argument(
        "--write-asset",
        action="store_true",
        help=f"write the fitted predictor to {ASSET.relative_to(ASSET.parents[3])}",
    )
    parser.add_argument("--asset", type=Path, default=ASSET, help="where --write-asset writes")
    parser.add_argument(
        "--compact", nargs=2, type=Path, metavar=("RUN_DIR", "DEST"),
        help="copy a control run into DEST as results/diagnose/runs keeps one (config and "
        "compact trial records) and stop",
    )
    args = parser.parse_args(argv)
    if args.compact:
        print(f"{compact_run(*args.compact)} trials -> {args.compact[1]}")
        return
    if args.models is None:
        parser.error("--models is required (or --compact RUN_DIR DEST)")
    listing = json.loads(args.models.read_text())
    entries = listing["models"]
    labels = [e["label"] for e in entries]
    if len(set(labels)) != len(labels):
        raise SystemExit(f"{args.models}: labels must be unique, got {labels}")
    shared = {env: common_keys(spec) for env, spec in listing.get("common_trials", {}).items()}
    rows, reports, trials = [], [], {}
    for entry in entries:
        report = diagnose_report(entry, args.out)
        reports.append(report)
        trials[entry["label"]] = control_trials(entry["control"], entry["env"])
        success, count = success_of(trials[entry["label"]])
        rows.append({
            "label": entry["label"], "env": entry["env"], "fit": bool(entry.get("fit", True)),
            "features": features(report), "success": success, "trials": count,
            **perceptual(entry.get("metrics")),
        })  # fmt: skip
        print(f"{entry['label']}: success {success:.2f} ({count} trials)", flush=True)
    result = validate(rows, _rates_for([r for r in rows if r["fit"]], reports), shared, trials)
    command = common.command_line(__spec__.name, argv)
    write_json_atomic(
        args.out / "validation.json",
        json_safe({"command": command, "rows": rows, "result": result}),
    )
    (args.out / "validation.md").write_text(validation_markdown(rows, result, command))
    print((args.out / "validation.md").read_text())
    if args.write_asset:
        predictors = {env: res["predictor"] for env, res in result.items() if "predictor" in res}
        write_json_atomic(args.asset, json_safe({
            "format": FORMAT,
            "created": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "command": command,
            "models": {env: [r["label"] for r in rows if r["env"] == env and r["fit"]]
                       for env in predictors},
            "predictors": predictors,
        }))  # fmt: skip
        print(f"wrote {args.asset}")


if __name__ == "__main__":
    main()
