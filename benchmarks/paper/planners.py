"""The paper's planner comparison (its appendix): MPPI, CEM, CEM-GD and L-BFGS planning with one
model on the tabletop, L-BFGS at each learning rate the paper swept, and the sampling-based
planners with the simulator oracle as well (docs/paper.md).

    python -m benchmarks.paper.planners --model zoo:svg_prime-tabletop-120min \\
        --out outputs/paper/planners [--num-instances 3] [--seeds 0 1 2] [--workers 2]

Every setting is one resumable ``vp2 run`` under ``OUT/runs/<setting>`` (the same command
resumes an interrupted study and only runs what is missing); the table of success per task
(mean over seeds [min, max]) and the mean over tasks, one column per setting, is written to
``OUT/planners.md`` and ``OUT/planners.json``. Each optimizer keeps its own defaults (SPEC §5
and docs/planning.md: CEM's elites, CEM-GD's samples, refinement and Adam steps, L-BFGS's
calls); ``--num-samples`` sets the samples of the sampling-based ones (SPEC: 200).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.common import argument_parser, command_line
from vp2.benchmark.runner import run_benchmark
from vp2.planning.config import PlannerConfig
from vp2.run.config import RunConfig
from vp2.run.run_dir import RunDir
from vp2.utils.io import atomic_path, write_json_atomic

#: L-BFGS step lengths the paper swept (its appendix).
LBFGS_LRS = (1e-3, 1e-2, 5e-2, 7e-2)
#: The planners that need no gradient, and so also plan with the simulator oracle.
SAMPLING = ("mppi", "cem")


@dataclasses.dataclass(frozen=True)
class Setting:
    """One column of the study: a model planned with one optimizer and its settings."""

    name: str
    model: str
    optimizer: str
    lr: float | None = None

    def planner(self, num_samples: int | None, grad_steps: int | None = None,
                num_samples_first: int | None = None) -> PlannerConfig:
        gradient = self.optimizer in ("cem_gd", "lbfgs")
        return PlannerConfig(
            optimizer=self.optimizer, num_samples=num_samples, lr=self.lr,
            grad_steps=grad_steps if gradient else None,
            num_samples_first=num_samples_first if self.optimizer == "cem_gd" else None)


def settings(model: str, lbfgs_lrs: Sequence[float], oracle: bool) -> list[Setting]:
    """The study's columns, in order: the model with MPPI, CEM, CEM-GD and L-BFGS at each rate;
    then, with ``oracle``, the simulator with the sampling-based planners."""
    out = [Setting(name, model, name) for name in ("mppi", "cem", "cem_gd")]
    out += [Setting(f"lbfgs-lr{lr:g}", model, "lbfgs", lr) for lr in lbfgs_lrs]
    if oracle:
        out += [Setting(f"oracle-{name}", "simulator", name) for name in SAMPLING]
    return out


def run_config(args: Any, setting: Setting) -> RunConfig:
    return RunConfig(
        model=setting.model, out=str(Path(args.out) / "runs" / setting.name),
        suite=args.suite, tasks=tuple(args.tasks), num_instances=args.num_instances,
        seeds=tuple(args.seeds),
        planner=setting.planner(args.num_samples, args.grad_steps, args.num_samples_first),
        num_steps=args.num_steps, workers=args.workers, resume=True,
        save_gifs=not args.no_gifs, progress=not args.no_progress, device=args.device,
    )


def _pct(x: float | None) -> str:
    return "–" if x is None else f"{100 * x:.0f}"


def table(out: Path, columns: Sequence[Setting]) -> tuple[list[str], list[dict[str, Any]]]:
    """Markdown lines and the JSON of the study's table, read from the runs' summaries."""
    summaries = {}
    for s in columns:
        path = RunDir(out / "runs" / s.name).summary_json
        summaries[s.name] = json.loads(path.read_text()) if path.is_file() else None
    tasks: list[str] = []
    for summary in summaries.values():
        for row in summary["tasks"] if summary else []:
            if row["task"] not in tasks:
                tasks.append(row["task"])
    lines = ["| task | " + " | ".join(s.name for s in columns) + " |",
             "|---" * (len(columns) + 1) + "|"]
    for task in tasks:
        cells = []
        for s in columns:
            row = next((r for r in (summaries[s.name] or {}).get("tasks", [])
                        if r["task"] == task), None)
            cells.append("pending" if summaries[s.name] is None else "–" if row is None else
                         f"{_pct(row['mean'])} [{_pct(row['min'])}, {_pct(row['max'])}] "
                         f"({row['num_trials']})")
        lines.append(f"| {task} | " + " | ".join(cells) + " |")
    means = [summaries[s.name] or {} for s in columns]
    lines.append("| **mean over tasks** | " + " | ".join(
        f"**{_pct(m.get('mean'))}** [{_pct(m.get('min'))}, {_pct(m.get('max'))}]" for m in means
    ) + " |")
    data = [{"name": s.name, "model": s.model, "optimizer": s.optimizer, "lr": s.lr,
             "summary": summaries[s.name]} for s in columns]
    return lines, data


def parse_args(argv: Sequence[str] | None = None) -> Any:
    parser = argument_parser(__spec__.name, __doc__)
    parser.add_argument("--model", required=True, help="a differentiable model (--model form)")
    parser.add_argument("--out", required=True)
    parser.add_argument("--tasks", nargs="+", default=["tabletop"])
    parser.add_argument("--suite", default=None, help="a task suite file (default: the shipped)")
    parser.add_argument("--num-instances", type=int, default=3)
    parser.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    parser.add_argument("--num-samples", type=int, default=None,
                        help="samples of MPPI and CEM (default: the SPEC's 200)")
    parser.add_argument("--num-steps", type=int, default=15)
    parser.add_argument("--grad-steps", type=int, default=None,
                        help="CEM-GD's most gradient steps, L-BFGS's step calls (default: "
                        "each optimizer's, the paper's)")
    parser.add_argument("--num-samples-first", type=int, default=None,
                        help="CEM-GD's samples on a trial's first step (default: its 500)")
    parser.add_argument("--lbfgs-lrs", type=float, nargs="+", default=list(LBFGS_LRS))
    parser.add_argument("--no-oracle", action="store_true",
                        help="leave out the simulator oracle's columns")
    parser.add_argument("--only", nargs="+", default=None, help="run only these settings")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--device", default=None)
    parser.add_argument("--no-gifs", action="store_true")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    if args.num_instances < 1 or not args.seeds or args.num_steps < 1:
        parser.error("--num-instances, --seeds and --num-steps need at least one each")
    if any(lr <= 0 for lr in args.lbfgs_lrs):
        parser.error(f"--lbfgs-lrs must be positive, got {args.lbfgs_lrs}")
    return args


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    out = Path(args.out)
    columns = settings(args.model, args.lbfgs_lrs, oracle=not args.no_oracle)
    known = {s.name for s in columns}
    unknown = sorted(set(args.only or ()) - known)
    if unknown:
        raise SystemExit(f"--only: no setting {', '.join(unknown)}; the settings are "
                         f"{', '.join(s.name for s in columns)}")
    for setting in columns:
        if args.only and setting.name not in args.only:
            continue
        print(f"[{setting.name}] {setting.model}, {setting.optimizer}"
              + (f", lr {setting.lr:g}" if setting.lr is not None else ""), flush=True)
        run_benchmark(run_config(args, setting))
    lines, data = table(out, columns)
    head = [f"# Planners with `{args.model}`", "", f"Command: `{command_line(__spec__.name, argv)}`",
            "", "Cell: success % mean over seeds [min, max] (trials).", ""]
    with atomic_path(out / "planners.md") as tmp:
        tmp.write_text("\n".join(head + lines) + "\n")
    write_json_atomic(out / "planners.json", {"command": command_line(__spec__.name, argv),
                                              "settings": data})
    print("\n".join(lines))


if __name__ == "__main__":
    main()
