"""The one parser of command-line ``KEY=VALUE`` items (``--model-arg``, ``--set``, ...)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import yaml


def parse_key_values(items: Sequence[str], what: str = "argument") -> dict[str, str]:
    """``["a=1", "b = x"]`` -> ``{"a": "1", "b": "x"}``: keys and values stripped, values
    left as strings for the caller to coerce (see :func:`yaml_value`).

    Raises:
        ValueError: an item without ``=`` or with an empty key; the message names ``what``.
    """
    out: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"{what} {item!r}: expected KEY=VALUE")
        out[key.strip()] = value.strip()
    return out


def yaml_value(value: str) -> Any:
    """A command-line value read as a YAML scalar or list (``2`` an int, ``[1, 2]`` a list,
    ``true`` a bool); text YAML cannot read stays a string."""
    try:
        return yaml.safe_load(value)
    except yaml.YAMLError:
        return value
