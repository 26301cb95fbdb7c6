"""Did a model change what the planner did? Its runs' executed actions against a reference run's.

    .venv/bin/python -m benchmarks.studies.executed_actions \\
        --reference outputs/comparison-v1/runs/repeat_last_frame \\
        outputs/comparison-v1/runs/fitvid outputs/comparison-v1/runs/struct_vrnn \\
        outputs/comparison-v1/runs/svg_prime

A model whose predictions do not depend on the actions gives every MPPI candidate the same cost,
so the planner executes the weighted mean of its samples with equal weights, whatever the
model. ``repeat_last_frame`` is such a model by construction. Trials of the same task, instance
and seed draw the same samples, so a run whose executed actions stay within a few thousandths
of repeat-last-frame's (actions are in [-1, 1]) planned as if it had no model; a model that
uses its actions moves them by tenths.

Per run: trials paired with the reference, the largest absolute difference of any executed
action component per trial (median and max over trials), the mean absolute x/y/z action and
the length of the summed x/y/z displacement command (how far the planner asked the arm to go).
Reads only ``trials.jsonl``; runs nothing.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from benchmarks import common
from vp2.run.results import is_ok, trial_key
from vp2.run.run_dir import RunDir


def executed(run_dir: Path) -> dict[tuple, np.ndarray]:
    """``(task, instance, seed) -> (T, A)`` executed actions of a run's finished trials (those
    its config covers, as its summary counts them)."""
    out = {}
    for record in RunDir(run_dir).split_trials()[0]:
        if is_ok(record):
            out[trial_key(record)] = np.asarray(record["actions"], dtype=np.float64)
    return out


def compare(reference: dict[tuple, np.ndarray], run: dict[tuple, np.ndarray]) -> dict:
    """The statistics of one run against the reference (see the module docstring)."""
    keys = [k for k in run if k in reference]
    if not keys:
        raise ValueError("no trial of this run has the same task, instance and seed as the reference")
    diffs = [float(np.abs(run[k] - reference[k]).max()) for k in keys]
    xyz = [run[k][1:, :3] for k in keys]  # step 0 executes the zero action (SPEC)
    return {
        "paired_trials": len(keys),
        "max_abs_diff_median": float(np.median(diffs)),
        "max_abs_diff_max": float(np.max(diffs)),
        "mean_abs_xyz": float(np.mean([np.abs(a).mean() for a in xyz])),
        "net_xyz_command": float(np.mean([np.linalg.norm(a.sum(0)) for a in xyz])),
    }


def main() -> None:
    p = common.argument_parser(__spec__.name, __doc__)
    p.add_argument("runs", nargs="+", type=Path, help="vp2 run folders to compare")
    p.add_argument("--reference", type=Path, required=True, help="the reference vp2 run folder")
    p.add_argument("--json", type=Path, help="also write the rows here")
    args = p.parse_args()
    reference = executed(args.reference)
    rows = {}
    print("| run | paired trials | max abs diff per trial: median | max | mean abs x/y/z | "
          "net x/y/z command |")
    print("|---|---|---|---|---|---|")
    for run in [args.reference, *args.runs]:
        try:
            r = compare(reference, executed(run))
        except ValueError as exc:
            raise SystemExit(f"executed_actions.py: {run}: {exc}") from None
        rows[str(run)] = r
        print(f"| {run.name} | {r['paired_trials']} | {r['max_abs_diff_median']:.4f} | "
              f"{r['max_abs_diff_max']:.4f} | {r['mean_abs_xyz']:.3f} | {r['net_xyz_command']:.2f} |")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
