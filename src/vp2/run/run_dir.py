"""A run directory (:class:`RunDir`): its files, its stored configuration, its trial records and
summaries, and the checks of a resume.

::

    RUN_DIR/
      config.yaml      the resolved RunConfig, vp2 version, departures from the SPEC protocol
      trials.jsonl     one record per finished trial (vp2.run.results)
      summary.md       the summary table (and summary.json)
      gifs/TASK/       one GIF per trial (vp2.benchmark.gifs)

Only the driver process of a run writes here (:meth:`RunDir.prepare`, :meth:`RunDir.trial_log`,
:meth:`RunDir.write_summary`); the report, the study and ``vp2 ship-oracle`` read. A resumed run
must keep the protocol settings (:data:`~vp2.run.config.PROTOCOL_FIELDS`) and the task
instances its finished trials ran on. Every score of a run counts only the trials its
``config.yaml`` covers (:meth:`RunDir.split_trials`).
"""

from __future__ import annotations

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
from vp2.run.config import RunConfig, flat_settings
from vp2.run.results import (
    TRIALS_FILE,
    Summary,
    TrialKey,
    TrialLog,
    format_summary,
    is_ok,
    read_trials,
    trial_key,
    trial_keys,
)
from vp2.utils.io import atomic_path, json_safe, remove_stale_temporaries, write_json_atomic

log = logging.getLogger(__name__)

CONFIG_FILE = "config.yaml"
SUMMARY_FILE = "summary.md"
SUMMARY_JSON = "summary.json"
GIF_DIR = "gifs"

Records = list[dict[str, Any]]


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
        """All of ``config.yaml`` as plain data; empty if there is none."""
        if not self.config_file.is_file():
            return {}
        data = yaml.safe_load(self.config_file.read_text())
        return dict(data) if isinstance(data, dict) else {}

    def settings(self) -> dict[str, Any]:
        """The stored ``config`` mapping in the flat form (the planner's fields beside the
        others), as written by any vp2 version, unchecked; empty without ``config.yaml``."""
        config = self.stored().get("config")
        return flat_settings(config) if isinstance(config, dict) else {}

    def deviations(self) -> list[str]:
        """The departures from the SPEC protocol stored with the configuration."""
        return list(self.stored().get("spec_deviations") or [])

    def config(self) -> RunConfig:
        """The stored configuration (either form of the planner's fields).

        Raises:
            FileNotFoundError: no ``config.yaml``.
            KeyError, TypeError, ValueError: a file that does not hold a run's configuration.
        """
        data = yaml.safe_load(self.config_file.read_text())
        return RunConfig.from_dict(data["config"])

    # ---- trial records --------------------------------------------------------------------

    def trials(self, repair: bool = False) -> Records:
        """Every record in ``trials.jsonl`` (:func:`~vp2.run.results.read_trials`)."""
        return read_trials(self.trials_file, repair=repair)

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
