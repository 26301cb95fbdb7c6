"""Does a model rank the planner's candidates as the simulator does, at the start and mid-push?

`vp2 diagnose` probes a trial's first planning step only. This study asks the question its
measures stand in for: does the model's cost order the planner's candidate action sequences as
the true future would? On each probed instance, at two points of its scripted path (the trial's
first planning step, and after half of the instance's scripted actions, when the object is on
its way), the MPPI sampler draws the candidates the trial would draw (plus the rest of the
scripted plan, last) and the task's cost scores them twice: with the simulator's futures
(the oracle) and with the model's. Per model and point:

* **agreement**: Spearman's ρ between the two scorings over the candidates (1: the model
  ranks them as the simulator does);
* **oracle's best in the model's top 10%**: the fraction of instances where the candidate the
  simulator scores best is among the model's best tenth.

The simulator's scores are computed once per instance and point (the candidates do not depend
on the model; cached on disk as `vp2 diagnose` caches them), then each model scores the same
batch. With ``--models FILE`` (the model list
of ``benchmarks.studies.diagnose_validation``: label, model, control run folders) each model's
measured success is read from its control runs and the page gives Spearman's ρ of each
measure with success across models.

Example::

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.studies.cost_agreement \\
        --models benchmarks/studies/diagnose_models.json --out outputs/cost-agreement
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm.auto import tqdm

from benchmarks import common
from vp2.data.suite import TaskInstance, TaskSuite
from vp2.diagnose.measures import (
    draw_batch,
    oracle_cache_dir,
    reset_agent,
    simulator_agreement,
    simulator_scores,
    spearman,
    step_context,
    step_objective,
)
from vp2.envs import env_class
from vp2.run.model_spec import resolve_model
from vp2.run.run_dir import read_trials
from vp2.utils.io import write_json_atomic

#: The points of an instance's scripted path that are probed: after none, and after half, of
#: its scripted actions.
POINTS = ("start", "mid-push")
#: The image side the models and the cost see.
IMAGE_SIZE = 64


def model_scores(
    model: Any, instance: TaskInstance, context: dict[str, Any], seed: int, num_samples: int,
    device: torch.device,
) -> tuple[np.ndarray, torch.Tensor]:
    """The model's scores of the candidates the trial ``(instance, seed)`` draws at the
    planning step ``context`` plus the rest of the scripted plan (last), and that batch."""
    agent = reset_agent(model, instance, context["goal"], seed, num_samples, device)
    _, batch = draw_batch(agent, context["rest"], num_samples)
    with torch.no_grad():
        return step_objective(agent, instance, context)(batch).double().cpu().numpy(), batch


def success_of(run_dirs: Sequence[str | Path]) -> tuple[int, int]:
    """Successes and trials over the runs' records (errors left out)."""
    rows = [r for d in run_dirs for r in read_trials(d) if r.get("error") is None]
    return sum(bool(r["success"]) for r in rows), len(rows)


def _median(values: Sequence[float | None]) -> float | None:
    kept = [v for v in values if v is not None]
    return float(np.median(kept)) if kept else None


def run(
    models: Sequence[dict[str, Any]],
    env: str,
    instances_per_task: int,
    num_samples: int,
    seed: int,
    device: torch.device,
    cache: Path | None = None,
) -> dict[str, Any]:
    """The agreement of every model with the simulator (module docstring); ``cache``: where
    the simulator's scores are kept (:func:`~vp2.diagnose.measures.simulator_scores`)."""
    instances = TaskSuite.load(None).select([env], instances_per_task)
    action_dim = int(env_class(env).action_dim)
    oracle = resolve_model("simulator", {}, env=env, action_dim=action_dim, device=device)
    loaded = {
        m["label"]: resolve_model(m["model"], {}, env=env, action_dim=action_dim, device=device)
        for m in models
    }
    rows: list[dict[str, Any]] = []
    bar = tqdm(total=len(instances) * len(POINTS), desc="cost agreement", unit="point")
    for instance in instances:
        for name in POINTS:
            executed = 0 if name == "start" else len(instance.actions) // 2
            context = step_context(instance, IMAGE_SIZE, executed)
            oracle_scores = None
            for label, model in loaded.items():
                scores, batch = model_scores(model, instance, context, seed, num_samples, device)
                if oracle_scores is None:  # the batch is the same for every model
                    oracle_scores = simulator_scores(oracle, instance, batch, context, seed,
                                                     num_samples, device, cache)  # fmt: skip
                rows.append({
                    "model": label, "task": instance.task, "instance": instance.index,
                    "point": name, "executed": executed,
                    **simulator_agreement(scores[:num_samples], oracle_scores[:num_samples]),
                })  # fmt: skip
            bar.update(1)
    bar.close()
    summary = []
    for m in models:
        mine = [r for r in rows if r["model"] == m["label"]]
        entry: dict[str, Any] = {"model": m["label"], "spec": m["model"]}
        for name in POINTS:
            at = [r for r in mine if r["point"] == name]
            entry[name] = {
                "median_rho": _median([r["oracle_rho"] for r in at]),
                "oracle_best_in_top": sum(r["oracle_best_in_top"] for r in at) / len(at),
            }
        if m.get("control"):
            wins, trials = success_of(m["control"])
            entry["success"], entry["trials"] = wins / trials if trials else None, trials
        summary.append(entry)
    return {
        "env": env, "instances_per_task": instances_per_task, "num_samples": num_samples,
        "seed": seed, "rows": rows, "models": summary, "correlations": correlations(summary),
    }  # fmt: skip


def correlations(summary: Sequence[dict[str, Any]]) -> dict[str, float | None]:
    """Spearman's ρ across models of each measure with measured success (models with one)."""
    have = [m for m in summary if m.get("success") is not None]
    success = np.array([m["success"] for m in have], dtype=float)
    out: dict[str, float | None] = {}
    for name in POINTS:
        for key in ("median_rho", "oracle_best_in_top"):
            values = [m[name][key] for m in have]
            if len(have) < 3 or any(v is None for v in values):
                out[f"{name}/{key}"] = None
                continue
            out[f"{name}/{key}"] = spearman(np.array(values, dtype=float), success)
    return out


def markdown(result: dict[str, Any]) -> str:
    """The page: one row per model, then the correlations with success."""
    lines = [
        "| model | start: agreement ρ (median) | start: oracle's best in top 10% | "
        "mid-push: agreement ρ | mid-push: oracle's best in top 10% | success |",
        "|---|---|---|---|---|---|",
    ]

    def num(x: float | None) -> str:
        return "–" if x is None else f"{x:+.2f}"

    for m in result["models"]:
        s, p = m["start"], m["mid-push"]
        success = "–" if m.get("success") is None else f"{100 * m['success']:.0f}% ({m['trials']})"
        lines.append(
            f"| {m['model']} | {num(s['median_rho'])} | {s['oracle_best_in_top']:.0%} | "
            f"{num(p['median_rho'])} | {p['oracle_best_in_top']:.0%} | {success} |"
        )
    lines += ["", "Spearman's ρ with success across models:", ""]
    lines += [f"- {k}: {num(v)}" for k, v in result["correlations"].items()]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--models", type=Path, required=True,
                        help="model list (JSON: {'models': [{label, model, control}]})")
    parser.add_argument("--env", default="robodesk")
    parser.add_argument("--instances-per-task", type=int, default=2)
    parser.add_argument("-n", "--num-samples", type=int, default=50)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--only", nargs="+", help="labels of the models to measure")
    parser.add_argument("--out", type=Path, default=Path("outputs/cost-agreement"))
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    models = [m for m in json.loads(args.models.read_text())["models"] if m["env"] == args.env]
    if args.only:
        unknown = sorted(set(args.only) - {m["label"] for m in models})
        if unknown:
            parser.error(f"--only: no model {unknown} in {args.models}")
        models = [m for m in models if m["label"] in args.only]
    result = run(models, args.env, args.instances_per_task, args.num_samples, args.seed,
                 torch.device("cpu"), oracle_cache_dir())  # fmt: skip
    write_json_atomic(args.out / "cost_agreement.json", result)
    page = markdown(result)
    (args.out / "cost_agreement.md").write_text(page)
    print(page)


if __name__ == "__main__":
    main()
