"""A run directory: its layout, its stored configuration, and the checks of a resume.

::

    RUN_DIR/
      config.yaml      the resolved RunConfig, vp2 version, departures from the SPEC protocol
      trials.jsonl     one record per finished trial (vp2.benchmark.results)
      summary.md       the summary table (and summary.json)
      gifs/TASK/       one GIF per trial (vp2.benchmark.gifs)

Only the driver process writes here. A resumed run must keep the protocol settings
(:data:`~vp2.benchmark.config.PROTOCOL_FIELDS`) and the task instances its finished trials
ran on.
"""

from __future__ import annotations

import datetime
import json
import logging
import os
from pathlib import Path
from typing import Any

import yaml

import vp2
from vp2.benchmark.config import PROTOCOL_FIELDS, RunConfig
from vp2.benchmark.results import TRIALS_FILE, is_ok, read_trials
from vp2.data.suite import TaskInstance
from vp2.utils.io import atomic_path, remove_stale_temporaries

log = logging.getLogger(__name__)

CONFIG_FILE = "config.yaml"
SUMMARY_FILE = "summary.md"
SUMMARY_JSON = "summary.json"
GIF_DIR = "gifs"


def write_config(run_dir: Path, config: RunConfig) -> None:
    """Writes ``config.yaml``: the config, the vp2 version and the SPEC deviations."""
    payload = {
        "vp2_version": vp2.__version__,
        "written_at": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
        "spec_deviations": config.deviations(),
        "config": config.to_dict(),
    }
    with atomic_path(run_dir / CONFIG_FILE) as tmp:
        tmp.write_text(yaml.safe_dump(payload, sort_keys=False))


def read_config(run_dir: str | os.PathLike[str]) -> RunConfig:
    """The configuration stored in a run directory."""
    data = yaml.safe_load((Path(run_dir) / CONFIG_FILE).read_text())
    return RunConfig.from_dict(data["config"])


def prepare_run_dir(config: RunConfig) -> Path:
    """Creates (or, resuming, checks) the run directory and writes ``config.yaml``.

    Raises:
        FileExistsError: the directory holds a run and ``config.resume`` is off.
        ValueError: resuming with different protocol settings.
    """
    run_dir = Path(config.out)
    existing = (run_dir / CONFIG_FILE).exists() or (run_dir / TRIALS_FILE).exists()
    if existing and not config.resume:
        done = len(read_trials(run_dir)) if (run_dir / TRIALS_FILE).exists() else 0
        if done:
            raise FileExistsError(
                f"{run_dir} already holds a run with {done} recorded trial(s): add --resume to "
                "continue it, or choose another --out directory"
            )
        # A run that stopped before its first trial (a bad model, a typo) left only its config:
        # there is nothing to lose, so the directory is reused instead of blocking the retry.
        log.info("%s holds no recorded trial; starting the run there afresh", run_dir)
        existing = False
    if existing and (run_dir / CONFIG_FILE).exists():
        old = read_config(run_dir)
        changed = [
            f"{f}: {getattr(old, f)!r} -> {getattr(config, f)!r}"
            for f in PROTOCOL_FIELDS
            if getattr(old, f) != getattr(config, f)
        ]
        if changed:
            raise ValueError(
                f"cannot resume {run_dir} with different protocol settings ({'; '.join(changed)}); "
                "use a new output directory"
            )
    run_dir.mkdir(parents=True, exist_ok=True)
    # Temporaries of writes a killed run left behind (GIFs live one level down per task).
    for directory in [run_dir, *(run_dir / GIF_DIR).glob("*")]:
        if directory.is_dir():
            remove_stale_temporaries(directory)
    write_config(run_dir, config)
    return run_dir


def check_same_instances(
    run_dir: Path, records: list[dict[str, Any]], by_key: dict[tuple[str, int], TaskInstance]
) -> None:
    """Refuses to resume when finished trials ran on other task instances than the suite's now."""
    changed = sorted({
        by_key[key].key
        for r in records
        if (key := (r["task"], r["instance"])) in by_key
        and r.get("instance_sha") not in (None, by_key[key].fingerprint)
    })
    if changed:
        raise ValueError(
            f"cannot resume {run_dir}: finished trials ran on {len(changed)} task instance(s) that "
            f"differ from the task suite's now ({', '.join(changed[:5])}"
            f"{', ...' if len(changed) > 5 else ''}); the suite changed since (a new vp2 "
            "release or another --suite). Use a new output directory"
        )
    if any("instance_sha" not in r for r in records):
        log.warning(
            "%s: trials recorded before instance fingerprints existed; cannot check that they "
            "ran on the same task instances as the suite now", run_dir
        )


def load_existing(run_dir: Path, retry_errors: bool) -> list[dict[str, Any]]:
    """Records already in the run, a partial last line cut off; error records dropped from
    the file (atomically) when they are to be re-run, so no key is ever written twice."""
    records = read_trials(run_dir, repair=True)
    if retry_errors and any(not is_ok(r) for r in records):
        records = [r for r in records if is_ok(r)]
        with atomic_path(run_dir / TRIALS_FILE) as tmp:
            tmp.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in records))
    return records
