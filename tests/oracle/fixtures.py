"""Hand-made simulator-oracle runs and oracle tables for the shipped-oracle tests.

:func:`write_oracle_run` leaves a run directory as the runner does (``config.yaml``,
``trials.jsonl``) on the tiny suite's ``tabletop/push_sphere``; its default outcomes give per
seed 1.0, 0.5, 0.5, so the oracle's rate is 2/3 (4 of 6 trials).
"""

from __future__ import annotations

import json
from pathlib import Path

import yaml

from tests.benchmark import tiny_suite_path
from vp2.data.suite import SUITE_FORMAT, TaskSuite
from vp2.envs.render_specs import render_fingerprints
from vp2.oracle.tables import OracleTable, OracleTask

TASK = "tabletop/push_sphere"
#: (instance, seed) -> success: per seed 1.0, 0.5, 0.5, so the rate is 2/3 (4 of 6).
OUTCOMES = {(0, 0): True, (1, 0): True, (0, 1): True, (1, 1): False, (0, 2): True, (1, 2): False}


def sha(index: int, suite: Path | None = None, task: str = TASK) -> str:
    """The fingerprint of the tiny suite's (or ``suite``'s) instance."""
    return TaskSuite.load(suite or tiny_suite_path()).get(task, index).fingerprint


def actions(i: int, s: int) -> list[list[float]]:
    """Recorded actions of a hand-made trial: float32 values as a run's records hold them."""
    return [[0.0, 0.0, 0.0, 0.0], [0.10000000149011612 * (i + 1), -0.3333333432674408 * s,
                                   0.7071067690849304, -1.0]]


def write_oracle_run(
    run_dir: Path,
    outcomes: dict[tuple[int, int], bool | None] = OUTCOMES,
    *,
    model: str = "simulator",
    suite: Path | None = None,
    classifier: dict | None = None,
    day: int = 2,
    **config_overrides,
) -> Path:
    """A simulator-oracle run directory as the runner leaves it (config.yaml, trials.jsonl);
    an outcome ``None`` is an error record. The last trial finishes on 2026-11-2``day``."""
    suite = suite or tiny_suite_path()
    run_dir.mkdir(parents=True)
    config = {
        "model": model, "agent": "planning", "suite": str(suite), "optimizer": "mppi",
        "num_samples": None, "gamma": 0.05, "num_iterations": None, "cost": "auto",
        "num_steps": 15, "seeds": sorted({s for _, s in outcomes}), "oracle": None,
        "tasks": [TASK], "num_instances": max(i for i, _ in outcomes) + 1,
        **config_overrides,
    }
    (run_dir / "config.yaml").write_text(
        yaml.safe_dump({"vp2_version": "test", "spec_deviations": [], "config": config})
    )
    last = max(s for _, s in outcomes)
    lines = []
    for (i, s), ok in outcomes.items():
        record = {
            "task": TASK, "instance": i, "instance_sha": sha(i, suite), "seed": s,
            "success": ok, "cost": "pixel", "num_steps": 2, "vp2_version": "test",
            "first_success_step": 1 if ok else None, "actions": actions(i, s),
            "finished_at": f"2026-11-2{day - (last - s)}T10:00:00+00:00",
            "error": None if ok is not None else {"type": "SimError", "message": "x"},
        }
        if classifier is not None:
            record["agent"] = {"agent": "planning", "classifier": classifier}
        lines.append(json.dumps(record, sort_keys=True))
    (run_dir / "trials.jsonl").write_text("\n".join(lines) + "\n")
    return run_dir


def table(name: str, tasks: dict[str, tuple[float, int]], **overrides) -> OracleTable:
    """A table by hand: ``{task: (rate, num_samples)}``, this package's render fingerprints and
    suite format, no instance fingerprints (so any instance matches)."""
    fields = dict(
        name=name, suite_format=SUITE_FORMAT, date="2026-11-22", measured_by="hand",
        note="", vp2_version="test", settings={}, render=render_fingerprints(),
        classifiers={}, instance_fingerprints={},
        tasks={t: OracleTask(successes=1, trials=2, rate=rate, instances=(0,), seeds=(0,),
                             num_samples=n) for t, (rate, n) in tasks.items()},
    )
    fields.update(overrides)
    return OracleTable(**fields)


def model_records(outcomes: dict[tuple[int, int], bool], task: str = TASK, shas=None):
    """A model run's records (instance fingerprints of the tiny suite, or ``shas(i)``)."""
    return [
        {"task": task, "instance": i, "instance_sha": (shas or sha)(i), "seed": s,
         "success": ok, "error": None, "cost": "pixel"}
        for (i, s), ok in outcomes.items()
    ]
