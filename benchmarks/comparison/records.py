"""The model comparison's evidence, kept in the repository (``--records DIR``).

A comparison's outputs (``--out``, git-ignored) hold many core-hours of control trials; a
machine that loses them loses the page's evidence with them. With ``--records DIR`` (the
published page uses ``results/comparison``), each environment's part keeps a small copy of
what it measured under ``DIR/<env>/``::

    runs/<name>/config.yaml       the `vp2 run` config, as written
    runs/<name>/trials.jsonl      one compact record per trial (:data:`RUN_FIELDS`: outcome,
                                  executed actions and wall time; no scores or GIFs)
    metrics/<name>.json           the `vp2 metrics` result, with the settings it was made with
    diagnose/<name>.json          the `vp2 diagnose` report (its settings inside)
    conditioning/<name>.json      the action-conditioning record

A build first copies any of them that ``--out`` lacks into it (a run only into a directory
that holds no trials yet), so its stages find that work done and a run resumes after its
last recorded trial; it copies each stage's outputs back as they finish, and a run's trials
after every run (``python -m benchmarks.comparison.records save OUT DIR`` does the same at any
time, e.g. at the end of a working session while a run is still going).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vp2.benchmark.results import read_trials
from vp2.utils.io import atomic_path, json_safe, write_json_atomic

#: The fields of a trial record that the records keep (``timings`` reduced to ``total_s``).
RUN_FIELDS = (
    "task", "instance", "seed", "instance_sha", "success", "success_steps",
    "first_success_step", "num_steps", "error", "cost", "actions", "model_spec",
    "num_samples", "finished_at", "timings",
)  # fmt: skip

#: The diagnose report's settings that the comparison's diagnose record repeats.
DIAGNOSE_SETTINGS = ("model", "data", "env", "num_samples", "clips", "instances_per_task",
                     "sampling_seeds", "seed")


def compact_trial(record: dict[str, Any], num_samples: int | None) -> dict[str, Any]:
    """One trial record as the records keep it: the :data:`RUN_FIELDS` it has (so compacting a
    compact record changes nothing)."""
    row = {
        **record,
        "model_spec": (record.get("model") or {}).get("spec", record.get("model_spec")),
        "num_samples": record.get("num_samples", num_samples),
    }
    timings = row.pop("timings", None) or {}
    if "total_s" in timings:
        row["timings"] = {"total_s": timings["total_s"]}
    return {k: row[k] for k in sorted(RUN_FIELDS) if k in row}


def _write(path: Path, text: str) -> bool:
    """Writes ``text`` atomically unless the file already holds it; True if written."""
    if path.is_file() and path.read_text() == text:
        return False
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(text)
    return True


def _write_json(path: Path, value: Any) -> bool:
    """Writes ``value`` as JSON (as the comparison writes it) unless the file already holds
    that value; True if written."""
    if path.is_file() and json.loads(path.read_text()) == json_safe(value):
        return False
    path.parent.mkdir(parents=True, exist_ok=True)
    write_json_atomic(path, json_safe(value))
    return True


def _undated(config: dict[str, Any]) -> dict[str, Any]:
    """A run's ``config.yaml`` without the time it was (re)written."""
    return {k: v for k, v in config.items() if k != "written_at"}


def save_run(run_dir: Path, dest: Path) -> int:
    """``run_dir``'s config and trials as compact records under ``dest``; returns the trials
    kept (0, writing nothing, for a run with no trial yet)."""
    trials = read_trials(run_dir) if (run_dir / "trials.jsonl").is_file() else []
    if not trials:
        return 0
    import yaml

    config = (run_dir / "config.yaml").read_text()
    num_samples = (yaml.safe_load(config).get("config") or {}).get("planner", {}).get("num_samples")
    rows = [json.dumps(compact_trial(t, num_samples), sort_keys=True) for t in trials]
    kept = dest / "config.yaml"
    if not kept.is_file() or _undated(yaml.safe_load(kept.read_text())) != _undated(
            yaml.safe_load(config)):  # a resumed run rewrites only its date: keep the first
        _write(kept, config)
    _write(dest / "trials.jsonl", "\n".join(rows) + "\n")
    return len(rows)


def save(out: Path, records: Path) -> dict[str, int]:
    """Copies what ``out`` (one environment's part) measured into ``records``; returns the
    count of each kind saved (runs: trials)."""
    counts = {"runs": 0, "metrics": 0, "diagnose": 0, "conditioning": 0}
    for run_dir in sorted((out / "runs").glob("*/")):
        counts["runs"] += save_run(run_dir, records / "runs" / run_dir.name)
    for path in sorted((out / "metrics").glob("*/metrics.json")):
        _write_json(records / "metrics" / f"{path.parent.name}.json", json.loads(path.read_text()))
        counts["metrics"] += 1
    for path in sorted((out / "diagnose").glob("*.json")):
        _write_json(records / "diagnose" / path.name, json.loads(path.read_text())["report"])
        counts["diagnose"] += 1
    for path in sorted((out / "conditioning").glob("*.json")):
        _write_json(records / "conditioning" / path.name, json.loads(path.read_text()))
        counts["conditioning"] += 1
    return counts


def diagnose_record(report: dict[str, Any]) -> dict[str, Any]:
    """The comparison's diagnose record (``settings`` and ``report``) of a saved report."""
    given = report.get("settings") or {}
    return {"settings": {k: given.get(k) for k in DIAGNOSE_SETTINGS}, "report": report}


def restore(records: Path, out: Path) -> dict[str, int]:
    """Copies into ``out`` what ``records`` holds and ``out`` lacks; returns the count of each
    kind restored (runs: trials). A run directory that already holds trials is left alone (its
    own records are newer or equal)."""
    counts = {"runs": 0, "metrics": 0, "diagnose": 0, "conditioning": 0}
    for saved in sorted((records / "runs").glob("*/trials.jsonl")):
        run_dir = out / "runs" / saved.parent.name
        if (run_dir / "trials.jsonl").is_file() and read_trials(run_dir):
            continue
        _write(run_dir / "config.yaml", (saved.parent / "config.yaml").read_text())
        _write(run_dir / "trials.jsonl", saved.read_text())
        counts["runs"] += len(read_trials(run_dir))
    for saved in sorted((records / "metrics").glob("*.json")):
        path = out / "metrics" / saved.stem / "metrics.json"
        if not path.is_file():
            _write(path, saved.read_text())
            counts["metrics"] += 1
    for saved in sorted((records / "diagnose").glob("*.json")):
        path = out / "diagnose" / saved.name
        if not path.is_file():
            _write_json(path, diagnose_record(json.loads(saved.read_text())))
            counts["diagnose"] += 1
    for saved in sorted((records / "conditioning").glob("*.json")):
        path = out / "conditioning" / saved.name
        if not path.is_file():
            _write(path, saved.read_text())
            counts["conditioning"] += 1
    return counts


def main(argv: Sequence[str] | None = None) -> None:
    p = argparse.ArgumentParser(
        prog="python -m benchmarks.comparison.records",
        description="save a comparison part's evidence into its records folder, or restore it",
    )
    p.add_argument("action", choices=["save", "restore"])
    p.add_argument("out", type=Path, help="one environment's part, e.g. outputs/comparison-zoo/robodesk")
    p.add_argument("records", type=Path, help="its records, e.g. results/comparison/robodesk")
    args = p.parse_args(argv)
    if args.action == "save" and not args.out.is_dir():
        sys.exit(f"records.py: {args.out} is not a directory: nothing to save")
    if args.action == "restore" and not args.records.is_dir():
        sys.exit(f"records.py: {args.records} is not a directory: nothing to restore")
    counts = (save if args.action == "save" else restore)(
        *((args.out, args.records) if args.action == "save" else (args.records, args.out)))
    print(f"{args.action}d: " + ", ".join(f"{k} {v}" for k, v in counts.items()))


if __name__ == "__main__":
    main()
