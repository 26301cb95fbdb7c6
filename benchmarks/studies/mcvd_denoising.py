"""How well does an MCVD checkpoint denoise, per diffusion timestep? (Is it still learning?)

    .venv/bin/python -m benchmarks.studies.mcvd_denoising --model runs/zoo2/mcvd_tiny \\
        --data data/robodesk-20x-64px --clips 8

For held-out clips, the model's first window (2 context frames, 5 targets, 6 actions) is noised
to timestep ``t`` of the DDPM chain with a fixed seed, and the model (EMA weights, as at
inference; ``--raw`` for the trained weights) predicts the noise. Printed per ``t``: the
signal share ``sqrt(alpha_bar_t)``, the noise-prediction MSE (1.0 = predicting zero, 0 = exact;
at the last timestep the input *is* the noise, so a trained model gets it almost exactly), and
the MSE of the implied one-step estimate of the clean frames (pixels in [0, 1], clipped as the
sampler clips them). A sampler can only turn noise into frames if the high-``t`` rows are
good: an estimate of the clean frames that is wrong by more than the signal it carries there
leaves the chain's state noise-like all the way down.

``--shuffled``: does the denoiser use its actions? Each clip's window is noised at ``--grid``
evenly spaced timesteps (the same noise for both) and denoised once conditioned on its own
actions and once on another clip's (a random derangement; the context frames kept). The
per-clip mean noise MSE over the grid is the training objective, DDPM's "simple" loss, a
reweighted variational bound on the likelihood of the true frames: lower under the true
actions means the model's predictive distribution puts more mass on what the actions did.
Reported per timestep and overall, with the ratio's bootstrap interval, clips won and a sign
test (as ``benchmarks.studies.action_conditioning``, which compares sampled frames instead).
"""

from __future__ import annotations

import numpy as np
import torch

from benchmarks import common
from vp2.diagnose.measures import derangement, held_out_clips, ratio_statistics
from vp2.models.registry import load_model


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--model", required=True, help="MCVD run directory or checkpoint")
    parser.add_argument("--data", required=True, help="dataset directory")
    parser.add_argument("--clips", type=int, default=8)
    parser.add_argument("--timesteps", type=int, nargs="+", default=[0, 10, 100, 300, 600, 999])
    parser.add_argument("--raw", action="store_true", help="the trained weights, not the EMA")
    parser.add_argument("--shuffled", action="store_true",
                        help="compare the noise MSE under true and other clips' actions")
    parser.add_argument("--grid", type=int, default=10, help="timesteps of the --shuffled grid")
    args = parser.parse_args()
    torch.set_num_threads(1)
    overrides = {"use_ema": False} if args.raw else None
    model = load_model(args.model, device="cpu", expected_name="mcvd", overrides=overrides)
    c, w = model.config.num_context, model.config.window
    frames, actions = held_out_clips(args.data, args.clips, 0, c, model.config.num_future)
    clip = frames[:, : c + w] * 2 - 1
    context, target = clip[:, :c], clip[:, c:].flatten(1, 2)
    cond = model._condition(context, actions[:, : w + 1])
    gen = torch.Generator().manual_seed(0)
    print(f"{args.model} ({'trained' if args.raw else 'EMA'} weights, "
          f"{int(model.ema_updates)} training steps), {len(frames)} held-out clips")
    print("| t | sqrt(alpha_bar) | noise MSE | clean-frame estimate MSE |")
    print("|---|---|---|---|")
    with torch.no_grad():
        for t in args.timesteps:
            noise, noisy, ab = _noised(model, target, t, gen)
            eps = model._denoiser(noisy, torch.full((len(frames),), t), cond)
            x0 = ((noisy - (1 - ab).sqrt() * eps) / ab.sqrt()).clamp(-1, 1)
            print(f"| {t} | {float(ab.sqrt()):.3f} | {float((eps - noise).square().mean()):.3f} | "
                  f"{float(((x0 - target) / 2).square().mean()):.4f} |")
    if args.shuffled:
        compare_actions(model, context, target, actions, args.grid)


def _noised(model, target: torch.Tensor, t: int, gen: torch.Generator):
    """``(noise, x_t, alpha_bar_t)``: ``target`` noised to timestep ``t`` of the chain."""
    noise = torch.randn(target.shape, generator=gen)
    ab = model.alphas_cumprod[t]
    return noise, ab.sqrt() * target + (1 - ab).sqrt() * noise, ab


def compare_actions(model, context, target, actions, grid: int) -> None:
    """Per-clip noise MSE over a timestep grid, own vs deranged actions (see the docstring)."""
    w = model.config.window
    n = len(target)
    perm = torch.from_numpy(derangement(n, np.random.default_rng(0)))
    cond_true = model._condition(context, actions[:, : w + 1])
    cond_shuf = model._condition(context, actions[perm][:, : w + 1])
    gen = torch.Generator().manual_seed(1)
    steps = np.linspace(0, model.config.num_timesteps - 1, grid).round().astype(int)
    per_clip = {"true": np.zeros(n), "shuffled": np.zeros(n)}
    print(f"\nnoise MSE under own vs other clips' actions, {grid} timesteps, same noise")
    print("| t | own actions | other actions | ratio |")
    print("|---|---|---|---|")
    with torch.no_grad():
        for t in steps:
            noise, noisy, _ = _noised(model, target, int(t), gen)
            tt = torch.full((n,), int(t))
            row = {}
            for name, cond in (("true", cond_true), ("shuffled", cond_shuf)):
                err = (model._denoiser(noisy, tt, cond) - noise).square().flatten(1).mean(1)
                per_clip[name] += err.numpy() / len(steps)
                row[name] = float(err.mean())
            print(f"| {t} | {row['true']:.4f} | {row['shuffled']:.4f} | "
                  f"{row['shuffled'] / row['true']:.3f} |")
    st = ratio_statistics(per_clip["true"], per_clip["shuffled"])
    print(f"| all (simple loss) | {per_clip['true'].mean():.4f} | "
          f"{per_clip['shuffled'].mean():.4f} | **{st['ratio']:.3f}** "
          f"[{st['ci'][0]:.3f}, {st['ci'][1]:.3f}] |")
    print(f"clips where own < other: {st['wins']}/{st['clips']}, sign test p = {st['sign_p']:.2g}")


if __name__ == "__main__":
    main()
