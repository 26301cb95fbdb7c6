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

from vp2.envs.tabletop_scene import (  # noqa: E402
    SceneArena,
    SceneController,
    TabletopScene,
    resolve_scene,
)

# robosuite logs an INFO line (the controller config path) on every construction.
logging.getLogger("robosuite_logs").setLevel(logging.WARNING)

#: robosuite's class of each scene object shape (:attr:`vp2.envs.tabletop_scene.SceneObject.shape`).
_OBJECT_CLASSES = {"box": BoxObject, "cylinder": CylinderObject, "ball": BallObject}

# robosuite's episode length (``horizon``): none in effect, the benchmark counts its own steps.
_NO_TIME_LIMIT = 10**9
# robosuite puts collision geoms in group 0 and IK-target markers in group 2, both of which
# MuJoCo's default visual options draw; the world moves them to a group nobody draws.
_HIDDEN_GEOM_GROUP = 5


def osc_position_controller_config(controller: SceneController) -> dict:
    """robosuite's Panda composite controller with the arm on the stock ``OSC_POSITION`` part.

    Δxyz of up to ``controller.output_max`` per control step, with the scene's gains and input
    range, plus robosuite's default ``GRIP`` gripper controller: a 4-D action in ``[-1, 1]``.
    The orientation goal is set by :class:`TabletopWorld` (``controller.hand_orientation``).
    """
    config = load_composite_controller_config(robot="Panda")
    parts_dir = pathlib.Path(robosuite.__file__).parent / "controllers/config/default/parts"
    with open(parts_dir / "osc_position.json") as f:
        position = json.load(f)
    position["output_max"] = [controller.output_max] * 3
    position["output_min"] = [-controller.output_max] * 3
    position["input_max"] = controller.input_max
    position["input_min"] = -controller.input_max
    position["kp"] = controller.kp
    position["damping_ratio"] = controller.damping_ratio
    position["gripper"] = {"type": "GRIP"}
    config["body_parts"]["right"] = position
    return config


class TabletopWorld(ManipulationEnv):
    """A robosuite environment: Panda arm, table, four objects with switchable textures.

    Everything in it is built from a :class:`~vp2.envs.tabletop_scene.TabletopScene`. The object
    textures are materials of the model (one per name of the scene's ``textures``), so
    re-texturing an object is a change of its visual geom's ``geom_matid``, never a model
    rebuild. robosuite's ``OSC_POSITION`` holds the hand at the scene's
    ``controller.hand_orientation`` (robosuite 1.3's behaviour; 1.5.2 would hold the current
    orientation), so ``world.step`` is the original's controller. Initial states are set by the caller (:class:`vp2.envs.tabletop.TabletopEnv`);
    robosuite's own ``reset`` only runs once, at construction.

    Args:
        scene: the scene (default :data:`~vp2.envs.tabletop_scene.DEFAULT_SCENE`).
        camera_obs_size: if given, robosuite renders the benchmark camera at this size as its
            camera observation on every step (the speed baseline of the benchmark); ``None``
            (default) creates no renderer at all.
    """

    def __init__(self, scene: TabletopScene | None = None, camera_obs_size: int | None = None):
        self.scene = resolve_scene(scene)
        use_camera = camera_obs_size is not None
        super().__init__(
            robots="Panda",
            controller_configs=osc_position_controller_config(self.scene.controller),
            initialization_noise=None,  # the benchmark draws its own arm noise
            use_camera_obs=use_camera,
            has_renderer=False,
            has_offscreen_renderer=use_camera,
            camera_names=self.scene.camera.name,
            camera_heights=camera_obs_size or 64,
            camera_widths=camera_obs_size or 64,
            control_freq=self.scene.controller.control_freq,
            lite_physics=True,
            horizon=_NO_TIME_LIMIT,
            ignore_done=True,
            hard_reset=False,
            seed=0,  # robosuite draws nothing that matters, but never from an unseeded generator
        )

    # ---- robosuite hooks ----------------------------------------------------------------
    def _load_model(self) -> None:
        super()._load_model()
        scene = self.scene
        robot_model = self.robots[0].robot_model
        robot_model.set_base_xpos(list(scene.robot.base_pos))

        table = scene.table
        arena = TableArena(
            table_full_size=table.full_size,
            table_friction=table.friction,
            table_offset=(table.center_x, 0.0, table.top_z),
        )
        arena.set_origin([0, 0, 0])
        _dress_arena(arena, scene.arena)
        camera = scene.camera
        arena.set_camera(
            camera.name,
            pos=list(camera.pos),
            quat=list(camera.quat),
            camera_attribs={"fovy": str(camera.fovy)},
        )
        # One cube-mapped texture + material per texture name, shared by all four objects.
        textures = scene.textures
        for name in textures.names:
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
                    specular=str(textures.specular),
                    shininess=str(textures.shininess),
                )
            )

        self.objects = [
            _OBJECT_CLASSES[obj.shape](
                obj.name,
                size=list(obj.size),
                rgba=list(obj.rgba),
                density=obj.density,
                friction=list(obj.friction),
            )
            for obj in scene.objects
        ]
        for obj, model in zip(scene.objects, self.objects, strict=True):
            for geom in model.get_obj().iter("geom"):
                if geom.get("group") == "0":  # the collision geoms
                    geom.set("priority", str(obj.priority))
                    if obj.condim is not None:
                        geom.set("condim", str(obj.condim))
        self.model = ManipulationTask(
            mujoco_arena=arena,
            mujoco_robots=[robot.robot_model for robot in self.robots],
            mujoco_objects=self.objects,
        )

    def _reset_internal(self) -> None:
        super()._reset_internal()
        # robosuite 1.3's OSC_POSITION: the orientation goal is the scene's fixed world
        # orientation at every control step (in the controller's base frame).
        osc = self.robots[0].composite_controller.part_controllers["right"]
        hand = np.array(self.scene.controller.hand_orientation, np.float64)

        def fixed_goal_ori(delta: np.ndarray, goal_update_mode: str | None = None) -> np.ndarray:
            return np.dot(np.asarray(osc.origin_ori).T, hand)

        osc.compute_goal_ori = fixed_goal_ori

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
            [model.material(f"vp2_mat_{name}").id for name in self.scene.textures.names]
        )
        groups = model.geom_group
        groups[(groups == 0) | (groups == 2)] = _HIDDEN_GEOM_GROUP
        # robosuite's sites are debugging markers (grip point, axis lines): never drawn here.
        model.site_group[:] = _HIDDEN_GEOM_GROUP
        # A matte scene: a reflective material (robosuite's floor has 1%, its table legs 80%)
        # costs a second scene pass per frame for a faint mirror image.
        model.mat_reflectance[:] = 0.0

    def edit_model_xml(self, xml_str: str) -> str:
        # robosuite's last XML processor before compiling: remember the exact MJCF that the
        # physics model is compiled from, so that a render model can be built from it.
        xml = super().edit_model_xml(xml_str)
        if self.scene.solver_arena is not None:
            xml = _set_arena_size(xml, self.scene.solver_arena)
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
        """Gives object ``k`` the material of the scene's ``textures.names[texture_ids[k]]``."""
        model = self.sim.model._model
        model.geom_matid[self.object_visual_geoms] = self.texture_material_ids[texture_ids]
        model.geom_rgba[self.object_visual_geoms] = [obj.rgba for obj in self.scene.objects]


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


def _dress_arena(arena: TableArena, look: SceneArena) -> None:
    """Gives robosuite's table arena the scene's floor and wall textures and lights (in place)."""
    files = {"texplane": look.floor_texture, "tex-light-gray-plaster": look.wall_texture}
    for texture in arena.asset.iter("texture"):
        name = texture.get("name")
        if name in files:
            texture.set("file", xml_path_completion(TEXTURES[files[name]]))
    for light in list(arena.worldbody.iter("light")):
        arena.worldbody.remove(light)
    grey = f"{look.light_diffuse} " * 3
    specular = f"{look.light_specular} " * 3
    for pos, direction in look.lights:
        arena.worldbody.append(
            _element(
                "light",
                pos=" ".join(str(v) for v in pos),
                dir=" ".join(str(v) for v in direction),
                diffuse=grey.strip(),
                specular=specular.strip(),
                directional="false",
                castshadow="false",
            )
        )


def _element(tag: str, **attrib: str) -> ET.Element:
    return ET.Element(tag, attrib=attrib)
