"""Which way does the planning cost push a model's plans? Scores one MPPI batch twice per task.

    .venv/bin/python -m benchmarks.studies.cost_by_action --num-samples 50 \\
        mcvd=mcvd:outputs/comparison-v1/train/mcvd/checkpoints/step_00000192.pt \\
        shipped_svg_prime=svg_prime:src/vp2/assets/models/svg_prime_tiny_robodesk.pt

For each model and each task instance (the first ``--num-instances`` of every ``--tasks``
category), the probe sets the scene up as a trial's first planning step does (the instance's
initial state, the zero action, two context frames, the goal image), draws one batch of
``--num-samples`` candidate action sequences with the planner's own sampler and scores the batch
twice with the model and the run's cost (SPEC §6: pixel and classifier terms). A model draws new
noise for the second scoring; the candidates stay the same. Per instance it reports:

- ``repeat ρ``: Spearman's ρ between the two scorings. 1 when the ranking is a property of the
  candidates (their actions); near 0 when it is the model's noise, which then picks MPPI's plan.
- ``ρ x / y / z``: Spearman's ρ between a candidate's score (higher is better) and the sum of
  its x, y, z actions over the horizon. A model that sees the task has signs that follow the
  goal (they differ between tasks); one sign on every task is a bias of the model's predictions
  that the cost rewards whatever the goal.
- ``score spread``: the scores' standard deviation (0: every candidate is predicted alike, so
  MPPI averages its samples with equal weights).

Runs no trial; one planning step per instance and scoring, so a slow model (MCVD: ~50 s a batch
of 50 on one CPU thread) costs twice that per instance.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
from scipy import stats
from tqdm import tqdm

from benchmarks import common
from vp2.benchmark.runner import select_instances
from vp2.data.suite import TaskSuite
from vp2.envs import env_class, split_name
from vp2.planning.agent import PlanningAgent, frames_to_tensor
from vp2.planning.planner import PlannerConfig
from vp2.planning.samplers import broadcast_std
from vp2.run.config import RunConfig
from vp2.run.model_spec import resolve_model
from vp2.run.trial import goal_image_at, trial_seed
from vp2.utils.io import write_json_atomic

AXES = ("x", "y", "z")


def rho(a: np.ndarray, b: np.ndarray) -> float | None:
    """Spearman's ρ, ``None`` where it is undefined (a constant side)."""
    if np.ptp(a) == 0 or np.ptp(b) == 0:
        return None
    return float(stats.spearmanr(a, b).statistic)


def statistics(first: np.ndarray, second: np.ndarray, candidates: np.ndarray) -> dict:
    """The probe's numbers for one batch: ``first``/``second`` ``(N,)`` scores of the same
    ``candidates`` ``(N, T, A)`` (see the module docstring)."""
    sums = candidates.sum(axis=1)  # (N, A)
    return {
        "repeat_rho": rho(first, second),
        **{f"rho_{axis}": rho(first, sums[:, k]) for k, axis in enumerate(AXES)},
        "score_spread": float(np.std(first)),
    }


def probe(model, instance, num_samples: int, seed: int) -> dict:
    """Scores one batch of candidates twice on ``instance``'s first planning step."""
    env = instance.make_env(observation_size=None)
    try:
        size = int(model.image_size)
        goal = goal_image_at(instance, env, size)  # as a trial takes it
        env.reset_to(instance.init_state)
        env.set_goal(instance.goal_state)
        frames = [env.render(size)]
        zero = np.zeros(env.action_dim)
        env.step(zero)  # SPEC §4: a trial's first step executes the zero action
        frames.append(env.render(size))
    finally:
        env.close()
    agent = PlanningAgent(model, PlannerConfig(num_samples=num_samples))
    agent.reset(instance.task, goal, trial_seed(instance.task, instance.index, seed))
    context = frames_to_tensor(np.stack(frames[-agent.num_context :]), agent.device)
    objective = agent.objective(context, torch.zeros(agent.action_dim, device=agent.device))
    optimizer = agent.optimizer
    std = broadcast_std(optimizer.sigma, agent.plan)
    candidates = optimizer.sampler.sample(agent.plan, std, num_samples, agent.generator)
    with torch.no_grad():
        first = objective(candidates).cpu().numpy()
        second = objective(candidates).cpu().numpy()
    return {
        "task": instance.task,
        "instance": instance.index,
        "cost": agent.cost_kind,
        **statistics(first, second, candidates.cpu().numpy()),
    }


def _cell(x: float | None) -> str:
    return "–" if x is None else f"{x:+.2f}"


def table(rows: Sequence[dict]) -> str:
    """The Markdown table of the probe's rows."""
    lines = [
        "| model | task | instance | repeat ρ | ρ x | ρ y | ρ z | score spread |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        cells = [_cell(r[k]) for k in ("repeat_rho", "rho_x", "rho_y", "rho_z")]
        lines.append(
            f"| {r['model']} | {r['task']} | {r['instance']} | " + " | ".join(cells)
            + f" | {r['score_spread']:.3g} |"
        )  # fmt: skip
    return "\n".join(lines)


def headline(label: str, rows: Sequence[dict]) -> str:
    """One line per model: mean repeat ρ and ρ z, and on how many instances ρ z < 0."""
    rep = [r["repeat_rho"] for r in rows if r["repeat_rho"] is not None]
    z = [r["rho_z"] for r in rows if r["rho_z"] is not None]
    mean = {k: f"{np.mean(v):+.2f}" if v else "–" for k, v in (("rep", rep), ("z", z))}
    return (
        f"{label}: mean repeat ρ {mean['rep']}, mean ρ z {mean['z']}, ρ z < 0 on "
        f"{sum(v < 0 for v in z)} of {len(rows)} instances"
    )


def parse_models(items: Sequence[str]) -> list[tuple[str, str]]:
    """``LABEL=SPEC`` (or a bare spec, labelled by itself) -> ``[(label, spec), ...]``."""
    out = []
    for item in items:
        label, sep, spec = item.partition("=")
        if not sep:
            label, spec = item, item
        if not label or not spec:
            raise ValueError(f"{item!r}: expected LABEL=MODEL or a --model spec of vp2 run")
        out.append((label, spec))
    return out


def main(argv: Sequence[str] | None = None) -> None:
    p = common.argument_parser(__spec__.name, __doc__)
    p.add_argument("models", nargs="+", help="LABEL=MODEL (any vp2 run --model spec)")
    p.add_argument("--tasks", nargs="+", default=["robodesk"], help="categories or an env")
    p.add_argument("--num-instances", type=int, default=1, help="first instances per task")
    p.add_argument("--num-samples", type=int, default=50, help="candidates per batch")
    p.add_argument("--seed", type=int, default=0, help="control-run seed of the samples")
    p.add_argument("--threads", type=int, help="torch threads (default: torch's)")
    p.add_argument("--json", type=Path, help="also write the rows here")
    args = p.parse_args(argv)
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    try:
        models = parse_models(args.models)
        config = RunConfig(out="", model="none", tasks=args.tasks, num_instances=args.num_instances)
        instances = select_instances(TaskSuite.load(None), config)
    except ValueError as exc:
        sys.exit(f"cost_by_action.py: {exc}")
    rows = []
    bar = tqdm(total=len(models) * len(instances), unit="batch", disable=not sys.stderr.isatty())
    for label, spec in models:
        built: dict[str, object] = {}  # one model per environment, as a run builds it
        for instance in instances:
            env_name = split_name(instance.task)[0]
            if env_name not in built:
                action_dim = int(env_class(env_name).action_dim)
                built[env_name] = resolve_model(
                    spec, env=env_name, action_dim=action_dim, device="cpu"
                )
            row = probe(built[env_name], instance, args.num_samples, args.seed)
            rows.append({"model": label, **row})
            bar.update()
    bar.close()
    for label, _ in models:
        print(headline(label, [r for r in rows if r["model"] == label]))
    print(table(rows))
    if args.json is not None:
        write_json_atomic(args.json, rows)  # undefined ρ are None already (see rho)


if __name__ == "__main__":
    main()
