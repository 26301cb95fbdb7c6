"""A trial's progress on disk, so that a run cut off mid-trial resumes at the step it reached.

A SPEC-count oracle trial plans 200 or 800 candidates per step and can take hours on a CPU; a
run that ends (a session's end, a killed process) would lose the trial in progress. While a
trial runs, the worker keeps ``<run>/partial/<task>_i<index>_s<seed>.npz``
(:meth:`vp2.run.run_dir.RunDir.partial_path`) up to date (every
:data:`CHECKPOINT_EVERY_S` seconds of trial time, after a control step): the executed actions,
success flags, planning times, scores, the predicted frames of the chosen plans, and the
agent's state after the step (its warm-start plan and its random generators). A resumed trial
steps the recorded actions again from the instance's initial state (no planning: the
simulator is deterministic, and the replay checks that the success flags come out the same),
restores the agent's state and plans on from there, so it ends exactly as the uninterrupted
trial would have.

A partial file is used only by a trial of the same settings: the file's ``meta`` (task,
instance fingerprint, seed, the agent's settings, the model's identity, steps, vp2 version,
render fingerprint) must equal the new attempt's, else it is discarded. The driver deletes the
file once the trial's record is written.
"""

from __future__ import annotations

import dataclasses
import io
import json
import logging
import zipfile
from pathlib import Path
from typing import Any

import numpy as np

from vp2.utils.io import atomic_path

log = logging.getLogger(__name__)

#: A trial writes its progress when this many seconds of the trial have passed since the last
#: write (or its start): trials of seconds never write, hour-long ones lose at most this much.
CHECKPOINT_EVERY_S = 30.0


class PartialMismatch(ValueError):
    """A partial trial that the new attempt cannot resume (other settings, or a replay that
    does not reproduce it)."""


@dataclasses.dataclass
class PartialTrial:
    """A trial up to some control step.

    Attributes:
        meta: What must match for a trial to resume it (JSON-able).
        actions: ``(k, A)`` the executed actions.
        success_steps: ``k`` success flags.
        planning_times: Seconds of each planning step so far.
        scores: The optimizer's best score at each planning step so far.
        predicted: The chosen plans' predicted frames so far (``(T, H, W, 3)`` uint8 each).
        agent_state: The agent's :meth:`trial_state` after step ``k``: arrays and JSON-able
            values.
        env_time: Seconds spent stepping and rendering so far.
        elapsed: Seconds of the trial so far.
    """

    meta: dict[str, Any]
    actions: np.ndarray
    success_steps: list[bool]
    planning_times: list[float]
    scores: list[float | None]
    predicted: list[np.ndarray]
    agent_state: dict[str, Any]
    env_time: float
    elapsed: float

    @property
    def steps(self) -> int:
        return len(self.success_steps)


def save_partial(path: Path, partial: PartialTrial) -> None:
    """Writes ``partial`` to ``path`` atomically (an ``.npz``: arrays, and one JSON entry)."""
    arrays = {f"agent.{k}": v for k, v in partial.agent_state.items() if isinstance(v, np.ndarray)}
    plain = {k: v for k, v in partial.agent_state.items() if not isinstance(v, np.ndarray)}
    head = {
        "meta": partial.meta,
        "success_steps": [bool(x) for x in partial.success_steps],
        "planning_times": [float(x) for x in partial.planning_times],
        "scores": [None if x is None else float(x) for x in partial.scores],
        "agent_state": plain,
        "env_time": float(partial.env_time),
        "elapsed": float(partial.elapsed),
        "num_predicted": len(partial.predicted),
    }
    arrays["actions"] = np.asarray(partial.actions, dtype=np.float64)
    for i, frames in enumerate(partial.predicted):
        arrays[f"predicted.{i}"] = np.asarray(frames, dtype=np.uint8)
    arrays["head"] = np.frombuffer(json.dumps(head).encode(), dtype=np.uint8)
    path.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    with atomic_path(path) as tmp:
        Path(tmp).write_bytes(buffer.getvalue())


def load_partial(path: Path) -> PartialTrial | None:
    """The partial trial at ``path``; ``None`` when there is none or it cannot be read (a
    warning says so; the trial then starts from its first step)."""
    if not path.is_file():
        return None
    try:
        with np.load(path) as data:
            head = json.loads(bytes(data["head"]).decode())
            agent_state = dict(head["agent_state"])
            agent_state.update({k[len("agent."):]: data[k] for k in data.files
                                if k.startswith("agent.")})
            return PartialTrial(
                meta=head["meta"],
                actions=data["actions"],
                success_steps=list(head["success_steps"]),
                planning_times=list(head["planning_times"]),
                scores=list(head["scores"]),
                predicted=[data[f"predicted.{i}"] for i in range(head["num_predicted"])],
                agent_state=agent_state,
                env_time=float(head["env_time"]),
                elapsed=float(head["elapsed"]),
            )
    except (OSError, ValueError, KeyError, zipfile.BadZipFile) as exc:
        log.warning("%s: unreadable partial trial (%s); the trial starts from its first step",
                    path, exc)
        return None


def check_resumable(partial: PartialTrial, meta: dict[str, Any]) -> None:
    """Raises :class:`PartialMismatch` unless ``partial`` was made with settings ``meta``."""
    stored = json.loads(json.dumps(partial.meta))
    wanted = json.loads(json.dumps(meta))
    if stored != wanted:
        differ = sorted(k for k in {*stored, *wanted} if stored.get(k) != wanted.get(k))
        raise PartialMismatch(f"the partial trial was made with other {', '.join(differ)}")
