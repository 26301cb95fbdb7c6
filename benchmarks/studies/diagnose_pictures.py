"""What do `vp2 diagnose`'s measurements look like on a model that plans and on one that cannot?

Draws the two pictures of docs/diagnose.md from a "good" and a "bad" model:

* ``conditioning.svg``: one held-out clip (the one of the first ``--clips`` whose frames change
  most) predicted by each model with the clip's true actions and with another clip's (the
  derangement the conditioning measure uses), beside the true future; each row labelled with
  its error against the truth;
* ``measures.svg``: from the two models' ``vp2 diagnose`` reports, per instance, the scripted
  plan's rank (as a percentile of the candidates), the ranking's repeatability (Spearman ρ)
  and the effective sample size of MPPI's weights over N, with the verdicts' thresholds::

    MUJOCO_GL=egl OMP_NUM_THREADS=1 python -m benchmarks.studies.diagnose_pictures \\
        --good svg_prime:src/vp2/assets/models/svg_prime_tiny_robodesk.pt \\
        --good-report outputs/diagnose-validation/reports/shipped_svg_prime.json \\
        --bad struct_vrnn:outputs/zoo-training/snapshots/struct_vrnn-15min.pt \\
        --bad-report outputs/diagnose-validation/reports/struct_vrnn-15min.json --out docs/diagnose

The reports are those ``vp2 diagnose --model M --out FILE`` writes (the default settings).
"""

from __future__ import annotations

import base64
import html
import io
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

from benchmarks import common
from vp2.report.charts import colour

#: Future frames shown (1-based, of the model's ``num_future``).
SHOWN_FUTURE = (1, 4, 7, 10)
#: Pixels per frame side in the picture (the 64-pixel frames drawn at twice their size).
FRAME_PX = 128


def pick_clip(frames: torch.Tensor, context: int) -> int:
    """The clip whose future differs most from its last context frame (mean absolute change)."""
    change = (frames[:, context:] - frames[:, context - 1 : context]).abs().mean(dim=(1, 2, 3, 4))
    return int(change.argmax())


def predictions(spec: str, env: str, data: Path, clips: int, seed: int) -> dict[str, Any]:
    """The model's predictions of the picked clip with its true and with shuffled actions."""
    from vp2.diagnose.measures import derangement, held_out_clips
    from vp2.envs import env_class
    from vp2.models.contract import predict_in_chunks
    from vp2.run.model_spec import ModelSpec, resolve_model

    model = resolve_model(
        ModelSpec.parse(spec), {}, env=env, action_dim=int(env_class(env).action_dim),
        device=torch.device("cpu"),
    )  # fmt: skip
    c, t = int(model.num_context), int(model.num_future)
    frames, actions = held_out_clips(data, clips, seed, c, t)
    perm = derangement(len(frames), np.random.default_rng(seed))
    i = pick_clip(frames, c)
    out = {"truth": frames[i, c:], "context": frames[i, c - 1]}
    for name, acts in (("true", actions[i : i + 1]), ("shuffled", actions[perm[i] : perm[i] + 1])):
        generator = torch.Generator().manual_seed(seed)
        with torch.no_grad():
            pred = predict_in_chunks(model, frames[i : i + 1, :c], acts, generator=generator)
        out[name] = pred[0].float().clamp(0, 1)
    out["clip"], out["partner"] = i, int(perm[i])
    return out


def _png(image: np.ndarray) -> str:
    """``(H, W, 3)`` uint8 as a base64 PNG data URI."""
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(image).save(buf, format="PNG", optimize=True)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _frame(x: torch.Tensor) -> np.ndarray:
    """``(3, H, W)`` in [0, 1] -> ``(FRAME_PX, FRAME_PX, 3)`` uint8, nearest-neighbour."""
    img = (x.permute(1, 2, 0).numpy() * 255).round().astype(np.uint8)
    k = FRAME_PX // img.shape[0]
    return np.repeat(np.repeat(img, k, axis=0), k, axis=1)


def conditioning_svg(good: dict[str, Any], bad: dict[str, Any], labels: Sequence[str]) -> str:
    """The strip picture: truth, then each model with true and with shuffled actions."""
    rows = [(("true future",), None, good["truth"])]
    for label, pred in zip(labels, (good, bad), strict=True):
        for name, text in (("true", "its true actions"), ("shuffled", "another clip's actions")):
            mse = float((pred[name] - good["truth"]).square().mean())
            rows.append(((label, text), mse, pred[name]))
    gap, left, top = 4, 200, 24
    width = left + (1 + len(SHOWN_FUTURE)) * (FRAME_PX + gap)
    height = top + len(rows) * (FRAME_PX + gap)
    grid = np.full((len(rows) * (FRAME_PX + gap), (1 + len(SHOWN_FUTURE)) * (FRAME_PX + gap), 3),
                   255, np.uint8)  # fmt: skip
    for r, (_, _, seq) in enumerate(rows):
        cells = [good["context"]] + [seq[k - 1] for k in SHOWN_FUTURE]
        for col, frame in enumerate(cells):
            y, x = r * (FRAME_PX + gap), col * (FRAME_PX + gap)
            grid[y : y + FRAME_PX, x : x + FRAME_PX] = _frame(frame)
    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'font-family="sans-serif" font-size="13">',
        f'<rect width="{width}" height="{height}" fill="white"/>',
        f'<image x="{left}" y="{top}" width="{grid.shape[1]}" height="{grid.shape[0]}" '
        f'href="{_png(grid)}"/>',
    ]
    heads = ["last context frame"] + [f"t+{k}" for k in SHOWN_FUTURE]
    for col, head in enumerate(heads):
        x = left + col * (FRAME_PX + gap) + FRAME_PX / 2
        parts.append(f'<text x="{x}" y="16" text-anchor="middle">{html.escape(head)}</text>')
    for r, (lines, mse, _) in enumerate(rows):
        y = top + r * (FRAME_PX + gap) + FRAME_PX / 2 - 8 * len(lines)
        for k, line in enumerate(lines):
            parts.append(f'<text x="8" y="{y + 16 * k}">{html.escape(line)}</text>')
        if mse is not None:
            parts.append(f'<text x="8" y="{y + 16 * len(lines)}" fill="#555">MSE {mse:.4f}</text>')
    parts.append("</svg>")
    return "\n".join(parts)


def measure_values(report: dict[str, Any]) -> dict[str, list[float]]:
    """Per instance: scripted plan percentile (0 best, 1 last), ρ, ESS / N."""
    out: dict[str, list[float]] = {"rank": [], "rho": [], "ess": []}
    n = report["planning"]["spread"]["num_samples"]
    for inst in report["planning"]["instances"]:
        if inst.get("rank") is not None:
            out["rank"].append((inst["rank"] - 1) / max(inst["of"] - 1, 1))
        if inst.get("repeat_rho") is not None:
            out["rho"].append(inst["repeat_rho"])
        if inst.get("ess") is not None:
            out["ess"].append(inst["ess"] / n)
    return out


#: (key, title, the verdict's threshold, what the threshold separates)
PANELS = (
    ("rank", "scripted plan's rank among the candidates (0 = best, 1 = last)", 0.1,
     "top 10%"),
    ("rho", "ranking repeatability across model noise (Spearman ρ)", 0.7, "repeats ≥ 0.7"),
    ("ess", "effective sample size of MPPI's weights / N", 0.9, "flat > 0.9"),
)  # fmt: skip


def measures_svg(values: Sequence[dict[str, list[float]]], labels: Sequence[str]) -> str:
    """Strip plots, one panel per measure, one row of dots per model."""
    left, right, width, row_h, panel_gap = 190, 110, 720, 26, 40
    plot_w = width - left - right
    panel_h = len(labels) * row_h + 50
    height = len(PANELS) * (panel_h + panel_gap)
    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
        f'font-family="sans-serif" font-size="12">',
        f'<rect width="{width}" height="{height}" fill="white"/>',
    ]
    for p, (key, title, threshold, note) in enumerate(PANELS):
        y0 = p * (panel_h + panel_gap) + 18
        parts.append(f'<text x="8" y="{y0}" font-weight="bold">{html.escape(title)}</text>')
        top, bottom = y0 + 26, y0 + 26 + len(labels) * row_h
        parts.append(f'<rect x="{left}" y="{top}" width="{plot_w}" height="{bottom - top}" '
                     f'fill="none" stroke="#999"/>')  # fmt: skip
        for tick in (0, 0.25, 0.5, 0.75, 1.0):
            x = left + tick * plot_w
            parts.append(f'<line x1="{x}" x2="{x}" y1="{top}" y2="{bottom}" stroke="#eee"/>')
            parts.append(f'<text x="{x}" y="{bottom + 14}" text-anchor="middle">{tick:g}</text>')
        tx = left + threshold * plot_w
        parts.append(f'<line x1="{tx}" x2="{tx}" y1="{top}" y2="{bottom}" stroke="#c00" '
                     f'stroke-dasharray="4 3"/>')  # fmt: skip
        parts.append(f'<text x="{tx + 4}" y="{top - 2}" fill="#c00">{html.escape(note)}</text>')
        for m, label in enumerate(labels):
            y = top + (m + 0.5) * row_h
            vals = values[m][key]
            summary = f"median {np.median(vals):.2f}" if vals else "undefined"
            parts.append(f'<text x="8" y="{y + 4}">{html.escape(label)}</text>')
            parts.append(f'<text x="{left + plot_w + 10}" y="{y + 4}" fill="#555">'
                         f"{summary}</text>")  # fmt: skip
            jitter = np.random.default_rng(m).uniform(-0.3, 0.3, len(vals)) * row_h
            for v, j in zip(vals, jitter, strict=True):
                x = left + float(np.clip(v, 0, 1)) * plot_w
                parts.append(f'<circle cx="{x:.1f}" cy="{y + j:.1f}" r="4" fill="{colour(m)}" '
                             f'fill-opacity="0.7"/>')  # fmt: skip
    parts.append("</svg>")
    return "\n".join(parts)


def main(argv: Sequence[str] | None = None) -> None:
    parser = common.argument_parser(__spec__.name, __doc__ or "")
    parser.add_argument("--good", required=True, help="model spec of a model that plans")
    parser.add_argument("--bad", required=True, help="model spec of a model that cannot")
    parser.add_argument("--good-report", type=Path, required=True, help="its vp2 diagnose report")
    parser.add_argument("--bad-report", type=Path, required=True, help="its vp2 diagnose report")
    parser.add_argument("--good-label", default="shipped SVG′")
    parser.add_argument("--bad-label", default="Struct-VRNN, 15 core-min")
    parser.add_argument("--env", default="robodesk")
    parser.add_argument("--data", type=Path, help="dataset (default: the environment's default)")
    parser.add_argument("--clips", type=int, default=64, help="held-out clips to pick from")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("docs/diagnose"))
    args = parser.parse_args(argv)
    from vp2.data.datasets import default_dataset

    data = args.data or default_dataset(args.env)
    labels = (args.good_label, args.bad_label)
    good = predictions(args.good, args.env, data, args.clips, args.seed)
    bad = predictions(args.bad, args.env, data, args.clips, args.seed)
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "conditioning.svg").write_text(conditioning_svg(good, bad, labels))
    reports = [json.loads(p.read_text()) for p in (args.good_report, args.bad_report)]
    values = [measure_values(r) for r in reports]
    (args.out / "measures.svg").write_text(measures_svg(values, labels))
    print(f"clip {good['clip']} (actions of clip {good['partner']} for the shuffled rows)")
    for label, r, v in zip(labels, reports, values, strict=True):
        cond = r["action_conditioning"]
        print(f"{label}: conditioning {cond.get('ratio', float('nan')):.3f} {cond.get('ci')}; "
              + ", ".join(f"{k} median {np.median(x):.3f}" if x else f"{k} undefined"
                          for k, x in v.items()))  # fmt: skip
    print(f"wrote {args.out / 'conditioning.svg'} and {args.out / 'measures.svg'}")


if __name__ == "__main__":
    main()
