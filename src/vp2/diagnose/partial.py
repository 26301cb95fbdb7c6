"""A diagnosis's partial file: the measurements ``vp2 diagnose`` has finished, kept as they
finish and reused by a re-run of the same settings and model (the ``partial`` argument of
:func:`vp2.diagnose.model.diagnose_model`)."""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

from vp2.utils.io import json_safe, write_json_atomic

log = logging.getLogger(__name__)

#: Format of a partial file.
PARTIAL_FORMAT = "vp2-diagnose-partial/1"


def partial_key(
    settings: dict[str, Any],
    env: str,
    identity: dict[str, Any],
    checkpoint: str | os.PathLike[str] | None,
) -> dict[str, Any]:
    """What a partial file's measurements depend on: the diagnosis's settings (``DiagnoseConfig``
    as a dict; its device and progress bar do not count), the environment, the model's identity
    and, for a checkpoint, its file's size and time."""
    from vp2 import __version__

    settings = {k: v for k, v in settings.items() if k not in ("device", "progress")}
    key: dict[str, Any] = {"settings": settings, "env": env, "model": identity,
                           "vp2_version": __version__}
    if checkpoint is not None:
        stat = os.stat(checkpoint)
        key["checkpoint"] = {"size": stat.st_size, "mtime_ns": stat.st_mtime_ns}
    return _as_json(key)


def _as_json(obj: Any) -> Any:
    """``obj`` as it reads back from a JSON file (so that measured and resumed values are the
    same objects)."""
    return json.loads(json.dumps(json_safe(obj)))


class PartialDiagnosis:
    """The measurements a diagnosis has finished, kept in a JSON file (``path``; ``None``:
    nowhere) and reused by a diagnosis of the same ``key`` (:func:`partial_key`)."""

    def __init__(self, path: str | Path | None, key: dict[str, Any]) -> None:
        self.path = None if path is None else Path(path)
        self.data: dict[str, Any] = {"format": PARTIAL_FORMAT, "key": key,
                                     "conditioning": None, "instances": {}}
        self.resumed: dict[str, Any] = {}
        if self.path is None or not self.path.is_file():
            return
        try:
            saved = json.loads(self.path.read_text())
        except (OSError, ValueError) as exc:
            log.warning("ignoring the unreadable partial diagnosis %s (%s)", self.path, exc)
            return
        if not isinstance(saved, dict) or saved.get("format") != PARTIAL_FORMAT or saved.get("key") != key:
            log.warning("%s holds a diagnosis of other settings, another model or another "
                        "vp2 version; starting over (it is replaced)", self.path)
            return
        self.data = saved
        self.resumed = {"conditioning": saved["conditioning"] is not None,
                        "instances": len(saved["instances"])}
        log.info("resuming the diagnosis in %s: %s", self.path, self.resumed)

    @property
    def conditioning(self) -> dict[str, Any] | None:
        return self.data["conditioning"]

    def row(self, key: str) -> dict[str, Any] | None:
        return self.data["instances"].get(key)

    def set_conditioning(self, result: dict[str, Any]) -> dict[str, Any]:
        """Keeps ``result`` and returns it as it reads back from the file."""
        self.data["conditioning"] = _as_json(result)
        self._save()
        return self.data["conditioning"]

    def add_row(self, key: str, row: dict[str, Any]) -> dict[str, Any]:
        """Keeps an instance's ``row`` and returns it as it reads back from the file."""
        self.data["instances"][key] = _as_json(row)
        self._save()
        return self.data["instances"][key]

    def _save(self) -> None:
        if self.path is not None:
            write_json_atomic(self.path, json_safe(self.data))
