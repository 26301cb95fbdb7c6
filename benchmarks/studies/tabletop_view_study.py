"""Candidate tabletop camera views / object scales vs. the share of the pixel cost due to objects.

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.studies.tabletop_view_study \\
        --instances 3 --sheet /tmp/s3/tabletop_views.png --json /tmp/s3/tabletop_views.json

Analysis only: the package is not changed. Each candidate is applied to the *built* MuJoCo
model at run time -- the benchmark camera's ``cam_pos`` / ``cam_quat`` / ``cam_fovy`` and, for
scaled objects, the size (and bounding radius) of the objects' visual geoms, with the objects
lifted so that they rest on the table -- and the renderer is re-created for it (the renderer
keeps its own copy of the model). Physics is never stepped with the modified model: a scaled
object is only a pixel-analysis proxy (the fingers in a goal state touch the 5 cm object).

Per candidate, over the first ``--instances`` shipped suite instances of each tabletop task:

* the object share of the pixel SSE, computed as ``benchmarks/studies/tabletop_cost_share.py`` does:
  object term = SSE(goal state with the objects put back at their start positions, goal
  image), arm term = SSE(initial state with the objects moved to their goal positions, goal
  image), share = object / (object + arm). The goal image is re-rendered from the goal state
  with the candidate's camera/objects (for the current view it equals the shipped one);
* the objects' visible size at 64x64 (square root of the visible pixel count in a segmentation
  render of the initial states; median per object) and the geometric width of 5 cm at the
  centre of ``SCENE.placement.region``;
* whether the whole table top, every object's start and goal footprint (its bounding box, at
  the candidate's scale) and the arm's wrist/hand/fingers (and the forearm) in the initial and
  goal states project inside the 64x64 image (smallest margin in pixels; negative = cut off),
  and how many object pairs would overlap at that scale;
* the fidelity of ``SCENE.render`` with that camera: mean absolute error (/255) of the initial
  frames against ``SCENE.render.full_quality()`` (SPEC §1.3 budget: 8/255), also with the
  floor's (and every other material's) reflectance set to 0;
* the render time of one 64x64 frame through ``TabletopEnv.render`` (median over
  ``--timing-frames`` frames, candidates interleaved frame by frame so that the machine's load
  affects all alike).

"Fitted" candidates choose the look-at point and the distance for a given elevation (camera in
front of the table, looking back at the robot, as the current one) and field of view: the
closest camera that keeps the table top corners, the tops of objects anywhere in the target
and placement regions, and the forearm/wrist/hand of the initial states 1 px inside the image.
"""

from __future__ import annotations

import dataclasses
import json
import os
import statistics
import time

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402
from PIL import Image  # noqa: E402

from benchmarks import common  # noqa: E402
from vp2.data.suite import TaskSuite  # noqa: E402
from vp2.envs import ENV_TASKS  # noqa: E402
from vp2.envs._tabletop_world import _look_at_quat  # noqa: E402
from vp2.envs.rendering import Renderer, contact_sheet, mean_abs_error  # noqa: E402
from vp2.envs.tabletop import DEFAULT_SCENE, OBJECT_NAMES, TabletopEnv  # noqa: E402

SIZE = 64
#: The scene the candidates are compared against (they are applied to its built model).
SCENE = DEFAULT_SCENE
#: Arm bodies whose origins must stay in view: the wrist, hand and finger bodies (required) and
#: the forearm (link5/6 origin, at the elbow end of the forearm; reported separately).
HAND_BODIES = ("robot0_link7", "robot0_right_hand", "gripper0_right_leftfinger",
               "gripper0_right_rightfinger")
FOREARM_BODIES = ("robot0_link5",)


@dataclasses.dataclass(frozen=True)
class Candidate:
    name: str
    pos: tuple[float, float, float]
    lookat: tuple[float, float, float]
    fovy: float
    scale: float = 1.0
    note: str = ""

    @property
    def elevation(self) -> float:
        v = np.subtract(self.pos, self.lookat)
        return float(np.degrees(np.arctan2(v[2], np.hypot(v[0], v[1]))))

    @property
    def distance(self) -> float:
        return float(np.linalg.norm(np.subtract(self.pos, self.lookat)))


# ---- geometry ------------------------------------------------------------------------------
def _cam_frame(pos, lookat) -> tuple[np.ndarray, np.ndarray]:
    quat = _look_at_quat(tuple(pos), tuple(lookat))
    mat = np.zeros(9)
    mujoco.mju_quat2Mat(mat, quat)
    return np.asarray(pos, np.float64), mat.reshape(3, 3)


def project(points: np.ndarray, pos, lookat, fovy: float, size: int = SIZE) -> np.ndarray:
    """World points ``(..., 3)`` -> pixel coordinates ``(..., 2)`` (u right, v down); NaN behind."""
    p, rot = _cam_frame(pos, lookat)
    c = (np.asarray(points, np.float64) - p) @ rot  # camera frame: x right, y up, looks along -z
    depth = -c[..., 2]
    f = size / 2 / np.tan(np.radians(fovy) / 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = np.stack([size / 2 + f * c[..., 0] / depth, size / 2 - f * c[..., 1] / depth], -1)
    uv[depth <= 0] = np.nan
    return uv


def margin_px(uv: np.ndarray, size: int = SIZE) -> float:
    """Smallest distance of the projected points to the image border (negative: outside)."""
    uv = uv.reshape(-1, 2)
    if np.isnan(uv).any():
        return -np.inf
    return float(np.min(np.concatenate([uv, size - uv], axis=1)))


def table_corners(env: TabletopEnv) -> np.ndarray:
    (x0, x1), (y0, y1) = env.table_bounds
    return np.array([[x, y, SCENE.table.top_z] for x in (x0, x1) for y in (y0, y1)])


def object_boxes(xy: np.ndarray, scale: float) -> np.ndarray:
    """Bounding-box corners ``(4, 8, 3)`` of the four objects with centres ``xy`` ``(4, 2)``."""
    out = []
    for k, name in enumerate(OBJECT_NAMES):
        r, h = SCENE.footprints[name] * scale, 2 * SCENE.rest_heights[name] * scale
        out.append([[xy[k, 0] + sx * r, xy[k, 1] + sy * r, SCENE.table.top_z + sz * h]
                    for sx in (-1, 1) for sy in (-1, 1) for sz in (0, 1)])
    return np.array(out)


def region_object_tops(scale: float) -> np.ndarray:
    """Top corners of the largest object anywhere in the target and placement regions."""
    r = max(SCENE.footprints.values()) * scale
    h = 2 * max(SCENE.rest_heights.values()) * scale
    pts = []
    for (x0, x1), (y0, y1) in (SCENE.placement.target_region, SCENE.placement.region):
        for x in (x0 - r, x1 + r):
            for y in (y0 - r, y1 + r):
                pts.append([x, y, SCENE.table.top_z + h])
    return np.array(pts)


def fit_camera(elevation: float, fovy: float, required: np.ndarray, margin: float = 1.0,
               lookat_x: np.ndarray | None = None) -> tuple[tuple, tuple]:
    """Closest camera at ``elevation`` (in front, looking towards -x) keeping ``required`` in view.

    Searches the look-at point's x on a grid (y = 0, z = table top) and, for each, the smallest
    distance (bisection) at which every required point lies ``margin`` px inside the image.
    """
    if lookat_x is None:
        lookat_x = np.arange(-0.30, 0.101, 0.005)
    e = np.radians(elevation)
    direction = np.array([np.cos(e), 0.0, np.sin(e)])
    best = None
    for lx in lookat_x:
        lookat = np.array([lx, 0.0, SCENE.table.top_z])

        def ok(dist: float, lookat: np.ndarray = lookat) -> bool:
            return margin_px(project(required, lookat + dist * direction, lookat, fovy)) >= margin

        lo, hi = 0.2, 30.0
        if not ok(hi):
            continue
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if ok(mid) else (mid, hi)
        if best is None or hi < best[0]:
            best = (hi, lookat)
    if best is None:
        raise RuntimeError(f"no camera at elevation {elevation} / fovy {fovy} fits")
    dist, lookat = best
    pos = lookat + dist * direction
    return tuple(round(float(v), 3) for v in pos), tuple(round(float(v), 3) for v in lookat)


# ---- model modification --------------------------------------------------------------------
class Applier:
    """Applies a candidate's camera and object scale to the env's model (and restores it)."""

    def __init__(self, env: TabletopEnv):
        self.env = env
        m = env._model
        self.cam = m.camera(SCENE.camera.name).id
        self.geoms = np.asarray(env._world.object_visual_geoms)
        self.orig = (m.cam_pos[self.cam].copy(), m.cam_quat[self.cam].copy(),
                     float(m.cam_fovy[self.cam]), m.geom_size[self.geoms].copy(),
                     m.geom_rbound[self.geoms].copy())

    def apply(self, c: Candidate) -> None:
        m = self.env._model
        _, _, _, size0, rb0 = self.orig
        m.cam_pos[self.cam] = c.pos
        m.cam_quat[self.cam] = _look_at_quat(c.pos, c.lookat)
        m.cam_fovy[self.cam] = c.fovy
        m.geom_size[self.geoms] = size0 * c.scale
        m.geom_rbound[self.geoms] = rb0 * c.scale

    def restore(self) -> None:
        m = self.env._model
        pos, quat, fovy, size, rb = self.orig
        m.cam_pos[self.cam], m.cam_quat[self.cam], m.cam_fovy[self.cam] = pos, quat, fovy
        m.geom_size[self.geoms], m.geom_rbound[self.geoms] = size, rb


def lifted(state: np.ndarray, positions: np.ndarray, scale: float) -> np.ndarray:
    """``state`` with the objects at ``positions``, raised so that scaled objects rest on the table."""
    pos = np.array(positions, np.float64)
    if scale != 1.0:
        pos[:, 2] += np.array([SCENE.rest_heights[n] for n in OBJECT_NAMES]) * (scale - 1.0)
    return TabletopEnv.with_object_positions(state, pos)


def _sse(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.square(a.astype(np.float64) / 255 - b.astype(np.float64) / 255).sum())


def _body_xpos(env: TabletopEnv, names: tuple[str, ...]) -> np.ndarray:
    mujoco.mj_kinematics(env._model, env._data)
    return np.array([env._data.xpos[env._model.body(n).id] for n in names])


def _visible_fractions(env: TabletopEnv, seg: mujoco.Renderer, geoms: np.ndarray,
                       counts_out: dict | None = None) -> np.ndarray:
    """Per object: visible pixels / pixels it covers when drawn alone (segmentation renders)."""
    m, geom_type = env._model, int(mujoco.mjtObj.mjOBJ_GEOM)
    seg.update_scene(env._data, camera=SCENE.camera.name)
    full = seg.render()
    opt = mujoco.MjvOption()
    opt.geomgroup[:] = 0
    opt.geomgroup[3] = 1  # draw only the object moved to group 3
    out = []
    for k, g in enumerate(geoms):
        seen = int(((full[..., 0] == g) & (full[..., 1] == geom_type)).sum())
        group = int(m.geom_group[g])
        m.geom_group[g] = 3
        seg.update_scene(env._data, camera=SCENE.camera.name, scene_option=opt)
        alone = seg.render()
        m.geom_group[g] = group
        total = int(((alone[..., 0] == g) & (alone[..., 1] == geom_type)).sum())
        out.append(seen / total if total else 0.0)
        if counts_out is not None:
            counts_out[OBJECT_NAMES[k]].append(float(np.sqrt(seen)))
    return np.array(out)


# ---- evaluation ----------------------------------------------------------------------------
def evaluate(env: TabletopEnv, applier: Applier, c: Candidate, instances: list) -> dict:
    applier.apply(c)
    renderer = Renderer(env._model, SCENE.render)
    full_quality = Renderer(env._model, SCENE.render.full_quality())
    # The same pair with every material's reflectance set to 0 (the floor's 1% is the only one
    # visible): the oblique views see the floor, whose reflection SCENE.render does not draw.
    spec_matte = Renderer(env._model, SCENE.render)
    full_matte = Renderer(env._model, SCENE.render.full_quality())
    reflectance = env._model.mat_reflectance.copy()
    env._renderer = renderer
    seg = mujoco.Renderer(env._model, SIZE, SIZE)  # reads the (modified) model when drawing
    seg.enable_segmentation_rendering()
    shares, obj_terms, arm_terms, per_task = [], [], [], {}
    visible = {n: [] for n in OBJECT_NAMES}
    margins = {"table": np.inf, "objects": np.inf, "hand": np.inf, "forearm": np.inf}
    overlaps = 0
    goal_match = []
    fractions, pushed_goal, mae, mae_matte = [], [], [], []
    sheet = None
    for inst in instances:
        start_pos = TabletopEnv.object_positions_from_state(inst.init_state)
        goal_pos = TabletopEnv.object_positions_from_state(inst.goal_state)
        init = lifted(inst.init_state, start_pos, c.scale)
        goal = lifted(inst.goal_state, goal_pos, c.scale)
        env.reset_to(goal)
        goal_img = env.render(SIZE)
        vis_goal = _visible_fractions(env, seg, applier.geoms)
        pushed_goal.append(vis_goal[OBJECT_NAMES.index(inst.task.split("/push_")[1])])
        hand_goal = _body_xpos(env, HAND_BODIES)
        fore_goal = _body_xpos(env, FOREARM_BODIES)
        if c.scale == 1.0:
            goal_match.append(int(np.abs(goal_img.astype(int) - inst.goal_image).max()))
        env.reset_to(init)
        start_img = env.render(SIZE)
        mae.append(mean_abs_error(start_img, full_quality.render(env._data, SIZE)))
        env._model.mat_reflectance[:] = 0.0  # the renderers copy the model at their first use
        mae_matte.append(mean_abs_error(spec_matte.render(env._data, SIZE),
                                        full_matte.render(env._data, SIZE)))
        env._model.mat_reflectance[:] = reflectance
        hand_init = _body_xpos(env, HAND_BODIES)
        fore_init = _body_xpos(env, FOREARM_BODIES)
        vis_start = _visible_fractions(env, seg, applier.geoms, counts_out=visible)
        fractions += list(vis_start) + list(vis_goal)
        env.reset_to(lifted(inst.goal_state, start_pos, c.scale))
        objects_back = env.render(SIZE)
        env.reset_to(lifted(inst.init_state, goal_pos, c.scale))
        arm_at_start = env.render(SIZE)
        obj, arm = _sse(objects_back, goal_img), _sse(arm_at_start, goal_img)
        obj_terms.append(obj)
        arm_terms.append(arm)
        shares.append(obj / (obj + arm))
        per_task.setdefault(inst.task, []).append((obj, arm))
        if sheet is None:
            sheet = (start_img, goal_img, f"{inst.task.split('/')[1]} #{inst.index}")
        proj = lambda p: project(p, c.pos, c.lookat, c.fovy)  # noqa: E731
        margins["objects"] = min(margins["objects"],
                                 margin_px(proj(object_boxes(start_pos[:, :2], c.scale))),
                                 margin_px(proj(object_boxes(goal_pos[:, :2], c.scale))))
        margins["hand"] = min(margins["hand"], margin_px(proj(hand_init)),
                              margin_px(proj(hand_goal)))
        margins["forearm"] = min(margins["forearm"], margin_px(proj(fore_init)),
                                 margin_px(proj(fore_goal)))
        for xy in (start_pos[:, :2], goal_pos[:, :2]):
            r = np.array([SCENE.footprints[n] for n in OBJECT_NAMES]) * c.scale
            dist = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
            overlaps += int(np.triu(dist < r[:, None] + r[None], 1).sum())
    margins["table"] = margin_px(project(table_corners(env), c.pos, c.lookat, c.fovy))
    seg.close()
    for r in (full_quality, spec_matte, full_matte):
        r.close()
    (x0, x1), (y0, y1) = SCENE.placement.region
    centre = np.array([(x0 + x1) / 2, (y0 + y1) / 2, SCENE.table.top_z])
    uv_y = project(np.array([centre - [0, 0.025, 0], centre + [0, 0.025, 0]]), c.pos, c.lookat,
                   c.fovy)
    uv_x = project(np.array([centre - [0.025, 0, 0], centre + [0.025, 0, 0]]), c.pos, c.lookat,
                   c.fovy)
    px5 = float(np.linalg.norm(uv_y[1] - uv_y[0]))
    px5_depth = float(np.linalg.norm(uv_x[1] - uv_x[0]))
    task_share = {t: sum(o for o, _ in v) / sum(o + a for o, a in v) for t, v in per_task.items()}
    applier.restore()
    return {
        "candidate": dataclasses.asdict(c) | {"elevation": c.elevation, "distance": c.distance},
        "share_mean": statistics.mean(shares),
        "share_min": min(shares),
        "share_pooled": sum(obj_terms) / (sum(obj_terms) + sum(arm_terms)),
        "share_per_task": task_share,
        "object_term_mean": statistics.mean(obj_terms),
        "arm_term_mean": statistics.mean(arm_terms),
        "visible_px": {n: statistics.median(v) for n, v in visible.items()},
        "px_per_5cm": px5,
        "px_per_5cm_depth": px5_depth,
        "hidden_objects": float(np.mean(np.array(fractions) < 0.5)),
        "pushed_visible_at_goal": statistics.mean(pushed_goal),
        "margins_px": margins,
        "in_view": bool(min(margins.values()) >= 0),
        "overlapping_pairs": overlaps,
        "mae_vs_full_quality": [statistics.mean(mae), max(mae)],
        "mae_vs_full_quality_matte_floor": [statistics.mean(mae_matte), max(mae_matte)],
        "goal_image_max_diff": max(goal_match) if goal_match else None,
        "_renderer": renderer,
        "_sheet": sheet,
        "_start_state": lifted(instances[0].init_state,
                               TabletopEnv.object_positions_from_state(instances[0].init_state),
                               c.scale),
    }


def time_renders(env: TabletopEnv, applier: Applier, cands: list[Candidate], results: list[dict],
                 frames: int) -> None:
    times = [[] for _ in cands]
    for _ in range(frames):
        for i, (c, r) in enumerate(zip(cands, results, strict=True)):
            applier.apply(c)  # the camera pose is read from the physics model by mj_kinematics
            env.reset_to(r["_start_state"])
            env._renderer = r["_renderer"]
            t = time.perf_counter()
            env.render(SIZE)
            times[i].append(1e3 * (time.perf_counter() - t))
    applier.restore()
    for r, t in zip(results, times, strict=True):
        r["render_ms_median"] = statistics.median(t)
        r["render_ms_quartiles"] = [float(q) for q in np.percentile(t, [25, 75])]


def candidates(env: TabletopEnv, instances: list) -> list[Candidate]:
    """The current view, fitted views, and object scales (see the module docstring)."""
    arm = []
    for inst in instances:
        env.reset_to(inst.init_state)
        arm.append(_body_xpos(env, HAND_BODIES + FOREARM_BODIES))
    arm = np.concatenate(arm)

    def required(scale: float) -> np.ndarray:
        return np.concatenate([table_corners(env), region_object_tops(scale), arm])

    def fitted(name: str, elevation: float, fovy: float, scale: float = 1.0,
               note: str = "") -> Candidate:
        pos, lookat = fit_camera(elevation, fovy, required(scale))
        return Candidate(name, pos, lookat, fovy, scale, note)

    cur = Candidate("C0 current", SCENE.camera.pos, SCENE.camera.lookat, SCENE.camera.fovy, 1.0, "shipped view")
    return [
        cur,
        fitted("C1 84deg fovy45", 84.0, 45.0, note="current elevation, closer, wider fovy"),
        fitted("C2 70deg fovy10", 70.0, 10.0, note="lower, far, narrow"),
        fitted("C3 55deg fovy10", 55.0, 10.0, note="oblique, far, narrow"),
        fitted("C4 45deg fovy10", 45.0, 10.0, note="agent-view-like oblique"),
        dataclasses.replace(cur, name="C5 current x1.5", scale=1.5, note="objects 1.5x"),
        dataclasses.replace(cur, name="C6 current x2", scale=2.0, note="objects 2x"),
        fitted("C7 45deg fovy10 x1.5", 45.0, 10.0, scale=1.5, note="objects 1.5x"),
        fitted("C8 45deg fovy10 x2", 45.0, 10.0, scale=2.0, note="objects 2x"),
    ]


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--instances", type=int, default=3, help="first N instances per task")
    parser.add_argument("--timing-frames", type=int, default=20)
    parser.add_argument("--sheet", default="/tmp/s3/tabletop_views.png")
    parser.add_argument("--json", default=None)
    args = parser.parse_args()

    suite = TaskSuite.load()
    instances = [inst for task in (f"tabletop/{t}" for t in ENV_TASKS["tabletop"])
                 for inst in suite.for_task(task)[: args.instances]]
    env = TabletopEnv("push_sphere", observation_size=None)  # task only names the pushed object
    applier = Applier(env)
    cands = candidates(env, instances)
    results = [evaluate(env, applier, c, instances) for c in cands]
    time_renders(env, applier, cands, results, args.timing_frames)

    print("| candidate | camera pos / lookat / fovy (elev., dist.) | object scale | object share "
          "mean / min / pooled | visible px L/S/C/Sp (px per 5 cm across / in depth) | margins "
          "table/objects/hand/forearm px | all in view | objects <50% visible / pushed object "
          "visible at goal | overlaps | MAE vs full quality mean/max (matte floor) | ms/frame |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in results:
        c, mg, v = r["candidate"], r["margins_px"], r["visible_px"]
        print(f"| {c['name']} | {c['pos']} / {c['lookat']} / {c['fovy']:g} "
              f"({c['elevation']:.0f}°, {c['distance']:.2f} m) | {c['scale']:g} | "
              f"{100 * r['share_mean']:.1f}% / {100 * r['share_min']:.1f}% / "
              f"{100 * r['share_pooled']:.1f}% | "
              f"{v['large_cube']:.1f}/{v['small_cube']:.1f}/{v['cylinder']:.1f}/{v['sphere']:.1f}"
              f" ({r['px_per_5cm']:.1f} / {r['px_per_5cm_depth']:.1f}) | {mg['table']:.1f}/"
              f"{mg['objects']:.1f}/{mg['hand']:.1f}/{mg['forearm']:.1f} | "
              f"{'yes' if r['in_view'] else 'NO'} | {100 * r['hidden_objects']:.0f}% / "
              f"{100 * r['pushed_visible_at_goal']:.0f}% | {r['overlapping_pairs']} | "
              f"{r['mae_vs_full_quality'][0]:.1f}/{r['mae_vs_full_quality'][1]:.1f} "
              f"({r['mae_vs_full_quality_matte_floor'][0]:.1f}/"
              f"{r['mae_vs_full_quality_matte_floor'][1]:.1f}) | "
              f"{r['render_ms_median']:.1f} |")
    print()
    print("object share per task (pooled over its instances):")
    for r in results:
        print(f"  {r['candidate']['name']:28s} " + "  ".join(
            f"{t.split('/')[1]} {100 * s:.1f}%" for t, s in r["share_per_task"].items()))
    gm = results[0]["goal_image_max_diff"]
    print(f"\ncurrent view: re-rendered goal images vs shipped, max abs diff = {gm}")

    if args.sheet:
        images, labels = [], []
        for r in results:
            start, goal, which = r["_sheet"]
            images += [start, goal]
            short = r["candidate"]["name"]
            labels += [f"{short} start ({which})", f"{short} goal"]
        os.makedirs(os.path.dirname(args.sheet) or ".", exist_ok=True)
        Image.fromarray(contact_sheet(images, labels, columns=4, scale=4)).save(args.sheet)
        print(f"contact sheet: {args.sheet}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump([{k: v for k, v in r.items() if not k.startswith("_")} for r in results],
                      f, indent=1)
    for r in results:
        r["_renderer"].close()
    env.close()


if __name__ == "__main__":
    main()
