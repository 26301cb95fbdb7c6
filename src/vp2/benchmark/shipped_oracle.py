"""The shipped oracle: the simulator oracle's per-task success rates, the default normaliser.

A run's oracle-normalised score (SPEC §4) divides its success by the simulator oracle's on the
same tasks. Measuring the oracle takes hours, so its rates ship with the package as
``vp2/assets/oracle.json`` (``vp2 ship-oracle RUN_DIR ...`` builds the file from
simulator-oracle run directories, :mod:`vp2.benchmark.ship_oracle`), and ``vp2 run``, ``vp2 main`` and ``vp2 report`` normalise
by it unless an oracle run is given (``--oracle RUN_DIR``). The environment variable
``VP2_ORACLE_ASSET`` points the readers at another file (tests; a file that does not exist
means "no shipped oracle").

The file (``format`` :data:`ASSET_FORMAT`)::

    {"format": "vp2-oracle/1",
     "suite_format": "<vp2.data.suite.SUITE_FORMAT of the runs>",
     "date": "YYYY-MM-DD",            # when the oracle trials finished (the last one)
     "measured_by": "...",            # how: the runs' settings and vp2 versions
     "note": "...",                   # free text (--note)
     "settings": {...},               # the runs' protocol settings (model, planner, steps, cost)
     "tasks": {"robodesk/push_red": {"successes": 7, "trials": 9, "rate": 0.778,
                                     "instances": [0, 1, 2], "seeds": [0, 1, 2],
                                     "num_samples": 200}, ...},
     "instance_fingerprints": {"robodesk/push_red#0": "<TaskInstance.fingerprint>", ...}}

``rate`` is what a normalisation by the oracle run itself would use: the mean over seeds of
each seed's success rate (``successes / trials`` when every seed ran every instance).

A run is normalised only on tasks whose instances the oracle ran on are the run's (the
records' ``instance_sha`` against the file's fingerprints, and the suite format); the others
are omitted from the normalised score, and the summary says so.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Iterable, Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

from vp2.benchmark.results import Summary, TaskSummary, read_trials, summarize

PathLike = str | os.PathLike[str]

#: Format tag of the asset file.
ASSET_FORMAT = "vp2-oracle/1"
#: File name of the asset in ``vp2/assets``.
ASSET_FILE = "oracle.json"
#: Environment variable naming another asset file (a missing file: no shipped oracle).
ENV_VAR = "VP2_ORACLE_ASSET"
#: Model specs of the simulator oracle.
ORACLE_SPECS = ("simulator", "oracle")
#: Settings of an oracle run that must agree between the runs of one asset.
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
class OracleTask:
    """The oracle on one task category (see the module docstring for the fields)."""

    successes: int
    trials: int
    rate: float
    instances: tuple[int, ...]
    seeds: tuple[int, ...]
    num_samples: int | None


@dataclasses.dataclass(frozen=True)
class ShippedOracle:
    """A loaded asset file.

    Attributes:
        path: The file it was read from.
        suite_format: Task suite format the oracle ran on.
        date: When it was measured (``YYYY-MM-DD``).
        measured_by: How (the runs' settings).
        note: Free text given when it was built.
        settings: The runs' protocol settings.
        tasks: Per task category.
        instance_fingerprints: ``"task#index"`` -> instance fingerprint, for every instance
            the oracle ran on.
    """

    path: Path
    suite_format: str
    date: str
    measured_by: str
    note: str
    settings: dict[str, Any]
    tasks: dict[str, OracleTask]
    instance_fingerprints: dict[str, str]

    def describe(self) -> str:
        """One line: how the oracle was measured."""
        counts = sorted({len(t.instances) for t in self.tasks.values()})
        instances = (
            f"{counts[0]}" if len(counts) == 1 else f"{counts[0]}-{counts[-1]}"
        ) + " instance(s) per task"
        samples: dict[int | None, list[str]] = {}
        for name, t in self.tasks.items():
            samples.setdefault(t.num_samples, []).append(name)
        common = max(samples, key=lambda s: len(samples[s]))
        text = f"{common} planner samples"
        others = [f"{s} on {', '.join(n)}" for s, n in samples.items() if s != common]
        if others:
            text += f" ({'; '.join(others)})"
        seeds = sorted({s for t in self.tasks.values() for s in t.seeds})
        return (
            f"shipped oracle: simulator oracle on {len(self.tasks)} task(s), {instances}, "
            f"{text}, seed(s) {', '.join(map(str, seeds))}, suite {self.suite_format}, "
            f"measured {self.date}"
        )

    def task_summaries(self, tasks: Iterable[str] | None = None) -> dict[str, TaskSummary]:
        """The tasks as :class:`TaskSummary` rows (what the normalisation reads)."""
        names = self.tasks if tasks is None else [t for t in tasks if t in self.tasks]
        out = {}
        for name in names:
            t = self.tasks[name]
            out[name] = TaskSummary(
                task=name,
                per_seed={},
                mean=t.rate,
                min=t.rate,
                max=t.rate,
                num_instances=len(t.instances),
                num_trials=t.trials,
                num_errors=0,
                cost_kinds=[],
            )
        return out

    def for_records(
        self, records: Sequence[dict[str, Any]]
    ) -> tuple[dict[str, TaskSummary], list[str]]:
        """The tasks a run with ``records`` may be normalised on, and why others may not.

        A task is left out when a record ran on an instance whose fingerprint differs from
        the one the oracle ran on (another version of the task suite); every task is left out
        when the oracle's suite format is not this vp2's. Tasks the oracle lacks are left to
        the normalisation's own warning.
        """
        from vp2.data.suite import SUITE_FORMAT

        if self.suite_format != SUITE_FORMAT:
            return {}, [
                f"the shipped oracle was measured on task suite {self.suite_format!r}, this vp2 "
                f"uses {SUITE_FORMAT!r}: not normalised by it (rebuild it with `vp2 ship-oracle` "
                "from a new oracle run, or pass --oracle RUN_DIR)"
            ]
        changed = sorted(
            {
                r["task"]
                for r in records
                if r.get("instance_sha") is not None
                and self.instance_fingerprints.get(f"{r['task']}#{r['instance']}")
                not in (None, r["instance_sha"])
            }
        )
        warnings = []
        if changed:
            warnings.append(
                f"the shipped oracle ran on other instances of {changed} than this run (another "
                "task suite version); the normalised score omits them"
            )
        tasks = [t for t in dict.fromkeys(r["task"] for r in records) if t not in changed]
        return self.task_summaries(tasks), warnings


def _parse(data: Any, path: Path) -> ShippedOracle:
    try:
        if data.get("format") != ASSET_FORMAT:
            raise ValueError(f"format {data.get('format')!r}, expected {ASSET_FORMAT!r}")
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
        return ShippedOracle(
            path=path,
            suite_format=str(data["suite_format"]),
            date=str(data["date"]),
            measured_by=str(data.get("measured_by", "")),
            note=str(data.get("note", "")),
            settings=dict(data.get("settings") or {}),
            tasks=tasks,
            instance_fingerprints={
                str(k): str(v) for k, v in data["instance_fingerprints"].items()
            },
        )
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
        ValueError: the file exists but is not an oracle asset.
    """
    import json

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
    return _parse(data, path)


# --------------------------------------------------------------------------- normalising


def summarize_run(
    records: Sequence[dict[str, Any]],
    *,
    is_oracle: bool = False,
    oracle_run: PathLike | None = None,
    shipped: ShippedOracle | None = None,
    note_missing: bool = True,
) -> Summary:
    """A run's summary, normalised as every command does it.

    An oracle run is not normalised; else by ``oracle_run`` (``--oracle``) if given, else by
    the shipped oracle ``shipped`` (on the tasks it has for the run's instances). Without
    either, ``note_missing`` adds :data:`NO_SHIPPED_ORACLE` to the warnings.
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
    tasks, warnings = shipped.for_records(records)
    summary = summarize(records, oracle=tasks, oracle_source=shipped.describe())
    summary.warnings += warnings
    return summary
