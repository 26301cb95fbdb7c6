"""Does this install reproduce the task suite? ``vp2 tasks verify``.

Two checks, both bit for bit:

* **replay**: every instance's stored scripted actions, stepped from its initial state, reach its
  stored goal state, and rendering that goal state gives its stored goal image. This exercises
  the whole stepping path (controllers, physics) and the renderer on this machine.
* **regenerate**: the first ``k`` instances of every category are generated again from their
  seeds (the scripted policy, the randomised reset, the look-back) and must equal the stored
  ones field by field.

A mismatch means trials on this machine do not run on the instances the suite describes (a
CPU-dependent floating-point path, another simulator version): results are then not comparable
with those measured elsewhere. ``docs/data.md`` ("Reproducibility") says what is meant to be
bit-identical.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from tqdm import tqdm

from vp2.data.suite import GOAL_IMAGE_SIZE, TaskInstance, TaskSuite, _env, generate_instance

#: Fields of an instance a regeneration must reproduce.
REGENERATED_FIELDS: tuple[str, ...] = ("init_state", "goal_state", "goal_image", "actions")


@dataclasses.dataclass(frozen=True)
class Mismatch:
    """One instance that this machine does not reproduce."""

    key: str  # "env/task#index"
    check: str  # "replay" or "regenerate"
    field: str  # the first field that differs
    detail: str  # how much: elements differing, the largest difference

    def __str__(self) -> str:
        return f"{self.key}: {self.check}: {self.field} differs ({self.detail})"


@dataclasses.dataclass(frozen=True)
class VerifyReport:
    """What :func:`verify_suite` checked and what did not match."""

    replayed: int
    regenerated: int
    mismatches: tuple[Mismatch, ...]

    @property
    def ok(self) -> bool:
        return not self.mismatches


def _difference(stored: np.ndarray, fresh: np.ndarray) -> str | None:
    """``None`` if the arrays are bit-identical, else a short description of the difference."""
    stored, fresh = np.asarray(stored), np.asarray(fresh)
    if stored.shape != fresh.shape:
        return f"shape {fresh.shape} here, {stored.shape} stored"
    if stored.tobytes() == fresh.tobytes():
        return None
    wide_s, wide_f = stored.astype(np.float64), fresh.astype(np.float64)
    differ = ~((wide_s == wide_f) | (np.isnan(wide_s) & np.isnan(wide_f)))
    largest = float(np.nanmax(np.abs(wide_s - wide_f)[differ])) if differ.any() else 0.0
    return f"{int(differ.sum())} of {stored.size} elements, largest {largest:.3g}"


def replay_mismatch(instance: TaskInstance) -> Mismatch | None:
    """Steps the instance's actions from its initial state and renders its goal state."""
    env = _env(instance.task)
    env.reset_to(instance.init_state)
    for action in instance.actions:
        env.step(action)
    detail = _difference(instance.goal_state, env.get_state())
    if detail is not None:
        return Mismatch(instance.key, "replay", "goal_state", detail)
    env.reset_to(instance.goal_state)
    detail = _difference(instance.goal_image, env.render(GOAL_IMAGE_SIZE))
    if detail is not None:
        return Mismatch(instance.key, "replay", "goal_image", detail)
    return None


def regenerate_mismatch(instance: TaskInstance) -> Mismatch | None:
    """Generates the instance again from its seed and compares every stored field."""
    fresh = generate_instance(instance.task, instance.seed, index=instance.index)
    if fresh is None:
        return Mismatch(instance.key, "regenerate", "instance", "its seed is rejected here")
    for field in REGENERATED_FIELDS:
        detail = _difference(getattr(instance, field), getattr(fresh, field))
        if detail is not None:
            return Mismatch(instance.key, "regenerate", field, detail)
    if fresh.env_meta != instance.env_meta:
        return Mismatch(instance.key, "regenerate", "env_meta", "another environment set-up")
    return None


def verify_suite(
    suite: TaskSuite,
    tasks: Sequence[str] = (),
    regenerate: int = 1,
    replay: bool = True,
    progress: bool = True,
) -> VerifyReport:
    """Replays every instance of ``tasks`` (default: all) and regenerates the first
    ``regenerate`` of each category; returns what did not match."""
    chosen = suite.select(tasks, None) if tasks else list(suite)
    to_replay = chosen if replay else []
    first: dict[str, list[TaskInstance]] = {}
    for inst in chosen:
        if len(first.setdefault(inst.task, [])) < regenerate:
            first[inst.task].append(inst)
    to_regenerate = [inst for insts in first.values() for inst in insts]
    mismatches = []
    with tqdm(total=len(to_replay) + len(to_regenerate), unit="inst", desc="verify suite",
              disable=not progress) as bar:
        for check, instances in ((replay_mismatch, to_replay),
                                 (regenerate_mismatch, to_regenerate)):
            for inst in instances:
                found = check(inst)
                if found is not None:
                    mismatches.append(found)
                bar.update()
                bar.set_postfix(mismatches=len(mismatches))
    return VerifyReport(len(to_replay), len(to_regenerate), tuple(mismatches))
