"""Trial records (``trials.jsonl``) and the summary table of a run (SPEC §4 scores).

A run directory holds one JSON line per finished trial, appended by the driver process
alone. A line is written with one ``write`` call, flushed and ``fsync``-ed, so after a crash
at most the last line is partial; :func:`read_trials_file` ignores it (and ``repair=True`` cuts it
off before a resumed run appends).

Scores: per task category, the success rate of each control run (seed) over its instances,
then the mean over seeds with min and max. Trials that ended in an error count neither as a
success nor as a failure; they are reported separately. The overall score is the mean over
task categories; normalised by the simulator oracle's overall score on the same tasks
(ratio of the means, so a task on which the oracle rarely succeeds does not blow up the
score). The oracle's per-task rates come from an oracle run's records or from the shipped
oracle's table of the run's planner budget (:mod:`vp2.oracle.shipped`), both as
:class:`TaskSummary` rows.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
from collections import defaultdict
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, TextIO

from vp2.envs.tasks import TASK_NAMES

TrialKey = tuple[str, int, int]


def trial_key(record: dict[str, Any]) -> TrialKey:
    """``(task, instance index, seed)`` of a record."""
    return record["task"], int(record["instance"]), int(record["seed"])


def trial_keys(instances: Iterable[Any], seeds: Sequence[int]) -> list[TrialKey]:
    """The keys of task instances (``.task``, ``.index``) × seeds, seed-major: an interrupted
    run has whole control runs finished first."""
    instances = list(instances)
    return [(inst.task, inst.index, seed) for seed in seeds for inst in instances]


def is_ok(record: dict[str, Any]) -> bool:
    """Whether a record is a finished trial (not an error)."""
    return record.get("error") is None


def read_trials_file(
    path: str | os.PathLike[str], repair: bool = False
) -> list[dict[str, Any]]:
    """Reads the records of a ``trials.jsonl`` file (of a run directory or a directory:
    :func:`vp2.run.run_dir.read_trials`).

    Args:
        path: The file. A missing file reads as no records.
        repair: Truncate a partial last line (left by a killed writer) from the file, so that
            appending can continue. Only the process that owns the run may do this.

    Returns:
        The records in file order.

    Raises:
        ValueError: if a line other than the last is not valid JSON (the file was damaged by
            something other than an interrupted append).
    """
    path = Path(path)
    if not path.exists():
        return []
    data = path.read_bytes()
    complete_end = data.rfind(b"\n") + 1  # bytes up to and including the last newline
    if complete_end < len(data) and repair:
        with open(path, "r+b") as fh:
            fh.truncate(complete_end)
            fh.flush()
            os.fsync(fh.fileno())
    records = []
    for number, line in enumerate(data[:complete_end].splitlines(), start=1):
        if not line.strip():
            continue
        try:
            records.append(json.loads(line))
        except json.JSONDecodeError as exc:
            raise ValueError(f"{path}:{number}: not a JSON record ({exc})") from exc
    return records


class TrialLog:
    """Append-only ``trials.jsonl`` writer used by the runner's driver process.

    Each record is one line written with a single ``write``, then flushed and ``fsync``-ed,
    so a record is either wholly on disk or (after a crash) a partial last line that
    :func:`read_trials_file` drops.
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh: TextIO = open(self.path, "a", encoding="utf-8")  # noqa: SIM115

    def append(self, record: dict[str, Any]) -> None:
        line = json.dumps(record, sort_keys=True, default=_json_default) + "\n"
        self._fh.write(line)
        self._fh.flush()
        os.fsync(self._fh.fileno())

    def close(self) -> None:
        self._fh.close()

    def __enter__(self) -> TrialLog:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _json_default(value: Any) -> Any:
    import numpy as np

    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


# --------------------------------------------------------------------------- summary


@dataclasses.dataclass
class TaskSummary:
    """Success of one task category.

    Attributes:
        task: Task category.
        per_seed: Success rate of each control run (seed), over its finished trials.
        mean: Mean of ``per_seed``.
        min: Lowest per-seed rate.
        max: Highest per-seed rate.
        num_instances: Distinct instances with a finished trial.
        num_trials: Finished trials (all seeds).
        num_errors: Trials that ended in an error (excluded from the rates).
        cost_kinds: Cost kinds of the finished trials (one entry unless a run mixed them).
        oracle_mean: The oracle's mean success on this task, if oracle results were given.
        normalised: ``mean / oracle_mean`` (``None`` without oracle results or if it is 0).
    """

    task: str
    per_seed: dict[int, float]
    mean: float
    min: float
    max: float
    num_instances: int
    num_trials: int
    num_errors: int
    cost_kinds: list[str]
    oracle_mean: float | None = None
    normalised: float | None = None


@dataclasses.dataclass
class Summary:
    """Scores of a run.

    Attributes:
        tasks: One row per task category with finished trials, in first-seen order.
        env_means: Mean success over each environment's task categories.
        mean: Mean success over all task categories.
        seed_means: Mean over task categories of each seed's rate (seeds every task has).
        min: Lowest of ``seed_means``.
        max: Highest of ``seed_means``.
        num_errors: Trials that ended in an error.
        normalised: ``mean`` / the oracle's mean over the same task categories.
        normalised_min: ``min`` / the oracle's mean.
        normalised_max: ``max`` / the oracle's mean.
        warnings: Things a reader of the numbers must know (mixed cost kinds, unequal seeds,
            errors, tasks missing from the oracle results).
        oracle_source: What the scores were normalised by (one line), ``None`` if by nothing.
        oracle_note: Why there is no normalised score although a shipped oracle was looked
            up (no table at the run's planner budget, another render, ...), one line.
    """

    tasks: list[TaskSummary]
    env_means: dict[str, float]
    mean: float
    seed_means: dict[int, float]
    min: float
    max: float
    num_errors: int
    normalised: float | None = None
    normalised_min: float | None = None
    normalised_max: float | None = None
    warnings: list[str] = dataclasses.field(default_factory=list)
    oracle_source: str | None = None
    oracle_note: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


def _mean(values: Iterable[float]) -> float:
    values = list(values)
    return sum(values) / len(values) if values else math.nan


def _latest_per_key(records: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    # A key appears once in a runner-written file; should a file be concatenated by hand, the
    # last record of a key is the one that counts.
    latest: dict[TrialKey, dict[str, Any]] = {}
    for r in records:
        latest[trial_key(r)] = r
    return list(latest.values())


def task_success(records: Iterable[dict[str, Any]]) -> dict[str, TaskSummary]:
    """Per-task success rates (mean, min, max over seeds) from trial records."""
    ok: dict[str, dict[int, list[bool]]] = defaultdict(lambda: defaultdict(list))
    instances: dict[str, set[int]] = defaultdict(set)
    errors: dict[str, int] = defaultdict(int)
    kinds: dict[str, set[str]] = defaultdict(set)
    order: list[str] = []
    for r in _latest_per_key(records):
        task = r["task"]
        if task not in order:
            order.append(task)
        if not is_ok(r):
            errors[task] += 1
            continue
        ok[task][int(r["seed"])].append(bool(r["success"]))
        instances[task].add(int(r["instance"]))
        kinds[task].add(str(r.get("cost", "unknown")))
    # The suite's order (RoboDesk, then the tabletop, as in TASK_NAMES), not the order in which
    # parallel trials happened to finish; unknown names keep their order after those.
    canonical = {name: i for i, name in enumerate(TASK_NAMES)}
    order.sort(key=lambda t: canonical.get(t, len(canonical)))
    out = {}
    for task in order:
        per_seed = {s: _mean(v) for s, v in sorted(ok[task].items())}
        rates = list(per_seed.values())
        out[task] = TaskSummary(
            task=task,
            per_seed=per_seed,
            mean=_mean(rates),
            min=min(rates) if rates else math.nan,
            max=max(rates) if rates else math.nan,
            num_instances=len(instances[task]),
            num_trials=sum(len(v) for v in ok[task].values()),
            num_errors=errors[task],
            cost_kinds=sorted(kinds[task]),
        )
    return out


def summarize(
    records: Sequence[dict[str, Any]],
    oracle_records: Sequence[dict[str, Any]] | None = None,
    *,
    oracle: Mapping[str, TaskSummary] | None = None,
    oracle_source: str | None = None,
    explained: Sequence[str] = (),
) -> Summary:
    """The scores of a run, optionally normalised by the oracle's.

    Args:
        records: Trial records of the run.
        oracle_records: Trial records of a simulator-oracle run on (at least) the same tasks.
        oracle: Or the oracle's per-task rows directly (e.g. the shipped oracle's,
            :meth:`vp2.oracle.shipped.ShippedOracle.match`).
        oracle_source: What the oracle is, one line (shown with the normalised score).
        explained: Tasks the caller left out of ``oracle`` and explains in its own notes: the
            note on tasks without oracle results does not name them again.

    Returns:
        The :class:`Summary`.
    """
    per_task = task_success(records)
    rows = [t for t in per_task.values() if t.num_trials > 0]
    warnings = []
    for t in per_task.values():
        if len(t.cost_kinds) > 1:
            warnings.append(f"{t.task}: trials used different costs {t.cost_kinds}")
        if "pixel_only" in t.cost_kinds:
            warnings.append(f"{t.task}: planned without its success classifier (cost pixel_only)")
        if t.num_errors:
            warnings.append(f"{t.task}: {t.num_errors} trial(s) ended in an error (not counted)")
        if t.num_trials == 0:
            warnings.append(f"{t.task}: no finished trials")
    seed_sets = [set(t.per_seed) for t in rows]
    common_seeds = sorted(set.intersection(*seed_sets)) if seed_sets else []
    if seed_sets and any(s != seed_sets[0] for s in seed_sets):
        warnings.append("task categories have different sets of seeds; min/max use the common ones")
    seed_means = {s: _mean(t.per_seed[s] for t in rows) for s in common_seeds}
    env_rows: dict[str, list[float]] = defaultdict(list)
    for t in rows:
        env_rows[t.task.split("/")[0]].append(t.mean)
    summary = Summary(
        tasks=rows,
        env_means={e: _mean(v) for e, v in env_rows.items()},
        mean=_mean(t.mean for t in rows),
        seed_means=seed_means,
        min=min(seed_means.values()) if seed_means else math.nan,
        max=max(seed_means.values()) if seed_means else math.nan,
        num_errors=sum(t.num_errors for t in per_task.values()),
        warnings=warnings,
    )
    if oracle_records is not None and oracle is not None:
        raise ValueError("give the oracle's records or its per-task rows, not both")
    if oracle_records is not None:
        oracle = task_success(oracle_records)
    if oracle is not None:
        summary.oracle_source = oracle_source
        _normalise(summary, oracle, explained)
    return summary


def _normalise(
    summary: Summary, oracle: Mapping[str, TaskSummary], explained: Sequence[str] = ()
) -> None:
    missing = [
        t.task for t in summary.tasks if t.task not in oracle or not oracle[t.task].num_trials
    ]
    unexplained = [t for t in missing if t not in explained]
    if unexplained:
        summary.warnings.append(
            f"no oracle results for {unexplained}; the normalised score omits them"
        )
    rows = [t for t in summary.tasks if t.task not in missing]
    for t in rows:
        t.oracle_mean = oracle[t.task].mean
        t.normalised = t.mean / t.oracle_mean if t.oracle_mean > 0 else None
    oracle_mean = _mean(t.oracle_mean for t in rows)  # type: ignore[misc]
    if not rows or not oracle_mean > 0:
        return
    common = set.intersection(*(set(t.per_seed) for t in rows))
    seed_means = [_mean(t.per_seed[s] for t in rows) for s in sorted(common)]
    summary.normalised = _mean(t.mean for t in rows) / oracle_mean
    if seed_means:
        summary.normalised_min = min(seed_means) / oracle_mean
        summary.normalised_max = max(seed_means) / oracle_mean


def _pct(x: float | None) -> str:
    return "-" if x is None or (isinstance(x, float) and math.isnan(x)) else f"{100 * x:.1f}"


def format_summary(summary: Summary, title: str | None = None) -> str:
    """The summary as a Markdown table (success in %, mean [min, max] over seeds)."""
    normalised = any(t.oracle_mean is not None for t in summary.tasks)
    head = "| task | success % mean | min | max | seeds | instances | errors | cost |"
    rule = "|---|---|---|---|---|---|---|---|"
    if normalised:
        head += " oracle % | normalised |"
        rule += "---|---|"
    lines = [f"## {title}", ""] if title else []
    lines += [head, rule]
    for t in summary.tasks:
        row = (
            f"| {t.task} | {_pct(t.mean)} | {_pct(t.min)} | {_pct(t.max)} | {len(t.per_seed)} | "
            f"{t.num_instances} | {t.num_errors} | {', '.join(t.cost_kinds)} |"
        )
        if normalised:
            ratio = "-" if t.normalised is None else f"{t.normalised:.2f}"
            row += f" {_pct(t.oracle_mean)} | {ratio} |"
        lines.append(row)
    for env, value in summary.env_means.items():
        lines.append(
            f"| **{env} (mean of tasks)** | {_pct(value)} | | | | | | |"
            + (" | |" if normalised else "")
        )
    lines.append(
        f"| **all tasks** | {_pct(summary.mean)} | {_pct(summary.min)} | {_pct(summary.max)} | "
        f"{len(summary.seed_means)} | | {summary.num_errors} | |" + (" | |" if normalised else "")
    )
    if summary.normalised is not None:
        lines += [
            "",
            f"Oracle-normalised score: {summary.normalised:.3f} "
            f"[{summary.normalised_min:.3f}, {summary.normalised_max:.3f}] (mean [min, max] over seeds)",
        ]
        if summary.oracle_source:
            lines.append(f"Normalised by the {summary.oracle_source}")
    elif summary.oracle_note:
        lines += ["", f"Not oracle-normalised: {summary.oracle_note}"]
    if summary.warnings:
        lines += ["", "Notes:"] + [f"- {w}" for w in summary.warnings]
    return "\n".join(lines)
