"""Small run directories shared by the report and study tests (built once per session).

* ``repeat``: ``repeat_last_frame`` planning on the tiny suite (2 instances × seeds 0, 1,
  3 steps, 8 samples), with plan GIFs: success 0.5 on every seed (instance 0 succeeds by
  construction, instance 1 cannot).
* ``random``: the random agent on instance 0 only, seed 0: success 1.0.
* ``oracle``: a hand-written simulator-oracle run (records only, no GIFs) with per-seed
  success 1.0, 0.5, 0.5: mean 2/3, min 0.5, max 1.0.
"""

from __future__ import annotations

import functools
import json
import tempfile
from pathlib import Path

import yaml

from tests.benchmark import tiny_suite_path
from vp2.benchmark.runner import run_benchmark
from vp2.planning.config import PlannerConfig
from vp2.report.page import write_run_report
from vp2.run.config import RunConfig

TASK = "tabletop/push_sphere"
#: Mean success over seeds of each run.
SUCCESS = {"repeat": 0.5, "random": 1.0, "oracle": 2 / 3}
#: Oracle successes by (instance, seed).
ORACLE_SUCCESS = {
    (0, 0): True,
    (1, 0): True,
    (0, 1): True,
    (1, 1): False,
    (0, 2): True,
    (1, 2): False,
}


def write_handmade_run(
    run_dir: Path, model: str, outcomes: dict[tuple[int, int], bool], task: str = TASK
) -> Path:
    """A run directory with ``config.yaml`` and ``trials.jsonl`` only."""
    run_dir.mkdir(parents=True)
    config = {
        "model": model,
        "agent": "planning",
        "num_steps": 15,
        "optimizer": "mppi",
        "num_samples": None,
        "cost": "auto",
        "seeds": sorted({s for _, s in outcomes}),
    }
    (run_dir / "config.yaml").write_text(
        yaml.safe_dump({"vp2_version": "test", "spec_deviations": [], "config": config})
    )
    lines = [
        json.dumps(
            {
                "task": task,
                "instance": i,
                "seed": s,
                "success": ok,
                "error": None,
                "cost": "pixel",
                "num_steps": 15,
                "first_success_step": 3 if ok else None,
                "scores": [-10.0, -5.0],
            }
        )
        for (i, s), ok in outcomes.items()
    ]
    (run_dir / "trials.jsonl").write_text("\n".join(lines) + "\n")
    return run_dir


@functools.cache
def small_runs() -> dict[str, Path]:
    """The three run directories described in the module docstring."""
    root = Path(tempfile.mkdtemp(prefix="vp2-report-runs-"))
    common = dict(suite=str(tiny_suite_path()), num_steps=3, planner=PlannerConfig(num_samples=8),
                  progress=False)
    run_benchmark(
        RunConfig(
            model="repeat_last_frame",
            out=str(root / "repeat"),
            seeds=(0, 1),
            save_predictions=True,
            **common,
        ),
        after_run=write_run_report,  # as `vp2 run` does: report.html in the run directory
    )
    run_benchmark(
        RunConfig(
            model="repeat_last_frame",
            agent="random",
            out=str(root / "random"),
            seeds=(0,),
            num_instances=1,
            **common,
        ),
        after_run=write_run_report,
    )
    write_handmade_run(root / "oracle", "simulator", ORACLE_SUCCESS)
    return {name: root / name for name in ("repeat", "random", "oracle")}


def write_metrics_file(
    path: Path, fvd: float, lpips: float, ssim: float, env: str = "tabletop"
) -> Path:
    """A minimal ``metrics.json`` as ``vp2 metrics`` writes it (raw values)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(
        json.dumps({"env": env, "metrics": {"fvd": fvd, "lpips_alex": lpips, "ssim": ssim}})
    )
    return path
