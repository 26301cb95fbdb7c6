"""The robosuite side of the tabletop environment: the MJCF world and a lean control step.

Two pieces live here so that :mod:`vp2.envs.tabletop` only deals with the benchmark contract:

* :class:`TabletopWorld`, a robosuite ``ManipulationEnv`` with a Panda arm (operational-space
  *position* controller + gripper), a table, four objects, 13 object materials and the
  benchmark camera. It is an ordinary robosuite environment: ``TabletopWorld(...).step(a)`` is
  robosuite's own step, which the benchmark uses as the reference for the dynamics (and, with
  ``camera_obs_size``, as the speed baseline).
* :class:`LeanStepper`, which advances a :class:`TabletopWorld` by one control step with
  exactly the arithmetic of robosuite's ``env.step`` -- the controllers' own ``set_goal`` for the
  new action, then per physics step the same NumPy/numba operations in the same order for the
  torques and the same ``mj_step1``/``mj_step2`` split -- but without robosuite's per-substep
  bookkeeping (observables, action-dimension properties, proprioception buffers, repeated
  Jacobian queries by name). The result is bit-identical to robosuite's step;
  ``tests/envs/test_tabletop.py`` checks it.
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


class _DropMinkWarning(logging.Filter):
    """Drops robosuite's import-time "Could not load the mink-based whole-body IK" warning.

    robosuite 1.5.2 logs it on every import when the optional ``mink`` package (only needed for
    its GR1 whole-body IK, which vp2 does not use) is missing. robosuite sets its logger's level
    while importing, so a level set beforehand would not stick; this filter drops that one
    message and nothing else, and is removed once robosuite is imported.
    """

    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith("Could not load the mink-based whole-body IK")


_robosuite_logger = logging.getLogger("robosuite_logs")
_mink_filter = _DropMinkWarning()
_robosuite_logger.addFilter(_mink_filter)
try:
    import robosuite  # noqa: E402
finally:
    _robosuite_logger.removeFilter(_mink_filter)
from robosuite.controllers import load_composite_controller_config  # noqa: E402
from robosuite.environments.manipulation.manipulation_env import ManipulationEnv  # noqa: E402
from robosuite.models.arenas import TableArena  # noqa: E402
from robosuite.models.objects import BallObject, BoxObject, CylinderObject  # noqa: E402
from robosuite.models.tasks import ManipulationTask  # noqa: E402
from robosuite.utils.control_utils import (  # noqa: E402
    nullspace_torques,
    opspace_matrices,
    orientation_error,
)
from robosuite.utils.mjcf_utils import TEXTURES, xml_path_completion  # noqa: E402

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
#: hid it): ``benchmarks/tabletop_view_study.py``, docs/benchmark.md.
CAMERA_NAME = "vp2_tabletop"
CAMERA_POS = (2.696, 0.0, 3.741)
CAMERA_LOOKAT = (-0.245, 0.0, 0.8)
CAMERA_FOVY = 10.0

# MuJoCo's default geom colour: with a material assigned, the renderer uses the material's.
_DEFAULT_RGBA = (0.5, 0.5, 0.5, 1.0)
# robosuite puts collision geoms in group 0 and IK-target markers in group 2, both of which
# MuJoCo's default visual options draw; the world moves them to a group nobody draws.
_HIDDEN_GEOM_GROUP = 5


def _look_at_quat(pos: tuple[float, ...], target: tuple[float, ...]) -> np.ndarray:
    """Quaternion (w, x, y, z) of a MuJoCo camera at ``pos`` looking at ``target``, z up."""
    back = np.asarray(pos, np.float64) - np.asarray(target, np.float64)
    back /= np.linalg.norm(back)  # a MuJoCo camera looks along its -z axis
    right = np.cross(np.array([0.0, 0.0, 1.0]), back)
    right /= np.linalg.norm(right)
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
            horizon=10**9,
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

        self.objects = [
            BoxObject(
                "large_cube",
                size=list(OBJECT_SIZES["large_cube"]),
                rgba=list(_DEFAULT_RGBA),
                friction=OBJECT_FRICTION,
            ),
            BoxObject(
                "small_cube",
                size=list(OBJECT_SIZES["small_cube"]),
                rgba=list(_DEFAULT_RGBA),
                friction=OBJECT_FRICTION,
            ),
            CylinderObject(
                "cylinder",
                size=list(OBJECT_SIZES["cylinder"]),
                rgba=list(_DEFAULT_RGBA),
                friction=OBJECT_FRICTION,
            ),
            BallObject(
                "sphere",
                size=list(OBJECT_SIZES["sphere"]),
                rgba=list(_DEFAULT_RGBA),
                friction=[OBJECT_FRICTION[0], OBJECT_FRICTION[1], SPHERE_ROLLING_FRICTION],
            ),
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


def _element(tag: str, **attrib: str) -> ET.Element:
    return ET.Element(tag, attrib=attrib)


class LeanStepper:
    """One control step of a :class:`TabletopWorld`, bit-identical to robosuite's ``env.step``.

    robosuite's step spends most of its time outside the physics: per physics step (25 per
    control step) it re-queries Jacobians by site name four times, recomputes action limits,
    updates every observable, and pushes proprioception buffers. This class keeps only what
    changes the simulation: at the first physics step the controllers' own ``set_goal`` (so the
    goal arithmetic is robosuite's code), then at every physics step the operational-space
    torques computed with the same operations, in the same order, on arrays of the same
    layout as ``OperationalSpaceController.run_controller`` (the numba kernels are robosuite's
    own), and the same gripper command.

    State that robosuite keeps between control steps and that changes what a step does:
    the gripper's accumulated command (``PandaGripper.current_action``) and the nullspace target
    of the OSC (``initial_joint``, the arm configuration at reset). :meth:`controller_state` /
    :meth:`set_controller_state` save and restore both; the OSC goal itself is recomputed from
    the simulator state at every control step (robosuite's "achieved" goal-update mode).
    """

    #: Length of :meth:`controller_state`: gripper command (2) + OSC nullspace target (7).
    CONTROLLER_STATE_SIZE = 9

    def __init__(self, world: TabletopWorld):
        self.world = world
        robot = world.robots[0]
        self.composite = robot.composite_controller
        self.osc = self.composite.part_controllers["right"]
        self.grip = self.composite.part_controllers["right_gripper"]
        self.gripper_model = robot.gripper["right"]
        self.model = world.sim.model._model
        self.data = world.sim.data._data
        self.n_substeps = int(round(world.control_timestep / world.model_timestep))

        osc = self.osc
        if osc.interpolator_pos is not None or osc.use_ori or osc.impedance_mode != "fixed":
            raise RuntimeError(
                "LeanStepper mirrors OSC_POSITION with fixed impedance, no interpolator"
            )
        self._ref_site = self.model.site(osc.ref_name).id
        self._center_site = self.model.site(f"{osc.naming_prefix}{osc.part_name}_center").id
        self._qvel_index = np.asarray(osc.qvel_index, dtype=np.intp)
        self._qpos_index = np.asarray(osc.qpos_index, dtype=np.intp)
        self._arm_actuators = np.array(robot._ref_actuators_indexes_dict["right"])
        self._grip_actuators = np.array(robot._ref_actuators_indexes_dict["right_gripper"])
        ctrlrange = self.model.actuator_ctrlrange
        self._arm_low = ctrlrange[self._arm_actuators, 0]
        self._arm_high = ctrlrange[self._arm_actuators, 1]
        self._grip_low = ctrlrange[self._grip_actuators, 0]
        self._grip_high = ctrlrange[self._grip_actuators, 1]
        # SimpleGripController.run_controller's affine map from [-1, 1] to the actuator range.
        grip_range = np.stack([self.grip.actuator_min, self.grip.actuator_max], axis=-1)
        self._grip_bias = 0.5 * (grip_range[:, 1] + grip_range[:, 0])
        self._grip_weight = 0.5 * (grip_range[:, 1] - grip_range[:, 0])
        nv = self.model.nv
        self._jacp = np.zeros((3, nv))
        self._jacr = np.zeros((3, nv))
        self._full_mass = np.zeros((nv, nv))
        self._kp_pos = np.array(osc.kp[0:3])
        self._kp_ori = np.array(osc.kp[3:6])
        self._kd_pos = osc.kd[0:3]
        self._kd_ori = osc.kd[3:6]

    # ---- controller state --------------------------------------------------------------------
    def controller_state(self) -> np.ndarray:
        """The controller state that survives between control steps, shape ``(9,)``."""
        grip = np.broadcast_to(np.asarray(self.gripper_model.current_action, np.float64), (2,))
        return np.concatenate([grip, np.asarray(self.osc.initial_joint, np.float64)])

    def set_controller_state(self, state: np.ndarray) -> None:
        """Restores :meth:`controller_state`; the simulator state must already be set."""
        state = np.asarray(state, np.float64)
        self.gripper_model.current_action = state[0:2].copy()
        self.osc.initial_joint = state[2:9].copy()
        self.grip.goal_qvel = None
        # The next set_goal must read the restored simulator state, not a cached one.
        self.osc.new_update = True
        self.grip.new_update = True

    def reset_controllers(self, initial_joint: np.ndarray) -> None:
        """Controller state of a fresh episode: open gripper command, nullspace target ``q0``."""
        self.set_controller_state(np.concatenate([np.zeros(2), np.asarray(initial_joint)]))
        self.composite.update_state()
        self.osc.update(force=True)
        self.osc.reset_goal()

    # ---- stepping ---------------------------------------------------------------------------
    def step(self, action: np.ndarray) -> None:
        """Advances one control step (``n_substeps`` physics steps) with a 4-D action."""
        m, d = self.model, self.data
        mujoco.mj_step1(m, d)
        # robosuite's own goal arithmetic, once per control step, on fresh simulator data.
        self.osc.new_update = True
        self.grip.new_update = True
        self.composite.update_state()
        self.composite.set_goal(action)
        goal_pos, goal_ori = self.osc.goal_pos, self.osc.goal_ori
        grip_ctrl = np.clip(
            self._grip_bias + self._grip_weight * np.array(self.grip.goal_qvel),
            self._grip_low,
            self._grip_high,
        )
        for i in range(self.n_substeps):
            if i:
                mujoco.mj_step1(m, d)
            torques = self._osc_torques(goal_pos, goal_ori)
            d.ctrl[self._arm_actuators] = np.minimum(
                np.maximum(torques, self._arm_low), self._arm_high
            )
            d.ctrl[self._grip_actuators] = grip_ctrl
            mujoco.mj_step2(m, d)
        # Leave the controllers as robosuite's run_controller would: the next read is fresh.
        self.osc.new_update = True
        self.grip.new_update = True

    def _osc_torques(self, goal_pos: np.ndarray, goal_ori: np.ndarray) -> np.ndarray:
        """``OperationalSpaceController.run_controller`` (+ ``update``), operation for operation.

        Element-wise arithmetic may read MuJoCo's arrays in place; everything that goes into a
        matrix product (BLAS) or one of robosuite's numba kernels is a fresh C-ordered copy, as
        in robosuite, because those may round differently for other layouts.
        """
        m, d = self.model, self.data
        qvel = d.qvel
        qvel_index = self._qvel_index
        jacp, jacr = self._jacp, self._jacr

        # CompositeController.update_state -> origin of the base frame.
        origin_pos = d.site_xpos[self._center_site]
        origin_ori = np.array(d.site_xmat[self._center_site].reshape([3, 3]))
        mujoco.mj_jacSite(m, d, jacp, jacr, self._center_site)
        base_pos_vel = np.dot(jacp, qvel)
        base_ori_vel = np.dot(jacr, qvel)

        # Controller.update: end-effector site pose, velocity, Jacobians, arm mass matrix.
        ref_pos = d.site_xpos[self._ref_site]
        ref_ori_mat = np.array(d.site_xmat[self._ref_site].reshape([3, 3]))
        mujoco.mj_jacSite(m, d, jacp, jacr, self._ref_site)
        ref_pos_vel = np.dot(jacp, qvel)
        ref_ori_vel = np.dot(jacr, qvel)
        # robosuite copies the Jacobians into preallocated C-ordered arrays; numba compiles
        # (and rounds) differently for other layouts, so the layout must match, not just values.
        j_pos = np.ascontiguousarray(jacp[:, qvel_index])
        j_ori = np.ascontiguousarray(jacr[:, qvel_index])
        j_full = np.concatenate([j_pos, j_ori])
        joint_pos = d.qpos[self._qpos_index]
        joint_vel = qvel[qvel_index]
        mujoco.mj_fullM(m, self._full_mass, d.qM)
        mass_matrix = self._full_mass[qvel_index, :][:, qvel_index]

        # OperationalSpaceController.run_controller ("base" input frame, no interpolator).
        desired_world_pos = origin_pos + np.dot(origin_ori, goal_pos)
        desired_world_ori = np.dot(origin_ori, goal_ori)
        ori_error = orientation_error(desired_world_ori, ref_ori_mat)
        desired_force = (desired_world_pos - ref_pos) * self._kp_pos + (
            -(ref_pos_vel - base_pos_vel)
        ) * self._kd_pos
        desired_torque = ori_error * self._kp_ori + (-(ref_ori_vel - base_ori_vel)) * self._kd_ori
        _, lambda_pos, lambda_ori, nullspace_matrix = opspace_matrices(
            mass_matrix, j_full, j_pos, j_ori
        )
        decoupled_wrench = np.concatenate(
            [np.dot(lambda_pos, desired_force), np.dot(lambda_ori, desired_torque)]
        )
        torques = np.dot(j_full.T, decoupled_wrench) + d.qfrc_bias[qvel_index]
        torques += nullspace_torques(
            mass_matrix, nullspace_matrix, self.osc.initial_joint, joint_pos, joint_vel
        )
        return torques
