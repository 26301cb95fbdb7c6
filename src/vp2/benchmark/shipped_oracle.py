"""The shipped oracle: the simulator oracle's per-task success rates, the default normaliser.

A run's oracle-normalised score (SPEC §4) divides its success by the simulator oracle's on the
same tasks. Measuring the oracle takes hours, so its rates ship with the package as
``vp2/assets/oracle.json`` (``vp2 ship-oracle RUN_DIR ...`` builds the file from
simulator-oracle run directories), and ``vp2 run``, ``vp2 main`` and ``vp2 report`` normalise
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

import argparse
import dataclasses
import datetime
import os
from collections.abc import Iterable, Mapping, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import yaml

from vp2.benchmark.results import (
    Summary,
    TaskSummary,
    is_ok,
    read_trials,
    summarize,
    task_success,
    trial_key,
)
from vp2.utils.io import write_json_atomic

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


def read_run_config(run_dir: PathLike) -> dict[str, Any]:
    """The ``config`` mapping of a run's ``config.yaml`` (empty if the file is missing)."""
    path = Path(run_dir) / "config.yaml"
    if not path.is_file():
        return {}
    return dict((yaml.safe_load(path.read_text()) or {}).get("config") or {})


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


# --------------------------------------------------------------------------- building


def _num_samples(task: str, config: Mapping[str, Any]) -> int | None:
    """Planner samples the run used on ``task`` (its setting, else the SPEC default)."""
    from vp2.benchmark.agent import PlannerConfig, planner_settings

    planner = PlannerConfig(
        optimizer=config.get("optimizer", "mppi"),
        num_samples=config.get("num_samples"),
        gamma=config.get("gamma", 0.05),
    )
    return planner_settings(task, planner).get("num_samples")


def _finished_date(records: Iterable[dict[str, Any]]) -> str | None:
    stamps = [r["finished_at"] for r in records if r.get("finished_at")]
    return max(stamps)[:10] if stamps else None


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
        run_dir = Path(d)
        config = read_run_config(run_dir)
        if not config:
            raise ValueError(f"{run_dir}: no config.yaml (not a vp2 run directory)")
        if not is_oracle_config(config):
            raise ValueError(
                f"{run_dir} is not a simulator-oracle run (model {config.get('model')!r}, agent "
                f"{config.get('agent')!r}); build the oracle from runs of `vp2 run --model "
                "simulator`"
            )
        run_records = list({trial_key(r): r for r in read_trials(run_dir)}.values())
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


# --------------------------------------------------------------------------- vp2 ship-oracle


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 ship-oracle`` arguments to ``p`` (a sub-parser) and returns it."""
    p.add_argument(
        "run_dirs",
        nargs="+",
        type=Path,
        metavar="RUN_DIR",
        help="simulator-oracle run directories (vp2 run --model simulator), finished, no errors",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=None,
        metavar="PATH",
        help=f"the file to write (default: the package's vp2/assets/{ASSET_FILE})",
    )
    p.add_argument("--note", default="", metavar="TEXT", help="free text stored with it")
    return p


def run_from_args(args: argparse.Namespace) -> int:
    """Runs ``vp2 ship-oracle`` from parsed arguments."""
    out = write_oracle_asset(build_oracle_asset(args.run_dirs, note=args.note), args.out)
    oracle = load_shipped_oracle(out)
    assert oracle is not None
    for name, t in oracle.tasks.items():
        print(
            f"{name:34s} {100 * t.rate:5.1f}%  ({t.successes}/{t.trials} trials, "
            f"{len(t.instances)} instances, {t.num_samples} samples)"
        )
    print(f"{oracle.describe()}\nwrote {out}")
    return 0
