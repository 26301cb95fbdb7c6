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
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import yaml

from vp2.run.run_dir import TRIALS_FILE, RunDir, read_trials
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
    trials = read_trials(run_dir)  # a missing file reads as no trials
    if not trials:
        return 0
    run = RunDir(run_dir)
    config = run.config_file.read_text()
    num_samples = (run.stored().get("config") or {}).get("planner", {}).get("num_samples")
    rows = [json.dumps(compact_trial(t, num_samples), sort_keys=True) for t in trials]
    kept = RunDir(dest).config_file
    if not kept.is_file() or _undated(yaml.safe_load(kept.read_text())) != _undated(
            yaml.safe_load(config)):  # a resumed run rewrites only its date: keep the first
        _write(kept, config)
    _write(RunDir(dest).trials_file, "\n".join(rows) + "\n")
    return len(rows)


def _metrics_file(out: Path, name: str) -> Path:
    return out / "metrics" / name / "metrics.json"


def _file_in(folder: str) -> Callable[[Path, str], Path]:
    return lambda out, name: out / folder / f"{name}.json"


def diagnose_record(report: dict[str, Any]) -> dict[str, Any]:
    """The comparison's diagnose record (``settings`` and ``report``) of a saved report."""
    given = report.get("settings") or {}
    return {"settings": {k: given.get(k) for k in DIAGNOSE_SETTINGS}, "report": report}


def _same(value: Any) -> Any:
    return value


#: The JSON outputs kept, per kind: where a part keeps one (``out``, name), and how its value
#: becomes the kept one and back (the diagnose record keeps only its report).
JSON_KINDS: dict[str, tuple[Callable[[Path, str], Path], Callable[[Any], Any], Callable[[Any], Any]]] = {
    "metrics": (_metrics_file, _same, _same),
    "diagnose": (_file_in("diagnose"), lambda record: record["report"], diagnose_record),
    "conditioning": (_file_in("conditioning"), _same, _same),
}


def _names(out: Path, kind: str) -> list[str]:
    """The names of the ``kind`` outputs under a part's ``out``."""
    if kind == "metrics":
        return sorted(p.parent.name for p in (out / "metrics").glob("*/metrics.json"))
    return sorted(p.stem for p in (out / kind).glob("*.json"))


def save(out: Path, records: Path) -> dict[str, int]:
    """Copies what ``out`` (one environment's part) measured into ``records``; returns the
    count of each kind saved (runs: trials)."""
    counts = {"runs": sum(save_run(d, records / "runs" / d.name)
                          for d in sorted((out / "runs").glob("*/")))}
    for kind, (where, to_kept, _) in JSON_KINDS.items():
        names = _names(out, kind)
        for name in names:
            value = to_kept(json.loads(where(out, name).read_text()))
            _write_json(records / kind / f"{name}.json", value)
        counts[kind] = len(names)
    return counts


def restore(records: Path, out: Path) -> dict[str, int]:
    """Copies into ``out`` what ``records`` holds and ``out`` lacks; returns the count of each
    kind restored (runs: trials). A run directory that already holds trials is left alone (its
    own records are newer or equal)."""
    counts = {"runs": 0}
    for saved in sorted((records / "runs").glob(f"*/{TRIALS_FILE}")):
        run = RunDir(out / "runs" / saved.parent.name)
        if read_trials(run.path):
            continue
        _write(run.config_file, RunDir(saved.parent).config_file.read_text())
        _write(run.trials_file, saved.read_text())
        counts["runs"] += len(read_trials(saved))
    for kind, (where, _, from_kept) in JSON_KINDS.items():
        counts[kind] = 0
        for saved in sorted((records / kind).glob("*.json")):
            path = where(out, saved.stem)
            if not path.is_file():
                _write_json(path, from_kept(json.loads(saved.read_text())))
                counts[kind] += 1
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
    counts = save(args.out, args.records) if args.action == "save" else restore(args.records,
                                                                                args.out)
    print(f"{args.action}d: " + ", ".join(f"{k} {v}" for k, v in counts.items()))


if __name__ == "__main__":
    main()
