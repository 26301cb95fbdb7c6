"""The shipped oracle: the simulator oracle's per-task success rates, the default normaliser.

A run's oracle-normalised score (SPEC §4) divides its success by the simulator oracle's on the
same tasks, measured at the run's own planner sample count and on the same images. Measuring
the oracle takes hours, so its rates ship with the package as ``vp2/assets/oracle.json``: a
set of *tables*, one per planner budget (e.g. ``samples-50``, the main job's count, and
``spec``, the SPEC's 200/800). ``vp2 ship-oracle`` builds the file from the trial records
committed under ``results/oracle`` (:mod:`vp2.oracle.build`); ``vp2 run``, ``vp2
main`` and ``vp2 report`` normalise by it unless an oracle run is given (``--oracle RUN_DIR``).
The environment variable ``VP2_ORACLE_ASSET`` points the readers at another file (tests; a
file that does not exist means "no shipped oracle").

The file (``format`` :data:`ASSET_FORMAT`)::

    {"format": "vp2-oracle/2",
     "tables": [
       {"name": "samples-50",
        "suite_format": "<vp2.data.suite.SUITE_FORMAT of the trials>",
        "date": "YYYY-MM-DD",             # when the oracle trials finished (the last one)
        "measured_by": "...",             # how: the runs, their settings and vp2 versions
        "note": "...",                    # free text (--note)
        "vp2_version": "...",             # of the trials (comma-separated if several)
        "settings": {...},                # the runs' protocol settings (model, planner, steps)
        "render": {"robodesk": "<fingerprint>", ...},   # vp2.envs.render_specs, per env
        "classifiers": {"robodesk/push_red": {"sha256": ..., "dataset": ...}, ...},
        "tasks": {"robodesk/push_red": {"successes": 7, "trials": 10, "rate": 0.7,
                                        "instances": [0, ...], "seeds": [0],
                                        "num_samples": 50}, ...},
        "instance_fingerprints": {"robodesk/push_red#0": "<TaskInstance.fingerprint>", ...}},
       ...]}

``rate`` is what a normalisation by the oracle run itself would use: the mean over seeds of
each seed's success rate (``successes / trials`` when every seed ran every instance).

Each task of a run is normalised by the table whose entry for the task has the planner sample
count the run used on it (:func:`vp2.planning.planner.planner_settings`; unset: the SPEC's
200/800), whose render fingerprint of the task's environment is this package's, whose suite
format is this vp2's and whose instances are the run's (the records' ``instance_sha`` against
the table's fingerprints). Tasks of one run may be matched by different tables. A task no
table matches is left out of the normalised score, with one line saying why
(:meth:`ShippedOracle.match`).
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

from vp2.oracle.tables import (
    OracleMatch,
    OracleTable,
    OracleTask,
    match_tables,
    samples_text,
)
from vp2.run.results import Summary, summarize
from vp2.run.run_dir import read_trials

PathLike = str | os.PathLike[str]

#: Format tag of the asset file.
ASSET_FORMAT = "vp2-oracle/2"
#: File name of the asset in ``vp2/assets``.
ASSET_FILE = "oracle.json"
#: Environment variable naming another asset file (a missing file: no shipped oracle).
ENV_VAR = "VP2_ORACLE_ASSET"
#: Model specs of the simulator oracle.
ORACLE_SPECS = ("simulator", "oracle")
#: Settings of an oracle run that must agree between the runs of one table.
SETTINGS = ("agent", "model", "optimizer", "gamma", "num_iterations", "cost", "num_steps")
#: What the summaries say when there is no shipped oracle.
NO_SHIPPED_ORACLE = (
    "no shipped oracle (vp2/assets/oracle.json): scores are not oracle-normalised; pass "
    "--oracle RUN_DIR (a simulator-oracle run) or build the file with `vp2 ship-oracle`"
)


def is_oracle_config(config: Mapping[str, Any]) -> bool:
    """Whether a run's ``config`` mapping (``config.yaml``) is a simulator-oracle run."""
    return config.get("agent", "planning") == "planning" and config.get("model") in ORACLE_SPECS


def default_asset_path() -> Path:
    """Where the package's asset lives (``vp2 ship-oracle`` writes there by default)."""
    return Path(str(resources.files("vp2") / "assets" / ASSET_FILE))


# --------------------------------------------------------------------------- the asset


@dataclasses.dataclass(frozen=True)
class ShippedOracle:
    """A loaded asset file: its tables."""

    path: Path
    tables: tuple[OracleTable, ...]

    def table(self, name: str) -> OracleTable:
        """The table called ``name``."""
        for t in self.tables:
            if t.name == name:
                return t
        raise KeyError(f"no shipped oracle table {name!r} (tables: {self.table_list()})")

    def table_list(self) -> str:
        """``"samples-50 at 50, spec at 200/800"``."""
        return ", ".join(f"{t.name} at {t.samples}" for t in self.tables) or "none"

    def describe(self) -> str:
        """One line per table."""
        return "\n".join(t.describe() for t in self.tables)

    def match(self, records: Sequence[dict[str, Any]], planner: Any = None) -> OracleMatch:
        """The table of each task of a run, and why some tasks have none.

        Args:
            records: The run's trial records.
            planner: The run's :class:`~vp2.planning.config.PlannerConfig` (``None``: the
                SPEC's), which gives the planner samples of each task.

        Returns:
            The :class:`~vp2.oracle.tables.OracleMatch`.
        """
        return match_tables(self.tables, records, planner)


def _parse_table(data: Mapping[str, Any]) -> OracleTable:
    tasks = {
        name: OracleTask(
            successes=int(t["successes"]),
            trials=int(t["trials"]),
            rate=float(t["rate"]),
            instances=tuple(int(i) for i in t["instances"]),
            seeds=tuple(int(s) for s in t["seeds"]),
            num_samples=None if t["num_samples"] is None else int(t["num_samples"]),
        )
        for name, t in data["tasks"].items()
    }
    return OracleTable(
        name=str(data["name"]),
        suite_format=str(data["suite_format"]),
        date=str(data["date"]),
        measured_by=str(data.get("measured_by", "")),
        note=str(data.get("note", "")),
        vp2_version=str(data.get("vp2_version", "")),
        settings=dict(data.get("settings") or {}),
        render={str(k): str(v) for k, v in data["render"].items()},
        classifiers={str(k): dict(v) for k, v in (data.get("classifiers") or {}).items()},
        tasks=tasks,
        instance_fingerprints={str(k): str(v) for k, v in data["instance_fingerprints"].items()},
    )


def parse_asset(data: Any, path: PathLike = "<asset>") -> ShippedOracle:
    """A :class:`ShippedOracle` of the asset's plain data (``json.load`` of the file).

    Raises:
        ValueError: not a ``vp2-oracle/2`` file (an older format is named as such).
    """
    path = Path(path)
    fmt = data.get("format") if isinstance(data, Mapping) else None
    if fmt == "vp2-oracle/1":
        raise ValueError(
            f"{path}: an oracle file of the old format vp2-oracle/1 (one table, no planner "
            f"budgets or render fingerprints); this vp2 reads {ASSET_FORMAT}: rebuild it with "
            "`vp2 ship-oracle` from the trial records under results/oracle"
        )
    try:
        if fmt != ASSET_FORMAT:
            raise ValueError(f"format {fmt!r}, expected {ASSET_FORMAT!r}")
        tables = tuple(_parse_table(t) for t in data["tables"])
        names = [t.name for t in tables]
        if len(set(names)) != len(names):
            raise ValueError(f"table names repeat: {names}")
        return ShippedOracle(path=path, tables=tables)
    except (AttributeError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(
            f"{path}: not a vp2 oracle file ({exc!r}); rebuild it with `vp2 ship-oracle`"
        ) from exc


def load_shipped_oracle(path: PathLike | None = None) -> ShippedOracle | None:
    """Loads an oracle asset; ``None`` if there is none.

    Args:
        path: The file; ``None``: ``$VP2_ORACLE_ASSET`` if set, else the package's
            ``vp2/assets/oracle.json``.

    Returns:
        The :class:`ShippedOracle`, or ``None`` if the file does not exist.

    Raises:
        ValueError: the file exists but is not an oracle asset of this format.
    """
    if path is None and not os.environ.get(ENV_VAR):
        ref = resources.files("vp2") / "assets" / ASSET_FILE
        if not ref.is_file():
            return None
        with resources.as_file(ref) as p:
            return load_shipped_oracle(p)
    path = Path(path if path is not None else os.environ[ENV_VAR])
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text())
    except ValueError as exc:
        raise ValueError(f"{path}: not a vp2 oracle file ({exc})") from exc
    return parse_asset(data, path)


# --------------------------------------------------------------------------- normalising


def summarize_run(
    records: Sequence[dict[str, Any]],
    *,
    is_oracle: bool = False,
    oracle_run: PathLike | None = None,
    shipped: ShippedOracle | None = None,
    planner: Any = None,
    note_missing: bool = True,
) -> Summary:
    """A run's summary, normalised as every command does it.

    An oracle run is not normalised; else by ``oracle_run`` (``--oracle``) if given, else by
    the shipped oracle ``shipped``: each task by the table of its planner samples under
    ``planner`` (the run's :class:`~vp2.planning.config.PlannerConfig`; ``None``: the
    SPEC's), :meth:`ShippedOracle.match`. Tasks no table matches are left out, and the
    summary's warnings say why, one line per reason; when no task is matched, ``oracle_note``
    does (and the summary has no normalised score). Without a shipped oracle, ``note_missing`` adds :data:`NO_SHIPPED_ORACLE` to
    the warnings.
    """
    if is_oracle:
        return summarize(records)
    if oracle_run:
        return summarize(records, read_trials(oracle_run), oracle_source=f"oracle run {oracle_run}")
    if shipped is None:
        summary = summarize(records)
        if note_missing:
            summary.warnings.append(NO_SHIPPED_ORACLE)
        return summary
    found = shipped.match(records, planner)
    if not found.tasks:
        summary = summarize(records)
        summary.oracle_note = "; ".join(found.notes) or None
    else:
        summary = summarize(records, oracle=found.tasks, oracle_source=found.source(),
                            explained=found.unmatched)
        summary.warnings += found.notes
    return summary


__all__ = [
    "ASSET_FILE",
    "ASSET_FORMAT",
    "ENV_VAR",
    "NO_SHIPPED_ORACLE",
    "OracleMatch",
    "OracleTable",
    "OracleTask",
    "ShippedOracle",
    "default_asset_path",
    "is_oracle_config",
    "load_shipped_oracle",
    "parse_asset",
    "samples_text",
    "summarize_run",
]
