"""``vp2 ship-oracle``: builds the shipped oracle asset from simulator-oracle run directories.

The asset's format and how runs are normalised by it: :mod:`vp2.benchmark.shipped_oracle`.
"""

from __future__ import annotations

import datetime
import json
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from vp2.benchmark.config import planner_of
from vp2.benchmark.results import is_ok, task_success, trial_key
from vp2.benchmark.run_dir import RunDir
from vp2.benchmark.shipped_oracle import (
    ASSET_FORMAT,
    SETTINGS,
    PathLike,
    default_asset_path,
    is_oracle_config,
)
from vp2.utils.io import write_json_atomic


def _num_samples(task: str, config: Mapping[str, Any]) -> int | None:
    """Planner samples the run used on ``task`` (its setting, else the SPEC default)."""
    from vp2.planning.planner import planner_settings

    return planner_settings(task, planner_of(config)).get("num_samples")


def _finished_date(records: Iterable[dict[str, Any]]) -> str | None:
    stamps = [r["finished_at"] for r in records if r.get("finished_at")]
    return max(stamps)[:10] if stamps else None


def _classifier_of(task: str, records: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """The classifier a task's trials planned with (their records' ``agent.classifier``);
    ``{}`` where none was recorded. Trials that used different classifiers are refused."""
    seen = {
        json.dumps(r["agent"]["classifier"], sort_keys=True)
        for r in records
        if isinstance(r.get("agent"), dict) and r["agent"].get("classifier")
    }
    if len(seen) > 1:
        raise ValueError(
            f"{task}: the trials planned with {len(seen)} different success classifiers "
            f"({', '.join(sorted(seen))}); build the oracle from runs with one classifier per task"
        )
    return json.loads(seen.pop()) if seen else {}


def build_oracle_asset(
    run_dirs: Sequence[PathLike],
    *,
    date: str | datetime.date | None = None,
    note: str = "",
) -> dict[str, Any]:
    """The asset (module docstring) of simulator-oracle run directories.

    Args:
        run_dirs: Oracle run directories (``trials.jsonl`` and ``config.yaml``), e.g. one per
            environment; a trial key may appear in one of them only.
        date: When the oracle was measured (default: the date its last trial finished).
        note: Free text stored with it.

    Returns:
        The asset as plain data (write it with :func:`write_oracle_asset`).

    Raises:
        ValueError: a directory that is not a finished simulator-oracle run (no records,
            another model, errored trials), runs whose settings or task suites differ, or a
            run whose records do not match its task suite any more.
    """
    from vp2.data.suite import SUITE_FORMAT, TaskSuite

    if not run_dirs:
        raise ValueError("give at least one simulator-oracle run directory")
    records: list[dict[str, Any]] = []
    origin: dict[tuple[str, int, int], Path] = {}
    samples: dict[str, int | None] = {}
    fingerprints: dict[str, str] = {}
    settings: dict[str, Any] | None = None
    names, versions = [], set()
    for d in run_dirs:
        run = RunDir(d)
        run_dir = run.path
        config = run.settings()  # the flat form: SETTINGS name the planner's fields directly
        if not config:
            raise ValueError(f"{run_dir}: no config.yaml (not a vp2 run directory)")
        if not is_oracle_config(config):
            raise ValueError(
                f"{run_dir} is not a simulator-oracle run (model {config.get('model')!r}, agent "
                f"{config.get('agent')!r}); build the oracle from runs of `vp2 run --model "
                "simulator`"
            )
        run_records = list({trial_key(r): r for r in run.trials()}.values())
        if not run_records:
            raise ValueError(f"{run_dir}: no trials in trials.jsonl")
        errors = [r for r in run_records if not is_ok(r)]
        if errors:
            e = errors[0]
            raise ValueError(
                f"{run_dir}: {len(errors)} trial(s) ended in an error (e.g. {e['task']}#"
                f"{e['instance']} seed {e['seed']}: {(e.get('error') or {}).get('type')}); "
                "re-run them with `vp2 run ... --resume --retry-errors` before shipping"
            )
        run_settings = {k: config.get(k) for k in SETTINGS}
        if settings is not None and run_settings != settings:
            raise ValueError(
                f"{run_dir}: settings {run_settings} differ from the other runs' {settings}; "
                "build the oracle from runs with the same protocol"
            )
        settings = run_settings
        try:
            suite = TaskSuite.load(config.get("suite"))
        except (OSError, ValueError) as exc:
            raise ValueError(
                f"{run_dir}: cannot load the task suite it ran on to check its instances ({exc})"
            ) from exc
        by_key = {i.key: i.fingerprint for i in suite}
        for r in run_records:
            key = trial_key(r)
            if key in origin:
                raise ValueError(
                    f"trial {key} is in both {origin[key]} and {run_dir}; give each trial once"
                )
            origin[key] = run_dir
            instance = f"{r['task']}#{r['instance']}"
            sha = r.get("instance_sha")
            if sha is None or by_key.get(instance) != sha:
                raise ValueError(
                    f"{run_dir}: {instance} ran on "
                    + (
                        "an unrecorded instance (a run from before instance fingerprints)"
                        if sha is None
                        else "another version of the task suite"
                    )
                    + f" than {config.get('suite') or 'the shipped suite'} now "
                    f"({SUITE_FORMAT}); re-run the oracle on the current suite"
                )
            if fingerprints.setdefault(instance, sha) != sha:
                raise ValueError(
                    f"the runs ran on different versions of {instance} (mixed task suites); "
                    "build the oracle from runs on one suite"
                )
            n = _num_samples(r["task"], config)
            if samples.setdefault(r["task"], n) != n:
                raise ValueError(
                    f"{r['task']}: the runs used different planner samples "
                    f"({samples[r['task']]} and {n}); build the oracle from runs that agree"
                )
        records += run_records
        names.append(run_dir.name)
        versions |= {str(r.get("vp2_version")) for r in run_records if r.get("vp2_version")}
    if isinstance(date, datetime.date):
        date = date.isoformat()[:10]
    date = date or _finished_date(records) or datetime.date.today().isoformat()
    tasks = {}
    for name, t in task_success(records).items():
        task_records = [r for r in records if r["task"] == name]
        tasks[name] = {
            "successes": sum(bool(r["success"]) for r in task_records),
            "trials": t.num_trials,
            "rate": t.mean,
            "instances": sorted({int(r["instance"]) for r in task_records}),
            "seeds": sorted(t.per_seed),
            "num_samples": samples[name],
        }
        classifier = _classifier_of(name, task_records)
        if classifier:
            tasks[name]["classifier"] = classifier
    assert settings is not None
    return {
        "format": ASSET_FORMAT,
        "suite_format": SUITE_FORMAT,
        "date": str(date),
        "measured_by": (
            f"vp2 ship-oracle of {len(names)} run(s) ({', '.join(names)}) of vp2 "
            f"{', '.join(sorted(versions)) or '?'}: "
            + ", ".join(f"{k}={v}" for k, v in settings.items())
        ),
        "note": note,
        "settings": settings,
        "tasks": tasks,
        "instance_fingerprints": dict(sorted(fingerprints.items())),
    }


def write_oracle_asset(asset: Mapping[str, Any], path: PathLike | None = None) -> Path:
    """Writes an asset atomically (default: the package's); returns the path."""
    out = Path(path) if path is not None else default_asset_path()
    write_json_atomic(out, dict(asset))
    return out


