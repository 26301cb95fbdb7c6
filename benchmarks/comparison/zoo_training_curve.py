"""What :mod:`benchmarks.comparison.zoo_training` publishes from its curve points
(``curve/<family>-<L>min.json``): the table ``curve.md``, the chart ``curve.svg`` and the zoo
card fields of a round's snapshot (``--card``)."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vp2.data.datasets import default_dataset
from vp2.envs import ENV_NAMES
from vp2.report.charts import line_chart


def _label(level: float) -> str:
    return f"{level:g}min"


def target_interval(c: dict[str, Any]) -> list[float]:
    """The interval the target is judged on: over the clips' trajectories where measured (the
    clips of one trajectory are not independent draws), else over clips (points measured
    before the trajectory interval existed)."""
    return c.get("trajectory_ci") or c["ci"]


def _interval(c: dict[str, Any], key: str) -> str:
    return "–" if key not in c else f"[{c[key][0]:.3f}, {c[key][1]:.3f}]"


def read_points(out: Path) -> list[dict[str, Any]]:
    """Every curve point under ``out``, by family then level."""
    points = [json.loads(p.read_text()) for p in sorted((out / "curve").glob("*.json"))]
    return sorted(points, key=lambda r: (r["family"], r["level_minutes"]))


def curve_markdown(points: Sequence[dict[str, Any]], target: float, command: str) -> str:
    """The curve as a Markdown table, one row per point."""
    lines = [
        "# Action conditioning along training",
        "",
        f"Command: `{command}`",
        "",
        "Ratio of held-out prediction error under shuffled vs true actions, with 95% bootstrap "
        "intervals over clips and over the clips' trajectories (whole trajectories resampled; "
        "– where a point predates that interval); target: the interval over trajectories (else "
        f"over clips) wholly above {target:g}.",
        "",
        "| family | budget (min) | minutes used | steps | ratio | 95% CI, clips | "
        "95% CI, trajectories | changing pixels | wins | valid MSE | above target |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in points:
        c, m = r["conditioning"], r["conditioning_moving"]
        mse = r.get("valid", {}).get("valid/pred_mse")
        lines.append(
            f"| {r['family']} | {r['level_minutes']:g} | {r['train_minutes']:.1f} | {r['step']} | "
            f"{c['ratio']:.3f} | {_interval(c, 'ci')} | {_interval(c, 'trajectory_ci')} | "
            f"{m['ratio']:.3f} | {c['wins']}/{c['clips']} | "
            f"{'–' if mse is None else f'{mse:.5f}'} | {'yes' if r['above_target'] else 'no'} |"
        )
    return "\n".join(lines) + "\n"


def curve_svg(points: Sequence[dict[str, Any]], target: float, clock: str = "cpu") -> str:
    """The ratio against training minutes, one line per family, the target dashed."""
    series: dict[str, list[tuple[float, float, float, float]]] = {}
    for r in points:
        c = r["conditioning"]
        series.setdefault(r["family"], []).append(
            (r["train_minutes"], c["ratio"], *target_interval(c))
        )
    return line_chart(
        series,
        x_label="training time (core-minutes)" if clock == "cpu" else "training wall time (min)",
        y_label="shuffled / true error",
        reference=(target, f"target {target:g}"),
        title="Action conditioning on held-out clips along training",
    )


def card_fields(record: dict[str, Any], command: str) -> dict[str, Any]:
    """The zoo card fields a round's snapshot has from its training and its conditioning
    measure (``vp2 zoo add SNAPSHOT --card-from`` takes them; ``--control``/``--metrics`` the
    rest): budget, device, dataset commands, ``action_conditioning``, ``rebuild``, notes."""
    c, moving = record["conditioning"], record["conditioning_moving"]
    data, family, level = record["settings"]["data"], record["family"], record["level_minutes"]
    date = record["date"][:10]
    collect = [f"vp2 collect {env}" for env in ENV_NAMES if Path(data) == default_dataset(env)]
    clock = "core" if record["settings"]["clock"] == "cpu" else "wall"
    return {
        "dataset": {"made_with": collect or None},
        "budget": {
            "wall_minutes": None if clock == "core" else round(record["train_minutes"], 1),
            "core_minutes": round(record["train_minutes"], 1) if clock == "core" else None,
            "cores": "one CPU core (the process's CPU time, one torch thread)"
            if clock == "core" else None,
            "date": date,
            "note": f"round {_label(level)} of the zoo training: every family gets the same "
            f"{clock}-minutes; batch {record['settings']['batch_size']}, the family's own "
            "learning rate",
        },  # fmt: skip
        "device": record["device"],
        "action_conditioning": {
            "ratio": round(c["ratio"], 3),
            "interval": [round(c["ci"][0], 3), round(c["ci"][1], 3)],
            "clips": c["clips"],
            **({} if "trajectory_ci" not in c else {
                "trajectory_interval": [round(v, 3) for v in c["trajectory_ci"]],
                "trajectories": c["trajectories"],
            }),
            "samples": record["settings"]["samples"],
            "changing_pixels": {"ratio": round(moving["ratio"], 3),
                                "interval": [round(v, 3) for v in moving["ci"]]},
            "true_wins": f"{c['wins']} of {c['clips']} clips (sign test p = {c['sign_p']:.2g})",
            "dataset": f"{data} (held-out clips)",
            "date": date,
            "command": command,
            "note": "measured by the zoo training after the round (vp2.diagnose.model."
            "measure_conditioning, as vp2 diagnose does)"
            + (f"; measured again on {record['remeasured'][:10]} for the interval over "
               "trajectories (--remeasure: the same ratio)" if record.get("remeasured") else "")
            + f"; MSE per pixel with the true actions {c['mse_true']:.5f}, with another clip's "
            f"{c['mse_shuffled']:.5f}",
        },  # fmt: skip
        "rebuild": [*collect, command],
        "notes": f"{family} after {_label(level)} of the zoo training; the snapshot "
        f"snapshots/{family}-{_label(level)}.pt of the command's output folder",
    }
