"""Helpers shared by test modules: processes as Linux's /proc lists them."""

from __future__ import annotations

import time
from pathlib import Path

from benchmarks.checks.orphans import alive

__all__ = ["alive", "child_pids", "wait_until_gone"]


def _stat(pid: int) -> list[str] | None:
    """Fields of ``/proc/PID/stat`` after the command name (state first), or None if gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return None
    return text[text.rindex(")") + 2 :].split()


def child_pids(pid: int) -> list[int]:
    """Live processes whose parent is ``pid``."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            fields = _stat(int(entry.name))
            if fields is not None and fields[0] != "Z" and int(fields[1]) == pid:
                found.append(int(entry.name))
    return sorted(found)


def wait_until_gone(pids: list[int], timeout: float) -> list[int]:
    """Waits up to ``timeout`` seconds for every process of ``pids`` to end; returns those
    still alive then."""
    deadline = time.monotonic() + timeout
    while (left := [p for p in pids if alive(p)]) and time.monotonic() < deadline:
        time.sleep(0.2)
    return left
