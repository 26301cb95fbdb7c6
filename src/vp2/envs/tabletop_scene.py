"""The tabletop scene as one value: every number that fixes the tabletop environment.

A :class:`TabletopScene` is a frozen dataclass of frozen parts -- the objects
(:class:`SceneObject`: shape, size, density, friction, contact dimension, colour), the table
(:class:`SceneTable`), the robot's placement and initial pose (:class:`SceneRobot`), where
objects start and where pushes may end (:class:`ScenePlacement`), the arm's controller
(:class:`SceneController`), the benchmark camera (:class:`SceneCamera`), the objects'
textures (:class:`SceneTextures`) and the render specification -- and the numbers derived from
them (rest heights, footprints, the table's bounds, what the render fingerprint hashes) are
computed from it, never written twice. :data:`DEFAULT_SCENE` is the benchmark's scene.

The world and the environment are built from a scene (``TabletopEnv(task, scene=...)``,
``TabletopWorld(scene)``), the default when none is given. A variant is a
:func:`dataclasses.replace` of the default, e.g. larger objects::

    big = dataclasses.replace(DEFAULT_SCENE, objects=tuple(
        dataclasses.replace(o, size=tuple(1.5 * s for s in o.size)) for o in DEFAULT_SCENE.objects))
    env = TabletopEnv("push_sphere", scene=big)

An environment built from another scene records it in its metadata
(:meth:`TabletopScene.to_dict`, rebuilt by :meth:`TabletopScene.from_dict`), so datasets, task
instances and the simulator oracle rebuild the same scene; the default scene records nothing
(the shipped suite's metadata predates the scene value).

This module imports no simulator: reading the scene (the render fingerprint included) is cheap.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from vp2.envs.rendering import SOFTWARE_RENDERING, RenderSpec

__all__ = [
    "DEFAULT_SCENE",
    "OBJECT_NAMES",
    "SceneCamera",
    "SceneController",
    "SceneObject",
    "ScenePlacement",
    "SceneRobot",
    "SceneTable",
    "SceneTextures",
    "TabletopScene",
    "resolve_scene",
]

#: The four objects of SPEC §1.2, in the order of every ``(4, 3)`` position array, of the
#: state vector's texture ids and of the model's object joints. A scene's objects carry these
#: names in this order (the task registry names its targets by them).
OBJECT_NAMES: tuple[str, ...] = ("large_cube", "small_cube", "cylinder", "sphere")
#: robosuite's primitive object classes a scene object may be, and the length of each one's
#: ``size``: box half sides (x, y, z), cylinder (radius, half height), ball radius.
SHAPE_SIZES: dict[str, int] = {"box": 3, "cylinder": 2, "ball": 1}

Range = tuple[tuple[float, float], tuple[float, float]]


@dataclasses.dataclass(frozen=True)
class SceneObject:
    """One object: a robosuite primitive with a free joint.

    Attributes:
        name: one of :data:`OBJECT_NAMES`.
        shape: ``"box"``, ``"cylinder"`` or ``"ball"`` (robosuite's ``BoxObject``,
            ``CylinderObject``, ``BallObject``).
        size: robosuite's size parameters (see :data:`SHAPE_SIZES`), metres.
        density: kg/m^3 (robosuite's default, water).
        friction: sliding, torsional and rolling friction. MuJoCo uses the larger value of the
            two geoms in contact.
        condim: contact dimension of the collision geoms; ``None`` keeps MuJoCo's default (3).
        rgba: the geoms' colour (the renderer uses the texture's material instead).
    """

    name: str
    shape: str
    size: tuple[float, ...]
    density: float = 1000
    friction: tuple[float, float, float] = (0.5, 0.005, 0.0001)
    condim: int | None = None
    rgba: tuple[float, float, float, float] = (0.5, 0.5, 0.5, 1.0)

    def __post_init__(self) -> None:
        if self.shape not in SHAPE_SIZES:
            raise ValueError(
                f"object {self.name!r}: unknown shape {self.shape!r}; use one of "
                f"{', '.join(SHAPE_SIZES)}"
            )
        if len(self.size) != SHAPE_SIZES[self.shape] or not all(s > 0 for s in self.size):
            raise ValueError(
                f"object {self.name!r}: a {self.shape} needs {SHAPE_SIZES[self.shape]} positive "
                f"size numbers (metres), got {tuple(self.size)}"
            )

    @property
    def rest_height(self) -> float:
        """Height of the centre above the table top when resting on it (metres)."""
        if self.shape == "box":
            return self.size[2]
        if self.shape == "cylinder":
            return self.size[1]
        return self.size[0]

    @property
    def footprint(self) -> float:
        """Radius of the circle around the object's footprint (metres): the circumradius of a
        box's base, the radius of a cylinder or ball."""
        if self.shape == "box":
            return math.sqrt(self.size[0] * self.size[0] + self.size[1] * self.size[1])
        return self.size[0]

    @property
    def height(self) -> float:
        """Full height when resting on the table (metres)."""
        return 2.0 * self.rest_height


@dataclasses.dataclass(frozen=True)
class SceneTable:
    """The table: only the part of robosuite's 0.8 x 0.8 m table that the arm works on, so that
    the camera shows the whole table with objects large enough to see at 64x64.

    Attributes:
        full_size: x, y, thickness (metres).
        center_x: world x of the table top's centre (its y is 0).
        top_z: world height of the table top.
        friction: sliding, torsional and rolling friction of the top; below robosuite's default
            of 1 so that objects slide rather than tip when pushed (a cube tips when pushed
            above half side / friction).
    """

    full_size: tuple[float, float, float] = (0.58, 0.64, 0.05)
    center_x: float = -0.08
    top_z: float = 0.8
    friction: tuple[float, float, float] = (0.5, 0.005, 0.0001)

    @property
    def bounds(self) -> Range:
        """World ``(x0, x1), (y0, y1)`` of the table top, metres."""
        hx, hy = self.full_size[0] / 2, self.full_size[1] / 2
        return (self.center_x - hx, self.center_x + hx), (-hy, hy)


#: robosuite's default Panda pose (joints 1-7, radians).
ROBOSUITE_PANDA_POSE: tuple[float, ...] = (
    0.0, math.pi / 16.0, 0.0, -math.pi / 2.0 - math.pi / 3.0, 0.0, math.pi - 0.2, math.pi / 4,
)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class SceneRobot:
    """The Panda arm's base and initial pose.

    Attributes:
        base_pos: world position of the base: where robosuite puts it in front of its default
            0.8 m table (the near edge of the smaller table is 0.19 m in front of it).
        home_qpos: the pose the initial pose is an offset of (robosuite's default).
        init_offset: change of the initial pose from ``home_qpos``. In robosuite's pose the hand
            hangs over the middle of the placement region, where the camera sees nothing of the
            objects under it; bending the shoulder and elbow back (the wrist turned by as much,
            so the hand keeps its orientation) retracts the grip site from x = -0.10 to
            x = -0.22 at the same height: over the back edge of the placement region.
        init_noise: standard deviation of the Gaussian noise added to the initial joint angles
            at reset (radians; robosuite's default for the Panda).
        gripper_qpos: the open fingers' joint positions.
    """

    base_pos: tuple[float, float, float] = (-0.56, 0.0, 0.0)
    home_qpos: tuple[float, ...] = ROBOSUITE_PANDA_POSE
    init_offset: tuple[float, ...] = (0.0, -0.1, 0.0, -0.35, 0.0, 0.25, 0.0)
    init_noise: float = 0.02
    gripper_qpos: tuple[float, float] = (0.020833, -0.020833)

    @property
    def init_qpos(self) -> np.ndarray:
        """The initial arm pose before noise, ``home_qpos + init_offset`` (radians, ``(7,)``)."""
        return np.array(self.home_qpos) + np.array(self.init_offset)


@dataclasses.dataclass(frozen=True)
class ScenePlacement:
    """Where objects start and where scripted pushes may end.

    Attributes:
        region: world (x, y) ranges where objects start: in front of the arm, within comfortable
            reach at table height, shifted to the right (-y) because the scripted pushes go left
            (directions in [0, pi]) and must stay on the table.
        gap: minimum free gap between two objects' footprints at reset (metres).
        yaw_range: range of the objects' uniform initial yaw (radians).
        max_draws: placement draws before a reset gives up.
        initial_layout: object (x, y) before the first reset (a valid, deterministic state).
        target_region: world (x, y) ranges where a scripted push may end: on the table with
            every object's centre at least 6 cm from its edges, and not so far from the robot
            (x > 0.15) that the arm pushes poorly there.
    """

    region: Range = ((-0.22, 0.1), (-0.26, 0.09))
    gap: float = 0.03
    yaw_range: tuple[float, float] = (0.0, 2.0 * math.pi)
    max_draws: int = 1000
    initial_layout: tuple[tuple[float, float], ...] = (
        (-0.1, -0.15), (-0.1, 0.15), (0.05, -0.1), (0.05, 0.1),
    )  # fmt: skip
    target_region: Range = ((-0.3, 0.15), (-0.26, 0.26))


@dataclasses.dataclass(frozen=True)
class SceneController:
    """The arm's controller: robosuite's ``OSC_POSITION`` (orientation held) and ``GRIP``.

    Attributes:
        control_freq: control steps per second. robosuite's default of 20 Hz moves the end
            effector at most 1.2 cm per step, too little to reach an object and push it 0.3 m in
            35 steps (SPEC §3); at 5 Hz (100 physics steps of 2 ms) a full action moves it about
            3.6 cm and the arm stops within about a step of a zero action.
        output_max: largest end-effector goal displacement per control step (m; a full action,
            robosuite's default).
        input_max: the action magnitude mapped to ``output_max``.
        kp: the OSC's position stiffness (robosuite's default).
        damping_ratio: the OSC's damping ratio (``kd = 2 sqrt(kp) damping_ratio``).
        nullspace_kp: stiffness of the nullspace pull towards the episode's initial joints
            (robosuite's ``nullspace_torques`` uses 10; :mod:`vp2.envs._osc_kernel`).
    """

    control_freq: float = 5
    output_max: float = 0.05
    input_max: float = 1
    kp: float = 150
    damping_ratio: float = 1
    nullspace_kp: float = 10.0


@dataclasses.dataclass(frozen=True)
class SceneCamera:
    """The benchmark camera: fixed, in front of the table looking back at the robot from 45
    degrees of elevation (like robosuite's ``agentview``), far away with a narrow field of view
    so that objects look about the same size everywhere on the table: the closest such camera
    that keeps the four table corners, the tops of objects anywhere in the placement and target
    regions and the arm's forearm and hand in the 64x64 image
    (``benchmarks/studies/tabletop_view_study.py``, docs/findings/environments.md).

    Attributes:
        name: the camera's name in the model.
        pos: world position.
        lookat: the point it looks at (z up).
        fovy: vertical field of view, degrees.
    """

    name: str = "vp2_tabletop"
    pos: tuple[float, float, float] = (2.696, 0.0, 3.741)
    lookat: tuple[float, float, float] = (-0.245, 0.0, 0.8)
    fovy: float = 10.0


#: The 13 robosuite textures of the default scene (names of
#: ``robosuite.utils.mjcf_utils.TEXTURE_FILES``), chosen for distinct mean colours (objects
#: are a few pixels wide at 64x64) that stand out from the white ceramic table top.
_DEFAULT_TEXTURES = (
    "WoodRed", "WoodGreen", "WoodBlue", "Glass", "Lemon", "WoodDark", "WoodPanels", "Brass",
    "Metal", "WoodLight", "Clay", "SteelScratched", "WoodTiles",
)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class SceneTextures:
    """The textures every reset draws the objects' looks from (distinct per object).

    Attributes:
        names: robosuite texture names; a state vector's texture ids index this tuple.
        specular, shininess: the materials' (one per texture, cube-mapped) MuJoCo settings.
    """

    names: tuple[str, ...] = _DEFAULT_TEXTURES
    specular: float = 0.4
    shininess: float = 0.1


#: The benchmark camera's render specification. The quality knobs were chosen by measurement
#: (``benchmarks/speed/bench_tabletop.py``, ``benchmarks/speed/bench_render_floor.py``,
#: docs/measurements.md): the arena's only light casts no shadow, so no shadow pass is drawn (a
#: small shadow map saves GL memory); the floor's 1% reflectance would re-render the whole
#: scene for no visible effect from this camera; multisampling costs more than half of the
#: render time on a software rasteriser. The frame is then geometry-bound (the Panda's and its
#: pedestal's visual meshes, 168k triangles), so the renderer draws a render-only model with
#: those meshes decimated by 70% (``mesh_reduction=0.7``; 80% and more visibly facets the
#: base's rings and costs ~0.5-1.6/255), the floor tessellated into 0.5 m squares and the
#: built-in primitives more coarsely; the physics model is untouched. Mean absolute error
#: against ``full_quality()`` (original meshes) at 64x64: 6.46/255 on average, 7.15/255 at most
#: over 56 varied states (budget 8/255); 5.0 ms per frame vs 13.1 ms with the original meshes
#: (2026-11-24, load ~4). See docs/measurements.md.
_DEFAULT_RENDER = RenderSpec(
    camera=SceneCamera.name,
    shadow_size=256,
    shadow_lights=(),
    skybox=False,
    mesh_reduction=0.7,
    **SOFTWARE_RENDERING,
)


def _default_objects() -> tuple[SceneObject, ...]:
    # No object is taller than 5 cm: the Panda hand starts 3 cm above the grip site, so at
    # pushing height only the fingers touch the objects (a taller one would meet the hand).
    # MuJoCo's default 3-D contacts have no rolling resistance, so a pushed ball would roll on
    # at constant speed (off the table): 6-D contacts and a rolling friction of 0.004 m (a ball
    # pushed at 0.2 m/s stops within about 2 cm of where the push ends), like a rubber ball on a
    # cloth-covered table.
    return (
        SceneObject("large_cube", "box", (0.025, 0.025, 0.025)),
        SceneObject("small_cube", "box", (0.0175, 0.0175, 0.0175)),
        SceneObject("cylinder", "cylinder", (0.025, 0.025)),
        SceneObject("sphere", "ball", (0.025,), friction=(0.5, 0.005, 0.004), condim=6),
    )


_PARTS: dict[str, type] = {}  # filled below: field name -> part class


@dataclasses.dataclass(frozen=True)
class TabletopScene:
    """Every number that fixes the tabletop scene (module docstring).

    Attributes:
        objects: the four objects, in the order of :data:`OBJECT_NAMES`.
        table, robot, placement, controller, camera, textures: the scene's parts.
        render: the render specification (its ``camera`` names :attr:`camera`).
        solver_arena: MuJoCo's arena per ``MjData`` (``<size memory=...>``). robosuite's base
            model sizes the solver for 5,000 contacts and rows, which makes every ``MjData``
            reserve 1.26 GB; this world uses 19 contacts and 69 rows at most (0.08 MB). A process
            holding a few such reservations has one anonymous mapping larger than the machine's
            RAM, and Linux refuses to fork it. 16 MB is 200 times what a trajectory uses; the
            dynamics do not depend on it. ``None`` keeps robosuite's sizes
            (``benchmarks/checks/env_memory.py`` compares the two).
    """

    objects: tuple[SceneObject, ...] = dataclasses.field(default_factory=_default_objects)
    table: SceneTable = SceneTable()
    robot: SceneRobot = SceneRobot()
    placement: ScenePlacement = ScenePlacement()
    controller: SceneController = SceneController()
    camera: SceneCamera = SceneCamera()
    textures: SceneTextures = SceneTextures()
    render: RenderSpec = _DEFAULT_RENDER
    solver_arena: str | None = "16M"

    def __post_init__(self) -> None:
        names = tuple(o.name for o in self.objects)
        if names != OBJECT_NAMES:
            raise ValueError(
                f"a tabletop scene has the objects {', '.join(OBJECT_NAMES)} in this order, got "
                f"{', '.join(names) or 'none'}; replace an object's numbers, not its name"
            )
        if len(self.textures.names) < len(self.objects):
            raise ValueError(
                f"a tabletop scene needs at least {len(self.objects)} textures (one per object), "
                f"got {len(self.textures.names)}"
            )
        if self.render.camera != self.camera.name:
            raise ValueError(
                f"the scene's render spec draws camera {self.render.camera!r} but its camera is "
                f"{self.camera.name!r}; replace both together"
            )
        if not self.controller.control_freq > 0:
            raise ValueError(
                f"control_freq must be positive (Hz), got {self.controller.control_freq}"
            )

    # ---- derived numbers -------------------------------------------------------------------
    def object(self, name: str) -> SceneObject:
        """The object called ``name`` (one of :data:`OBJECT_NAMES`)."""
        return self.objects[OBJECT_NAMES.index(name)]

    @property
    def rest_heights(self) -> dict[str, float]:
        """``{object name: height of its centre above the table top at rest}`` (metres)."""
        return {o.name: o.rest_height for o in self.objects}

    @property
    def footprints(self) -> dict[str, float]:
        """``{object name: radius of the circle around its footprint}`` (metres)."""
        return {o.name: o.footprint for o in self.objects}

    def render_description(self) -> dict[str, Any]:
        """What the tabletop's render fingerprint hashes of the scene: the render spec and the
        camera's placement. ``vp2.envs.render_specs.render_fingerprint("tabletop", scene)`` adds
        the env and the render path's version and hashes it."""
        cam = self.camera
        return {
            "spec": dataclasses.asdict(self.render),
            "camera": {"CAMERA_POS": cam.pos, "CAMERA_LOOKAT": cam.lookat, "CAMERA_FOVY": cam.fovy},
        }

    # ---- as data ---------------------------------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """The scene as plain data (JSON-able); :meth:`from_dict` rebuilds an equal scene."""
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> TabletopScene:
        """The scene of :meth:`to_dict` output (lists read back as tuples).

        Raises:
            ValueError: unknown or malformed fields.
        """
        if not isinstance(data, Mapping):
            raise ValueError(f"a tabletop scene must be a dict from TabletopScene.to_dict(), got {data!r}")
        kwargs: dict[str, Any] = {}
        for key, value in data.items():
            if key == "objects":
                kwargs[key] = tuple(_build(SceneObject, o, "objects[]") for o in value)
            elif key in _PARTS:
                kwargs[key] = _build(_PARTS[key], value, key)
            elif key == "solver_arena":
                kwargs[key] = value
            else:
                raise ValueError(
                    f"unknown tabletop scene field {key!r}; known: "
                    f"{', '.join(f.name for f in dataclasses.fields(cls))}"
                )
        return cls(**kwargs)


_PARTS.update(
    table=SceneTable, robot=SceneRobot, placement=ScenePlacement, controller=SceneController,
    camera=SceneCamera, textures=SceneTextures, render=RenderSpec,
)  # fmt: skip


def _tuples(value: Any) -> Any:
    """Lists (JSON's arrays) as tuples, recursively."""
    if isinstance(value, (list, tuple)):
        return tuple(_tuples(v) for v in value)
    return value


def _build(cls: type, data: Any, where: str) -> Any:
    if not isinstance(data, Mapping):
        raise ValueError(f"tabletop scene field {where!r} must be a dict, got {data!r}")
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ValueError(
            f"unknown field(s) {', '.join(unknown)} in tabletop scene {where!r}; known: "
            f"{', '.join(sorted(known))}"
        )
    return cls(**{k: _tuples(v) for k, v in data.items()})


#: The benchmark's tabletop scene.
DEFAULT_SCENE = TabletopScene()


def resolve_scene(scene: TabletopScene | Mapping[str, Any] | None) -> TabletopScene:
    """``scene`` as a :class:`TabletopScene`: ``None`` is :data:`DEFAULT_SCENE`, a dict is read
    by :meth:`TabletopScene.from_dict` (environment metadata)."""
    if scene is None:
        return DEFAULT_SCENE
    if isinstance(scene, TabletopScene):
        return scene
    return TabletopScene.from_dict(scene)
