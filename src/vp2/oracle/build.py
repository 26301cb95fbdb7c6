"""``vp2 ship-oracle``: the shipped oracle's tables, from simulator-oracle runs to the asset.

Two steps, each deterministic:

1. :func:`build_table` turns finished simulator-oracle run directories (one planner budget)
   into a table's evidence, written by :func:`write_table` to ``results/oracle/<name>/``:
   ``meta.json`` (the table's provenance: suite format, date, settings, vp2 version, render
   fingerprints, classifiers, the commands that ran the trials) and ``trials.jsonl`` (one
   compact record per trial, sorted by task, instance and seed: :func:`compact_record`).
2. :func:`build_asset` reads every table folder under ``results/oracle`` and computes the
   asset (:mod:`vp2.oracle.shipped` describes its format) from those files alone:
   the same files give the same bytes (:func:`asset_text`), on any machine, on any day.

The replay of a record against the simulator: :mod:`vp2.oracle.replay`.
"""

from __future__ import annotations

import datetime
import json
import re
import shlex
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from vp2 import spec
from vp2.oracle.shipped import (
    ASSET_FORMAT,
    SETTINGS,
    PathLike,
    default_asset_path,
    is_oracle_config,
)
from vp2.run.config import planner_of
from vp2.run.results import is_ok, task_success, trial_key, trial_keys
from vp2.run.run_dir import CONFIG_FILE, TRIALS_FILE, RunDir, read_trials
from vp2.utils.io import atomic_path, write_json_atomic

#: Where the tables' evidence lives, relative to the repository root.
RESULTS_DIR = Path("results") / "oracle"
#: Format tag of a table's ``meta.json``.
META_FORMAT = "vp2-oracle-table/1"
META_FILE = "meta.json"
#: What a table name may be (it names a folder).
TABLE_NAME = re.compile(r"[a-z0-9][a-z0-9._-]{0,63}")
#: Fields of a compact trial record (``classifier`` only where the trial used one).
COMPACT_FIELDS = ("task", "instance", "seed", "instance_sha", "success", "first_success_step",
                  "num_steps", "num_samples", "actions")


def _num_samples(task: str, config: Mapping[str, Any]) -> int | None:
    """Planner samples the run used on ``task`` (its setting, else the SPEC default)."""
    from vp2.planning.planner import planner_settings

    return planner_settings(task, planner_of(config)).get("num_samples")


def _finished_date(records: Iterable[dict[str, Any]]) -> str | None:
    stamps = [r["finished_at"] for r in records if r.get("finished_at")]
    return max(stamps)[:10] if stamps else None


def _classifier_of(task: str, records: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """The classifier a task's trials planned with (their records' ``agent.classifier``) and
    its weight in the cost; ``{}`` where none was recorded. Trials that used different
    classifiers or weights are refused. Records written before the weight was recorded
    (``weight`` absent) planned at the SPEC's weight, the only one ``vp2 run`` used then, and
    count as that weight (as the matcher reads them, :mod:`vp2.oracle.tables`)."""
    provenances = [
        dict(r["agent"]["classifier"])
        for r in records
        if isinstance(r.get("agent"), dict) and r["agent"].get("classifier")
    ]
    weights = {float(spec.ROBODESK_CLASSIFIER_WEIGHT if (w := p.pop("weight", None)) is None else w)
               for p in provenances}
    seen = {json.dumps(p, sort_keys=True) for p in provenances}
    if len(seen) > 1 or len(weights) > 1:
        what = sorted(seen) + [f"weight {w:g}" for w in sorted(weights)]
        raise ValueError(
            f"{task}: the trials planned with {len(seen)} different success classifiers and "
            f"{len(weights)} classifier weights ({', '.join(what)}); build the oracle from runs "
            "with one classifier and weight per task"
        )
    if not seen:
        return {}
    out = json.loads(seen.pop())
    if weights:
        out["weight"] = weights.pop()
    return out


def compact_record(record: Mapping[str, Any], num_samples: int | None) -> dict[str, Any]:
    """A trial record as ``results/oracle/*/trials.jsonl`` keeps it: :data:`COMPACT_FIELDS`
    (the executed actions exactly as the run recorded them) and the classifier's SHA-256
    prefix, if the trial planned with one."""
    out = {
        "task": record["task"],
        "instance": int(record["instance"]),
        "seed": int(record["seed"]),
        "instance_sha": record["instance_sha"],
        "success": bool(record["success"]),
        "first_success_step": record.get("first_success_step"),
        "num_steps": record.get("num_steps"),
        "num_samples": num_samples,
        "actions": record.get("actions", []),
    }
    classifier = (record.get("agent") or {}).get("classifier") or {}
    if classifier.get("sha256"):
        out["classifier"] = classifier["sha256"]
    return out


def run_command(settings: Mapping[str, Any], run_dir: PathLike, full_out: bool = False) -> str:
    """The ``vp2 run`` command line of a run's settings (``RunDir.settings``, flat form). Its
    ``--out`` is the run directory's name (a table's runs sit side by side under
    ``results/``), or with ``full_out`` the run's own ``out`` setting (where it ran)."""
    parts = ["vp2", "run", "--model", str(settings.get("model"))]
    for key, value in sorted((settings.get("model_args") or {}).items()):
        parts += ["--model-arg", f"{key}={value}"]
    if settings.get("suite"):
        parts += ["--suite", str(settings["suite"])]
    if settings.get("tasks"):
        parts += ["--tasks", *map(str, settings["tasks"])]
    if settings.get("num_instances") is not None:
        parts += ["--num-instances", str(settings["num_instances"])]
    parts += ["--seeds", *map(str, settings.get("seeds") or [])]
    for key, flag, default in [
        ("optimizer", "--optimizer", "mppi"), ("num_samples", "--num-samples", None),
        ("gamma", "--gamma", spec.GAMMA), ("num_iterations", "--num-iterations", None),
        ("cost", "--cost", "auto"), ("num_steps", "--num-steps", spec.NUM_CONTROL_STEPS),
    ]:
        if settings.get(key) is not None and settings.get(key) != default:
            parts += [flag, str(settings[key])]
    if settings.get("stop_on_success"):
        parts.append("--stop-on-success")
    out = str(settings.get("out") or run_dir) if full_out else Path(run_dir).name
    return shlex.join([*parts, "--out", out])


def default_table_name(samples: Mapping[str, int | None]) -> str:
    """``spec`` when every task ran at the SPEC's count, ``samples-N`` at one other count.

    Raises:
        ValueError: tasks at several counts other than the SPEC's.
    """
    from vp2.envs.tasks import get_task

    if all(n == get_task(t).num_samples for t, n in samples.items()):
        return "spec"
    counts = set(samples.values())
    if len(counts) == 1 and None not in counts:
        return f"samples-{counts.pop()}"
    raise ValueError(
        f"the runs used several planner sample counts ({sorted(map(str, counts))}); name the "
        "table with --table NAME"
    )


def _render_of(envs: Iterable[str], records: Sequence[dict[str, Any]]) -> dict[str, str]:
    """The render fingerprint of each environment: this package's, checked against the
    records' ``render_fingerprint`` where they carry one."""
    from vp2.envs.render_specs import render_fingerprint

    out = {}
    for env in sorted(envs):
        current = render_fingerprint(env)
        recorded = {r["render_fingerprint"] for r in records
                    if r["task"].startswith(env + "/") and r.get("render_fingerprint")}
        if recorded - {current}:
            raise ValueError(
                f"the {env} trials rendered with render fingerprint(s) {sorted(recorded)}, this "
                f"vp2 renders {env} as {current} (another camera or render spec): re-run the "
                "oracle with this vp2"
            )
        out[env] = current
    return out


def _check_run(run: RunDir, settings: dict[str, Any] | None) -> tuple[dict[str, Any], list]:
    """A run's flat config and records, refused unless a finished oracle run like the others."""
    config = run.settings()  # shown flat: SETTINGS name the planner's fields directly
    if not config:
        raise ValueError(f"{run.path}: no {CONFIG_FILE} (not a vp2 run directory)")
    if not is_oracle_config(config):
        raise ValueError(
            f"{run.path} is not a simulator-oracle run (model {config.get('model')!r}, agent "
            f"{config.get('agent')!r}); build the oracle from runs of `vp2 run --model simulator`"
        )
    records = list({trial_key(r): r for r in run.trials()}.values())
    if not records:
        raise ValueError(f"{run.path}: no trials in {TRIALS_FILE}")
    errors = [r for r in records if not is_ok(r)]
    if errors:
        e = errors[0]
        raise ValueError(
            f"{run.path}: {len(errors)} trial(s) ended in an error (e.g. {e['task']}#"
            f"{e['instance']} seed {e['seed']}: {(e.get('error') or {}).get('type')}); "
            "re-run them with `vp2 run ... --resume --retry-errors` before shipping"
        )
    run_settings = {k: config.get(k) for k in SETTINGS}
    if settings is not None and run_settings != settings:
        raise ValueError(
            f"{run.path}: settings {run_settings} differ from the other runs' {settings}; "
            "build the oracle from runs with the same protocol"
        )
    return config, records


def _finished_records(
    path: Path, config: dict[str, Any], suite: Any, records: list[dict[str, Any]],
    tasks: Sequence[str] | None,
) -> list[dict[str, Any]]:
    """The run's records of ``tasks`` (all when ``None``), refused unless every trial the run
    planned for them (its tasks x instances x seeds) has finished."""
    planned = trial_keys(
        suite.select(config.get("tasks") or (), config.get("num_instances")),
        config.get("seeds") or (0,),
    )
    if tasks:
        # a name is a category, or an environment: those of its categories the run planned
        def named(task: str, name: str) -> bool:
            return task == name or task.split("/")[0] == name

        ran = {key[0] for key in planned}
        wanted = {t for t in ran if any(named(t, n) for n in tasks)}
        absent = [n for n in tasks if not any(named(t, n) for t in ran)]
        if absent:
            raise ValueError(f"{path}: the run planned no trials of {', '.join(absent)}")
        planned = [key for key in planned if key[0] in wanted]
        records = [r for r in records if r["task"] in wanted]
    have = {trial_key(r) for r in records}
    missing = [key for key in planned if key not in have]
    if missing:
        task, index, seed = missing[0]
        raise ValueError(
            f"{path}: {len(missing)} of its {len(planned)} planned trials have not finished "
            f"(e.g. {task}#{index} seed {seed}); finish the run with `vp2 run ... --resume`, or "
            "ship the task categories it has finished with --tasks"
        )
    return records


def build_table(
    run_dirs: Sequence[PathLike],
    *,
    name: str | None = None,
    note: str = "",
    date: str | datetime.date | None = None,
    commands: Sequence[str] | None = None,
    tasks: Sequence[str] | None = None,
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A table's ``meta.json`` and compact trial records from simulator-oracle run directories.

    Args:
        run_dirs: Oracle run directories (``trials.jsonl`` and ``config.yaml``) at one planner
            budget, e.g. one per environment; a trial key may appear in one of them only.
        name: The table's name (default: :func:`default_table_name` of the runs' samples).
        note: Free text stored with it.
        date: When the oracle was measured (default: the date its last trial finished).
        commands: The commands that ran the trials (default: :func:`run_command` of each
            run's settings).
        tasks: Only these task categories (or environments) of the runs, e.g. the categories a
            long run has finished (default: every task the runs planned).

    Returns:
        ``(meta, trials)``, plain data (write them with :func:`write_table`).

    Raises:
        ValueError: a directory that is not a finished simulator-oracle run (no records,
            another model, errored trials, planned trials of the shipped tasks missing), runs
            whose settings or task suites differ, a run whose records do not match its task
            suite any more or rendered differently from this vp2, trials of one task at
            different budgets, a bad name, no date.
    """
    from vp2.data.suite import SUITE_FORMAT, TaskSuite

    if not run_dirs:
        raise ValueError("give at least one simulator-oracle run directory")
    records: list[dict[str, Any]] = []
    origin: dict[tuple[str, int, int], Path] = {}
    samples: dict[str, int | None] = {}
    settings: dict[str, Any] | None = None
    names, versions, run_commands = [], set(), []
    for d in run_dirs:
        run = RunDir(d)
        config, run_records = _check_run(run, settings)
        settings = {k: config.get(k) for k in SETTINGS}
        try:
            suite = TaskSuite.load(config.get("suite"))
        except (OSError, ValueError) as exc:
            raise ValueError(
                f"{run.path}: cannot load the task suite it ran on to check its instances ({exc})"
            ) from exc
        run_records = _finished_records(run.path, config, suite, run_records, tasks)
        by_key = {i.key: i.fingerprint for i in suite}
        for r in run_records:
            key = trial_key(r)
            if key in origin:
                raise ValueError(
                    f"trial {key} is in both {origin[key]} and {run.path}; give each trial once"
                )
            origin[key] = run.path
            instance = f"{r['task']}#{r['instance']}"
            sha = r.get("instance_sha")
            if sha is None or by_key.get(instance) != sha:
                raise ValueError(
                    f"{run.path}: {instance} ran on "
                    + ("an unrecorded instance (a run from before instance fingerprints)"
                       if sha is None else "another version of the task suite")
                    + f" than {config.get('suite') or 'the shipped suite'} now "
                    f"({SUITE_FORMAT}); re-run the oracle on the current suite"
                )
            n = _num_samples(r["task"], config)
            if samples.setdefault(r["task"], n) != n:
                raise ValueError(
                    f"{r['task']}: the runs used different planner samples "
                    f"({samples[r['task']]} and {n}); build a table from runs that agree"
                )
        records += run_records
        names.append(run.path.name)
        versions |= {str(r["vp2_version"]) for r in run_records if r.get("vp2_version")}
        run_commands.append(run_command(config, run.path))
    by_instance: dict[str, str] = {}
    for r in records:
        if by_instance.setdefault(f"{r['task']}#{r['instance']}", r["instance_sha"]) != r[
                "instance_sha"]:
            raise ValueError(
                f"the runs ran on different versions of {r['task']}#{r['instance']} (mixed task "
                "suites); build the oracle from runs on one suite"
            )
    name = name or default_table_name(samples)
    if not TABLE_NAME.fullmatch(name):
        raise ValueError(
            f"table name {name!r}: use lower-case letters, digits, '.', '_' and '-' (it names "
            "a folder), e.g. samples-50 or spec"
        )
    if isinstance(date, datetime.date):
        date = date.isoformat()[:10]
    date = date or _finished_date(records)
    if not date:
        raise ValueError("the records carry no finished_at: give the date the oracle ran")
    if not re.fullmatch(r"\d{4}-\d{2}-\d{2}", str(date)):
        raise ValueError(f"date {date!r}: give it as YYYY-MM-DD")
    assert settings is not None
    tasks = sorted({r["task"] for r in records})
    classifiers = {t: c for t in tasks
                   if (c := _classifier_of(t, [r for r in records if r["task"] == t]))}
    meta = {
        "format": META_FORMAT,
        "name": name,
        "suite_format": SUITE_FORMAT,
        "date": str(date),
        "measured_by": (
            f"vp2 ship-oracle of {len(names)} run(s) ({', '.join(names)}) of vp2 "
            f"{', '.join(sorted(versions)) or '?'}: "
            + ", ".join(f"{k}={v}" for k, v in settings.items())
        ),
        "note": note,
        "vp2_version": ", ".join(sorted(versions)),
        "settings": settings,
        "render": _render_of({t.split("/")[0] for t in tasks}, records),
        "classifiers": classifiers,
        "commands": list(commands) if commands is not None else run_commands,
    }
    trials = sorted((compact_record(r, samples[r["task"]]) for r in records),
                    key=lambda r: (r["task"], r["instance"], r["seed"]))
    return meta, trials


def write_table(meta: Mapping[str, Any], trials: Sequence[Mapping[str, Any]],
                results: PathLike = RESULTS_DIR) -> Path:
    """Writes (or replaces) ``results/<name>/``: ``meta.json`` and ``trials.jsonl``, each
    atomically; returns the folder."""
    folder = Path(results) / str(meta["name"])
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_path(folder / TRIALS_FILE) as tmp:
        tmp.write_text("".join(json.dumps(dict(r), sort_keys=True, separators=(",", ":")) + "\n"
                               for r in trials))
    write_json_atomic(folder / META_FILE, dict(meta))
    return folder


def table_of(meta: Mapping[str, Any], trials: Sequence[Mapping[str, Any]]) -> dict[str, Any]:
    """The asset's table (aggregates per task) of a table's ``meta.json`` and trials.

    Raises:
        ValueError: inconsistent evidence (a task at two budgets, an instance with two
            fingerprints, a trial whose classifier is not the one ``meta.json`` names).
    """
    name = meta.get("name")
    if meta.get("format") != META_FORMAT:
        raise ValueError(f"table {name!r}: meta.json format {meta.get('format')!r}, expected "
                         f"{META_FORMAT!r}")
    if not trials:
        raise ValueError(f"table {name!r}: no trials")
    fingerprints: dict[str, str] = {}
    samples: dict[str, set[Any]] = {}
    classifiers = dict(meta.get("classifiers") or {})
    for r in trials:
        key = f"{r['task']}#{r['instance']}"
        if fingerprints.setdefault(key, r["instance_sha"]) != r["instance_sha"]:
            raise ValueError(f"table {name!r}: {key} has two instance fingerprints")
        samples.setdefault(r["task"], set()).add(r["num_samples"])
        expected = (classifiers.get(r["task"]) or {}).get("sha256")
        if r.get("classifier") != expected:
            raise ValueError(
                f"table {name!r}: a {r['task']} trial planned with classifier "
                f"{r.get('classifier')!r}, meta.json names {expected!r}"
            )
    tasks = {}
    for task, t in task_success(list(trials)).items():
        if len(samples[task]) > 1:
            raise ValueError(f"table {name!r}: {task} at several planner samples {samples[task]}")
        task_trials = [r for r in trials if r["task"] == task]
        tasks[task] = {
            "successes": sum(bool(r["success"]) for r in task_trials),
            "trials": t.num_trials,
            "rate": t.mean,
            "instances": sorted({int(r["instance"]) for r in task_trials}),
            "seeds": sorted(t.per_seed),
            "num_samples": next(iter(samples[task])),
        }
    keep = ("name", "suite_format", "date", "measured_by", "note", "vp2_version", "settings",
            "render", "classifiers")
    return {**{k: meta.get(k) for k in keep}, "classifiers": classifiers, "tasks": tasks,
            "instance_fingerprints": dict(sorted(fingerprints.items()))}


def read_table(folder: PathLike) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A table folder's ``meta.json`` and trials."""
    folder = Path(folder)
    try:
        meta = json.loads((folder / META_FILE).read_text())
    except (OSError, ValueError) as exc:
        raise ValueError(f"{folder}: no readable {META_FILE} ({exc})") from exc
    if meta.get("name") != folder.name:
        raise ValueError(f"{folder}: meta.json names the table {meta.get('name')!r}, its folder "
                         f"{folder.name!r}; they must agree")
    return meta, read_trials(folder / TRIALS_FILE)


def build_asset(results: PathLike = RESULTS_DIR) -> dict[str, Any]:
    """The asset of every table folder under ``results`` (sorted by name), from its files alone.

    Raises:
        ValueError: no table folder, or a folder whose evidence is inconsistent.
    """
    root = Path(results)
    folders = sorted(d for d in root.iterdir() if d.is_dir()) if root.is_dir() else []
    if not folders:
        raise ValueError(
            f"{root}: no oracle tables (folders with {META_FILE} and {TRIALS_FILE}); add one "
            "with `vp2 ship-oracle RUN_DIR... --table NAME`"
        )
    return {"format": ASSET_FORMAT, "tables": [table_of(*read_table(d)) for d in folders]}


def build_oracle_asset(
    run_dirs: Sequence[PathLike],
    *,
    name: str | None = None,
    date: str | datetime.date | None = None,
    note: str = "",
) -> dict[str, Any]:
    """A one-table asset straight from run directories (:func:`build_table`, no files)."""
    return {"format": ASSET_FORMAT,
            "tables": [table_of(*build_table(run_dirs, name=name, date=date, note=note))]}


def asset_text(asset: Mapping[str, Any]) -> str:
    """The asset file's text: JSON with sorted keys, 2-space indent, Python's shortest float
    repr, a final newline (the same data always gives the same bytes)."""
    return json.dumps(dict(asset), indent=2, sort_keys=True, allow_nan=False) + "\n"


def write_oracle_asset(asset: Mapping[str, Any], path: PathLike | None = None) -> Path:
    """Writes an asset atomically (default: the package's); returns the path."""
    out = Path(path) if path is not None else default_asset_path()
    with atomic_path(out) as tmp:
        tmp.write_text(asset_text(asset))
    return out
