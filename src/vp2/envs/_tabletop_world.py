"""The robosuite side of the tabletop environment: the MJCF world.

:class:`TabletopWorld` is a robosuite ``ManipulationEnv`` with a Panda arm (operational-space
*position* controller + gripper), a table, four objects, 13 object materials and the benchmark
camera. It is an ordinary robosuite environment: ``TabletopWorld(...).step(a)`` is robosuite's
own step, which the benchmark uses as the reference for the dynamics (and, with
``camera_obs_size``, as the speed baseline). The benchmark itself advances it with
:class:`vp2.envs._tabletop_stepper.LeanStepper`, bit-identical and faster, so that
:mod:`vp2.envs.tabletop` only deals with the benchmark contract.

robosuite's import-time notices (e.g. the missing ``mink`` package's) are dropped by
:mod:`vp2._quiet`, which ``import vp2`` installs before any simulator is imported.
"""

from __future__ import annotations

import json
import logging
import os
import pathlib
import xml.etree.ElementTree as ET

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
import robosuite  # noqa: E402
from robosuite.controllers import load_composite_controller_config  # noqa: E402
from robosuite.environments.manipulation.manipulation_env import ManipulationEnv  # noqa: E402
from robosuite.models.arenas import TableArena  # noqa: E402
from robosuite.models.objects import BallObject, BoxObject, CylinderObject  # noqa: E402
from robosuite.models.tasks import ManipulationTask  # noqa: E402
from robosuite.utils.mjcf_utils import TEXTURES, xml_path_completion  # noqa: E402

from vp2.utils.fixedmath import norm  # noqa: E402

# robosuite logs an INFO line (the controller config path) on every construction.
logging.getLogger("robosuite_logs").setLevel(logging.WARNING)

#: Object names, in the order of every ``(4, 3)`` position array of the environment.
OBJECT_NAMES: tuple[str, ...] = ("large_cube", "small_cube", "cylinder", "sphere")

#: The 13 robosuite textures objects are drawn from (names of
#: ``robosuite.utils.mjcf_utils.TEXTURE_FILES``), chosen for distinct mean colours (objects are
#: a few pixels wide at 64x64) that stand out from the white ceramic table top.
TEXTURE_NAMES: tuple[str, ...] = (
    "WoodRed",
    "WoodGreen",
    "WoodBlue",
    "Glass",
    "Lemon",
    "WoodDark",
    "WoodPanels",
    "Brass",
    "Metal",
    "WoodLight",
    "Clay",
    "SteelScratched",
    "WoodTiles",
)

#: Control steps per second. robosuite's default of 20 Hz moves the end effector at most 1.2 cm
#: per step, too little to reach an object and push it 0.3 m in 35 steps (SPEC §3); at 5 Hz
#: (100 physics steps of 2 ms per control step) a full action moves it about 3.6 cm and the arm
#: stops within about a step of a zero action. See docs/tabletop.md.
CONTROL_FREQ = 5
#: Largest end-effector goal displacement per control step (m): robosuite's OSC default.
OSC_OUTPUT_MAX = 0.05

#: The table (x, y, thickness; metres): only the part of robosuite's 0.8 x 0.8 m table that the
#: arm works on, so that the camera can show the whole table with objects large enough to see
#: at 64x64. Its top spans x in [-0.37, 0.21] (centre TABLE_CENTER_X), y in [-0.32, 0.32].
TABLE_FULL_SIZE = (0.58, 0.64, 0.05)
TABLE_CENTER_X = -0.08
TABLE_TOP_Z = 0.8
#: The robot's base: where robosuite puts it in front of its default 0.8 m table (the near
#: edge of the smaller table is 0.19 m in front of it, robosuite's default gap is 0.16 m).
ROBOT_BASE_POS = (-0.56, 0.0, 0.0)
#: robosuite size parameters: cube half sides, cylinder (radius, half height), sphere radius.
OBJECT_SIZES: dict[str, tuple[float, ...]] = {
    "large_cube": (0.025, 0.025, 0.025),
    "small_cube": (0.0175, 0.0175, 0.0175),
    "cylinder": (0.025, 0.025),
    "sphere": (0.025,),
}
#: robosuite's class of each object.
_OBJECT_CLASSES = dict(
    zip(OBJECT_NAMES, (BoxObject, BoxObject, CylinderObject, BallObject), strict=True)
)
#: Height of each object's centre above the table top when it rests on the table. No object is
#: taller than 5 cm: the Panda hand starts 3 cm above the grip site, so at pushing height only
#: the fingers touch the objects (a taller object would also meet the 20 cm wide hand).
OBJECT_REST_HEIGHT: dict[str, float] = {
    "large_cube": 0.025,
    "small_cube": 0.0175,
    "cylinder": 0.025,
    "sphere": 0.025,
}
#: Radius of the circle around each object's footprint (for non-overlapping placement).
OBJECT_FOOTPRINT: dict[str, float] = {
    "large_cube": 0.025 * float(np.sqrt(2.0)),
    "small_cube": 0.0175 * float(np.sqrt(2.0)),
    "cylinder": 0.025,
    "sphere": 0.025,
}
#: Sliding, torsional and rolling friction of the table top and of the objects. MuJoCo uses the
#: larger value of the two geoms in contact. Below robosuite's default of 1 so that objects slide
#: rather than tip when pushed (a cube tips when pushed above half side / friction).
TABLE_FRICTION = (0.5, 0.005, 0.0001)
OBJECT_FRICTION = [0.5, 0.005, 0.0001]
#: Rolling friction coefficient of the sphere (metres; torque per unit normal force). A ball
#: pushed at 0.2 m/s stops within about 2 cm of where the push ends.
SPHERE_ROLLING_FRICTION = 0.004

#: The benchmark camera: fixed, in front of the table looking back at the robot from 45 degrees
#: of elevation (like robosuite's ``agentview``, which the paper's ``agentview_shift_2``
#: shifts), far away with a narrow field of view so that objects look about the same size
#: everywhere on the table. The closest such camera that keeps the four table corners, the
#: tops of objects anywhere in the placement and target regions and the arm's forearm and hand
#: in the 64x64 image. Against the first, nearly overhead view (84 degrees) it doubles the
#: objects' share of the pixel cost between the initial frame and the goal image (6.8% -> 13.5%)
#: and shows the pushed object in 80% of the goal images instead of 34% (from above the hand
#: hid it): ``benchmarks/studies/tabletop_view_study.py``, docs/findings/environments.md.
CAMERA_NAME = "vp2_tabletop"
CAMERA_POS = (2.696, 0.0, 3.741)
CAMERA_LOOKAT = (-0.245, 0.0, 0.8)
CAMERA_FOVY = 10.0

# robosuite's episode length (``horizon``): none in effect, the benchmark counts its own steps.
_NO_TIME_LIMIT = 10**9
# MuJoCo's default geom colour: with a material assigned, the renderer uses the material's.
_DEFAULT_RGBA = (0.5, 0.5, 0.5, 1.0)
# robosuite puts collision geoms in group 0 and IK-target markers in group 2, both of which
# MuJoCo's default visual options draw; the world moves them to a group nobody draws.
_HIDDEN_GEOM_GROUP = 5
# robosuite's base model sizes the constraint solver for 5,000 contacts and 5,000 constraint
# rows (``<size nconmax="5000" njmax="5000"/>``), which makes every ``MjData`` reserve a
# 1.26 GB arena; this world uses 19 contacts and 69 rows at most (a 0.08 MB arena). The
# reservation is virtual, but a process holding a few environments then has one merged
# anonymous mapping larger than the machine's RAM, and Linux refuses to fork it (ENOMEM).
# 16 MB is 200 times what a trajectory uses; the dynamics do not depend on it. ``None`` keeps
# robosuite's sizes (benchmarks/checks/env_memory.py compares the two).
ARENA_SIZE: str | None = "16M"


def _look_at_quat(pos: tuple[float, ...], target: tuple[float, ...]) -> np.ndarray:
    """Quaternion (w, x, y, z) of a MuJoCo camera at ``pos`` looking at ``target``, z up."""
    back = np.asarray(pos, np.float64) - np.asarray(target, np.float64)
    back /= norm(back)  # a MuJoCo camera looks along its -z axis
    right = np.cross(np.array([0.0, 0.0, 1.0]), back)
    right /= norm(right)
    up = np.cross(back, right)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, np.stack([right, up, back], axis=1).reshape(-1))
    return quat


def osc_position_controller_config() -> dict:
    """robosuite's Panda composite controller with the arm on the stock ``OSC_POSITION`` part.

    Δxyz of up to 5 cm per control step (robosuite's default ``output_max``), orientation held,
    plus robosuite's default ``GRIP`` gripper controller: a 4-D action in ``[-1, 1]``.
    """
    config = load_composite_controller_config(robot="Panda")
    parts_dir = pathlib.Path(robosuite.__file__).parent / "controllers/config/default/parts"
    with open(parts_dir / "osc_position.json") as f:
        position = json.load(f)
    position["output_max"] = [OSC_OUTPUT_MAX] * 3
    position["output_min"] = [-OSC_OUTPUT_MAX] * 3
    position["gripper"] = {"type": "GRIP"}
    config["body_parts"]["right"] = position
    return config


class TabletopWorld(ManipulationEnv):
    """A robosuite environment: Panda arm, table, four objects with switchable textures.

    The object textures are materials of the model (one per entry of :data:`TEXTURE_NAMES`),
    so re-texturing an object is a change of its visual geom's ``geom_matid``, never a model
    rebuild. Initial states are set by the caller (:class:`vp2.envs.tabletop.TabletopEnv`);
    robosuite's own ``reset`` only runs once, at construction.

    Args:
        camera_obs_size: if given, robosuite renders the benchmark camera at this size as its
            camera observation on every step (the speed baseline of the benchmark); ``None``
            (default) creates no renderer at all.
    """

    def __init__(self, camera_obs_size: int | None = None):
        use_camera = camera_obs_size is not None
        super().__init__(
            robots="Panda",
            controller_configs=osc_position_controller_config(),
            initialization_noise=None,  # the benchmark draws its own arm noise
            use_camera_obs=use_camera,
            has_renderer=False,
            has_offscreen_renderer=use_camera,
            camera_names=CAMERA_NAME,
            camera_heights=camera_obs_size or 64,
            camera_widths=camera_obs_size or 64,
            control_freq=CONTROL_FREQ,
            lite_physics=True,
            horizon=_NO_TIME_LIMIT,
            ignore_done=True,
            hard_reset=False,
            seed=0,  # robosuite draws nothing that matters, but never from an unseeded generator
        )

    # ---- robosuite hooks ----------------------------------------------------------------
    def _load_model(self) -> None:
        super()._load_model()
        robot_model = self.robots[0].robot_model
        robot_model.set_base_xpos(list(ROBOT_BASE_POS))

        arena = TableArena(
            table_full_size=TABLE_FULL_SIZE,
            table_friction=TABLE_FRICTION,
            table_offset=(TABLE_CENTER_X, 0.0, TABLE_TOP_Z),
        )
        arena.set_origin([0, 0, 0])
        arena.set_camera(
            CAMERA_NAME,
            pos=list(CAMERA_POS),
            quat=list(_look_at_quat(CAMERA_POS, CAMERA_LOOKAT)),
            camera_attribs={"fovy": str(CAMERA_FOVY)},
        )
        # One cube-mapped texture + material per texture name, shared by all four objects.
        for name in TEXTURE_NAMES:
            tex_file = xml_path_completion(TEXTURES[name])
            arena.asset.append(
                _element("texture", name=f"vp2_tex_{name}", type="cube", file=tex_file)
            )
            arena.asset.append(
                _element(
                    "material",
                    name=f"vp2_mat_{name}",
                    texture=f"vp2_tex_{name}",
                    texrepeat="1 1",
                    specular="0.4",
                    shininess="0.1",
                )
            )

        sphere_friction = [OBJECT_FRICTION[0], OBJECT_FRICTION[1], SPHERE_ROLLING_FRICTION]
        self.objects = [
            object_class(
                name,
                size=list(OBJECT_SIZES[name]),
                rgba=list(_DEFAULT_RGBA),
                friction=sphere_friction if name == "sphere" else OBJECT_FRICTION,
            )
            for name, object_class in _OBJECT_CLASSES.items()
        ]
        # MuJoCo's default 3-D contacts have no rolling resistance, so a pushed ball would roll
        # on at constant speed (off the table). 6-D contacts on the sphere give it rolling and
        # torsional friction, like a rubber ball on a cloth-covered table.
        for geom in self.objects[3].get_obj().iter("geom"):
            if geom.get("group") == "0":
                geom.set("condim", "6")
        self.model = ManipulationTask(
            mujoco_arena=arena,
            mujoco_robots=[robot.robot_model for robot in self.robots],
            mujoco_objects=self.objects,
        )

    def _setup_references(self) -> None:
        super()._setup_references()
        model = self.sim.model._model
        self.object_qpos_adr = np.array(
            [model.jnt_qposadr[model.joint(obj.joints[0]).id] for obj in self.objects]
        )
        self.object_visual_geoms = np.array(
            [model.geom(obj.visual_geoms[0]).id for obj in self.objects]
        )
        self.texture_material_ids = np.array(
            [model.material(f"vp2_mat_{name}").id for name in TEXTURE_NAMES]
        )
        groups = model.geom_group
        groups[(groups == 0) | (groups == 2)] = _HIDDEN_GEOM_GROUP
        # robosuite's sites are debugging markers (grip point, axis lines): never drawn here.
        model.site_group[:] = _HIDDEN_GEOM_GROUP
        # A matte scene: the floor's 1% reflectance (robosuite's) is visible from the oblique
        # camera and would cost a second scene pass per frame for a faint mirror image.
        model.mat_reflectance[:] = 0.0

    def edit_model_xml(self, xml_str: str) -> str:
        # robosuite's last XML processor before compiling: remember the exact MJCF that the
        # physics model is compiled from, so that a render model can be built from it.
        xml = super().edit_model_xml(xml_str)
        if ARENA_SIZE is not None:
            xml = _set_arena_size(xml, ARENA_SIZE)
        self.compiled_xml = xml
        return xml

    def render_model(self, mesh_reduction: float) -> mujoco.MjModel:
        """A render-only model of this world: the MJCF the physics model was compiled from,
        its large visual-only meshes (the Panda's and its pedestal's) decimated by
        ``mesh_reduction`` (:func:`vp2.envs.meshes.simplified_render_model`).

        Built once per process and XML (about a second; the decimated meshes are cached on
        disk); the caller gets a copy. The visual changes this world makes to its compiled
        model (hidden geom groups, sites, reflectance, textures) are applied by
        :class:`vp2.envs.rendering.Renderer`, which copies them from the physics model.
        """
        import copy
        import hashlib

        from vp2.envs.meshes import simplified_render_model

        key = (hashlib.sha256(self.compiled_xml.encode()).hexdigest(), float(mesh_reduction))
        model = _RENDER_MODELS.get(key)
        if model is None:
            model = simplified_render_model(
                mujoco.MjSpec.from_string(self.compiled_xml),
                target_reduction=mesh_reduction,
                body_prefixes=RENDER_MESH_BODIES,
            )
            _RENDER_MODELS[key] = model
        return copy.copy(model)

    def reward(self, action: np.ndarray | None = None) -> float:
        """Unused by the benchmark (success is judged against a goal state)."""
        return 0.0

    def _check_success(self) -> bool:
        return False

    # ---- used by the benchmark env ---------------------------------------------------------
    def set_textures(self, texture_ids: np.ndarray) -> None:
        """Gives object ``k`` the material of ``TEXTURE_NAMES[texture_ids[k]]``."""
        model = self.sim.model._model
        model.geom_matid[self.object_visual_geoms] = self.texture_material_ids[texture_ids]
        model.geom_rgba[self.object_visual_geoms] = _DEFAULT_RGBA


#: The bodies whose visual-only meshes the render model simplifies: robosuite's Panda (arm,
#: gripper) and its mount.
RENDER_MESH_BODIES = ("robot0_", "gripper0_", "fixed_mount0_")
_RENDER_MODELS: dict[tuple[str, float], mujoco.MjModel] = {}


def _set_arena_size(xml: str, memory: str) -> str:
    """``xml`` with its ``<size>`` element's solver limits replaced by an arena of ``memory``."""
    root = ET.fromstring(xml)
    for size in root.iter("size"):
        for attribute in ("nconmax", "njmax", "memory"):
            size.attrib.pop(attribute, None)
    size = root.find("size")
    if size is None:
        size = ET.SubElement(root, "size")
    size.set("memory", memory)
    return ET.tostring(root, encoding="unicode")


def _element(tag: str, **attrib: str) -> ET.Element:
    return ET.Element(tag, attrib=attrib)
