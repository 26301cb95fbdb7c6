"""Would choosing the predictor's measures inside each fold order the models better?

    .venv/bin/python -m benchmarks.studies.diagnose_selection [--validation results/diagnose/validation.json]

The shipped predictor of `vp2 diagnose` (:mod:`vp2.diagnose.score`) fits all six
measures. On some model sets one measure alone orders the models better than the fit, but which
one changes with the set. This study asks whether a choice among the candidates (all six
measures, or one alone) made **inside each leave-one-model-out fold** helps: for each held-out
model, every candidate is scored by the leave-one-out deviance of the *other* models (each fit's
ridge penalty chosen on its own models, as the shipped fit does), the best candidate is fitted on
those models, and it predicts the held-out one. The held-out model never takes part in the
choice, so the Spearman of these predictions with success is as honest as the shipped one's.

Reads the features, successes and trials that ``benchmarks.studies.diagnose_validation`` wrote
(``validation.json``; nothing is run) and prints, per environment with a fitted predictor, the
held-out Spearman of the selection, each candidate's own held-out Spearman and deviance, and the
candidate chosen for each model. About half a CPU-minute for twelve models.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from benchmarks import common
from vp2.diagnose import score as ds
from vp2.diagnose.measures import spearman

#: The candidates: all measures, or one alone (the others held at 0, so they carry no weight).
CANDIDATES: dict[str, tuple[str, ...]] = {"all six": ds.FEATURES, **{f: (f,) for f in ds.FEATURES}}


def only(row: Mapping[str, float], keep: Sequence[str]) -> dict[str, float]:
    """``row`` with every feature outside ``keep`` set to 0 (a constant: no weight)."""
    return {k: (float(v) if k in keep else 0.0) for k, v in row.items()}


def held_out(rows: Sequence[Mapping[str, float]], success: Sequence[float],
             trials: Sequence[int], keep: Sequence[str]) -> list[float]:
    """Leave-one-out predictions of the predictor on the measures ``keep`` (ridge chosen inside)."""
    return ds.leave_one_out([only(r, keep) for r in rows], success, trials, ridge="auto")


def choose(rows: Sequence[Mapping[str, float]], success: Sequence[float],
           trials: Sequence[int]) -> str:
    """The candidate whose leave-one-out predictions on these models have the lowest deviance."""
    scored = [(ds.deviance(held_out(rows, success, trials, keep), success, trials), name)
              for name, keep in CANDIDATES.items()]  # fmt: skip
    return min(scored)[1]


def select_then_predict(rows: Sequence[Mapping[str, float]], success: Sequence[float],
                        trials: Sequence[int]) -> tuple[list[float], list[str]]:
    """Each model's prediction from the candidate chosen, and fitted, on the other models."""
    predictions, chosen = [], []
    for i in range(len(rows)):
        others = [j for j in range(len(rows)) if j != i]
        r = [rows[j] for j in others]
        y, n = [success[j] for j in others], [trials[j] for j in others]
        name = choose(r, y, n)
        keep = CANDIDATES[name]
        sub = [only(x, keep) for x in r]
        predictor = ds.fit(sub, y, n, ds.choose_ridge(sub, y, n))
        predictions.append(ds.predict(predictor, only(rows[i], keep)))
        chosen.append(name)
    return predictions, chosen


def _rho(predicted: Sequence[float], success: Sequence[float]) -> str:
    """Spearman's ρ as the validation table prints it (the same function); "–" if undefined."""
    rho = spearman(predicted, success)
    return "–" if rho is None else f"{rho:+.2f}"


def study(models: Sequence[Mapping[str, Any]]) -> list[str]:
    """The report's lines for one environment's models (``features``, ``success``, ``trials``)."""
    rows = [m["features"] for m in models]
    success, trials = [m["success"] for m in models], [m["trials"] for m in models]
    predictions, chosen = select_then_predict(rows, success, trials)
    lines = [f"choice inside each fold: held-out Spearman {_rho(predictions, success)}"
             f" over {len(models)} models", "", "| candidate | held-out Spearman | deviance |",
             "|---|---|---|"]  # fmt: skip
    for name, keep in CANDIDATES.items():
        p = held_out(rows, success, trials, keep)
        lines.append(f"| {name} | {_rho(p, success)} | "
                     f"{ds.deviance(p, success, trials):.1f} |")
    lines += ["", "| model | success | held out | candidate chosen without it |", "|---|---|---|---|"]
    for m, p, c in zip(models, predictions, chosen, strict=True):
        lines.append(f"| {m['label']} | {m['success']:.0%} | {p:.0%} | {c} |")
    return lines


def main(argv: Sequence[str] | None = None) -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--validation", type=Path, default=Path("results/diagnose/validation.json"))
    args = parser.parse_args(argv)
    rows = json.loads(args.validation.read_text())["rows"]
    for env in sorted({r["env"] for r in rows}):
        models = [r for r in rows if r["env"] == env]
        if len(models) < 5:
            print(f"## {env}\n\n{len(models)} models: too few to fit (it borrows a predictor)\n")
            continue
        print(f"## {env}\n\n" + "\n".join(study(models)) + "\n")


if __name__ == "__main__":
    main()
