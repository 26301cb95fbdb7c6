"""Re-measuring some tasks of a shipped oracle table: the new runs' tasks replace the table's.

A table at the SPEC's count takes days of CPU; when a change moves only some tasks (a new
scene for one environment, a re-trained classifier), only those are measured again.
``vp2 ship-oracle RUN_DIR... --table NAME --update`` builds the new runs' part with
:func:`vp2.oracle.build.build_table` and :func:`merge_tables` puts it in place of the table's
records of the same tasks, keeping the others, provided they still describe this vp2: the same
protocol settings, and instances the current suite holds unchanged.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any


def merge_tables(
    old_meta: Mapping[str, Any],
    old_trials: Sequence[Mapping[str, Any]],
    new_meta: Mapping[str, Any],
    new_trials: Sequence[Mapping[str, Any]],
) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The table ``old`` with every task of ``new`` replaced by ``new``'s records.

    Raises:
        ValueError: the two were planned with other settings, or a kept record ran on an
            instance the current task suite no longer holds (re-measure that task too).
    """
    from vp2.data.suite import TaskSuite

    if dict(old_meta.get("settings") or {}) != dict(new_meta.get("settings") or {}):
        raise ValueError(
            f"table {old_meta.get('name')!r} was planned with {old_meta.get('settings')}, the "
            f"runs with {new_meta.get('settings')}; update a table only with runs of its protocol"
        )
    replaced = {r["task"] for r in new_trials}
    kept = [dict(r) for r in old_trials if r["task"] not in replaced]
    current = {i.key: i.fingerprint for i in TaskSuite.load()}
    stale = sorted(
        {
            r["task"]
            for r in kept
            if current.get(f"{r['task']}#{r['instance']}") != r.get("instance_sha")
        }
    )
    if stale:
        raise ValueError(
            f"table {old_meta.get('name')!r} keeps records of {', '.join(stale)} on instances "
            "the current task suite changed; re-measure those tasks too and pass their runs"
        )
    kept_tasks = {r["task"] for r in kept}
    kept_envs = {t.split("/")[0] for t in kept_tasks}
    render = {e: f for e, f in (old_meta.get("render") or {}).items() if e in kept_envs}
    render.update(new_meta.get("render") or {})
    classifiers = {t: c for t, c in (old_meta.get("classifiers") or {}).items() if t in kept_tasks}
    classifiers.update(new_meta.get("classifiers") or {})
    versions = {
        v.strip()
        for m in (old_meta, new_meta)
        for v in str(m.get("vp2_version") or "").split(",")
        if v.strip()
    }
    note = str(old_meta.get("note") or "")
    if new_meta.get("note"):
        note = (
            f"{note} Updated {new_meta['date']} ({', '.join(sorted(replaced))}): {new_meta['note']}"
        )
    meta = {
        **dict(old_meta),
        "suite_format": new_meta["suite_format"],
        "date": max(str(old_meta["date"]), str(new_meta["date"])),
        "measured_by": _measured_by(
            str(old_meta.get("measured_by")), replaced, str(new_meta.get("measured_by"))
        ),
        "note": note.strip(),
        "vp2_version": ", ".join(sorted(versions)),
        "render": dict(sorted(render.items())),
        "classifiers": dict(sorted(classifiers.items())),
        # once each: a run shipped category by category brings its command at every update
        "commands": list(dict.fromkeys(
            [c for c in old_meta.get("commands") or [] if not _only(c, replaced)]
            + list(new_meta.get("commands") or [])
        )),
    }
    trials = sorted(
        kept + [dict(r) for r in new_trials], key=lambda r: (r["task"], r["instance"], r["seed"])
    )
    return meta, trials


def _measured_by(old: str, tasks: set[str], new: str) -> str:
    """``old`` followed by ``"; TASKS then by NEW"``; when ``old``'s last entry is by the same
    ``new`` (a run shipped category by category), its tasks join that entry instead."""
    head, sep, last = old.rpartition("; ")
    before, by, run = last.partition(" then by ")
    if sep and by and run == new:
        old, tasks = head, tasks | set(before.split(", "))
    return f"{old}; {', '.join(sorted(tasks))} then by {new}"


def _only(command: str, tasks: set[str]) -> bool:
    """Whether a ``vp2 run`` command's ``--tasks`` name only tasks of ``tasks`` (an environment
    name stands for all its tasks)."""
    from vp2.envs import TASK_NAMES

    words = command.split()
    if "--tasks" not in words:
        return False
    named = []
    for word in words[words.index("--tasks") + 1 :]:
        if word.startswith("--"):
            break
        named += [t for t in TASK_NAMES if t == word or t.split("/")[0] == word]
    return bool(named) and set(named) <= tasks
