"""The predicted control score: `vp2 diagnose`'s measurements mapped to a success rate.

A diagnose report (:mod:`vp2.diagnose.model`) holds cheap measurements of a model. This
module turns them into **features** (:func:`features`), fits a **predictor** of a model's control
success from models whose control runs were measured (:func:`fit`: an L2-regularised logistic
regression of the success fraction on the standardised features, weighted by the trials behind
each fraction), applies it (:func:`predict`), and validates it **leave-one-model-out**
(:func:`leave_one_out`: each model's score comes from a predictor fitted without it). The
ridge penalty is chosen from :data:`RIDGE_GRID` by the leave-one-out deviance of the models a
predictor is fitted on (:func:`choose_ridge`; nested inside the validation's leave-one-out).

An environment with too few models' control runs to fit its own predictor borrows another's
(:func:`transfer`): the same constants, the success they predict rescaled by the ratio of the
two environments' simulator oracle success at the diagnose's planner budget. The asset names
the shipped oracle table; the ratio is read from it when a score is computed
(:func:`oracle_rates`), so re-measuring an oracle row moves the score without refitting. Its
validation is then on all its models, none of which the constants were fitted on (a constant
rescale leaves their ranking, and so the held-out Spearman, unchanged).

The fitted constants ship as ``vp2/assets/diagnose_predictor.json`` (written by
``benchmarks.studies.diagnose_validation``, which also measures the held-out Spearman); without
that file, or without constants for the report's environment, :func:`predicted_score` says why
instead of giving a number.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

#: The asset's format tag.
FORMAT = "vp2-diagnose-predictor/1"
#: The features, in the order of the predictor's weights.
FEATURES: tuple[str, ...] = (
    "log_conditioning",  # log of the shuffled/true error ratio's lower 95% bound (>= 0)
    "scripted_top",  # fraction of instances whose scripted plan is in the top 10%
    "scripted_rank",  # 1 - (median rank - 1) / (candidates - 1): 1 = always the favourite
    "repeatability",  # median Spearman of the ranking across model noise (0 if undefined)
    "steering",  # 1 - exp(-median gamma * spread): 0 = flat scores, MPPI executes the mean
    "oracle_agreement",  # median Spearman of the model's and the simulator's scores (>= 0)
)
#: Why there is no score when vp2 ships no predictor.
NO_PREDICTOR = ("no predictor asset (vp2/assets/diagnose_predictor.json); fit one with "
                "python -m benchmarks.studies.diagnose_validation --write-asset")
#: Ridge penalty on the standardised weights (not on the intercept) where none is chosen.
RIDGE = 1.0
#: The penalties :func:`choose_ridge` chooses from.
RIDGE_GRID: tuple[float, ...] = (0.1, 0.3, 1.0, 3.0, 10.0, 30.0, 100.0)


def _num(value: Any, default: float = 0.0) -> float:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else default


def features(report: Mapping[str, Any]) -> dict[str, float]:
    """The predictor's features of one diagnose report (absent measures count as 0: a model
    whose conditioning or planning was not measured gets no credit for it)."""
    cond = report.get("action_conditioning") or {}
    plan = report.get("planning") or {}
    scripted = plan.get("scripted_plan") or {}
    of = _num(scripted.get("of"), 0.0)
    rank = scripted.get("median_rank")
    low = _num((cond.get("ci") or [None])[0], 1.0)
    return {
        "log_conditioning": max(0.0, math.log(low)) if low > 0 else 0.0,
        "scripted_top": _num(scripted.get("top_fraction")),
        "scripted_rank": (1.0 - (_num(rank) - 1.0) / (of - 1.0))
        if rank is not None and of > 1
        else 0.0,
        "repeatability": max(0.0, _num((plan.get("repeatability") or {}).get("median_rho"))),
        "steering": 1.0
        - math.exp(-max(0.0, _num((plan.get("spread") or {}).get("median_gamma_spread")))),
        "oracle_agreement": max(
            0.0, _num((plan.get("oracle_agreement") or {}).get("median_rho"))
        ),
    }


def _matrix(rows: Sequence[Mapping[str, float]]) -> np.ndarray:
    return np.array([[float(r[f]) for f in FEATURES] for r in rows], np.float64)


def _sigmoid(z: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.clip(z, -30, 30)))


def fit(
    rows: Sequence[Mapping[str, float]],
    success: Sequence[float],
    trials: Sequence[int],
    ridge: float = RIDGE,
) -> dict[str, Any]:
    """Fits ``success ~ sigmoid(b + w . standardised features)`` by Newton's method on the
    binomial likelihood (each model's fraction weighted by its trials) plus ``ridge * |w|^2``.

    Args:
        rows: Features of each model (:func:`features`).
        success: Each model's measured success fraction in [0, 1].
        trials: The control trials behind each fraction.

    Returns:
        The predictor: feature means and scales, weights, intercept (plain data, JSON-ready).
    """
    x = _matrix(rows)
    y = np.asarray(success, np.float64)
    n = np.asarray(trials, np.float64)
    if len(x) < 2 or len(y) != len(x) or len(n) != len(x):
        raise ValueError(
            f"fit needs matching rows, successes and trials for >= 2 models, got {len(x)}"
        )
    if np.any((y < 0) | (y > 1)) or np.any(n <= 0):
        raise ValueError("successes must lie in [0, 1] and trials be positive")
    mean = x.mean(axis=0)
    scale = x.std(axis=0)
    scale[scale < 1e-9] = 1.0  # a constant feature: weight stays ~0 under the ridge
    z = np.hstack([np.ones((len(x), 1)), (x - mean) / scale])
    penalty = np.diag([0.0] + [ridge] * len(FEATURES))
    beta = np.zeros(z.shape[1])
    beta[0] = math.log((y @ n + 0.5) / ((1 - y) @ n + 0.5))  # start at the overall rate
    for _ in range(100):
        p = _sigmoid(z @ beta)
        grad = z.T @ (n * (p - y)) + penalty @ beta
        hess = (z * (n * p * (1 - p))[:, None]).T @ z + penalty + 1e-9 * np.eye(len(beta))
        step = np.linalg.solve(hess, grad)
        beta -= step
        if np.max(np.abs(step)) < 1e-10:
            break
    return {
        "features": list(FEATURES),
        "mean": mean.tolist(),
        "scale": scale.tolist(),
        "intercept": float(beta[0]),
        "weights": beta[1:].tolist(),
        "ridge": ridge,
    }


def fitted_on_these_features(predictor: Mapping[str, Any]) -> bool:
    """Whether ``predictor`` was fitted on the features this vp2 computes (:data:`FEATURES`,
    in order); an asset of an older vp2 may hold others."""
    return list(predictor.get("features") or []) == list(FEATURES)


def predict(
    predictor: Mapping[str, Any], row: Mapping[str, float],
    rates: Mapping[str, float] | None = None,
) -> float:
    """The predicted success fraction of a model with features ``row``. A transferred
    predictor's is rescaled by the oracles' ratio (:func:`rescale`; ``rates`` as there)."""
    if not fitted_on_these_features(predictor):
        raise ValueError(
            f"the predictor was fitted on features {predictor['features']}, this vp2 computes "
            f"{list(FEATURES)}: refit it (benchmarks.studies.diagnose_validation)"
        )
    x = (_matrix([row])[0] - np.asarray(predictor["mean"])) / np.asarray(predictor["scale"])
    p = float(_sigmoid(np.asarray(predictor["intercept"] + x @ np.asarray(predictor["weights"]))))
    return min(1.0, p * rescale(predictor, rates))


def transfer(
    predictor: Mapping[str, Any], source: str, target: str, table: str
) -> dict[str, Any]:
    """``source``'s fitted predictor applied to ``target``'s models: the same constants, the
    predicted success multiplied by the simulator oracle's success in ``target`` over that in
    ``source``, both from the shipped oracle table ``table`` (:func:`rescale`, read when the
    predictor scores, not frozen here).

    What carries over is how close a model's measures come to those of models that plan; what
    a perfect model can reach differs by environment, and the oracle measures that.
    """
    out = {k: v for k, v in predictor.items() if k not in ("validation", "transfer")}
    out["transfer"] = {"from": source, "to": target, "table": table}
    return out


def oracle_rates(table: str) -> dict[str, float]:
    """Each environment's simulator oracle success in the shipped oracle table ``table``
    (:meth:`vp2.oracle.tables.OracleTable.env_rates`).

    Raises:
        ValueError: if vp2 ships no oracle asset or no table of that name.
    """
    from vp2.oracle.shipped import load_shipped_oracle

    shipped = load_shipped_oracle()
    if shipped is None:
        raise ValueError(f"no shipped oracle asset to read table {table!r}'s rates from")
    try:
        return shipped.table(table).env_rates()
    except KeyError as exc:
        raise ValueError(exc.args[0]) from None


def rescale(predictor: Mapping[str, Any], rates: Mapping[str, float] | None = None) -> float:
    """What a transferred predictor's success is multiplied by: ``rates[to] / rates[from]``,
    ``rates`` the oracle's success per environment (default: :func:`oracle_rates` of the
    table the predictor names); 1 for a predictor fitted on its own environment.

    Raises:
        ValueError: if either rate is missing or the source's is not positive.
    """
    moved = predictor.get("transfer")
    if not moved:
        return 1.0
    source, target, table = moved.get("from"), moved.get("to"), moved.get("table")
    if rates is None:
        rates = oracle_rates(str(table))
    rate_s, rate_t = rates.get(source), rates.get(target)
    if rate_s is None or rate_t is None or rate_s <= 0:
        raise ValueError(
            f"transfer {source} -> {target} needs both oracle rates, the source's positive; "
            f"got {dict(rates)} from table {table!r}"
        )
    return float(rate_t) / float(rate_s)


def leave_one_out(
    rows: Sequence[Mapping[str, float]],
    success: Sequence[float],
    trials: Sequence[int],
    ridge: float | str = RIDGE,
) -> list[float]:
    """Each model's predicted score from a predictor fitted on all the other models. With
    ``ridge="auto"`` each fit's penalty is chosen by :func:`choose_ridge` on its own models
    only (nested: the held-out model does not choose it)."""
    out = []
    for i in range(len(rows)):
        keep = [j for j in range(len(rows)) if j != i]
        r, y, n = [rows[j] for j in keep], [success[j] for j in keep], [trials[j] for j in keep]
        penalty = choose_ridge(r, y, n) if ridge == "auto" else float(ridge)
        out.append(predict(fit(r, y, n, penalty), rows[i]))
    return out


def deviance(predicted: Sequence[float], success: Sequence[float], trials: Sequence[int]) -> float:
    """The binomial deviance's likelihood part, ``-sum n (y log p + (1 - y) log (1 - p))``: how
    badly predicted fractions explain measured ones, each weighted by its trials."""
    p = np.clip(np.asarray(predicted, np.float64), 1e-9, 1 - 1e-9)
    y, n = np.asarray(success, np.float64), np.asarray(trials, np.float64)
    return float(-np.sum(n * (y * np.log(p) + (1 - y) * np.log(1 - p))))


def choose_ridge(
    rows: Sequence[Mapping[str, float]],
    success: Sequence[float],
    trials: Sequence[int],
    grid: Sequence[float] = RIDGE_GRID,
) -> float:
    """The penalty of ``grid`` whose leave-one-out predictions have the lowest
    :func:`deviance` on these models (ties: the larger penalty); :data:`RIDGE` for fewer than
    3 models."""
    if len(rows) < 3:
        return RIDGE
    scores = [(deviance(leave_one_out(rows, success, trials, r), success, trials), -r)
              for r in grid]  # fmt: skip
    return -min(scores)[1]


def load_predictor(path: str | Path | None = None) -> dict[str, Any] | None:
    """The shipped predictor asset (or ``path``); ``None`` when there is none."""
    if path is None:
        ref = resources.files("vp2") / "assets" / "diagnose_predictor.json"
        if not ref.is_file():
            return None
        return json.loads(ref.read_text())
    return json.loads(Path(path).read_text())


def predicted_score(
    report: Mapping[str, Any], asset: Mapping[str, Any] | None,
    rates: Mapping[str, float] | None = None,
) -> tuple[float | None, str]:
    """``(score, reason)``: the report's predicted control success for its environment, or
    ``None`` and why not (no asset, no predictor fitted for the environment, the model was
    not measured: no conditioning and no planning measures, or a transferred predictor's
    oracle table is not shipped). ``rates``: as :func:`rescale` (default: the shipped table)."""
    if asset is None:
        return None, NO_PREDICTOR
    predictor = (asset.get("predictors") or {}).get(report.get("env"))
    if predictor is None:
        return None, (
            f"not fitted for {report.get('env')}: too few of its models have control runs"
        )
    planning = report.get("planning") or {}
    # Planned on some instances (a suite without scripted plans still measures the rest).
    if not (planning.get("instances") or (planning.get("scripted_plan") or {}).get("instances")):
        return None, "not predicted: the planning measures were skipped (--instances-per-task 0)"
    if not fitted_on_these_features(predictor):
        return None, (
            f"not predicted: the shipped predictor was fitted on other measures "
            f"({', '.join(predictor.get('features') or [])}) than this vp2 reports; refit it "
            "with python -m benchmarks.studies.diagnose_validation --write-asset"
        )
    validation = predictor.get("validation") or {}
    rho = validation.get("held_out_spearman")
    figure = f"Spearman {rho:+.2f} over {validation.get('models')} models" if rho is not None else None
    moved = predictor.get("transfer")
    if moved:
        try:
            rates = rates if rates is not None else oracle_rates(str(moved.get("table")))
            score = predict(predictor, features(report), rates)
        except ValueError as exc:
            return None, f"not predicted: {exc}"
        src, env = moved["from"], report.get("env")
        return score, (
            f"success fraction, the {src} predictor (fitted on {predictor.get('models_fitted')} "
            f"{src} models) times the oracles' success ratio {env}/{src}, "
            f"{rates[env]:.0%}/{rates[src]:.0%} (table {moved['table']}); "
            f"on {env} models: {figure or 'unvalidated'}"
        )
    score = predict(predictor, features(report))
    note = f"held-out {figure}" if figure else "unvalidated"
    return score, (
        f"success fraction, predictor fitted on {predictor.get('models_fitted')} models ({note})"
    )
