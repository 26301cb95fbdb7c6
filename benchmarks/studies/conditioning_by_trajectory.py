"""How sure is an action-conditioning ratio? Every held-out clip, intervals over trajectories.

The action-conditioning ratio (prediction error under another clip's actions over the clip's
own, :func:`vp2.diagnose.measures.conditioning_errors`) is usually measured on 64
clips drawn from a dataset's ``valid`` split. The clips are windows of a few trajectories (the
default RoboDesk dataset's 350 valid clips come from 14), so clips of one trajectory are not
independent draws, and an interval over clips is narrower than the evidence; ``vp2 diagnose``
therefore gives an interval over the clips' trajectories beside it
(:func:`vp2.diagnose.measures.trajectory_interval`). This study measures the ratio on
**every** valid clip (or ``--clips`` of them) with both 95% intervals: the bootstrap over
clips, and the bootstrap over trajectories (each resample draws whole trajectories with all
their clips).

Example::

    OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.studies.conditioning_by_trajectory \\
        --model zoo:maskvit-robodesk-120min --data data/robodesk-20x-64px
"""

from __future__ import annotations

import numpy as np
import torch

from benchmarks import common
from vp2.data.loader import ClipDataset, select_clips
from vp2.data.storage import load_manifest
from vp2.diagnose.measures import (
    conditioning_errors,
    ratio_statistics,
)
from vp2.run.model_spec import resolve_model

CONTEXT, FUTURE = 2, 10


def valid_clips(data: str, clips: int | None) -> tuple[torch.Tensor, torch.Tensor, np.ndarray]:
    """Frames, actions and trajectory index of every valid clip (or ``clips`` of them, drawn as
    ``vp2 diagnose`` draws them)."""
    dataset = ClipDataset(data, split="valid", context=CONTEXT, future=FUTURE)
    try:
        indices = (range(len(dataset)) if clips is None
                   else select_clips(len(dataset), clips, seed=0))
        items = [dataset[i] for i in indices]
        trajectory = np.array([dataset.trajectory(i) for i in indices])
    finally:
        dataset.close()
    return (torch.stack([it["frames"] for it in items]),
            torch.stack([it["actions"] for it in items]).float(),
            trajectory)


def measure(model, frames: torch.Tensor, actions: torch.Tensor, trajectory: np.ndarray,
            samples: int, batch: int = 64) -> dict:
    """The ratio on the clips, with its interval over clips and over trajectories."""
    true, shuffled = [], []
    for start in range(0, len(frames), batch):
        errors = conditioning_errors(model, frames[start:start + batch],
                                     actions[start:start + batch], samples, seed=0,
                                     device=torch.device("cpu"))
        true.append(np.asarray(errors["true"]))
        shuffled.append(np.asarray(errors["shuffled"]))
    true_all, shuffled_all = np.concatenate(true), np.concatenate(shuffled)
    stats = ratio_statistics(true_all, shuffled_all, trajectory=trajectory)
    return {
        "clips": len(frames),
        "trajectories": stats["trajectories"],
        "ratio": stats["ratio"],
        "clip_interval": stats["ci"],
        "trajectory_interval": stats["trajectory_ci"],
    }


def main(argv: list[str] | None = None) -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--model", required=True, nargs="+", help="model specs (zoo:NAME, ...)")
    parser.add_argument("--data", required=True, help="dataset folder (its valid split)")
    parser.add_argument("--clips", type=int, help="clips drawn as vp2 diagnose draws them "
                        "(default: every valid clip)")
    parser.add_argument("--samples", type=int, default=2, help="sampling seeds per clip")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    env = load_manifest(args.data).get("config", {}).get("env", "robodesk")
    frames, actions, trajectory = valid_clips(args.data, args.clips)  # once, for every model
    print("| model | clips | ratio | 95% CI over clips | 95% CI over trajectories |")
    print("|---|---|---|---|---|")
    for spec in args.model:
        model = resolve_model(spec, {}, env=env, action_dim=actions.shape[-1], device="cpu")
        r = measure(model, frames, actions, trajectory, args.samples)
        c, t = r["clip_interval"], r["trajectory_interval"]
        print(f"| {spec} | {r['clips']} of {r['trajectories']} trajectories | {r['ratio']:.3f} | "
              f"[{c[0]:.3f}, {c[1]:.3f}] | [{t[0]:.3f}, {t[1]:.3f}] |", flush=True)


if __name__ == "__main__":
    main()
