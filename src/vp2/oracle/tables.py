"""The shipped oracle's tables, and which table normalises each task of a run.

A table (:class:`OracleTable`) is the simulator oracle measured at one planner budget; the
asset that holds them and how summaries use them: :mod:`vp2.oracle.shipped`.
:func:`match_tables` picks, for every task of a run, the table measured at the run's planner
samples on that task, with this package's render fingerprint of the task's environment, this
vp2's task suite format and the run's instances; the tasks it cannot match get one note per
reason (no table at that budget, another render, another suite, other instances, no table
with the task).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Sequence
from typing import Any

from vp2 import spec
from vp2.run.results import TaskSummary


def samples_text(counts: Iterable[int | None]) -> str:
    """Planner sample counts as the notes write them: ``"50"``, ``"200/800"``."""
    values = sorted(set(counts), key=lambda c: (c is None, c or 0))
    return "/".join("?" if c is None else str(c) for c in values)


@dataclasses.dataclass(frozen=True)
class OracleTask:
    """The oracle on one task category in one table (fields as in the asset file)."""

    successes: int
    trials: int
    rate: float
    instances: tuple[int, ...]
    seeds: tuple[int, ...]
    num_samples: int | None


@dataclasses.dataclass(frozen=True)
class OracleTable:
    """One table of the asset: the oracle at one planner budget.

    Attributes:
        name: The table's name (its folder under ``results/oracle``).
        suite_format: Task suite format the oracle ran on.
        date: When it was measured (``YYYY-MM-DD``).
        measured_by: How (the runs and their settings).
        note: Free text given when it was built.
        vp2_version: The vp2 version(s) of the trials.
        settings: The runs' protocol settings.
        render: Render fingerprint of each environment it ran on
            (:func:`vp2.envs.render_specs.render_fingerprint`).
        classifiers: The success classifier each task planned with (its provenance).
        tasks: Per task category.
        instance_fingerprints: ``"task#index"`` -> instance fingerprint, for every instance
            the oracle ran on.
    """

    name: str
    suite_format: str
    date: str
    measured_by: str
    note: str
    vp2_version: str
    settings: dict[str, Any]
    render: dict[str, str]
    classifiers: dict[str, dict[str, Any]]
    tasks: dict[str, OracleTask]
    instance_fingerprints: dict[str, str]

    @property
    def samples(self) -> str:
        """Its planner sample counts, ``"50"`` or ``"200/800"``."""
        return samples_text(t.num_samples for t in self.tasks.values())

    def label(self) -> str:
        """``'samples-50' (50 planner samples, measured 2026-11-30)``."""
        return f"'{self.name}' ({self.samples} planner samples, measured {self.date})"

    def describe(self) -> str:
        """One line: which table, and how the oracle was measured."""
        counts = sorted({len(t.instances) for t in self.tasks.values()})
        instances = (
            f"{counts[0]}" if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"
        ) + " instance(s) per task"
        seeds = sorted({s for t in self.tasks.values() for s in t.seeds})
        return (
            f"shipped oracle table {self.label()}: simulator oracle on {len(self.tasks)} "
            f"task(s), {instances}, seed(s) {', '.join(map(str, seeds))}, "
            f"suite {self.suite_format}"
        )

    def env_rates(self) -> dict[str, float]:
        """Each environment's success fraction, its tasks' successes and trials pooled:
        ``{"robodesk": 49 / 70, "tabletop": 25 / 40}``."""
        pooled: dict[str, list[int]] = {}
        for name, t in self.tasks.items():
            acc = pooled.setdefault(name.split("/")[0], [0, 0])
            acc[0] += t.successes
            acc[1] += t.trials
        return {env: s / n for env, (s, n) in sorted(pooled.items()) if n}

    def task_summary(self, task: str) -> TaskSummary:
        """The table's row of ``task`` as a :class:`TaskSummary` (what normalising reads)."""
        t = self.tasks[task]
        return TaskSummary(
            task=task, per_seed={}, mean=t.rate, min=t.rate, max=t.rate,
            num_instances=len(t.instances), num_trials=t.trials, num_errors=0, cost_kinds=[],
        )


@dataclasses.dataclass
class OracleMatch:
    """Which table normalises each task of a run.

    Attributes:
        tasks: The oracle's row of each matched task (what
            :func:`~vp2.run.results.summarize` normalises by).
        tables: The table of each matched task.
        notes: One line per reason why tasks have no table.
        unmatched: The tasks without a table (each named or implied by a note).
    """

    tasks: dict[str, TaskSummary]
    tables: dict[str, OracleTable]
    notes: list[str]
    unmatched: list[str]

    def source(self) -> str | None:
        """What normalised the run, one line; ``None`` if no task was matched."""
        used: dict[str, tuple[OracleTable, int]] = {}
        for table in self.tables.values():
            used[table.name] = (table, used.get(table.name, (table, 0))[1] + 1)
        if not used:
            return None
        if len(used) == 1:
            return next(iter(used.values()))[0].describe()
        return "shipped oracle tables " + " and ".join(
            f"{table.label()} on {n} task(s)" for table, n in used.values())


def task_samples(task: str, planner: Any = None) -> int | None:
    """Planner samples a run with ``planner`` (a :class:`~vp2.planning.config.PlannerConfig`;
    ``None``: the SPEC's) uses on ``task``; ``None`` if its settings give none."""
    from vp2.planning.config import PlannerConfig
    from vp2.planning.planner import planner_settings

    try:
        return planner_settings(task, planner or PlannerConfig()).get("num_samples")
    except (KeyError, ValueError):
        return None


def _classifier_key(classifier: dict[str, Any] | None) -> tuple[Any, Any] | None:
    """``(sha256, weight)`` of a classifier's provenance, ``None`` for none.

    Records written before the weight was recorded (and tables built from them) name no
    weight; they planned at the SPEC's weight, the only one ``vp2 run`` used until per-task
    weights came with the field.
    """
    if not classifier:
        return None
    weight = classifier.get("weight")
    return (classifier.get("sha256"),
            float(spec.ROBODESK_CLASSIFIER_WEIGHT if weight is None else weight))


def _describe_classifier(key: tuple[Any, Any] | None) -> str:
    return "no classifier" if key is None else f"classifier {key[0]} at weight {key[1]:g}"


def _problem(table: OracleTable, task: str, shas: dict[int, str], fingerprints: dict[str, str],
             classifiers: Sequence[tuple[Any, Any] | None] = ()) -> tuple[Any, ...] | None:
    """Why ``table`` may not normalise ``task`` (a note's key), ``None`` if it may.

    A table measured on another suite version normalises the task only where it fingerprinted
    every instance the run used (``shas``) and each fingerprint matches.

    ``classifiers`` are the :func:`_classifier_key` of every success classifier the run's
    trials of the task planned with (``None`` for a pixel-only cost; empty where the records
    do not say); a table measured with another classifier file or weight does not normalise
    the task.
    """
    from vp2.data.suite import SUITE_FORMAT

    env = task.split("/")[0]
    # A table of an earlier suite still normalises a task whose instances it fingerprinted
    # and the run used unchanged (a new suite version may regenerate only some categories).
    if table.suite_format != SUITE_FORMAT and not (
        shas and all(table.instance_fingerprints.get(f"{task}#{i}") == sha for i, sha in shas.items())
    ):
        return ("suite", table.name, table.suite_format)
    if table.render.get(env) != fingerprints[env]:
        return ("render", table.name, env, table.render.get(env), fingerprints[env])
    if any(table.instance_fingerprints.get(f"{task}#{i}") not in (None, sha)
           for i, sha in shas.items()):
        return ("instances", table.name)
    theirs = _classifier_key(table.classifiers.get(task))
    for ours in classifiers:
        if ours != theirs:
            return ("classifier", table.name, _describe_classifier(theirs),
                    _describe_classifier(ours))
    return None


def _note(key: tuple[Any, ...], tasks: list[str], every: bool, normalised: bool,
          tables: Sequence[OracleTable], samples: dict[str, int | None]) -> str:
    """One line: why ``tasks`` have no table (``key`` from :func:`_problem`, or ``("samples",)``
    / ``("absent",)``). Where no task of the run is normalised, the reader's prefix says so
    ("not oracle-normalised: ..."); otherwise the line says that the score omits them."""
    from vp2.data.suite import SUITE_FORMAT

    named = ", ".join(tasks)
    which = "" if every else f" for {named}"
    remeasure = "re-measure it (`vp2 ship-oracle`) or pass --oracle RUN_DIR"
    kind = key[0]
    if kind == "samples":
        listed = ", ".join(f"{t.name} at {t.samples}" for t in tables)
        head = (f"no shipped oracle table at {samples_text(samples[t] for t in tasks)} planner "
                f"samples{which} (tables: {listed})")
        remedy = "pass --oracle RUN_DIR (a simulator-oracle run at the same budget)"
    elif kind == "absent":
        head, remedy = f"no shipped oracle table has {named}", ""
    elif kind == "suite":
        head = (f"the shipped oracle table '{key[1]}' was measured on task suite {key[2]!r}, "
                f"this vp2 uses {SUITE_FORMAT!r}{which}")
        remedy = remeasure
    elif kind == "classifier":
        head = (f"the shipped oracle table '{key[1]}' planned{which} with {key[2]}, this run "
                f"with {key[3]}")
        remedy = remeasure
    elif kind == "render":
        head = (f"the shipped oracle table '{key[1]}' was rendered with another camera/render "
                f"spec ({key[2]} render fingerprint {key[3]}, this vp2's {key[4]}){which}")
        remedy = remeasure
    else:
        head = (f"the shipped oracle table '{key[1]}' ran on other instances of {named} than "
                "this run (another task suite version)")
        remedy = ""
    if normalised:
        head += f": the normalised score omits {'it' if len(tasks) == 1 else 'them'}"
    return head + (f"; {remedy}" if remedy else "")


def match_tables(
    tables: Sequence[OracleTable], records: Sequence[dict[str, Any]], planner: Any = None
) -> OracleMatch:
    """The table of each task of a run (module docstring); see :class:`OracleMatch`.

    Args:
        tables: The shipped oracle's tables, in the asset's order (the first table that
            matches a task is used).
        records: The run's trial records (their tasks, instances, ``instance_sha`` and
            ``agent.classifier``, the success classifier and weight they planned with).
        planner: The run's :class:`~vp2.planning.config.PlannerConfig` (``None``: SPEC).
    """
    from vp2.envs.render_specs import render_fingerprint

    order = list(dict.fromkeys(r["task"] for r in records))
    shas: dict[str, dict[int, str]] = {t: {} for t in order}
    classifiers: dict[str, dict[Any, None]] = {t: {} for t in order}  # ordered sets
    for r in records:
        if r.get("instance_sha") is not None:
            shas[r["task"]][int(r["instance"])] = r["instance_sha"]
        # An agent that plans nothing (random actions: cost "none") has no classifier to compare.
        if isinstance(r.get("agent"), dict) and r.get("cost") != "none":
            classifiers[r["task"]][_classifier_key(r["agent"].get("classifier"))] = None
    samples = {t: task_samples(t, planner) for t in order}
    fingerprints: dict[str, str] = {}
    rows: dict[str, TaskSummary] = {}
    chosen: dict[str, OracleTable] = {}
    reasons: dict[tuple[Any, ...], list[str]] = {}
    for task in order:
        env = task.split("/")[0]
        candidates = [t for t in tables if task in t.tasks]
        at_budget = [t for t in candidates if t.tasks[task].num_samples == samples[task]]
        if not candidates:
            reasons.setdefault(("absent",), []).append(task)
            continue
        if not at_budget:
            reasons.setdefault(("samples",), []).append(task)
            continue
        if env not in fingerprints:
            fingerprints[env] = render_fingerprint(env)
        problems = [_problem(t, task, shas[task], fingerprints, list(classifiers[task]))
                    for t in at_budget]
        ok = [t for t, p in zip(at_budget, problems, strict=True) if p is None]
        if ok:
            chosen[task], rows[task] = ok[0], ok[0].task_summary(task)
        else:
            reasons.setdefault(problems[0], []).append(task)  # type: ignore[arg-type]
    notes = [
        _note(key, tasks, set(tasks) == set(order), bool(rows), tables, samples)
        for key, tasks in reasons.items()
    ]
    unmatched = [t for t in order if t not in rows]
    return OracleMatch(tasks=rows, tables=chosen, notes=notes, unmatched=unmatched)
