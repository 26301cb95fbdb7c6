"""Replaying an oracle trial record: the first control steps again, against what was recorded.

A shipped oracle table is only as good as the trials behind it (``results/oracle/*/
trials.jsonl``, :mod:`vp2.oracle.build`). :func:`replay_record` rebuilds a record's
instance from the task suite (checking its fingerprint), plans with the simulator oracle as a
benchmark worker does (the same :class:`~vp2.planning.agent.PlanningAgent`, planner settings
and trial seed) for the first control steps, and returns the executed actions next to the
recorded ones. A change that moves the oracle (the planner, the simulator, the rendering, the
cost) shows as actions that differ from step 1 (the first planned step) on.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from typing import Any

import numpy as np

#: Tolerance of a replayed action against the recorded one (the records keep float32 values).
ATOL = 1e-5


@dataclasses.dataclass
class Replay:
    """A replayed record.

    Attributes:
        key: ``"task#instance seed S"``.
        actions: ``(steps, A)`` the replay's executed actions.
        recorded: ``(steps, A)`` the record's first actions.
        classifier: The replay's classifier SHA-256 prefix (``None``: none planned).
        recorded_classifier: The record's.
    """

    key: str
    actions: np.ndarray
    recorded: np.ndarray
    classifier: str | None
    recorded_classifier: str | None

    @property
    def max_abs_diff(self) -> float:
        """Largest difference between a replayed and a recorded action entry (``inf`` if
        their shapes differ)."""
        if self.actions.shape != self.recorded.shape:
            return float("inf")
        return float(np.max(np.abs(self.actions - self.recorded)))

    def mismatch(self, atol: float = ATOL) -> str | None:
        """What differs (one line), ``None`` if the replay matches the record."""
        if self.classifier != self.recorded_classifier:
            return (f"{self.key}: planned with classifier {self.classifier!r}, the record with "
                    f"{self.recorded_classifier!r}")
        if self.actions.shape != self.recorded.shape:
            return (f"{self.key}: the replay's actions have shape {self.actions.shape}, the "
                    f"record's {self.recorded.shape}")
        diff = np.abs(self.actions - self.recorded)
        bad = np.argwhere(diff > atol)
        if not len(bad):
            return None
        step, dim = (int(x) for x in bad[0])
        return (
            f"{self.key}: step {step} action[{dim}] is {self.actions[step, dim]!r}, the record "
            f"has {self.recorded[step, dim]!r} (largest difference {self.max_abs_diff:.3g} > "
            f"{atol:g})"
        )


def replay_record(
    record: Mapping[str, Any],
    steps: int = 2,
    *,
    settings: Mapping[str, Any] | None = None,
    suite: str | None = None,
) -> Replay:
    """Runs the first ``steps`` control steps of an oracle trial again.

    Args:
        record: A compact trial record (:func:`~vp2.oracle.build.compact_record`:
            task, instance, seed, instance_sha, num_samples, actions, classifier) or a run's
            full record with ``num_samples`` added.
        steps: Control steps to replay (at least 2: the zero action, then planning).
        settings: The table's ``settings`` (``meta.json``: optimizer, gamma, num_iterations,
            cost, model); missing ones take the SPEC's.
        suite: Task suite file (``None``: the shipped suite).

    Returns:
        The :class:`Replay`; :meth:`Replay.mismatch` says whether it matches.

    Raises:
        ValueError: the suite's instance is not the record's (another suite version), or the
            record has fewer than ``steps`` actions.
    """
    from vp2.data.suite import TaskSuite
    from vp2.envs import env_class, split_name
    from vp2.planning.agent import PlanningAgent
    from vp2.run.config import planner_of
    from vp2.run.model_spec import resolve_model
    from vp2.run.trial import ControlTrial

    settings = dict(settings or {})
    task, index, seed = record["task"], int(record["instance"]), int(record["seed"])
    key = f"{task}#{index} seed {seed}"
    instance = TaskSuite.load(suite).get(task, index)
    if instance.fingerprint != record["instance_sha"]:
        raise ValueError(
            f"{key}: the suite's instance (fingerprint {instance.fingerprint}) is not the one "
            f"the record ran on ({record['instance_sha']}): another task suite version"
        )
    recorded = np.asarray(record["actions"], dtype=np.float64)[:steps]
    if len(recorded) < steps:
        raise ValueError(f"{key}: the record has {len(recorded)} action(s), fewer than {steps}")
    env_name = split_name(task)[0]
    planner = planner_of({**settings, "num_samples": record["num_samples"]})
    model = resolve_model(str(settings.get("model") or "simulator"), {}, env=env_name,
                          action_dim=int(env_class(env_name).action_dim), device="cpu")
    try:
        agent = PlanningAgent(model, planner=planner, cost_mode=settings.get("cost") or "auto",
                              device="cpu")
        result = ControlTrial(instance, agent, seed=seed, num_steps=steps).run()
    finally:
        close = getattr(model, "close", None)
        if callable(close):
            close()
    return Replay(
        key=key,
        actions=np.asarray(result.actions, dtype=np.float64),
        recorded=recorded,
        classifier=(result.agent.get("classifier") or {}).get("sha256"),
        recorded_classifier=_recorded_classifier(record),
    )


def _recorded_classifier(record: Mapping[str, Any]) -> str | None:
    """The classifier SHA-256 prefix of a compact record, or of a run's full record."""
    if record.get("classifier"):
        return str(record["classifier"])
    agent = record.get("agent")
    return ((agent.get("classifier") or {}).get("sha256")) if isinstance(agent, Mapping) else None
