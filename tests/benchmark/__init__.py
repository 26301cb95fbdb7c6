"""Shared helpers of the benchmark tests: a tiny hand-made task suite and fault-injecting models.

The models here are loaded by the runner through the plugin mechanism
(``tests.benchmark:NaNModel`` ...), also in spawned worker processes, so they live in an
importable module rather than in a conftest.

The hand-made instances do not need the scripted policies: the initial state is a reset with
a known seed, and the goal is chosen so that success is known in advance:

* tabletop ``index 0``: goal = the initial object positions, so success holds after the first
  (zero-action) step;
* tabletop ``index 1``: goal = every object 0.25 m away, which a 3-step trial cannot reach;
* RoboDesk ``push_red``: the goal image after a few random actions; the block is not pushed.

Every instance's environment seed is distinct (``env_meta["kwargs"]["seed"]``), which the
fault-injecting models use to misbehave on one instance only.
"""

from __future__ import annotations

import functools
import os
import signal
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import torch

from vp2.data.suite import TaskInstance, TaskSuite
from vp2.envs import make_env

#: Environment seed of each hand-made instance, by (task, index).
ENV_SEEDS: dict[tuple[str, int], int] = {
    ("tabletop/push_sphere", 0): 101,
    ("tabletop/push_sphere", 1): 102,
    ("robodesk/push_red", 0): 201,
}


#: What the shipped diagnose predictor (vp2/assets/diagnose_predictor.json) says of a tabletop
#: model: the tabletop's own predictor, fitted on seven of its models' control runs.
TABLETOP_PREDICTOR = (
    "success fraction, predictor fitted on 7 models (held-out Spearman -0.23 over 7 models)"
)
#: Its score for a model with no credit on any measure (action-blind, flat scores): 8%, as
#: its ridge penalty (100, the grid's largest) keeps every score near the models' mean.
TABLETOP_BLIND_SCORE = 0.078471


def make_instance(task: str, index: int) -> TaskInstance:
    """One hand-made task instance (see the module docstring)."""
    seed = ENV_SEEDS[(task, index)]
    env = make_env(task, seed=seed, observation_size=None)
    try:
        env.reset(seed=seed)
        init_state = env.get_state()
        if task.startswith("tabletop"):
            positions = env.object_positions()
            if index == 1:
                positions = positions + np.array([0.25, 0.0, 0.0])
            goal_state = env.with_object_positions(init_state, positions)
        else:
            rng = np.random.default_rng(seed)
            for _ in range(2):
                env.step(rng.uniform(-1, 1, env.action_dim))
            goal_state = env.get_state()
        env.reset_to(goal_state)
        goal_image = env.render(64)
        env.reset_to(init_state)
        meta = env.serialize()
    finally:
        env.close()
    return TaskInstance(
        task=task,
        index=index,
        seed=seed,
        init_state=init_state,
        goal_state=goal_state,
        goal_image=goal_image,
        actions=np.zeros((0, env.action_dim)),
        env_meta=meta,
    )


@functools.cache
def tiny_suite_path(include_robodesk: bool = False) -> Path:
    """A saved tiny suite (cached for the test session): tabletop 2 instances (+ RoboDesk 1)."""
    keys = [("tabletop/push_sphere", 0), ("tabletop/push_sphere", 1)]
    if include_robodesk:
        keys.append(("robodesk/push_red", 0))
    suite = TaskSuite([make_instance(t, i) for t, i in keys])
    path = Path(tempfile.mkdtemp(prefix="vp2-bench-suite-")) / "suite.npz"
    suite.save(path)
    return path


# --------------------------------------------------------------------------- fault injection


class _Base:
    """RepeatLastFrame-like model that sees the env metadata (to misbehave on one instance)."""

    num_context = 2
    num_future = 10
    image_size = 64
    max_batch_size = 64
    needs_simulator_state = True

    def __init__(self, action_dim: int, bad_seed: int | None = None) -> None:
        self.action_dim = action_dim
        self.bad_seed = bad_seed
        self._meta: dict[str, Any] = {}

    def set_simulator_state(self, env_meta: dict[str, Any], state: np.ndarray) -> None:
        self._meta = env_meta

    def _bad(self) -> bool:
        return self.bad_seed is None or self._meta.get("kwargs", {}).get("seed") == self.bad_seed

    def _good(self, context_frames: torch.Tensor) -> torch.Tensor:
        return context_frames[:, -1:].float().expand(-1, self.num_future, -1, -1, -1).contiguous()


class NaNModel(_Base):
    """Predicts NaN frames (on the instance with env seed ``bad_seed``; all if ``None``)."""

    name = "nan_model"

    def predict(self, context_frames, actions, *, generator=None, grad=None):
        out = self._good(context_frames)
        return out * float("nan") if self._bad() else out


class WrongShapeModel(_Base):
    """Predicts 9 frames instead of 10 (on the bad instance)."""

    name = "wrong_shape_model"

    def predict(self, context_frames, actions, *, generator=None, grad=None):
        out = self._good(context_frames)
        return out[:, :9] if self._bad() else out


class FlakyModel(_Base):
    """Raises on the bad instance until the file ``marker`` exists, then creates it: the
    first attempt fails, the retry succeeds (a transient error)."""

    name = "flaky_model"

    def __init__(self, action_dim: int, bad_seed: int, marker: str) -> None:
        super().__init__(action_dim, bad_seed)
        self.marker = marker

    def predict(self, context_frames, actions, *, generator=None, grad=None):
        if self._bad() and not os.path.exists(self.marker):
            Path(self.marker).touch()
            raise RuntimeError("transient failure")
        return self._good(context_frames)


class SlowModel(_Base):
    """Repeats the last frame after sleeping ``delay`` seconds per call (a slow model)."""

    name = "slow_model"

    def __init__(self, action_dim: int, delay: float) -> None:
        super().__init__(action_dim)
        self.delay = delay

    def predict(self, context_frames, actions, *, generator=None, grad=None):
        time.sleep(self.delay)
        return self._good(context_frames)


class KillerModel(_Base):
    """Kills its own process (SIGKILL, as the OOM killer would) on the bad instance."""

    name = "killer_model"

    def predict(self, context_frames, actions, *, generator=None, grad=None):
        if self._bad():
            os.kill(os.getpid(), signal.SIGKILL)
        return self._good(context_frames)


def broken_factory(action_dim: int) -> Any:
    """A factory that fails: the run must stop with a clear error."""
    raise ImportError("checkpoint weights not found (test)")


def repeat_factory(action_dim: int, image_size: int = 64) -> Any:
    """A plain ``module:factory`` plugin."""
    from vp2.models.baselines import RepeatLastFrame

    return RepeatLastFrame(action_dim=action_dim, image_size=image_size)


class NaNUntilFixed(_Base):
    """Predicts NaN frames until the file ``fixed`` exists (a model broken, then fixed)."""

    name = "nan_until_fixed"

    def __init__(self, action_dim: int, fixed: str) -> None:
        super().__init__(action_dim)
        self.fixed = fixed

    def predict(self, context_frames, actions, *, generator=None, grad=None):
        out = self._good(context_frames)
        return out if os.path.exists(self.fixed) else out * float("nan")
