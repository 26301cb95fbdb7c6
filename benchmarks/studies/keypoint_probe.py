"""Does a Struct-VRNN's keypoint bottleneck carry the motion, or has it collapsed?

A Struct-VRNN can use its actions only through its keypoints: the dynamics move keypoints, and
the decoder draws a frame from them on top of the first frame. If the detector's keypoints do
not follow what moves, or the decoder draws the same frame whatever keypoints it gets, the
predicted video cannot depend on the actions, however well the dynamics learn. This study
measures each link on held-out clips of a dataset's ``valid`` split:

* **detector**: how far the detected keypoints move across a clip (coordinates in [-1, 1], so
  0.03 is one pixel at 64x64) and their intensities;
* **decoder**: the reconstruction error of every frame drawn from its own detected keypoints,
  against the same frames drawn from the first frame's keypoints held still. Equal errors:
  the decoder ignores the keypoints;
* **dynamics**: how far the predicted keypoints move when the actions are swapped between
  clips (the prior's mean, no sampling noise), and their error against the detected ones.

Example::

    OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.studies.keypoint_probe \\
        --model outputs/zoo-training/snapshots/struct_vrnn-30min.pt \\
        --data data/robodesk-20x-64px --clips 64 --out outputs/keypoint-probe.json
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import torch

from benchmarks import common
from vp2.diagnose.measures import held_out_clips
from vp2.models.registry import load_model
from vp2.models.struct_vrnn import StructVRNN
from vp2.utils.io import write_json_atomic


def probe(model: StructVRNN, frames: torch.Tensor, actions: torch.Tensor) -> dict[str, Any]:
    """The three links' measurements on clips ``frames (N, C + T, 3, H, W)``, ``actions``."""
    if not isinstance(model, StructVRNN):
        raise TypeError(f"the keypoint probe needs a Struct-VRNN, got {type(model).__name__}")
    c = model.config.num_context

    def mse(pred: torch.Tensor, target: torch.Tensor) -> float:
        return float((pred.clamp(0, 1) - target).square().mean())

    with torch.no_grad():
        detected = model._detect(frames)  # (N, T, K, 3)
        motion = (detected[..., :2] - detected[:, :1, :, :2]).norm(dim=-1)  # (N, T, K)
        own = model._render(detected, detected[:, 0], frames[:, 0])
        still = model._render(detected[:, :1].expand_as(detected), detected[:, 0], frames[:, 0])
        perm = torch.roll(torch.arange(len(frames)), 1)
        true_k = model.rollout_keypoints(frames[:, :c], actions)[0]  # the prior's mean
        swapped_k = model.rollout_keypoints(frames[:, :c], actions[perm])[0]
        future = detected[:, c:]
    return {
        "clips": len(frames),
        "detector": {
            "motion_mean": float(motion.mean()),
            "motion_max": float(motion.max()),
            "motion_mean_px": float(motion.mean()) * frames.shape[-1] / 2,
            "intensity_mean": float(detected[..., 2].mean()),
        },
        "decoder": {
            "mse_own_keypoints": mse(own, frames),
            "mse_keypoints_held_still": mse(still, frames),
            "mse_copy_first_frame": mse(frames[:, :1].expand_as(frames), frames),
        },
        "dynamics": {
            "swap_shift_mean": float((true_k[..., :2] - swapped_k[..., :2]).norm(dim=-1).mean()),
            "error_to_detected": float((true_k[..., :2] - future[..., :2]).norm(dim=-1).mean()),
            "detected_future_motion": float(
                (future[..., :2] - detected[:, c - 1 : c, :, :2]).norm(dim=-1).mean()
            ),
        },
    }


def main(argv: list[str] | None = None) -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--model", required=True, help="a Struct-VRNN checkpoint or run folder")
    parser.add_argument("--data", required=True, help="dataset folder (its valid split)")
    parser.add_argument("--clips", type=int, default=64)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, help="also write the figures here (JSON)")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    model = load_model(args.model, device="cpu", expected_name="struct_vrnn")
    cfg = model.config
    frames, actions = held_out_clips(args.data, args.clips, args.seed, cfg.num_context, cfg.num_future)
    result = {"model": str(args.model), "data": str(args.data), **probe(model, frames, actions)}
    print(json.dumps(result, indent=2))
    if args.out:
        write_json_atomic(args.out, result)


if __name__ == "__main__":
    main()
