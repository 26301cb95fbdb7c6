"""The environment contract every benchmark environment implements.

An environment is one task category (e.g. ``robodesk/push_red``) of one simulator.
The benchmark only ever talks to environments through this class, so that datasets,
task suites, planning and the simulator oracle all see the same thing:

* ``reset(seed=...)`` draws a random initial state from the task's distribution;
* ``get_state()`` / ``reset_to(state)`` save and restore the *complete* simulator state as a
  flat ``float64`` vector (restoring it and replaying the same actions is bit-identical);
* ``step(action)`` advances one control step (Gymnasium's 5-tuple);
* ``render(height, width)`` renders the environment's single benchmark camera with its
  render specification, as ``uint8`` RGB ``(height, width, 3)``;
* ``is_success(goal_state)`` judges the task's success criterion from the simulator state;
* ``serialize()`` returns JSON-able metadata from which :func:`vp2.envs.make_env_from_metadata`
  rebuilds an identical environment (textures included).

Actions live in ``[-1, 1]^action_dim``. Actions outside that box are clipped; actions of the
wrong shape or containing NaN/inf raise ``ValueError``.

Every environment is a :class:`gymnasium.Env` (``gymnasium.make("vp2/RoboDesk-PushRed-v0")``,
see :mod:`vp2.envs.registration`): ``action_space`` is ``Box(-1, 1, (action_dim,), float32)``,
``observation_space`` is ``Box(0, 255, (S, S, 3), uint8)`` for ``observation_size=S``, and
``None`` for ``observation_size=None`` (``reset``/``step`` then return ``None`` observations,
which no gymnasium space holds: such an env is for the benchmark's own state-only use, and
:func:`gymnasium.make` refuses it). ``np_random`` is the environment's own generator (the one
``reset(seed=...)`` reseeds). With ``render_mode="rgb_array"``, ``render()`` returns the
64x64 benchmark frame; ``render(height, width)`` any size.
"""

from __future__ import annotations

import abc
from typing import Any, ClassVar

import gymnasium
import numpy as np
from gymnasium import spaces


class Env(gymnasium.Env, abc.ABC):  # type: ignore[type-arg]
    """Base class of the benchmark environments. See the module docstring for the contract."""

    #: Gymnasium metadata: ``render()`` gives an RGB array; 5 Hz control (0.2 s per step).
    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 5}
    #: Gymnasium's render mode: ``None`` or ``"rgb_array"`` (set by :func:`gymnasium.make`).
    render_mode: str | None = None

    #: Registered name, ``"<env>/<task>"``, e.g. ``"robodesk/push_red"``.
    name: str
    #: Dimension of the action vector.
    action_dim: int
    #: Side of the square observation returned by ``reset``/``step`` (``None``: no image).
    observation_size: int | None

    # ---- lifecycle -------------------------------------------------------------------------
    @abc.abstractmethod
    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray | None, dict[str, Any]]:
        """Draws an initial state. Returns ``(observation, info)`` like Gymnasium.

        The same ``seed`` always gives the same initial state. ``seed=None`` continues the
        environment's own generator (seeded at construction).
        """

    @abc.abstractmethod
    def get_state(self) -> np.ndarray:
        """The complete simulator state as a flat float64 vector (a copy)."""

    @abc.abstractmethod
    def reset_to(self, state: np.ndarray) -> np.ndarray | None:
        """Restores a state from :meth:`get_state`; returns the observation there."""

    @abc.abstractmethod
    def step(
        self, action: np.ndarray
    ) -> tuple[np.ndarray | None, float, bool, bool, dict[str, Any]]:
        """Applies one control action.

        Returns ``(observation, reward, terminated, truncated, info)``. ``reward`` is
        ``float(success)``, ``info["success"]`` is the success flag of the new state (for
        environments whose criterion needs a goal, against the goal set with
        :meth:`set_goal`, else ``False``). The benchmark has no time limit, so
        ``terminated`` and ``truncated`` are always ``False``.
        """

    @abc.abstractmethod
    def render(self, height: int = 64, width: int | None = None) -> np.ndarray:
        """Renders the benchmark camera: ``uint8`` array of shape ``(height, width, 3)``."""

    @abc.abstractmethod
    def is_success(self, goal_state: np.ndarray | None = None) -> bool:
        """The task's success criterion on the current simulator state.

        ``goal_state`` is the goal of a task instance, for criteria defined relative to a
        goal (tabletop pushing); criteria that need none ignore it.
        """

    @abc.abstractmethod
    def serialize(self) -> dict[str, Any]:
        """JSON-able metadata that rebuilds an identical environment."""

    @abc.abstractmethod
    def reseed(self, seed: int | None) -> None:
        """Reseeds the generator of ``reset()`` as a build with ``seed`` would have it (and
        ``serialize()`` records ``seed``); the state is left as it is."""

    def set_goal(self, goal_state: np.ndarray | None) -> None:
        """Sets the goal that ``step`` reports ``info["success"]`` against."""
        self._goal_state = None if goal_state is None else np.asarray(goal_state, np.float64)

    def close(self) -> None:  # noqa: B027 (a no-op is right for envs without a renderer)
        """Releases renderer resources. Safe to call twice."""

    def __enter__(self) -> Env:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---- gymnasium spaces and generator -----------------------------------------------------
    def _cached_box(self, key: str, low: float, high: float, shape: tuple[int, ...],
                    dtype: type) -> spaces.Box:
        """The space stored under ``key``, made anew only when its shape no longer fits."""
        space = self.__dict__.get(key)
        if space is None or space.shape != shape:
            space = spaces.Box(low, high, shape, dtype)
            self.__dict__[key] = space
        return space

    @property
    def action_space(self) -> spaces.Box:
        """``Box(-1, 1, (action_dim,), float32)``, one object per environment (seedable)."""
        return self._cached_box("_action_space", -1.0, 1.0, (self.action_dim,), np.float32)

    @action_space.setter
    def action_space(self, space: spaces.Space) -> None:
        self.__dict__["_action_space"] = space

    @property
    def observation_space(self) -> spaces.Box | None:
        """``Box(0, 255, (S, S, 3), uint8)`` for ``observation_size=S``; ``None`` without
        observations (``observation_size=None``)."""
        size = getattr(self, "observation_size", None)
        if size is None:
            return None
        return self._cached_box("_observation_space", 0, 255, (size, size, 3), np.uint8)

    @observation_space.setter
    def observation_space(self, space: spaces.Space) -> None:
        self.__dict__["_observation_space"] = space

    # Gymnasium's generator is the environment's own (``self._rng``), which ``reset(seed=...)``
    # reseeds: ``np_random`` and gymnasium's seeding checks see the draws ``reset`` makes.
    @property
    def _np_random(self) -> np.random.Generator | None:  # type: ignore[override]
        return self.__dict__.get("_rng")

    @_np_random.setter
    def _np_random(self, rng: np.random.Generator | None) -> None:
        if rng is not None:
            self.__dict__["_rng"] = rng

    # ---- shared input checking -------------------------------------------------------------
    def check_action(self, action: Any) -> np.ndarray:
        """Validates an action and clips it to ``[-1, 1]``.

        Raises:
            ValueError: if the action has the wrong shape or contains NaN or inf.
        """
        arr = np.asarray(action, dtype=np.float64)
        if arr.shape != (self.action_dim,):
            raise ValueError(
                f"{self.name}: action must have shape ({self.action_dim},), got {arr.shape}. "
                f"Pass one action per call as a 1-D array of {self.action_dim} floats in [-1, 1]."
            )
        if not np.all(np.isfinite(arr)):
            raise ValueError(
                f"{self.name}: action contains NaN or inf: {arr.tolist()}. "
                "Actions must be finite floats in [-1, 1]."
            )
        return np.clip(arr, -1.0, 1.0)
