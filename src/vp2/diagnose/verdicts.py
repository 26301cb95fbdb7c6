"""The verdicts of ``vp2 diagnose`` (:mod:`vp2.diagnose.model`): the planning measures
summarised over instances, one ``{"status", "text"}`` per measure from fixed thresholds (the
constants below, listed in ``docs/diagnose.md``), and the printed lines.

============================  =================================================================
measure                       statuses
============================  =================================================================
``action_conditioning``       ``uses``, ``weak``, ``blind``, ``inverted``, ``skipped``
``scripted_plan``             ``preferred``, ``not_preferred``, ``skipped``
``repeatability``             ``repeats``, ``partial``, ``noise``, ``undefined``, ``skipped``
``spread``                    ``steers``, ``flat``, ``skipped``
``direction``                 ``varies``, ``biased``, ``undefined``, ``skipped``
``oracle_agreement``          ``agrees``, ``partial``, ``disagrees``, ``skipped``
============================  =================================================================
"""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from typing import Any

from vp2 import spec
from vp2.diagnose.measures import AGREEMENT_TOP_FRACTION, cross_task_cosine

#: A conditioning ratio whose 95% interval holds 1 and stays below WEAK_RATIO: "does not
#: depend on the actions"; one that holds 1 and reaches WEAK_RATIO: "inconclusive" (too few
#: clips to tell); an interval above 1 with a ratio below WEAK_RATIO: "depends, weakly".
WEAK_RATIO = 1.05
#: Median Spearman ρ between the two scorings: below REPEAT_NOISE the ranking is noise, from
#: REPEAT_FIRM on it repeats.
REPEAT_NOISE = 0.3
REPEAT_FIRM = 0.7
#: Median ESS / N of MPPI's weights above this: the scores are too flat to steer MPPI.
FLAT_ESS_FRACTION = 0.9
#: The scripted plan "ranks well" within this top fraction of the candidates.
TOP_FRACTION = 0.10
#: Mean cross-task cosine of the plan shifts from this on: one direction whatever the goal;
#: judged only with shifts on at least BIAS_MIN_TASKS tasks.
BIAS_COSINE = 0.7
BIAS_MIN_TASKS = 3
#: Median Spearman ρ between the model's and the simulator's scores of the candidates: from
#: AGREE_FIRM on the model ranks them much as the simulator does, below AGREE_NONE not at all.
AGREE_NONE = 0.2
AGREE_FIRM = 0.5


def _median(values: Sequence[float]) -> float | None:
    return float(statistics.median(values)) if values else None


def summarize_planning(rows: Sequence[dict[str, Any]], num_samples: int) -> dict[str, Any]:
    """The planning measures over instances: medians, the top fraction, the cross-task
    cosine (``None`` where no instance defines a value)."""
    ranks = [r["rank"] for r in rows if r["rank"] is not None]
    top = max(1, int(TOP_FRACTION * (num_samples + 1)))
    rhos = [r["repeat_rho"] for r in rows if r["repeat_rho"] is not None]
    cosine, pairs = cross_task_cosine(rows)
    agreed = [r for r in rows if r.get("oracle_rho") is not None]
    return {
        "scripted_plan": {
            "instances": len(ranks),
            "of": num_samples + 1,
            "median_rank": _median(ranks),
            "top": top,
            "top_fraction": sum(r <= top for r in ranks) / len(ranks) if ranks else None,
        },
        "repeatability": {
            "instances": len(rows),
            "defined": len(rhos),
            "median_rho": _median(rhos),
        },
        "spread": {
            "gamma": rows[0]["gamma"] if rows else spec.GAMMA,
            "median_gamma_spread": _median([r["gamma_spread"] for r in rows]),
            "median_ess": _median([r["ess"] for r in rows]),
            "num_samples": num_samples,
        },
        "direction": {
            "mean_cross_task_cosine": cosine,
            "pairs": pairs,
            "tasks": len({r["task"] for r in rows if r["shift"] is not None}),
        },
        "oracle_agreement": {
            "instances": len(agreed),
            "median_rho": _median([r["oracle_rho"] for r in agreed]),
            "best_in_top_fraction": (
                sum(bool(r["oracle_best_in_top"]) for r in agreed) / len(agreed) if agreed else None
            ),
        },
    }


# --------------------------------------------------------------------------- verdicts


def _over_trajectories(c: dict[str, Any]) -> str:
    """``, a-b over N trajectories`` where the measure has that interval (reports before it
    did not)."""
    if "trajectory_ci" not in c:
        return ""
    low, high = c["trajectory_ci"]
    return f", {low:.3f}-{high:.3f} over {c['trajectories']} trajectories"


def conditioning_verdict(result: dict[str, Any]) -> dict[str, str]:
    """``{"status", "text"}`` of the conditioning measure (thresholds: module constants)."""
    if "skipped" in result:
        return {"status": "skipped", "text": f"not measured: {result['skipped']}"}
    low, high = result["ci"]
    if low <= 1.0 <= high and high >= WEAK_RATIO:
        return {"status": "inconclusive", "text": "not settled on these clips: the interval "
                f"holds 1 but also a {high - 1:.0%} rise of the error; measure on more clips "
                f"than these {result['clips']} (vp2 diagnose --clips {4 * result['clips']})"}
    if low <= 1.0 <= high:
        return {"status": "blind", "text": "predictions do not depend on the actions: it will "
                "plan like repeat-last-frame"}
    if high < 1.0:
        return {"status": "inverted", "text": "predictions are worse with the true actions than "
                "with other clips': check the action alignment (actions[k] is executed in frame "
                "k and produces frame k + 1)"}
    if result["ratio"] < WEAK_RATIO:
        return {"status": "weak", "text": "predictions depend on the actions, weakly (shuffling "
                f"them raises the error by {result['ratio'] - 1:.1%})"}
    return {"status": "uses", "text": "predictions depend on the actions"}


def verdicts(report: dict[str, Any]) -> dict[str, dict[str, str]]:
    """One ``{"status", "text"}`` per measure of a report (docs/diagnose.md lists them)."""
    planning = report["planning"]
    out = {"action_conditioning": conditioning_verdict(report["action_conditioning"])}
    if not planning["instances"]:
        skipped = {"status": "skipped", "text": "not measured: no instance probed"}
        return out | dict.fromkeys(
            ("scripted_plan", "repeatability", "spread", "direction", "oracle_agreement"), skipped
        )
    scripted = planning["scripted_plan"]
    if not scripted["instances"]:
        out["scripted_plan"] = {"status": "skipped",
                                "text": "not measured: the instances store no scripted plan"}
    elif scripted["top_fraction"] == 0:
        out["scripted_plan"] = {"status": "not_preferred", "text": "the cost does not prefer the "
                                f"scripted plan: it is never in the top {TOP_FRACTION:.0%} of the "
                                "candidates"}
    else:
        hits = round(scripted["top_fraction"] * scripted["instances"])
        out["scripted_plan"] = {"status": "preferred", "text": "the cost prefers the scripted "
                                f"plan on {hits} of {scripted['instances']} instances"}
    rho = planning["repeatability"]["median_rho"]
    if rho is None:
        out["repeatability"] = {"status": "undefined",
                                "text": "undefined: every candidate gets the same score"}
    elif rho < REPEAT_NOISE:
        out["repeatability"] = {"status": "noise", "text": "the ranking is noise: MPPI follows "
                                "the model's sampling noise, not the actions"}
    elif rho < REPEAT_FIRM:
        out["repeatability"] = {"status": "partial",
                                "text": "the ranking repeats only in part across the model's noise"}
    else:
        out["repeatability"] = {"status": "repeats",
                                "text": "the ranking repeats across the model's noise"}
    spread = planning["spread"]
    if spread["median_ess"] > FLAT_ESS_FRACTION * spread["num_samples"]:
        out["spread"] = {"status": "flat", "text": "the scores are too flat to steer MPPI: it "
                         "executes the mean of its samples, as with repeat-last-frame"}
    else:
        out["spread"] = {"status": "steers", "text": "the scores move MPPI's weights"}
    direction = planning["direction"]
    cosine = direction["mean_cross_task_cosine"]
    if cosine is None or direction["tasks"] < BIAS_MIN_TASKS:
        out["direction"] = {"status": "undefined", "text": "not judged: the weights move the plan "
                            f"on fewer than {BIAS_MIN_TASKS} tasks"}
    elif cosine >= BIAS_COSINE:
        out["direction"] = {"status": "biased",
                            "text": "a bias toward one direction regardless of the goal"}
    else:
        out["direction"] = {"status": "varies", "text": "the planned direction changes with the task"}
    agree = planning.get("oracle_agreement") or {}
    rho = agree.get("median_rho")
    if not agree.get("instances") or rho is None:
        out["oracle_agreement"] = {"status": "skipped", "text": "not measured: no simulator scores "
                                   "(--no-oracle-agreement, or a model that is the simulator)"}
    elif rho >= AGREE_FIRM:
        out["oracle_agreement"] = {"status": "agrees", "text": "the model ranks the candidates "
                                   "much as the simulator does"}
    elif rho >= AGREE_NONE:
        out["oracle_agreement"] = {"status": "partial", "text": "the model ranks the candidates "
                                   "only partly as the simulator does"}
    else:
        out["oracle_agreement"] = {"status": "disagrees", "text": "the model's ranking of the "
                                   "candidates is not the simulator's: its favourites are not "
                                   "what would happen"}
    return out


# --------------------------------------------------------------------------- output


def _f(x: float | None, fmt: str) -> str:
    return "-" if x is None else format(x, fmt)


def format_report(report: dict[str, Any]) -> list[str]:
    """The printed lines: a header, one line per measure with its verdict, the predicted score
    and the wall time."""
    v = report["verdicts"]
    c = report["action_conditioning"]
    p = report["planning"]
    n = len(p["instances"])
    lines = [f"{report['model']['name']} ({report['model']['spec']}) on {report['env']}"]
    if "skipped" in c:
        lines.append(f"action conditioning: {v['action_conditioning']['text']}")
    else:
        lines.append(
            f"action conditioning: shuffled/true error ratio {c['ratio']:.3f} [95% CI "
            f"{c['ci'][0]:.3f}-{c['ci'][1]:.3f} over clips{_over_trajectories(c)}], "
            f"{c['wins']}/{c['clips']} held-out clips better with the true actions -> "
            f"{v['action_conditioning']['text']}"
        )
    s = p["scripted_plan"]
    if s["instances"]:
        lines.append(
            f"scripted plan: median rank {_f(s['median_rank'], 'g')} of {s['of']}, in the top "
            f"{s['top']} on {round(s['top_fraction'] * s['instances'])} of {s['instances']} "
            f"instances -> {v['scripted_plan']['text']}"
        )
    else:
        lines.append(f"scripted plan: {v['scripted_plan']['text']}")
    r = p["repeatability"]
    lines.append(
        f"ranking repeatability: Spearman {_f(r['median_rho'], '+.2f')} (median over "
        f"{r['defined']} of {r['instances']} instances) -> {v['repeatability']['text']}"
    )
    sp = p["spread"]
    lines.append(
        f"score spread: gamma*spread {_f(sp['median_gamma_spread'], '.3g')}, ESS "
        f"{_f(sp['median_ess'], '.1f')} of {sp['num_samples']} (medians over {n} instances) -> "
        f"{v['spread']['text']}"
    )
    d = p["direction"]
    lines.append(
        f"direction: mean cosine {_f(d['mean_cross_task_cosine'], '+.2f')} between plan shifts "
        f"of different tasks ({d['tasks']} tasks) -> {v['direction']['text']}"
    )
    a = p.get("oracle_agreement") or {}
    if a.get("instances"):
        lines.append(
            f"agreement with the simulator: Spearman {_f(a['median_rho'], '+.2f')} (median over "
            f"{a['instances']} instances), its best candidate in the model's top "
            f"{AGREEMENT_TOP_FRACTION:.0%} on {round(a['best_in_top_fraction'] * a['instances'])} "
            f"-> {v['oracle_agreement']['text']}"
        )
    elif "oracle_agreement" in v:
        lines.append(f"agreement with the simulator: {v['oracle_agreement']['text']}")
    score = report.get("predicted_control_score")
    reason = report["predicted_control_score_reason"]
    lines.append(
        f"predicted control score: {reason}" if score is None
        else f"predicted control score: {100 * score:.0f}% success ({reason})"
    )
    lines.append(f"wall time {report['timing']['total_s']:.1f} s")
    return lines
