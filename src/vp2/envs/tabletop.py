"""Tabletop pushing (4 task categories): a robosuite Panda arm pushing one of four objects.

SPEC §1.2: the original release's scene. A robosuite table arena with a Panda arm driven by
robosuite's operational-space *position* controller (hand held straight down) and gripper
controller, and four objects: a large cube, a small cube, a cylinder and a sphere. Every number
of the scene (object sizes and frictions, the table, the arm's pose, placement ranges,
controller gains and rate, the camera, the render spec) is one value, a
:class:`~vp2.envs.tabletop_scene.TabletopScene` (:data:`~vp2.envs.tabletop_scene.DEFAULT_SCENE`
is the benchmark's). Every reset draws a texture for each object from the scene's set of 13,
non-overlapping object positions in front of the arm (dropped from 1 cm), and a little arm
joint noise, all from the environment's own generator.

Action (4-D, in ``[-1, 1]``; outside values are clipped, see :meth:`Env.check_action`):
``(dx, dy, dz, gripper)``. ``dx, dy, dz`` move the end-effector goal by up to 5 cm per control
step in the robot base frame (robosuite's ``OSC_POSITION`` default scaling); ``gripper`` > 0
closes and < 0 opens the gripper by one increment of robosuite's ``PandaGripper`` per step.
A control step is 1 s of simulated time (1 Hz control, 500 physics steps of 2 ms): the hand
reaches its goal and comes to rest within the step.

Success (SPEC §1.2): every object is within 5 cm of its position in the goal state::

    max_k || p_k - p_k^goal || < 0.05

State vector (:meth:`TabletopEnv.get_state`), ``float64``::

    [ mj_getState(mjSTATE_INTEGRATION) | texture ids (4) | gripper command (2) | OSC q0 (7) ]

The first block is MuJoCo's full integration state (time, qpos, qvel, warm start, ctrl, ...);
the texture ids index the scene's ``textures.names``; the last 9 numbers are the controller state that
robosuite keeps between steps (see :class:`vp2.envs._tabletop_stepper.LeanStepper`).
Restoring a state and replaying actions is bit-identical, also in a fresh process.

Speed: a control step does not go through robosuite's ``env.step`` but through
:class:`~vp2.envs._tabletop_stepper.LeanStepper`, which performs the same arithmetic without
robosuite's per-physics-step bookkeeping (bit-identical results, several times faster); images
come from the shared :class:`~vp2.envs.rendering.Renderer` with the scene's ``render`` spec. See
``docs/measurements.md`` for the measurements.
"""

from __future__ import annotations

import math
from typing import Any

import mujoco
import numpy as np

from vp2.envs._tabletop_stepper import LeanStepper
from vp2.envs._tabletop_world import TabletopWorld
from vp2.envs.base import Env
from vp2.envs.rendering import Renderer
from vp2.envs.tabletop_scene import DEFAULT_SCENE, OBJECT_NAMES, TabletopScene, resolve_scene
from vp2.envs.tasks import TABLETOP_TASKS, get_task
from vp2.utils.fixedmath import rows_norm

__all__ = [
    "DEFAULT_SCENE",
    "OBJECT_NAMES",
    "SUCCESS_THRESHOLD",
    "TabletopEnv",
    "TabletopScene",
]

#: Success threshold on the largest object displacement from the goal (metres), SPEC §1.2.
SUCCESS_THRESHOLD = 0.05

_STATE_SPEC = mujoco.mjtState.mjSTATE_INTEGRATION
# Layout facts of the model (checked against the built model in __init__), so that object
# positions can be read out of a state vector without building an environment.
_NQ = 37
_OBJECT_QPOS_ADR = (9, 16, 23, 30)
_ARM_QPOS_ADR = tuple(range(7))
_GRIPPER_QPOS_ADR = (7, 8)
_QPOS_OFFSET = 1  # the integration state starts with the simulation time


class TabletopEnv(Env):
    """One tabletop pushing task category (see the module docstring for the details).

    Args:
        task: one of ``push_large_cube``, ``push_small_cube``, ``push_cylinder``,
            ``push_sphere``. The task only names which object the task suite and the
            scripted policy push; dynamics, rendering and the success criterion are shared.
        seed: seed of the environment's generator (initial states of ``reset()``).
        observation_size: side of the square RGB observation returned by ``reset``/``step``;
            ``None`` returns no observation (faster when only states are needed).
        scene: the scene (:class:`~vp2.envs.tabletop_scene.TabletopScene`, or its ``to_dict()``
            from metadata); ``None`` is :data:`~vp2.envs.tabletop_scene.DEFAULT_SCENE`.
    """

    action_dim = 4
    #: Index of the object the task pushes (into :data:`OBJECT_NAMES`), set per instance.
    target_object: int

    def __init__(
        self,
        task: str,
        seed: int | None = None,
        observation_size: int | None = 64,
        scene: TabletopScene | dict[str, Any] | None = None,
    ):
        if task not in TABLETOP_TASKS:
            raise ValueError(f"unknown tabletop task {task!r}; known: {', '.join(TABLETOP_TASKS)}")
        if observation_size is not None and int(observation_size) <= 0:
            raise ValueError(f"observation_size must be positive or None, got {observation_size}")
        self.scene = resolve_scene(scene)
        self.task = task
        self.name = f"tabletop/{task}"
        self.seed = seed
        self.observation_size = None if observation_size is None else int(observation_size)
        self.target_object = OBJECT_NAMES.index(get_task(self.name).target)
        self._rng = np.random.default_rng(seed)
        self._goal_state: np.ndarray | None = None

        self._world = TabletopWorld(self.scene)
        self._stepper = LeanStepper(self._world)
        self._model: mujoco.MjModel = self._world.sim.model._model
        self._data: mujoco.MjData = self._world.sim.data._data
        self._check_layout()
        self._n_integration = mujoco.mj_stateSize(self._model, _STATE_SPEC)
        self._textures = np.arange(len(OBJECT_NAMES))
        self._renderer: Renderer | None = None
        # A valid, deterministic state before the first reset (textures 0-3, a fixed layout).
        self._set_initial_state(
            arm_qpos=self.scene.robot.init_qpos,
            object_xy=np.array(self.scene.placement.initial_layout),
            object_yaw=np.zeros(len(OBJECT_NAMES)),
            textures=np.arange(len(OBJECT_NAMES)),
        )

    def _check_layout(self) -> None:
        world, model = self._world, self._model
        layout_ok = (
            model.nq == _NQ
            and tuple(int(a) for a in world.object_qpos_adr) == _OBJECT_QPOS_ADR
            and tuple(self._stepper.osc.qpos_index) == _ARM_QPOS_ADR
        )
        if not layout_ok:
            raise RuntimeError(
                "the robosuite model's joint layout differs from the one vp2 was written for "
                f"(nq={model.nq}, object qpos addresses {world.object_qpos_adr.tolist()}); "
                "check the installed robosuite version against pyproject.toml"
            )

    # ---- lifecycle -------------------------------------------------------------------------
    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray | None, dict[str, Any]]:
        """Draws textures, object placements and arm noise from the environment's generator.

        Args:
            seed: reseeds the generator first (the same seed gives the same initial state).
            options: unused (accepted for Gymnasium compatibility).
        """
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        rng, scene = self._rng, self.scene
        # One texture per object, with replacement (the original's draws).
        textures = rng.integers(0, len(scene.textures.names), size=len(OBJECT_NAMES))
        arm_qpos = scene.robot.init_qpos + scene.robot.init_noise * rng.standard_normal(7)
        object_xy = self._sample_placement(rng)
        yaw0, yaw1 = scene.placement.yaw_range
        object_yaw = rng.uniform(yaw0, yaw1, size=len(OBJECT_NAMES))
        self._set_initial_state(arm_qpos, object_xy, object_yaw, textures)
        obs = self._observation()
        return obs, {"textures": self.texture_names(), "success": self.is_success()}

    def _sample_placement(self, rng: np.random.Generator) -> np.ndarray:
        """Non-overlapping object positions in the scene's placement region, shape ``(4, 2)``:
        robosuite's ``UniformRandomSampler``, one object after the other, each redrawn while its
        centre is within the sum of footprint radii of an object placed before it."""
        placement = self.scene.placement
        (x0, x1), (y0, y1) = placement.region
        radii = np.array([obj.footprint for obj in self.scene.objects])
        xy = np.zeros((len(OBJECT_NAMES), 2))
        for k in range(len(OBJECT_NAMES)):
            for _ in range(placement.max_draws):
                xy[k] = (rng.uniform(x0, x1), rng.uniform(y0, y1))
                if k == 0 or np.all(rows_norm(xy[:k] - xy[k]) > radii[:k] + radii[k]):
                    break
            else:  # pragma: no cover
                raise RuntimeError(f"could not place {OBJECT_NAMES[k]} without overlap")
        return xy

    def _set_initial_state(
        self,
        arm_qpos: np.ndarray,
        object_xy: np.ndarray,
        object_yaw: np.ndarray,
        textures: np.ndarray,
    ) -> None:
        m, d = self._model, self._data
        mujoco.mj_resetData(m, d)
        d.qpos[list(_ARM_QPOS_ADR)] = arm_qpos
        d.qpos[list(_GRIPPER_QPOS_ADR)] = np.array(self.scene.robot.gripper_qpos)
        start_z = self.scene.table.top_z + self.scene.placement.drop_height
        for k, obj in enumerate(self.scene.objects):
            adr = _OBJECT_QPOS_ADR[k]
            d.qpos[adr : adr + 3] = (object_xy[k, 0], object_xy[k, 1], start_z + obj.rest_height)
            half_yaw = float(object_yaw[k]) / 2
            d.qpos[adr + 3 : adr + 7] = (math.cos(half_yaw), 0.0, 0.0, math.sin(half_yaw))
        mujoco.mj_forward(m, d)
        self._set_textures(np.asarray(textures))
        self._stepper.reset_controllers(np.array(arm_qpos, np.float64))

    def _set_textures(self, textures: np.ndarray) -> None:
        textures = np.asarray(textures).astype(np.int64)
        n_textures = len(self.scene.textures.names)
        if (
            textures.shape != (len(OBJECT_NAMES),)
            or np.any(textures < 0)
            or np.any(textures >= n_textures)
        ):
            raise ValueError(
                f"texture ids must be {len(OBJECT_NAMES)} integers in [0, {n_textures}), got {textures.tolist()}"
            )
        self._textures = textures.copy()
        self._world.set_textures(self._textures)

    def get_state(self) -> np.ndarray:
        """The complete state (see the module docstring for its layout), a copy."""
        sim_state = np.empty(self._n_integration)
        mujoco.mj_getState(self._model, self._data, sim_state, _STATE_SPEC)
        return np.concatenate(
            [sim_state, self._textures.astype(np.float64), self._stepper.controller_state()]
        )

    @property
    def state_size(self) -> int:
        """Length of :meth:`get_state` vectors."""
        return self._n_integration + len(OBJECT_NAMES) + LeanStepper.CONTROLLER_STATE_SIZE

    def reset_to(self, state: np.ndarray) -> np.ndarray | None:
        """Restores a state from :meth:`get_state` (textures and controller state included)."""
        state = np.asarray(state, dtype=np.float64)
        if state.shape != (self.state_size,) or not np.all(np.isfinite(state)):
            raise ValueError(
                f"{self.name}: state must be a finite float vector of shape ({self.state_size},) "
                f"from TabletopEnv.get_state(), got shape {state.shape}"
            )
        n = self._n_integration
        mujoco.mj_setState(self._model, self._data, state[:n], _STATE_SPEC)
        textures = state[n : n + len(OBJECT_NAMES)]
        if np.any(textures != np.round(textures)):
            raise ValueError(f"{self.name}: texture ids in the state are not integers: {textures}")
        self._set_textures(textures.astype(np.int64))
        self._stepper.set_controller_state(state[n + len(OBJECT_NAMES) :])
        mujoco.mj_forward(self._model, self._data)
        return self._observation()

    def step(
        self, action: np.ndarray
    ) -> tuple[np.ndarray | None, float, bool, bool, dict[str, Any]]:
        """One control step (1 s at the default 1 Hz). ``info["success"]`` is judged against :meth:`set_goal`."""
        self._stepper.step(self.check_action(action))
        success = self.is_success()
        return self._observation(), float(success), False, False, {"success": success}

    # ---- observation -----------------------------------------------------------------------
    def _observation(self) -> np.ndarray | None:
        if self.observation_size is None:
            return None
        return self.render(self.observation_size)

    def render(self, height: int = 64, width: int | None = None) -> np.ndarray:
        """Renders the benchmark camera with the scene's render spec, ``uint8 (height, width, 3)``."""
        if self._renderer is None:
            spec = self.scene.render
            self._renderer = Renderer(
                self._model, spec, render_model=self._world.render_model(spec.mesh_reduction)
            )
        # After mj_step the kinematics lag the integrated qpos by one physics step; recompute
        # them so that an image is a function of the state alone (re-rendering a saved state
        # gives the same image). The next mj_step1 recomputes them anyway, so the dynamics
        # are untouched.
        mujoco.mj_kinematics(self._model, self._data)
        mujoco.mj_camlight(self._model, self._data)
        return self._renderer.render(self._data, height, width)

    # ---- success ---------------------------------------------------------------------------
    def object_positions(self) -> np.ndarray:
        """Current object positions ``(4, 3)`` in the order of :data:`OBJECT_NAMES`."""
        qpos = self._data.qpos
        return np.stack([qpos[a : a + 3] for a in _OBJECT_QPOS_ADR]).copy()

    def object_quaternions(self) -> np.ndarray:
        """Current object orientations ``(4, 4)`` as (w, x, y, z) quaternions."""
        qpos = self._data.qpos
        return np.stack([qpos[a + 3 : a + 7] for a in _OBJECT_QPOS_ADR]).copy()

    @staticmethod
    def object_positions_from_state(state: np.ndarray) -> np.ndarray:
        """Object positions ``(4, 3)`` stored in a state vector from :meth:`get_state`."""
        state = np.asarray(state, np.float64)
        return np.stack([state[_QPOS_OFFSET + a : _QPOS_OFFSET + a + 3] for a in _OBJECT_QPOS_ADR])

    @staticmethod
    def with_object_positions(state: np.ndarray, positions: np.ndarray) -> np.ndarray:
        """A copy of ``state`` with the object positions ``(4, 3)`` replaced.

        Used to express a goal ("these objects at these places") as a state vector that
        :meth:`is_success` and :meth:`set_goal` accept; the rest of the state is kept as is.
        """
        out = np.array(state, dtype=np.float64, copy=True)
        positions = np.asarray(positions, np.float64)
        if positions.shape != (len(OBJECT_NAMES), 3):
            raise ValueError(
                f"positions must have shape ({len(OBJECT_NAMES)}, 3), got {positions.shape}"
            )
        for k, a in enumerate(_OBJECT_QPOS_ADR):
            out[_QPOS_OFFSET + a : _QPOS_OFFSET + a + 3] = positions[k]
        return out

    @staticmethod
    def goal_distance(positions: np.ndarray, goal_state: np.ndarray) -> float:
        """Largest distance of an object in ``positions`` ``(4, 3)`` from its goal position."""
        goal = TabletopEnv.object_positions_from_state(goal_state)
        return float(np.max(rows_norm(np.asarray(positions) - goal)))

    def is_success(self, goal_state: np.ndarray | None = None) -> bool:
        """All objects within :data:`SUCCESS_THRESHOLD` of their goal positions.

        ``goal_state`` defaults to the goal given to :meth:`set_goal` (an instance's
        ``make_env()`` sets it); ``False`` when there is neither.
        """
        if goal_state is None:
            goal_state = self._goal_state
        if goal_state is None:
            return False
        return self.goal_distance(self.object_positions(), goal_state) < SUCCESS_THRESHOLD

    # ---- end-effector (for scripted policies) ----------------------------------------------
    def end_effector_position(self) -> np.ndarray:
        """World position of the gripper's grip site (the point the controller moves), ``(3,)``."""
        mujoco.mj_kinematics(self._model, self._data)
        return self._data.site_xpos[self._stepper._ref_site].copy()

    def base_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """Position ``(3,)`` and rotation ``(3, 3)`` of the frame actions are expressed in."""
        mujoco.mj_kinematics(self._model, self._data)
        site = self._stepper._center_site
        return self._data.site_xpos[site].copy(), self._data.site_xmat[site].reshape(3, 3).copy()

    # ---- metadata --------------------------------------------------------------------------
    def texture_names(self) -> dict[str, str]:
        """The current texture of every object, ``{object name: texture name}``."""
        names = self.scene.textures.names
        return {obj: names[int(t)] for obj, t in zip(OBJECT_NAMES, self._textures, strict=True)}

    def reseed(self, seed: int | None) -> None:
        self.seed = seed
        self._rng = np.random.default_rng(seed)

    def serialize(self) -> dict[str, Any]:
        """``{"name", "kwargs"}`` for :func:`vp2.envs.make_env_from_metadata`, plus the textures.

        A scene other than :data:`~vp2.envs.tabletop_scene.DEFAULT_SCENE` is recorded as
        ``kwargs["scene"]`` (:meth:`TabletopScene.to_dict`); the default scene is not recorded,
        so the metadata of a default environment is what it was before scenes were values.
        The texture assignment is part of the state vector (so ``reset_to`` restores it);
        ``"textures"`` and ``"texture_set"`` are informational (what the ids mean).
        """
        kwargs: dict[str, Any] = {"seed": self.seed, "observation_size": self.observation_size}
        if self.scene != DEFAULT_SCENE:
            kwargs["scene"] = self.scene.to_dict()
        return {
            "name": self.name,
            "kwargs": kwargs,
            "textures": self.texture_names(),
            "texture_set": list(self.scene.textures.names),
        }

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    @property
    def table_bounds(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """World ``(x0, x1), (y0, y1)`` of the table top, metres."""
        return self.scene.table.bounds
