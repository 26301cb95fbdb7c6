"""The simulator oracle (SPEC §7): the true simulator used as the video prediction model.

:class:`SimulatorModel` is planned with like any model, with the same planner and cost. Its
success rate is the upper bound that other models' scores are normalised by.

The oracle needs the simulator state, which no learned model may ever see. It declares this
with ``needs_simulator_state = True``; the planning agent then calls
:meth:`SimulatorModel.set_simulator_state` with the environment metadata and the current state
before every planning step (see :class:`vp2.planning.agent.PlanningAgent`).
"""

from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

import numpy as np
import torch
from torch import Tensor

from vp2 import spec
from vp2.envs.cache import EnvCache
from vp2.models.contract import CheckedPredictor
from vp2.utils.executors.local import spawn_pool
from vp2.utils.tensors import images_to_float

#: Environments kept alive per process by the oracle: one per task category and observation
#: setting (instances of a category share one, :mod:`vp2.envs.cache`); four cover a run's
#: categories in order and a trial's retries.
_ENV_CACHE_SIZE = 4

_PROCESS_ENVS = EnvCache(_ENV_CACHE_SIZE)


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
    # No observations from step(): the oracle renders exactly once per predicted frame.
    env = _PROCESS_ENVS.get(env_meta, observation_size=None)
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


class SimulatorModel(CheckedPredictor):
    """The simulator oracle: predictions are the simulator's own renders of each candidate.

    For each of the ``N`` candidate sequences it resets an environment (rebuilt from the
    trial's env metadata) to the current simulator state, steps it through the 10 candidate
    actions and renders a frame after each. ``actions[:, 0]`` (the last executed action) has
    already happened and is skipped; the context frames are ignored.

    With ``num_workers > 1`` the candidates are split evenly over a persistent pool of
    ``spawn``-ed processes, each holding its own environments. The pool is started on the
    first call and lives until :meth:`close`. Do not nest it inside trial-level parallelism:
    the benchmark runner sets ``num_workers = 1`` when it runs trials in several processes
    (``docs/evaluation.md``).

    Args:
        action_dim: ``A`` of the environment it is used with (4 tabletop, 5 RoboDesk).
        num_workers: Processes the candidates are simulated in (1: this process).
        image_size: Side of the rendered frames.
        max_batch_size: Largest batch one call accepts; large, since the oracle splits work
            itself and holds no activations.
    """

    name = "simulator"
    needs_simulator_state = True
    num_context = spec.NUM_CONTEXT
    num_future = spec.NUM_FUTURE

    def __init__(
        self,
        action_dim: int,
        num_workers: int = 1,
        image_size: int = 64,
        max_batch_size: int = spec.LARGE_NUM_SAMPLES,
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
            self._pool = spawn_pool(self._num_workers, _init_oracle_worker)
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
    def _checked_call(
        self,
        context_frames: Tensor,
        actions: Tensor,
        generator: torch.Generator | None,
        grad: bool | None,
    ) -> Tensor:
        """Simulates the candidates: the body of ``predict``, which checks its inputs and output
        (:class:`vp2.models.contract.CheckedPredictor`).

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
        candidates = actions[:, spec.NUM_CONTEXT - 1 :].detach().to("cpu", torch.float64).numpy()
        n = candidates.shape[0]
        if self._num_workers == 1 or n == 1:
            frames = simulate_candidates(self._env_meta, self._state, candidates, self.image_size)
        else:
            frames = self._simulate_in_pool(candidates)  # (B, T, H, W, 3)
        # The channel axis moves by a view: no copy, the frames keep their (B, T, H, W, 3) memory.
        out = images_to_float(torch.from_numpy(frames)).permute(0, 1, 4, 2, 3)  # (B, T, 3, H, W)
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
