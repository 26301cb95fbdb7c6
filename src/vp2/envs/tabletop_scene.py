"""The tabletop scene as one value: every number that fixes the tabletop environment.

A :class:`TabletopScene` is a frozen dataclass of frozen parts -- the objects
(:class:`SceneObject`), the table (:class:`SceneTable`), the robot's placement and initial pose
(:class:`SceneRobot`), where objects start and where pushes may end (:class:`ScenePlacement`),
the arm's controller (:class:`SceneController`), the camera (:class:`SceneCamera`), the
objects' textures (:class:`SceneTextures`), the room's look (:class:`SceneArena`) and the render
specification -- and the numbers derived from them (rest heights, footprints, the table's
bounds, what the render fingerprint hashes) are computed from it, never written twice.
:data:`DEFAULT_SCENE` is the benchmark's scene: SPEC §1.2, the original release's.

The world and the environment are built from a scene (``TabletopEnv(task, scene=...)``,
``TabletopWorld(scene)``), the default when none is given. A variant is a
:func:`dataclasses.replace` of the default, e.g. larger objects::

    big = dataclasses.replace(DEFAULT_SCENE, objects=tuple(
        dataclasses.replace(o, size=tuple(1.5 * s for s in o.size)) for o in DEFAULT_SCENE.objects))
    env = TabletopEnv("push_sphere", scene=big)

An environment built from another scene records it in its metadata
(:meth:`TabletopScene.to_dict`, rebuilt by :meth:`TabletopScene.from_dict`); the default scene
records nothing.

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
    "SceneArena",
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
        friction: sliding, torsional and rolling friction of the collision geom.
        priority: MuJoCo contact priority of the collision geom. The original's robosuite fork
            gives every object's collision geom ``priority=1``, so an object's own friction
            (and solref/solimp) governs its contacts with the table, the fingers and the arm
            (priority 0); two objects in contact (equal priority) use the larger friction.
        condim: contact dimension of the collision geoms; ``None`` keeps MuJoCo's default
            (3: sliding friction only, so the torsional and rolling values have no effect and
            a pushed ball has no rolling resistance, as in the original).
        rgba: the geoms' colour (the renderer uses the texture's material instead).
    """

    name: str
    shape: str
    size: tuple[float, ...]
    density: float = 1000
    friction: tuple[float, float, float] = (0.7, 0.005, 0.0001)
    priority: int = 1
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
    """The table: the original's (``table_full_size``, ``table_friction``, ``table_offset`` of
    its ``PushCenterMulti``), robosuite's table arena centred at the world origin.

    Attributes:
        full_size: x, y, thickness (metres).
        center_x: world x of the table top's centre (its y is 0).
        top_z: world height of the table top.
        friction: sliding, torsional and rolling friction of the top. The objects' contact
            priority makes their own friction govern every object-table contact.
    """

    full_size: tuple[float, float, float] = (0.8, 0.8, 0.05)
    center_x: float = 0.0
    top_z: float = 0.8
    friction: tuple[float, float, float] = (1.0, 0.005, 0.0001)

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
        base_pos: world position of the base: where robosuite puts it for a 0.8 m table
            (``base_xpos_offset["table"](0.8)`` = (-0.16 - 0.8 / 2, 0, 0); the mount lifts
            the arm's base site to z = 0.912).
        home_qpos: the initial arm pose before noise (robosuite's Panda ``init_qpos``, the same
            in robosuite 1.3 and 1.5.2); the grip site is then at (-0.103, 0, 1.011).
        init_noise: standard deviation of the Gaussian noise added to the initial joint angles
            at reset (radians; robosuite's ``"default"`` initialization noise for the Panda).
        gripper_qpos: the fingers' joint positions (robosuite's Panda gripper ``init_qpos``).
    """

    base_pos: tuple[float, float, float] = (-0.56, 0.0, 0.0)
    home_qpos: tuple[float, ...] = ROBOSUITE_PANDA_POSE
    init_noise: float = 0.02
    gripper_qpos: tuple[float, float] = (0.020833, -0.020833)

    @property
    def init_qpos(self) -> np.ndarray:
        """The initial arm pose before noise, ``home_qpos`` (radians, ``(7,)``)."""
        return np.array(self.home_qpos, np.float64)


@dataclasses.dataclass(frozen=True)
class ScenePlacement:
    """Where objects start and where scripted pushes may end.

    The placement is the original's (robosuite's ``UniformRandomSampler`` with
    ``ensure_valid_placement``): objects are placed one after the other, in the order of
    :data:`OBJECT_NAMES`, each centre uniform in ``region`` (about the table centre, which is
    the world origin) and redrawn while its horizontal distance to an object already placed is
    at most the sum of their footprint radii; the yaw is uniform in ``yaw_range``; the object
    starts ``drop_height`` above its resting height.

    Attributes:
        region: world (x, y) ranges of the objects' centres at reset.
        yaw_range: range of the objects' uniform initial yaw (radians).
        drop_height: height above rest at which objects start (they fall onto the table during
            the first step).
        max_draws: draws per object before a reset gives up (robosuite's 5000).
        initial_layout: object (x, y) before the first reset (a valid, deterministic state).
        target_region: world (x, y) ranges where a scripted push may end: the original
            collection script clamps each coordinate of a push target to +-0.35 m.
    """

    region: Range = ((-0.1, 0.3), (-0.15, 0.15))
    yaw_range: tuple[float, float] = (0.0, 2.0 * math.pi)
    drop_height: float = 0.01
    max_draws: int = 5000
    initial_layout: tuple[tuple[float, float], ...] = (
        (0.0, -0.1), (0.0, 0.1), (0.2, -0.1), (0.2, 0.1),
    )  # fmt: skip
    target_region: Range = ((-0.35, 0.35), (-0.35, 0.35))


@dataclasses.dataclass(frozen=True)
class SceneController:
    """The arm's controller: robosuite's ``OSC_POSITION`` and ``GRIP``, as the original ran it.

    Attributes:
        control_freq: control steps per second: 1 Hz, one action is 500 physics steps of 2 ms,
            long enough for the hand to reach its goal (at most ``output_max`` away per axis)
            and come to rest within the step.
        output_max: largest end-effector goal displacement per control step and axis (m; a full
            action, robosuite's default).
        input_max: the action magnitude mapped to ``output_max``.
        kp: the OSC's stiffness (robosuite's default; position and orientation).
        damping_ratio: the OSC's damping ratio (``kd = 2 sqrt(kp) damping_ratio``).
        nullspace_kp: stiffness of the nullspace pull towards the episode's initial joints
            (robosuite's ``nullspace_torques`` uses 10; :mod:`vp2.envs._osc_kernel`).
        hand_orientation: the world orientation (rows of a rotation matrix) the OSC holds the
            grip site at: robosuite 1.3's ``OSC_POSITION`` sets this goal (hand straight down)
            at every control step, so the first step rotates out the initial pose's 7.3 degree
            tilt. robosuite 1.5.2 would hold whatever orientation the hand has.
    """

    control_freq: float = 1
    output_max: float = 0.05
    input_max: float = 1
    kp: float = 150
    damping_ratio: float = 1
    nullspace_kp: float = 10.0
    hand_orientation: tuple[tuple[float, float, float], ...] = (
        (0.0, 1.0, 0.0), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0),
    )  # fmt: skip


@dataclasses.dataclass(frozen=True)
class SceneCamera:
    """The benchmark camera: the original's ``agentview_shift_2`` (its robosuite fork's
    ``table_arena.xml``), fixed in front of the table looking back at the robot, 36.9 degrees
    below the horizontal; its optical axis meets the table top at (0.075, 0) from 0.751 m.

    Attributes:
        name: the camera's name in the model.
        pos: world position.
        quat: orientation quaternion (w, x, y, z); a MuJoCo camera looks along its -z axis.
        fovy: vertical field of view, degrees (the original sets none: MuJoCo's default).
    """

    name: str = "agentview_shift_2"
    pos: tuple[float, float, float] = (0.6758858572576728, -4.76e-08, 1.251269639768581)
    quat: tuple[float, float, float, float] = (
        0.6325998902320862, 0.31593844294548035, 0.31593817472457886, 0.6326003670692444,
    )  # fmt: skip
    fovy: float = 45.0


#: The 13 robosuite 1.5.2 textures standing in for the original's set (names of
#: ``robosuite.utils.mjcf_utils.TEXTURES``). The original draws from Can, Tile0-Tile4,
#: XmasOrnament, PaintedPlaster, Rocks, Chip, Fabric, Fabric2 and Candy, of which only
#: ``can.png`` ships with robosuite 1.5.2; each other one is replaced by a stock texture
#: (docs/tabletop.md has the pairs), none of them the floor's, the walls' or the table's.
_DEFAULT_TEXTURES = (
    "Can", "BricksWhite", "WoodRed", "WoodGreen", "WoodBlue", "PlasterYellow", "Brass",
    "PlasterPink", "Dirt", "Bread", "FeltGray", "Clay", "Lemon",
)  # fmt: skip


@dataclasses.dataclass(frozen=True)
class SceneTextures:
    """The textures every reset draws the objects' looks from: one uniform draw per object,
    with replacement (two objects may share a texture), as in the original.

    Attributes:
        names: robosuite texture names; a state vector's texture ids index this tuple.
        specular, shininess: the materials' (one per texture, cube-mapped) MuJoCo settings.
            The original draws one value from U(0, 1) per reset for specular, shininess and
            reflectance of all four objects; here both are that draw's mean, fixed, and the
            reflectance is 0 (a reflection costs a second scene pass per frame).
    """

    names: tuple[str, ...] = _DEFAULT_TEXTURES
    specular: float = 0.5
    shininess: float = 0.5


@dataclasses.dataclass(frozen=True)
class SceneArena:
    """The room around the table: the original's ``table_arena.xml`` look (its floor and wall
    textures, its two lights) on robosuite 1.5.2's table arena.

    Attributes:
        floor_texture, wall_texture: robosuite texture names of the floor and the walls.
        lights: ``(position, direction)`` of each light: spot lights (not directional) without
            shadows, all with ``light_diffuse`` and ``light_specular``.
        light_diffuse, light_specular: the lights' diffuse and specular intensity (grey).
    """

    floor_texture: str = "WoodTiles"
    wall_texture: str = "PlasterCream"
    lights: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = (
        ((1.0, 1.0, 4.0), (0.0, -0.15, -1.0)),
        ((-3.0, -3.0, 4.0), (0.0, -0.15, -1.0)),
    )
    light_diffuse: float = 0.8
    light_specular: float = 0.3


#: The benchmark camera's render specification, chosen by measurement against the original's
#: way of rendering (``full_quality()`` at 256x256, then an anti-aliased bilinear resize to
#: 64x64; ``benchmarks/speed/bench_tabletop.py --section fidelity``, docs/tabletop.md). The
#: arena's lights cast no shadow, so no shadow pass is drawn (a small shadow map saves GL
#: memory); no reflection pass (matte materials); no multisampling (it costs more than half of
#: the render time on a software rasteriser); the Panda's and its pedestal's visual meshes
#: decimated by 70% in a render-only model (the arm is at the top edge of the image). Boxes
#: keep MuJoCo's default of 4 quads per face edge: the fixed-function pipeline lights per
#: vertex, and with one quad the lit gradient over the table top, which fills most of the
#: image, is lost (twice the pixel error).
_DEFAULT_RENDER = RenderSpec(
    camera=SceneCamera.name,
    shadow_size=256,
    shadow_lights=(),
    skybox=False,
    mesh_reduction=0.7,
    **{**SOFTWARE_RENDERING, "numquads": 4},
)


def _default_objects() -> tuple[SceneObject, ...]:
    # SPEC §1.2's objects and frictions. The original gives the small cube no friction, i.e.
    # robosuite's default (1.0, 0.005, 0.0001); SPEC's 0.7 is used (docs/tabletop.md).
    return (
        SceneObject("large_cube", "box", (0.06, 0.06, 0.06)),
        SceneObject("small_cube", "box", (0.04, 0.04, 0.04)),
        SceneObject("cylinder", "cylinder", (0.06, 0.06)),
        SceneObject("sphere", "ball", (0.07,), friction=(0.5, 0.005, 0.0001)),
    )


_PARTS: dict[str, type] = {}  # filled below: field name -> part class


@dataclasses.dataclass(frozen=True)
class TabletopScene:
    """Every number that fixes the tabletop scene (module docstring).

    Attributes:
        objects: the four objects, in the order of :data:`OBJECT_NAMES`.
        table, robot, placement, controller, camera, textures, arena: the scene's parts.
        render: the render specification (its ``camera`` names :attr:`camera`).
        solver_arena: MuJoCo's arena per ``MjData`` (``<size memory=...>``). robosuite's base
            model reserves 1.26 GB per ``MjData`` (5,000 contacts and rows), and Linux refuses
            to fork a process holding a few; a trajectory uses well under 1 MB, and the
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
    arena: SceneArena = SceneArena()
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
        """What the tabletop's render fingerprint hashes of the scene: the render spec, the
        camera's placement and the arena's look (floor, walls, lights).
        ``vp2.envs.render_specs.render_fingerprint("tabletop", scene)`` adds the env and the
        render path's version and hashes it."""
        return {
            "spec": dataclasses.asdict(self.render),
            "camera": dataclasses.asdict(self.camera),
            "arena": dataclasses.asdict(self.arena),
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
    camera=SceneCamera, textures=SceneTextures, arena=SceneArena, render=RenderSpec,
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
