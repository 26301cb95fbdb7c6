"""The model zoo: trained checkpoints shipped by name, each with a card (``--model zoo:NAME``).

The zoo is a folder (``vp2/assets/zoo``, or the one ``$VP2_ZOO_DIR`` names) with one folder per
entry::

    NAME/card.json   the card: what the model is, how it was trained, what was measured of it
                     and the commands that rebuilt it (format "vp2-zoo-card/1", :data:`FIELDS`)
    NAME/model.pt    the checkpoint (:mod:`vp2.models.checkpoint`), unless the card's
                     ``checkpoint`` names another file (a path relative to the card's folder)

The card's ``sha256`` pins the checkpoint: a card whose file does not match is refused.
:func:`list_zoo` reads every card and :func:`get_card` one by name; making and filling
entries is :mod:`vp2.models.zoo_entries`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import re
from collections.abc import Callable, Mapping
from importlib import resources
from pathlib import Path
from typing import Any

from vp2.models.registry import MODELS, model_names

#: Format tag of a card.
CARD_FORMAT = "vp2-zoo-card/1"
#: The environment variable that points the zoo at another folder.
ZOO_DIR_ENV = "VP2_ZOO_DIR"
#: The ``--model`` prefix of a zoo entry: ``zoo:NAME``.
ZOO_PREFIX = "zoo:"
CARD_FILE = "card.json"
#: The checkpoint's file in an entry made by :func:`add_to_zoo`.
CHECKPOINT_FILE = "model.pt"
#: The measured fields: ``null`` until measured.
MEASURED = ("action_conditioning", "metrics", "control")
#: The metrics of a card's ``metrics`` (each a number or ``null``).
METRICS = ("fvd", "lpips", "ssim", "psnr", "mse")
#: Fields read from the checkpoint by :func:`add_to_zoo`, never taken from a user's JSON.
DERIVED = ("name", "family", "preset", "model_args", "parameters", "checkpoint", "sha256", "steps")
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")

Check = tuple[Callable[[Any], bool], str]


def _num(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


_STR: Check = (lambda v: isinstance(v, str) and bool(v), "a non-empty string")
_OPT_STR: Check = (lambda v: v is None or isinstance(v, str), "a string or null")
_OPT_NUM: Check = (lambda v: v is None or _num(v), "a number or null")
_COUNT: Check = (lambda v: _int(v) and v > 0, "a positive integer")
_MAPPING: Check = (lambda v: isinstance(v, dict), "a mapping")
_OPT_SECTION: Check = (lambda v: v is None or isinstance(v, dict), "a mapping or null")

#: The card's fields in the order written, each with its check.
FIELDS: dict[str, Check] = {
    "name": (lambda v: isinstance(v, str) and bool(NAME_PATTERN.fullmatch(v)),
             "a name of letters, digits, '.', '_' and '-'"),
    "family": _STR,
    "preset": _OPT_STR,
    "model_args": _MAPPING,
    "parameters": _COUNT,
    "env": _STR,
    "checkpoint": _STR,
    "sha256": (lambda v: isinstance(v, str) and bool(re.fullmatch(r"[0-9a-f]{64}", v)),
               "64 lowercase hex digits"),
    "dataset": _MAPPING,
    "steps": (lambda v: _int(v) and v >= 0, "a non-negative integer"),
    "budget": _MAPPING,
    "device": _OPT_STR,
    "action_conditioning": _OPT_SECTION,
    "metrics": _OPT_SECTION,
    "control": _OPT_SECTION,
    "rebuild": (lambda v: isinstance(v, list) and bool(v) and all(isinstance(c, str) for c in v),
                "a non-empty list of commands"),
    "notes": _OPT_STR,
}
#: The keys each section must have (more are allowed: dates, notes, details).
SECTIONS: dict[str, dict[str, Check]] = {
    "dataset": {"name": _STR, "made_with": (lambda v: v is None or isinstance(v, list),
                                            "a list of commands or null")},
    "budget": {"wall_minutes": _OPT_NUM, "cores": _OPT_STR, "date": _OPT_STR},
    "action_conditioning": {
        "ratio": (_num, "a number"),
        "interval": (lambda v: isinstance(v, list) and len(v) == 2 and all(map(_num, v)),
                     "[low, high]"),
        "clips": _COUNT,
        "command": _STR,
    },
    "metrics": {**{m: _OPT_NUM for m in METRICS}, "command": _STR},
    "control": {  # per environment
        "successes": (lambda v: _int(v) and v >= 0, "a non-negative integer"),
        "trials": _COUNT,
        "seeds": (lambda v: isinstance(v, list) and bool(v) and all(map(_int, v)),
                  "a list of seeds"),
        "instances": _COUNT,
        "samples": _COUNT,
        "command": _STR,
    },
}


class ZooError(ValueError):
    """An unknown zoo entry, a malformed card, or a checkpoint its card does not match."""


def zoo_dir() -> Path:
    """The zoo's folder: ``$VP2_ZOO_DIR`` if set, else the package's ``vp2/assets/zoo``."""
    if os.environ.get(ZOO_DIR_ENV):
        return Path(os.environ[ZOO_DIR_ENV])
    return Path(str(resources.files("vp2") / "assets" / "zoo"))


_SHA_CACHE: dict[tuple[str, int, int], str] = {}


def sha256_of(path: str | os.PathLike[str]) -> str:
    """The file's SHA-256 (hex); remembered per path, size and modification time."""
    stat = os.stat(path)
    key = (str(Path(path).resolve()), stat.st_size, stat.st_mtime_ns)
    if key not in _SHA_CACHE:
        digest = hashlib.sha256()
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                digest.update(block)
        _SHA_CACHE[key] = digest.hexdigest()
    return _SHA_CACHE[key]


def _check_fields(where: str, data: Mapping[str, Any], checks: Mapping[str, Check]) -> None:
    missing = [k for k in checks if k not in data]
    if missing:
        raise ZooError(f"{where}: missing field(s) {', '.join(missing)}")
    for key, (ok, want) in checks.items():
        if not ok(data[key]):
            raise ZooError(f"{where}: field {key!r} must be {want}, not {data[key]!r}")


@dataclasses.dataclass(frozen=True, eq=False)
class ZooCard:
    """One zoo entry's card (the fields of :data:`FIELDS`) and where it lives.

    Attributes:
        directory: The entry's folder (``checkpoint`` is relative to it).
    """

    name: str
    family: str
    preset: str | None
    model_args: dict[str, Any]
    parameters: int
    env: str
    checkpoint: str
    sha256: str
    dataset: dict[str, Any]
    steps: int
    budget: dict[str, Any]
    device: str | None
    action_conditioning: dict[str, Any] | None
    metrics: dict[str, Any] | None
    control: dict[str, Any] | None
    rebuild: list[str]
    notes: str | None
    directory: Path

    @classmethod
    def from_json(cls, data: Any, directory: Path, where: str = "") -> ZooCard:
        """A card from its JSON data, checked field by field.

        Raises:
            ZooError: naming ``where`` (the card's file) and the first field that is wrong.
        """
        where = where or str(directory / CARD_FILE)
        if not isinstance(data, dict) or data.get("format") != CARD_FORMAT:
            found = data.get("format") if isinstance(data, dict) else type(data).__name__
            raise ZooError(f"{where}: not a zoo card (format {found!r}, expected {CARD_FORMAT!r})")
        unknown = sorted(set(data) - set(FIELDS) - {"format"})
        if unknown:
            raise ZooError(f"{where}: unknown field(s) {', '.join(unknown)}; a card has "
                           f"{', '.join(FIELDS)}")
        _check_fields(where, data, FIELDS)
        if data["family"] not in MODELS:
            raise ZooError(f"{where}: family {data['family']!r} is not a registered model "
                           f"({', '.join(model_names())})")
        for section, checks in SECTIONS.items():
            value = data[section]
            if value is None:
                continue
            if section == "control":
                for env, row in value.items():
                    if not isinstance(row, dict):
                        raise ZooError(f"{where}: control[{env!r}] must be a mapping")
                    _check_fields(f"{where}: control[{env!r}]", row, checks)
            else:
                _check_fields(f"{where}: {section}", value, checks)
        return cls(**{k: data[k] for k in FIELDS}, directory=directory)

    def to_json(self) -> dict[str, Any]:
        """The card as written to ``card.json``: the format tag, then :data:`FIELDS` in order."""
        return {"format": CARD_FORMAT, **{k: getattr(self, k) for k in FIELDS}}

    @property
    def spec(self) -> str:
        """The ``--model`` string of this entry."""
        return f"{ZOO_PREFIX}{self.name}"

    @property
    def checkpoint_path(self) -> Path:
        """The checkpoint file the card names."""
        return Path(os.path.normpath(self.directory / self.checkpoint))

    def verify(self) -> Path:
        """Checks that the checkpoint exists and is the one the card describes (its sha256);
        returns its path.

        Raises:
            ZooError: the file is missing or its sha256 differs from the card's.
        """
        path = self.checkpoint_path
        if not path.is_file():
            raise ZooError(f"zoo model {self.name!r}: its checkpoint {path} is missing "
                           f"(the card {self.directory / CARD_FILE} names it)")
        actual = sha256_of(path)
        if actual != self.sha256:
            raise ZooError(
                f"zoo model {self.name!r}: the checkpoint {path} does not match its card "
                f"(sha256 {actual[:16]}..., the card says {self.sha256[:16]}...): the file "
                "changed after the card was written, so the card's figures are not of it; "
                f"restore the file, or make a new entry of it with `vp2 zoo add {path} "
                "--name NEW_NAME`"
            )
        return path

    def not_measured(self) -> list[str]:
        """The measured fields still ``null`` (``metrics.fvd``, ... for single metrics)."""
        missing = [k for k in MEASURED if getattr(self, k) is None]
        if self.metrics is not None:
            missing += [f"metrics.{m}" for m in METRICS if self.metrics.get(m) is None]
        return missing

    def not_recorded(self) -> list[str]:
        """Descriptive fields left ``null`` (the device, the budget's time or date, the
        commands that made the dataset)."""
        fields = [("device", self.device), ("dataset.made_with", self.dataset.get("made_with"))]
        fields += [(f"budget.{k}", self.budget.get(k)) for k in SECTIONS["budget"]]
        return [name for name, value in fields if value is None]


def read_card(path: str | os.PathLike[str]) -> ZooCard:
    """The card in a ``card.json`` file (or an entry's folder).

    Raises:
        ZooError: the file is missing, not JSON, or not a valid card.
    """
    path = Path(path)
    if path.is_dir():
        path = path / CARD_FILE
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise ZooError(f"cannot read the zoo card {path}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise ZooError(f"{path}: not JSON ({exc})") from None
    card = ZooCard.from_json(data, path.parent, str(path))
    if card.name != path.parent.name:
        raise ZooError(f"{path}: the card's name {card.name!r} is not its folder's name "
                       f"{path.parent.name!r}")
    return card


def list_zoo(directory: str | os.PathLike[str] | None = None) -> list[ZooCard]:
    """Every card of the zoo (default :func:`zoo_dir`), by name; folders without a card are
    left out.

    Raises:
        ZooError: a card is malformed (its file and field named).
    """
    root = Path(directory) if directory is not None else zoo_dir()
    if not root.is_dir():
        return []
    return [read_card(d) for d in sorted(root.iterdir()) if (d / CARD_FILE).is_file()]


def get_card(
    name: str, directory: str | os.PathLike[str] | None = None, verify: bool = True
) -> ZooCard:
    """The card of zoo entry ``name``; with ``verify``, its checkpoint checked against it.

    Raises:
        ZooError: no such entry (the message lists the known ones), a malformed card, or
            (``verify``) a checkpoint missing or not matching the card's sha256.
    """
    root = Path(directory) if directory is not None else zoo_dir()
    if not NAME_PATTERN.fullmatch(name) or not (root / name / CARD_FILE).is_file():
        known = [c.name for c in list_zoo(root)]
        listed = f"known: {', '.join(known)}" if known else "it is empty"
        raise ZooError(f"no model {name!r} in the zoo at {root} ({listed}; `vp2 zoo list`)")
    card = read_card(root / name)
    if verify:
        card.verify()
    return card
