"""Reference models and the random-action baseline.

* :class:`SimulatorModel` -- the simulator oracle (SPEC §7): the true simulator used as the
  video prediction model, with the same planner and cost. Its success rate is the upper bound
  that other models' scores are normalised by.
* :class:`RepeatLastFrame` -- predicts the last context frame ten times: a model that knows
  nothing about dynamics. Every candidate gets the same cost, so the planner executes the mean
  of its noise (a lower bound for any model that is useful at all).
* :class:`RandomActions` -- not a model: an agent that ignores observations and executes
  uniform random actions from a seeded generator.

The oracle needs the simulator state, which no learned model may ever see. It declares this
with ``needs_simulator_state = True``; the planning agent then calls
:meth:`SimulatorModel.set_simulator_state` with the environment metadata and the current state
before every planning step (see :class:`vp2.benchmark.agent.PlanningAgent`).
"""

from __future__ import annotations

import collections
import json
import multiprocessing as mp
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

import numpy as np
import torch
from torch import Tensor

from vp2.models.base import NUM_CONTEXT, NUM_FUTURE

#: Environments kept alive per process by the oracle (tabletop instances differ in textures,
#: so each instance rebuilds its env; a few cached cover a trial and its retries).
_ENV_CACHE_SIZE = 4


class _EnvCache:
    """Environments rebuilt from metadata, least recently used evicted (one per process)."""

    def __init__(self, size: int = _ENV_CACHE_SIZE) -> None:
        self.size = size
        self._envs: collections.OrderedDict[str, Any] = collections.OrderedDict()

    def get(self, env_meta: dict[str, Any]) -> Any:
        from vp2.envs import make_env_from_metadata

        key = json.dumps(env_meta, sort_keys=True)
        if key in self._envs:
            self._envs.move_to_end(key)
            return self._envs[key]
        # No observations from step(): the oracle renders exactly once per predicted frame.
        env = make_env_from_metadata(env_meta, observation_size=None)
        self._envs[key] = env
        while len(self._envs) > self.size:
            _, old = self._envs.popitem(last=False)
            old.close()
        return env

    def close(self) -> None:
        for env in self._envs.values():
            env.close()
        self._envs.clear()


_PROCESS_ENVS = _EnvCache()


def simulate_candidates(
    env_meta: dict[str, Any], state: np.ndarray, actions: np.ndarray, image_size: int
) -> np.ndarray:
    """Rolls every candidate action sequence out in the simulator from one state.

    Runs in the oracle's worker processes (or in the caller's, with one worker); each process
    keeps its own environments.

    Args:
        env_meta: :meth:`vp2.envs.base.Env.serialize` output of the trial's environment.
        state: ``(S,)`` simulator state to start every sequence from.
        actions: ``(n, T, A)`` candidate actions.
        image_size: Side of the rendered frames.

    Returns:
        ``(n, T, image_size, image_size, 3)`` uint8 frames, frame ``t`` after action ``t``.
    """
    env = _PROCESS_ENVS.get(env_meta)
    n, horizon = actions.shape[:2]
    frames = np.empty((n, horizon, image_size, image_size, 3), np.uint8)
    for i in range(n):
        env.reset_to(state)
        for t in range(horizon):
            env.step(actions[i, t])
            frames[i, t] = env.render(image_size)
    return frames


def _init_oracle_worker() -> None:
    # Each oracle worker is one of several processes on the machine's cores.
    torch.set_num_threads(1)


class SimulatorModel:
    """The simulator oracle: predictions are the simulator's own renders of each candidate.

    For each of the ``N`` candidate sequences it resets an environment (rebuilt from the
    trial's env metadata) to the current simulator state, steps it through the 10 candidate
    actions and renders a frame after each. ``actions[:, 0]`` (the last executed action) has
    already happened and is skipped; the context frames are ignored.

    With ``num_workers > 1`` the candidates are split evenly over a persistent pool of
    ``spawn``-ed processes, each holding its own environments. The pool is started on the
    first call and lives until :meth:`close`. Do not nest it inside trial-level parallelism:
    the benchmark runner sets ``num_workers = 1`` when it runs trials in several processes
    (``docs/benchmark.md``).

    Args:
        action_dim: ``A`` of the environment it is used with (4 tabletop, 5 RoboDesk).
        num_workers: Processes the candidates are simulated in (1: this process).
        image_size: Side of the rendered frames.
        max_batch_size: Largest batch one call accepts; large, since the oracle splits work
            itself and holds no activations.
    """

    name = "simulator"
    needs_simulator_state = True
    num_context = NUM_CONTEXT
    num_future = NUM_FUTURE

    def __init__(
        self,
        action_dim: int,
        num_workers: int = 1,
        image_size: int = 64,
        max_batch_size: int = 800,
    ) -> None:
        if num_workers < 1:
            raise ValueError(f"num_workers must be >= 1, got {num_workers}")
        self.action_dim = int(action_dim)
        self.image_size = int(image_size)
        self.max_batch_size = int(max_batch_size)
        self._num_workers = int(num_workers)
        self._pool: ProcessPoolExecutor | None = None
        self._env_meta: dict[str, Any] | None = None
        self._state: np.ndarray | None = None

    # ---- the simulator-state hook ----------------------------------------------------------
    def set_simulator_state(self, env_meta: dict[str, Any], state: np.ndarray) -> None:
        """Sets the environment and state the next predictions start from.

        Called by the planning agent before every planning step (models with
        ``needs_simulator_state = True`` only).
        """
        self._env_meta = env_meta
        self._state = np.asarray(state, np.float64).copy()

    # ---- parallelism ---------------------------------------------------------------------
    @property
    def num_workers(self) -> int:
        """Processes the candidates are simulated in; setting it restarts the pool."""
        return self._num_workers

    @num_workers.setter
    def num_workers(self, value: int) -> None:
        if value < 1:
            raise ValueError(f"num_workers must be >= 1, got {value}")
        if value != self._num_workers:
            self.close()
            self._num_workers = int(value)

    def _get_pool(self) -> ProcessPoolExecutor:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(
                max_workers=self._num_workers,
                mp_context=mp.get_context("spawn"),
                initializer=_init_oracle_worker,
            )
        return self._pool

    def close(self) -> None:
        """Stops the worker pool (it restarts on the next call). Safe to call twice."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None

    def __del__(self) -> None:
        pool = getattr(self, "_pool", None)
        if pool is not None:
            pool.shutdown(wait=False, cancel_futures=True)

    def __getstate__(self) -> dict[str, Any]:
        # A pool does not travel between processes; the copy starts its own.
        state = self.__dict__.copy()
        state["_pool"] = None
        return state

    # ---- prediction ------------------------------------------------------------------------
    def predict(
        self,
        context_frames: Tensor,
        actions: Tensor,
        *,
        generator: torch.Generator | None = None,
        grad: bool | None = None,
    ) -> Tensor:
        """Simulates the candidates; see :class:`vp2.models.base.VideoPredictionModel`.

        Args:
            context_frames: ``(B, 2, 3, H, W)`` (ignored: the state says everything).
            actions: ``(B, 11, A)``; ``actions[:, 1:]`` are simulated.
            generator: Unused (the simulator is deterministic).
            grad: Must not be ``True``: the simulator is not differentiable.

        Returns:
            ``(B, 10, 3, H, W)`` float32 frames in [0, 1] on ``context_frames``' device.

        Raises:
            RuntimeError: if no state was set, or a worker process died.
        """
        if grad:
            raise RuntimeError("the simulator oracle is not differentiable; plan with MPPI or CEM")
        if self._state is None or self._env_meta is None:
            raise RuntimeError(
                "SimulatorModel.predict called before set_simulator_state(env_meta, state); "
                "the planning agent calls it before every planning step"
            )
        candidates = actions[:, NUM_CONTEXT - 1 :].detach().to("cpu", torch.float64).numpy()
        n = candidates.shape[0]
        if self._num_workers == 1 or n == 1:
            frames = simulate_candidates(self._env_meta, self._state, candidates, self.image_size)
        else:
            frames = self._simulate_in_pool(candidates)  # (B, T, H, W, 3)
        out = torch.from_numpy(frames).permute(0, 1, 4, 2, 3).float().div_(255)  # (B, T, 3, H, W)
        return out.to(context_frames.device)

    def _simulate_in_pool(self, candidates: np.ndarray) -> np.ndarray:
        # Every sample costs the same (T steps + T renders): equal contiguous chunks, one per
        # worker, keep the order and balance the load.
        chunks = [c for c in np.array_split(candidates, self._num_workers) if len(c)]
        pool = self._get_pool()
        try:
            futures = [
                pool.submit(simulate_candidates, self._env_meta, self._state, c, self.image_size)
                for c in chunks
            ]
            return np.concatenate([f.result() for f in futures])
        except BrokenProcessPool as exc:
            self._pool = None  # the next call starts a fresh pool
            raise RuntimeError(
                "a SimulatorModel worker process died while simulating candidates"
            ) from exc


class RepeatLastFrame:
    """Predicts the last context frame for every future step.

    Args:
        action_dim: ``A`` of the environment it is used with.
        image_size: Side of the frames.
        max_batch_size: Largest batch per call (the prediction is a view, so any size works).
    """

    name = "repeat_last_frame"
    num_context = NUM_CONTEXT
    num_future = NUM_FUTURE

    def __init__(self, action_dim: int, image_size: int = 64, max_batch_size: int = 800) -> None:
        self.action_dim = int(action_dim)
        self.image_size = int(image_size)
        self.max_batch_size = int(max_batch_size)

    def predict(
        self,
        context_frames: Tensor,
        actions: Tensor,
        *,
        generator: torch.Generator | None = None,
        grad: bool | None = None,
    ) -> Tensor:
        """``(B, 10, 3, H, W)`` copies of ``context_frames[:, -1]`` as float32."""
        last = context_frames[:, -1:].float()  # (B, 1, 3, H, W)
        return last.expand(-1, self.num_future, -1, -1, -1).contiguous()  # (B, T, 3, H, W)


class RandomActions:
    """Baseline agent: uniform random actions in ``[-1, 1]^A``, ignoring every observation.

    It has the planning agent's interface (``reset``/``act``, see
    :class:`vp2.benchmark.agent.PlanningAgent`) but no model. Its actions depend only on the
    trial seed given to :meth:`reset`.

    Args:
        action_dim: ``A`` of the environment.
        image_size: Side of the frames the trial renders (for the execution GIF).
    """

    name = "random_actions"
    cost_kind = "none"

    def __init__(self, action_dim: int, image_size: int = 64) -> None:
        self.action_dim = int(action_dim)
        self.image_size = int(image_size)
        self._rng = np.random.default_rng(0)

    def describe(self) -> dict[str, Any]:
        """Identity for result records."""
        return {"agent": self.name}

    def reset(self, task: str, goal_image: np.ndarray, seed: int) -> None:
        """Starts a trial: reseeds the generator from the trial seed."""
        self._rng = np.random.default_rng(seed)

    def act(self, observation: Any) -> tuple[np.ndarray, dict[str, Any]]:
        """A uniform random action ``(A,)``; the observation is ignored."""
        return self._rng.uniform(-1.0, 1.0, self.action_dim), {}
