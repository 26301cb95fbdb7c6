"""A run directory (:class:`RunDir`): its files, its stored configuration, its trial records and
summaries, and the checks of a resume.

::

    RUN_DIR/
      config.yaml          the resolved RunConfig, vp2 version, departures from the SPEC protocol
      trials.jsonl         one record per finished trial (vp2.run.results)
      summary.md           the summary table (and summary.json)
      gifs/TASK/           one GIF per trial, and with predictions one of the plan
                           (vp2.benchmark.gifs)
      partial/             the progress of the trials in progress (vp2.run.partial)
      precheck.json        the diagnosis pre-check of the run's model (vp2.benchmark.runner)
      report.html          the HTML report (vp2.report.page)
      diagnose.json        ``vp2 diagnose --out RUN_DIR`` (vp2.diagnose.model), and while it
                           runs its measurements so far (diagnose.partial.json)

This module is the one place where these names are spelled (the constants below and the paths
of :class:`RunDir`); every other module, and the scripts under ``benchmarks/``, reads and
writes a run through them (``tests/run/test_run_dir.py`` checks it).

Only the driver process of a run writes here (:meth:`RunDir.prepare`, :meth:`RunDir.trial_log`,
:meth:`RunDir.write_summary`); the report, the study and ``vp2 ship-oracle`` read. A resumed run
must keep the protocol settings (:data:`~vp2.run.config.PROTOCOL_FIELDS`) and the task
instances its finished trials ran on. Every score of a run counts only the trials its
``config.yaml`` covers (:meth:`RunDir.split_trials`). ``config.yaml`` is written in one form
(the planner nested); a directory written before the nesting is converted as it is read
(:func:`nest_legacy_config`).
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

import vp2
from vp2.data.suite import TaskInstance, TaskSuite
from vp2.planning.config import PlannerConfig
from vp2.run.config import RunConfig, flat_settings
from vp2.run.results import (
    Summary,
    TrialKey,
    TrialLog,
    format_summary,
    is_ok,
    read_trials_file,
    trial_key,
    trial_keys,
)
from vp2.utils.io import atomic_path, json_safe, remove_stale_temporaries, write_json_atomic

log = logging.getLogger(__name__)

# The names of a run directory's files, spelled here only.
#: The run's configuration (:meth:`RunDir.write_config`).
CONFIG_FILE = "config.yaml"
#: One JSON line per finished trial (:meth:`RunDir.trial_log`; also the records of a table of
#: the shipped oracle, ``results/oracle/<name>/``, and of the scripts' studies).
TRIALS_FILE = "trials.jsonl"
#: The summary table (:meth:`RunDir.write_summary`), as Markdown and as JSON.
SUMMARY_FILE = "summary.md"
SUMMARY_JSON = "summary.json"
#: The HTML report (:func:`vp2.report.page.write_run_report`; ``vp2 report``'s default file).
REPORT_FILE = "report.html"
#: The measures of the run's diagnosis pre-check (:func:`vp2.diagnose.precheck_model`).
PRECHECK_FILE = "precheck.json"
#: The report of ``vp2 diagnose`` (:func:`vp2.diagnose.model.write_report`) in a directory.
DIAGNOSIS_FILE = "diagnose.json"
#: Ending of the file beside a diagnosis report that keeps its unfinished measurements.
DIAGNOSIS_PARTIAL_SUFFIX = ".partial.json"
#: The trials' GIFs, one folder per task; a GIF's file ending; the plan GIF's name ending.
GIF_DIR = "gifs"
GIF_SUFFIX = ".gif"
PLAN_GIF_SUFFIX = "_plan"
#: Folder of the partial trials (:mod:`vp2.run.partial`) and their file ending.
PARTIAL_DIR = "partial"
PARTIAL_SUFFIX = ".npz"

#: Every name above, for the check that no other module spells one.
RUN_FILE_NAMES: tuple[str, ...] = (
    CONFIG_FILE, TRIALS_FILE, SUMMARY_FILE, SUMMARY_JSON, REPORT_FILE, PRECHECK_FILE,
    DIAGNOSIS_FILE, DIAGNOSIS_PARTIAL_SUFFIX, GIF_DIR, GIF_SUFFIX, PLAN_GIF_SUFFIX, PARTIAL_DIR,
    PARTIAL_SUFFIX,
)

Records = list[dict[str, Any]]


def task_slug(task: str) -> str:
    """A task's name as a file or folder name (``robodesk/push_red`` -> ``robodesk_push_red``)."""
    return task.replace("/", "_")


def trials_path(path: str | os.PathLike[str]) -> Path:
    """``path`` itself if it is a file, else ``path / trials.jsonl``."""
    path = Path(path)
    return path / TRIALS_FILE if path.is_dir() else path


def read_trials(path: str | os.PathLike[str], repair: bool = False) -> Records:
    """Reads the records of a run directory or ``trials.jsonl`` file
    (:func:`~vp2.run.results.read_trials_file`).

    Args:
        path: Run directory or the file itself. A missing file reads as no records.
        repair: Truncate a partial last line (left by a killed writer) from the file, so that
            appending can continue. Only the process that owns the run may do this.

    Raises:
        ValueError: if a line other than the last is not valid JSON.
    """
    return read_trials_file(trials_path(path), repair=repair)


def diagnosis_partial_path(report: str | os.PathLike[str]) -> Path:
    """Where a diagnosis whose report goes to ``report`` keeps its unfinished measurements:
    beside it, ``<report stem>.partial.json``."""
    report = Path(report)
    return report.with_name(f"{report.stem}{DIAGNOSIS_PARTIAL_SUFFIX}")


def nest_legacy_config(config: dict[str, Any]) -> dict[str, Any]:
    """The ``config`` mapping of a ``config.yaml`` in the nested form (the planner's settings
    under ``planner:``), the one form vp2 writes.

    vp2 0.1.0 before its planner's settings became one :class:`~vp2.planning.config.
    PlannerConfig` (``RunConfig.planner``) wrote them flat, beside the other fields:
    ``optimizer``, ``num_samples``, ``gamma`` and ``num_iterations`` (``sigma`` and ``options``
    did not exist). Such a mapping is returned with those keys moved under ``planner``; a
    nested one (or any mapping without those keys) is returned unchanged. This is the one place
    that reads the old form: :class:`RunDir` converts ``config.yaml`` with it as it reads the
    file (:meth:`RunDir.stored`, :meth:`RunDir.settings`, :meth:`RunDir.config`).

    Raises:
        ValueError: a planner field given twice, flat and nested, differently.
    """
    planner_names = {f.name for f in dataclasses.fields(PlannerConfig)}
    run_names = {f.name for f in dataclasses.fields(RunConfig)}
    flat = [k for k in config if k in planner_names and k not in run_names]
    if not flat:
        return config
    out = {k: v for k, v in config.items() if k not in flat}
    nested = out.get("planner")
    nested = dict(nested) if isinstance(nested, dict) else {}
    clash = sorted(k for k in flat if k in nested and nested[k] != config[k])
    if clash:
        raise ValueError(f"planner field(s) {clash} given twice, flat and nested, differently")
    out["planner"] = {**nested, **{k: config[k] for k in flat}}
    return out


class RunDir:
    """A benchmark run directory (module docstring): paths, configuration, records, summaries.

    Args:
        path: The directory (it need not exist yet).
    """

    def __init__(self, path: str | os.PathLike[str]) -> None:
        self.path = Path(path)

    def __repr__(self) -> str:
        return f"RunDir({str(self.path)!r})"

    # ---- paths ----------------------------------------------------------------------------

    @property
    def config_file(self) -> Path:
        return self.path / CONFIG_FILE

    @property
    def trials_file(self) -> Path:
        return self.path / TRIALS_FILE

    @property
    def summary_file(self) -> Path:
        return self.path / SUMMARY_FILE

    @property
    def summary_json(self) -> Path:
        return self.path / SUMMARY_JSON

    @property
    def gif_dir(self) -> Path:
        return self.path / GIF_DIR

    @property
    def report_file(self) -> Path:
        return self.path / REPORT_FILE

    @property
    def precheck_file(self) -> Path:
        return self.path / PRECHECK_FILE

    @property
    def diagnosis_file(self) -> Path:
        return self.path / DIAGNOSIS_FILE

    @property
    def partial_dir(self) -> Path:
        return self.path / PARTIAL_DIR

    def gif_path(self, task: str, index: int, seed: int, plan: bool = False) -> Path:
        """The GIF of the trial ``(task, index, seed)``: its execution, or (``plan``) the
        chosen plans' predictions."""
        suffix = PLAN_GIF_SUFFIX if plan else ""
        return self.gif_dir / task_slug(task) / f"i{index:03d}_s{seed}{suffix}{GIF_SUFFIX}"

    def partial_path(self, task: str, index: int, seed: int) -> Path:
        """Where the run keeps the partial trial of ``(task, index, seed)``."""
        return self.partial_dir / f"{task_slug(task)}_i{index:03d}_s{seed}{PARTIAL_SUFFIX}"

    def check_is_run(self) -> None:
        """Raises ``FileNotFoundError`` unless the directory holds trial records."""
        if not self.trials_file.is_file():
            raise FileNotFoundError(f"{self.path}: no {TRIALS_FILE} (not a vp2 run directory)")

    # ---- configuration --------------------------------------------------------------------

    def write_config(self, config: RunConfig) -> None:
        """Writes ``config.yaml``: the config, the vp2 version and the SPEC deviations."""
        payload = {
            "vp2_version": vp2.__version__,
            "written_at": datetime.datetime.now(datetime.timezone.utc).isoformat(
                timespec="seconds"
            ),
            "spec_deviations": config.deviations(),
            "config": config.to_dict(),
        }
        with atomic_path(self.config_file) as tmp:
            tmp.write_text(yaml.safe_dump(payload, sort_keys=False))

    def stored(self) -> dict[str, Any]:
        """All of ``config.yaml`` as plain data, its ``config`` mapping in the nested form
        (:func:`nest_legacy_config`); empty if there is none.

        Raises:
            ValueError: an old ``config`` mapping that gives a planner field twice.
        """
        if not self.config_file.is_file():
            return {}
        data = self._read_config_file()
        return data if isinstance(data, dict) else {}

    def settings(self) -> dict[str, Any]:
        """The stored ``config`` mapping, unchecked, shown flat (the planner's fields beside the
        others, :func:`~vp2.run.config.flat_settings`); empty without ``config.yaml``."""
        config = self.stored().get("config")
        return flat_settings(config) if isinstance(config, dict) else {}

    def deviations(self) -> list[str]:
        """The departures from the SPEC protocol stored with the configuration."""
        return list(self.stored().get("spec_deviations") or [])

    def config(self) -> RunConfig:
        """The stored configuration (a directory written before the planner was nested too,
        :func:`nest_legacy_config`).

        Raises:
            FileNotFoundError: no ``config.yaml``.
            KeyError, TypeError, ValueError: a file that does not hold a run's configuration.
        """
        return RunConfig.from_dict(self._read_config_file()["config"])

    def _read_config_file(self) -> Any:
        """``config.yaml`` as YAML reads it, a ``config`` mapping in it nested
        (:func:`nest_legacy_config`)."""
        data = yaml.safe_load(self.config_file.read_text())
        if isinstance(data, dict) and isinstance(data.get("config"), dict):
            data = {**data, "config": nest_legacy_config(data["config"])}
        return data

    # ---- trial records --------------------------------------------------------------------

    def trials(self, repair: bool = False) -> Records:
        """Every record in ``trials.jsonl`` (:func:`read_trials`)."""
        return read_trials_file(self.trials_file, repair=repair)

    def trial_log(self) -> TrialLog:
        """The appending writer of ``trials.jsonl`` (the driver process's alone)."""
        return TrialLog(self.trials_file)

    def split_trials(self, keys: Sequence[TrialKey] | None = None) -> tuple[Records, Records]:
        """The records the run's ``config.yaml`` covers (its seeds, tasks and instances), and
        the others: trials left there by a run with more seeds or instances, or appended from
        elsewhere. Every score of a run (its summary, ``vp2 report``, ``vp2 study``) counts the
        first list only. Without a readable config or task suite every record counts.

        Args:
            keys: The trial keys that count, instead of those of the stored config.
        """
        records = self.trials()
        if keys is None:
            try:
                config = self.config()
                suite = TaskSuite.load(config.suite)
                keys = trial_keys(suite.select(config.tasks, config.num_instances), config.seeds)
            except (OSError, KeyError, TypeError, ValueError) as exc:
                log.debug("%s: all %d trial(s) count (%r)", self.path, len(records), exc)
                return records, []
        wanted = set(keys)
        ours = [r for r in records if trial_key(r) in wanted]
        return ours, [r for r in records if trial_key(r) not in wanted]

    def outside_note(self, outside: Records) -> str:
        """What a reader is told about the records :meth:`split_trials` leaves out."""
        task, index, seed = trial_key(outside[0])
        return (
            f"{len(outside)} trial(s) in {self.trials_file} are outside the run's "
            f"seeds, tasks or instances (e.g. {task} #{index} seed {seed}) and are not counted; "
            "resume the run with settings that include them to count them"
        )

    def counted_trials(self) -> tuple[Records, str | None]:
        """The records that count (:meth:`split_trials`) and the note on the others, if any."""
        records, outside = self.split_trials()
        return records, self.outside_note(outside) if outside else None

    # ---- summaries ------------------------------------------------------------------------

    def write_summary(self, summary: Summary) -> None:
        """Writes ``summary.json`` and ``summary.md`` (the table titled ``vp2 run NAME``)."""
        write_json_atomic(self.summary_json, json_safe(summary.to_dict()))
        with atomic_path(self.summary_file) as tmp:
            tmp.write_text(format_summary(summary, title=f"vp2 run {self.path.name}") + "\n")

    # ---- a run's start and its resume ----------------------------------------------------

    @classmethod
    def prepare(cls, config: RunConfig) -> RunDir:
        """Creates (or, resuming, checks) the run directory ``config.out`` and writes
        ``config.yaml``.

        Raises:
            FileExistsError: the directory holds a run and ``config.resume`` is off, or it
                holds other files.
            ValueError: resuming with different protocol settings.
        """
        run = cls(config.out)
        existing = run.config_file.exists() or run.trials_file.exists()
        if not existing and run.path.is_dir() and any(run.path.iterdir()):
            raise FileExistsError(
                f"{run.path} exists, is not empty and is not a vp2 run directory (no "
                f"{run.config_file.name}); choose another --out directory"
            )
        if existing and not config.resume:
            done = len(run.trials()) if run.trials_file.exists() else 0
            if done:
                raise FileExistsError(
                    f"{run.path} already holds a run with {done} recorded trial(s): add --resume "
                    "to continue it, or choose another --out directory"
                )
            # A run that stopped before its first trial (a bad model, a typo) left only its
            # config: there is nothing to lose, so the directory is reused instead of blocking
            # the retry.
            log.info("%s holds no recorded trial; starting the run there afresh", run.path)
            existing = False
        if existing and run.config_file.exists():
            # Field by field, the planner's one by one; a directory written before the planner
            # was nested reads as the same protocol.
            old, new = run.config().protocol(), config.protocol()
            changed = [f"{k}: {old[k]!r} -> {v!r}" for k, v in new.items() if old[k] != v]
            if changed:
                raise ValueError(
                    f"cannot resume {run.path} with different protocol settings "
                    f"({'; '.join(changed)}); use a new output directory"
                )
        run.path.mkdir(parents=True, exist_ok=True)
        # Temporaries of writes a killed run left behind (GIFs live one level down per task).
        for directory in [run.path, *run.gif_dir.glob("*")]:
            if directory.is_dir():
                remove_stale_temporaries(directory)
        run.write_config(config)
        return run

    def check_same_instances(
        self, records: Records, by_key: dict[tuple[str, int], TaskInstance]
    ) -> None:
        """Refuses to resume when finished trials ran on other task instances than the suite's
        now."""
        changed = sorted({
            by_key[key].key
            for r in records
            if (key := (r["task"], r["instance"])) in by_key
            and r.get("instance_sha") not in (None, by_key[key].fingerprint)
        })
        if changed:
            raise ValueError(
                f"cannot resume {self.path}: finished trials ran on {len(changed)} task "
                f"instance(s) that differ from the task suite's now ({', '.join(changed[:5])}"
                f"{', ...' if len(changed) > 5 else ''}); the suite changed since (a new vp2 "
                "release or another --suite). Use a new output directory"
            )
        if any("instance_sha" not in r for r in records):
            log.warning(
                "%s: trials recorded before instance fingerprints existed; cannot check that "
                "they ran on the same task instances as the suite now", self.path
            )

    def resume_records(self, retry_errors: bool) -> Records:
        """Records already in the run, a partial last line cut off; error records dropped from
        the file (atomically) when they are to be re-run, so no key is ever written twice."""
        records = self.trials(repair=True)
        if retry_errors and any(not is_ok(r) for r in records):
            records = [r for r in records if is_ok(r)]
            with atomic_path(self.trials_file) as tmp:
                tmp.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in records))
        return records


def read_config(run_dir: str | os.PathLike[str]) -> RunConfig:
    """The configuration stored in a run directory (:meth:`RunDir.config`)."""
    return RunDir(run_dir).config()
