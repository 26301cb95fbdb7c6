"""Does a model use its actions? Prediction error under true vs shuffled actions, held-out clips.

    .venv/bin/python -m benchmarks.studies.action_conditioning \\
        --model svg_prime:src/vp2/assets/models/svg_prime_tiny_robodesk.pt \\
        --data data/robodesk-20x-64px --clips 128 --samples 3

The measure of ``vp2 diagnose`` (:func:`vp2.diagnose.model.measure_conditioning`), printed
as a table with both pixel sets. For a fixed, seeded set of validation clips (the model's
context + future frames, drawn as ``vp2 metrics`` and ``vp2 diagnose`` draw them), the model
predicts the future frames from the true actions and from another clip's (a random derangement
of the clips, the context kept). A model that uses its actions has a lower error under the true
ones. Reported: per-frame MSE and the error on the frames that change (pixels whose true value
moves by more than 0.05 between the last context frame and the target frame; the static
background dilutes the plain MSE), each averaged over ``--samples`` sampling seeds, and their
ratio shuffled / true.

Whether the difference is more than noise: per clip the MSE under its true and under the
shuffled actions form a pair. Reported with the ratio: a 95% bootstrap interval over clips, the
share of clips whose true-action error is lower, and the two-sided sign test's p-value on those
pairs. A model that ignores its actions has a ratio whose interval contains 1 and wins about
half of the clips.
"""

from __future__ import annotations

from pathlib import Path

import torch

from benchmarks import common
from vp2.data.storage import load_manifest
from vp2.diagnose.model import measure_conditioning
from vp2.envs import env_class
from vp2.run.model_spec import resolve_model


def main(argv: list[str] | None = None) -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--model", required=True, help="model spec (as vp2 run --model)")
    parser.add_argument("--data", required=True, help="dataset directory")
    parser.add_argument("--clips", type=int, default=128)
    parser.add_argument("--samples", type=int, default=3, help="sampling seeds")
    parser.add_argument("--seed", type=int, default=0, help="draws the clips and the shuffle")
    parser.add_argument("--env", choices=("robodesk", "tabletop"),
                        help="the model's environment (default: the dataset's)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    env = args.env or load_manifest(args.data).get("config", {}).get("env", "robodesk")
    model = resolve_model(args.model, {}, env=env, action_dim=int(env_class(env).action_dim),
                          device="cpu")
    r = measure_conditioning(model, Path(args.data), args.clips, args.samples, args.seed,
                             torch.device("cpu"))
    m = r["moving"]
    print(f"{r['clips']} held-out clips of {args.data}, {args.samples} sampling seeds")
    print("| actions | MSE per pixel | MSE on changing pixels |")
    print("|---|---|---|")
    print(f"| true | {r['mse_true']:.5f} | {m['mse_true']:.5f} |")
    print(f"| shuffled | {r['mse_shuffled']:.5f} | {m['mse_shuffled']:.5f} |")
    print(f"| ratio shuffled / true | {r['ratio']:.3f} | {m['ratio']:.3f} |")
    print("| 95% bootstrap interval | {:.3f}-{:.3f} | {:.3f}-{:.3f} |".format(*r["ci"], *m["ci"]))
    print(f"| clips where true < shuffled | {r['wins']}/{r['clips']} | {m['wins']}/{r['clips']} |")
    print(f"sign test p (two-sided, all pixels): {r['sign_p']:.2g}")


if __name__ == "__main__":
    main()
