"""Does a success classifier inform the planner away from success? Mean logit vs steps to success.

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.studies.classifier_logit_curve \\
        --data data/robodesk-500x-64px [--classifiers DIR] [--out docs/classifier-logit-curve.png]

Along the held-out (``valid``) scripted trajectories of every RoboDesk task that reach strict
success, each frame ``t`` is ``d = k - t`` steps before the first successful frame ``k``
(negative after it). The script runs the task's classifier on every frame and reports the mean
logit per ``d``: a classifier that can guide MPPI rises toward success instead of sitting flat
at a floor. Trajectories that never succeed give the reference "never" column. Prints a
Markdown table and writes a PNG line chart (one line per task).
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import h5py
import numpy as np
import torch
from PIL import Image, ImageDraw

from benchmarks import common
from vp2.classifiers import (
    ASSETS_DIR,
    CLASSIFIER_TASKS,
    load_classifier,
    shipped_path,
    short_task,
    to_tensor,
)
from vp2.data.storage import dataset_index
from vp2.report.charts import PALETTE

COLUMNS = (15, 10, 8, 6, 4, 3, 2, 1, 0, -2, -5)


def logit_curves(data: Path, classifiers: Path, task: str, max_d: int) -> tuple[dict, list]:
    """Mean logit per steps-to-success ``d`` (``-max_d..max_d``) and the never-successful logits."""
    model = load_classifier(shipped_path(task, classifiers))
    records = [r for r in dataset_index(data) if r.task == f"robodesk/{task}" and r.split == "valid"]
    by_d: dict[int, list[float]] = defaultdict(list)
    never: list[float] = []
    for r in records:
        with h5py.File(r.path, "r") as f:
            g = f["data"][r.name]
            frames, success = g["obs/rgb"][()], g["success"][()].astype(bool)
        with torch.no_grad():
            logits = model(to_tensor(frames)).numpy()
        if not success.any():
            never += logits.tolist()
            continue
        k = int(np.argmax(success))
        for t, logit in enumerate(logits):
            d = k - t
            if -max_d <= d <= max_d:
                by_d[d].append(float(logit))
    return {d: (float(np.mean(v)), len(v)) for d, v in sorted(by_d.items())}, never


def draw(curves: dict[str, dict], out: Path, max_d: int) -> None:
    """A PNG line chart: x = steps to success (decreasing to the right), y = mean logit."""
    w, h, left, right, top, bottom = 760, 440, 60, 190, 30, 50
    img = Image.new("RGB", (w, h), "white")
    dr = ImageDraw.Draw(img)
    values = [m for c in curves.values() for m, _ in c.values()]
    lo, hi = min(values + [0.0]), max(values + [0.0])
    pad = 0.05 * (hi - lo or 1.0)
    lo, hi = lo - pad, hi + pad

    def xy(d: float, v: float) -> tuple[float, float]:
        x = left + (max_d - d) / (2 * max_d) * (w - left - right)
        y = top + (hi - v) / (hi - lo) * (h - top - bottom)
        return x, y

    dr.rectangle([left, top, w - right, h - bottom], outline="black")
    for v in np.linspace(lo, hi, 6):
        _, y = xy(0, v)
        dr.line([left - 4, y, left, y], fill="black")
        dr.text((5, y - 6), f"{v:.1f}", fill="black")
    for d in range(-max_d, max_d + 1, 5):
        x, _ = xy(d, lo)
        dr.line([x, h - bottom, x, h - bottom + 4], fill="black")
        dr.text((x - 6, h - bottom + 6), str(d), fill="black")
    x0, y0 = xy(0, lo)
    dr.line([x0, top, x0, h - bottom], fill=(180, 180, 180))
    _, yz = xy(0, 0.0)
    dr.line([left, yz, w - right, yz], fill=(180, 180, 180))
    dr.text((left, h - 22), "steps to first success (0 = success; negative: after it)", fill="black")
    dr.text((left, 8), "mean classifier logit along held-out scripted trajectories", fill="black")
    for i, (task, curve) in enumerate(curves.items()):
        colour = PALETTE[i % len(PALETTE)]
        pts = [xy(d, m) for d, (m, _) in curve.items()]
        if len(pts) > 1:
            dr.line(pts, fill=colour, width=2)
        dr.line([w - right + 10, top + 18 * i + 6, w - right + 30, top + 18 * i + 6], fill=colour, width=3)
        dr.text((w - right + 35, top + 18 * i), task, fill="black")
    out.parent.mkdir(parents=True, exist_ok=True)
    img.save(out)


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--data", type=Path, required=True, help="rendered RoboDesk dataset")
    parser.add_argument("--classifiers", type=Path, default=ASSETS_DIR)
    parser.add_argument("--tasks", nargs="+", default=[short_task(t) for t in CLASSIFIER_TASKS])
    parser.add_argument("--max-d", type=int, default=15)
    parser.add_argument("--out", type=Path, default=Path("outputs/classifier-logit-curve.png"))
    args = parser.parse_args()
    torch.set_num_threads(1)
    curves = {}
    print("| task | " + " | ".join(f"d={d}" for d in COLUMNS) + " | never succeeds |")
    print("|---|" + "---|" * (len(COLUMNS) + 1))
    for task in args.tasks:
        curve, never = logit_curves(args.data, args.classifiers, task, args.max_d)
        curves[task] = curve
        cells = [f"{curve[d][0]:.1f}" if d in curve else "" for d in COLUMNS]
        ref = f"{np.mean(never):.1f} ({len(never)} frames)" if never else "-"
        print(f"| {task} | " + " | ".join(cells) + f" | {ref} |", flush=True)
    draw(curves, args.out, args.max_d)
    print(f"\nchart: {args.out}")


if __name__ == "__main__":
    main()
