"""Which tabletop camera lets the pixel cost see the push? Cameras compared by the oracle.

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.studies.tabletop_camera_study \\
        --cameras front45 steep65 top85 --instances 0 1 2 3 4 --oracle-instances 0 1 2 \\
        --json outputs/camera-study/study.json --sheet outputs/camera-study/sheet.png

SPEC §1.2 leaves the tabletop camera free: any fixed camera that sees every object's start and
goal and the hand, chosen by the oracle. Each candidate is a camera pose (elevation from the
front, field of view) framed automatically: the look-at point and distance are the closest that
keep every object's start and goal (tops and bottoms) and the hand at the start and goal of
every tabletop suite instance inside the 64x64 image with a 2-pixel margin. Per camera, on the
same suite instances (states are camera-free; goal images are re-rendered through the camera):

* **pixels per object**: the pushed object's visible pixels at 64x64 in the initial and goal
  frames (MuJoCo's segmentation rendering), and how far the push moves it in the image (px);
* **arm share**: the fraction of the goal image covered by the robot, and the share of the
  initial-to-goal squared pixel error on pixels where the robot is in either frame;
* **scripted-plan rank** among the SPEC sampler's candidates at the first planning step
  (``benchmarks.studies.scripted_plan_rank``: 1 = the cost's favourite);
* **oracle success**: full control trials of the simulator oracle (MPPI at ``--num-samples``,
  seed 0, stop on success), with the pushed object's final and closest distance to its goal.

Each camera runs in its own process, on a variant of the tabletop scene
(:func:`camera_scene`: ``dataclasses.replace`` of ``DEFAULT_SCENE`` with the candidate's camera);
the environments it builds, the oracle's included, carry that scene in their metadata. ``--sheet`` writes
one contact sheet row per camera (initial frame and goal image of the first instances).
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from benchmarks import common  # noqa: E402
from vp2.utils.io import write_json_atomic  # noqa: E402

TASKS = (
    "tabletop/push_large_cube",
    "tabletop/push_small_cube",
    "tabletop/push_cylinder",
    "tabletop/push_sphere",
)


@dataclasses.dataclass(frozen=True)
class CameraCandidate:
    """A view from the front (+x, looking back at the robot): elevation and vertical field of
    view in degrees; the look-at point and distance are fitted to the must-see points. A
    candidate with a fixed ``pos``/``lookat`` is used as given."""

    elevation: float
    fovy: float
    pos: tuple[float, float, float] | None = None
    #: Direction of the camera from the scene in degrees, counter-clockwise seen from above:
    #: 0 in front of the table (+x, facing the robot), 90 on its left (+y), the side every
    #: push goes towards (push directions lie in [0, pi]).
    azimuth: float = 0.0
    lookat: tuple[float, float, float] | None = None


CANDIDATES: dict[str, CameraCandidate] = {
    # The camera of suite v3: 45 degrees, far away, framed to keep the table corners too.
    "front45": CameraCandidate(45.0, 10.0, pos=(2.696, 0.0, 3.741), lookat=(-0.245, 0.0, 0.8)),
    # The same direction framed to the must-see points only (closer).
    "front45-fit": CameraCandidate(45.0, 10.0),
    # Steeper and closer.
    "steep65": CameraCandidate(65.0, 20.0),
    # Near top-down (a few degrees from the front so that the hand's height shows).
    "top85": CameraCandidate(85.0, 20.0),
    # Top-down with a wide field of view (strong perspective: the hand grows as it rises).
    "top85-wide": CameraCandidate(85.0, 45.0),
    # Close to the table's front edge with a wide field of view, like robosuite's agentview:
    # near objects look large and the arm, further away, smaller.
    "front30-wide": CameraCandidate(30.0, 45.0),
    "front45-wide": CameraCandidate(45.0, 45.0),
    "front60-wide": CameraCandidate(60.0, 45.0),
    # From the left (+y): every push goes towards it (directions in [0, pi]), so the pushing
    # hand stays behind the object and never hides it.
    "left45": CameraCandidate(45.0, 20.0, azimuth=90.0),
    "left60": CameraCandidate(60.0, 20.0, azimuth=90.0),
    "left45-wide": CameraCandidate(45.0, 45.0, azimuth=90.0),
    "frontleft45": CameraCandidate(45.0, 20.0, azimuth=45.0),
}

SIZE = 64
MARGIN_PX = 2.0


# ---- geometry ------------------------------------------------------------------------------


def _frame(pos: np.ndarray, lookat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    back = pos - lookat
    back = back / np.linalg.norm(back)
    right = np.cross([0.0, 0.0, 1.0], back)
    right = right / np.linalg.norm(right)
    up = np.cross(back, right)
    return right, up, back


def project(points: np.ndarray, pos, lookat, fovy: float) -> np.ndarray:
    """``(N, 2)`` pixel coordinates (column, row) of world points in a SIZE x SIZE image."""
    pos, lookat = np.asarray(pos, float), np.asarray(lookat, float)
    right, up, back = _frame(pos, lookat)
    v = points - pos
    depth = -(v @ back)
    t = math.tan(math.radians(fovy) / 2)
    x = (v @ right) / depth / t
    y = (v @ up) / depth / t
    return np.stack([(x + 1) * SIZE / 2, (1 - y) * SIZE / 2], axis=1)


def fits(points: np.ndarray, pos, lookat, fovy: float) -> bool:
    px = project(points, pos, lookat, fovy)
    return bool(((px >= MARGIN_PX) & (px <= SIZE - MARGIN_PX)).all())


def fit_camera(cand: CameraCandidate, points: np.ndarray) -> tuple[tuple, tuple]:
    """The closest camera of ``cand``'s direction and fovy that keeps ``points`` in view, the
    look-at point searched over the points' range (y = 0 for a camera from the front)."""
    if cand.pos is not None:
        return cand.pos, cand.lookat
    el, az = math.radians(cand.elevation), math.radians(cand.azimuth)
    direction = np.array([math.cos(el) * math.cos(az), math.cos(el) * math.sin(az), math.sin(el)])
    best = None
    lo_x, hi_x = points[:, 0].min(), points[:, 0].max()
    lo_y, hi_y = points[:, 1].min(), points[:, 1].max()
    ys = [0.0] if cand.azimuth == 0 else np.linspace(lo_y, hi_y, 11)
    for lx, ly in [(x, y) for x in np.linspace(lo_x, hi_x, 21) for y in ys]:
        for lz in (0.8, 0.85, 0.9):
            lookat = np.array([lx, ly, lz])
            lo, hi = 0.2, 20.0
            if not fits(points, lookat + hi * direction, lookat, cand.fovy):
                continue
            for _ in range(40):
                mid = (lo + hi) / 2
                if fits(points, lookat + mid * direction, lookat, cand.fovy):
                    hi = mid
                else:
                    lo = mid
            if best is None or hi < best[0]:
                best = (hi, lookat)
    if best is None:
        raise RuntimeError(f"no {cand} camera keeps the must-see points in view")
    d, lookat = best
    pos = lookat + d * direction
    return tuple(round(float(v), 4) for v in pos), tuple(round(float(v), 4) for v in lookat)


def must_see_points(suite) -> np.ndarray:
    """Object tops and bottoms at the start and goal of every tabletop instance, and the hand
    (grip site and 12 cm above it) at the start and goal."""
    from vp2.envs.tabletop import TabletopEnv

    env = TabletopEnv("push_large_cube", observation_size=None)
    points = []
    try:
        for task in TASKS:
            for inst in suite.for_task(task):
                for state in (inst.init_state, inst.goal_state):
                    objects = TabletopEnv.object_positions_from_state(state)
                    points += [objects + [0, 0, 0.03], objects - [0, 0, 0.03]]
                    env.reset_to(state)
                    hand = env.end_effector_position()
                    points.append(np.stack([hand, hand + [0, 0, 0.12]]))
    finally:
        env.close()
    return np.concatenate(points)


# ---- one camera (runs in its own process) --------------------------------------------------


def camera_scene(pos, lookat, fovy: float):
    """The default tabletop scene seen through another camera."""
    from vp2.envs.tabletop_scene import DEFAULT_SCENE

    camera = dataclasses.replace(
        DEFAULT_SCENE.camera,
        pos=tuple(float(v) for v in pos),
        lookat=tuple(float(v) for v in lookat),
        fovy=float(fovy),
    )
    return dataclasses.replace(DEFAULT_SCENE, camera=camera)


def segmentation(env, state) -> np.ndarray:
    """``(SIZE, SIZE)`` int: 0 background/table, 1..4 the objects, 5 the robot."""
    import mujoco

    from vp2.envs.tabletop import OBJECT_NAMES

    env.reset_to(state)
    model, data = env._model, env._data
    if not hasattr(env, "_seg"):
        env._seg = mujoco.Renderer(model, SIZE, SIZE)
        env._seg.enable_segmentation_rendering()
        labels = np.zeros(model.ngeom, int)
        for g in range(model.ngeom):
            body = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, model.geom_bodyid[g]) or ""
            for k, name in enumerate(OBJECT_NAMES):
                if body.startswith(name):
                    labels[g] = k + 1
            if body.startswith(("robot0_", "gripper0_", "fixed_mount0_")):
                labels[g] = 5
        env._seg_labels = labels
    mujoco.mj_forward(model, data)
    env._seg.update_scene(data, camera=env.scene.camera.name)
    seg = env._seg.render()
    out = np.zeros((SIZE, SIZE), int)
    geom = (seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM)) & (seg[..., 0] >= 0)
    out[geom] = env._seg_labels[seg[..., 0][geom]]
    return out


def measure_camera(args) -> dict:
    import torch

    from benchmarks.studies.scripted_plan_rank import (
        first_step_candidates,
        predict_from_start,
        rank_of_last,
        scripted_plan,
    )
    from vp2.data.suite import TaskSuite
    from vp2.envs.tabletop import OBJECT_NAMES, TabletopEnv
    from vp2.models.simulator import SimulatorModel
    from vp2.planning.agent import PlanningAgent, frames_to_tensor
    from vp2.planning.config import PlannerConfig
    from vp2.planning.planner import build_cost
    from vp2.run.trial import ControlTrial
    from vp2.spec import NUM_FUTURE as HORIZON

    pos, lookat = json.loads(args.pose)
    scene = camera_scene(pos, lookat, args.fovy)
    torch.set_num_threads(1)
    suite = TaskSuite.load()
    rows, sheet = [], []
    for task in TASKS:
        env = TabletopEnv(task.split("/")[1], observation_size=None, scene=scene)
        pushed = OBJECT_NAMES.index(task.split("push_")[1])
        instances = sorted(set(args.instances) | set(args.oracle_instances))
        for index in instances:
            inst = suite.get(task, index)
            env.reset_to(inst.goal_state)
            goal_image = env.render(SIZE)
            env.reset_to(inst.init_state)
            init_image = env.render(SIZE)
            if index in args.instances[:3]:
                sheet.append((task, index, init_image, goal_image))
            seg_init, seg_goal = segmentation(env, inst.init_state), segmentation(env, inst.goal_state)
            p0 = TabletopEnv.object_positions_from_state(inst.init_state)[pushed]
            p1 = TabletopEnv.object_positions_from_state(inst.goal_state)[pushed]
            px = project(np.stack([p0, p1]), pos, lookat, args.fovy)
            sq = ((init_image.astype(float) - goal_image.astype(float)) / 255.0) ** 2
            sq = sq.sum(-1)
            arm = (seg_init == 5) | (seg_goal == 5)
            objects = ((seg_init >= 1) & (seg_init <= 4)) | ((seg_goal >= 1) & (seg_goal <= 4))
            row = {
                "task": task,
                "instance": index,
                "scripted_actions": len(inst.actions),
                "object_px_init": int((seg_init == pushed + 1).sum()),
                "object_px_goal": int((seg_goal == pushed + 1).sum()),
                "push_m": float(np.linalg.norm(p1 - p0)),
                "push_px": float(np.linalg.norm(px[1] - px[0])),
                "arm_fraction_goal": float((seg_goal == 5).mean()),
                "arm_share_sse": float(sq[arm].sum() / max(sq.sum(), 1e-12)),
                "object_share_sse": float(sq[objects & ~arm].sum() / max(sq.sum(), 1e-12)),
            }
            if index in args.instances:
                candidates = first_step_candidates("tabletop", inst.actions.shape[1], args.num_samples)
                plans = torch.cat([candidates, scripted_plan(inst.actions, HORIZON)[None]])
                frames = predict_from_start(inst, plans)
                cost, _ = build_cost(task, frames_to_tensor(goal_image, torch.device("cpu")), "auto")
                with torch.no_grad():
                    score = cost.score(frames).double().numpy()
                row["rank"] = rank_of_last(score)
                row["of"] = len(plans)
                spread = float(score[:-1].max() - score[:-1].min())
                row["score_spread"] = spread
            if index in args.oracle_instances:
                start = time.perf_counter()
                model = SimulatorModel(inst.actions.shape[1])
                agent = PlanningAgent(model, PlannerConfig(num_samples=args.num_samples))
                # The oracle rebuilds its environments from the metadata: this camera's scene.
                inst_cam = dataclasses.replace(
                    inst, goal_image=goal_image, env_meta=env.serialize()
                )
                result = ControlTrial(inst_cam, agent, seed=0, stop_on_success=True, env=env).run()
                model.close()
                # The pushed object's distance to its goal along the trial.
                env.reset_to(inst.init_state)
                dists, hands = [], [env.end_effector_position()]
                for action in result.actions:
                    env.step(np.asarray(action))
                    dists.append(float(np.linalg.norm(env.object_positions()[pushed] - p1)))
                    hands.append(env.end_effector_position())
                hands = np.stack(hands)
                in_view = project(hands, pos, lookat, args.fovy)
                row["oracle_hand_rise_m"] = float(hands[:, 2].max() - hands[0, 2])
                row["oracle_hand_out_of_view_steps"] = int(
                    (((in_view < 0) | (in_view > SIZE)).any(axis=1)).sum()
                )
                row["oracle_success"] = bool(result.success)
                row["oracle_steps"] = len(result.actions)
                row["oracle_final_m"] = dists[-1]
                row["oracle_closest_m"] = min(dists)
                row["oracle_seconds"] = round(time.perf_counter() - start, 1)
                if args.out_json:
                    strip = Path(args.out_json).with_suffix("") / f"{task.split('/')[1]}-{index}.png"
                    strip.parent.mkdir(parents=True, exist_ok=True)
                    from PIL import Image

                    Image.fromarray(
                        np.concatenate([goal_image, *result.frames], axis=1)
                    ).save(strip)
            rows.append(row)
            print(f"[{args.name}] " + json.dumps(row), flush=True)
        env.close()
    if args.sheet_npz:
        np.savez_compressed(
            args.sheet_npz,
            images=np.stack([np.concatenate([a, b], 1) for _, _, a, b in sheet]),
            labels=np.array([f"{t.split('/')[1]} #{i}" for t, i, _, _ in sheet]),
        )
    return {"name": args.name, "pos": pos, "lookat": lookat, "fovy": args.fovy, "rows": rows}


# ---- the study --------------------------------------------------------------------------------


def summarise(result: dict) -> dict:
    rows = result["rows"]

    def mean(key, rs=rows):
        vals = [r[key] for r in rs if key in r]
        return float(np.mean(vals)) if vals else None

    oracle = [r for r in rows if "oracle_success" in r]
    ranked = [r for r in rows if "rank" in r]
    return {
        "camera": result["name"],
        "pos": result["pos"],
        "lookat": result["lookat"],
        "fovy": result["fovy"],
        "object_px": mean("object_px_goal"),
        "push_px": mean("push_px"),
        "arm_fraction": mean("arm_fraction_goal"),
        "arm_share_sse": mean("arm_share_sse"),
        "object_share_sse": mean("object_share_sse"),
        "ranked_first": f"{sum(r['rank'] == 1 for r in ranked)}/{len(ranked)}",
        "median_rank": float(np.median([r["rank"] for r in ranked])) if ranked else None,
        "oracle": f"{sum(r['oracle_success'] for r in oracle)}/{len(oracle)}",
        "oracle_closest_m": mean("oracle_closest_m", oracle),
    }


def write_sheet(path: Path, parts: list[tuple[str, Path]], first_only: bool = False) -> None:
    """One row per camera: initial frame | goal image of its instances (``first_only``: the
    first instance of each task)."""
    from PIL import Image, ImageDraw

    rows = []
    for name, npz in parts:
        data = np.load(npz)
        images = data["images"]
        if first_only:
            images = images[[i for i, label in enumerate(data["labels"]) if label.endswith("#0")]]
        scale = 2
        row = np.concatenate(list(images), axis=1)
        img = Image.fromarray(row).resize((row.shape[1] * scale, row.shape[0] * scale), Image.NEAREST)
        canvas = Image.new("RGB", (img.width + 110, img.height), "white")
        canvas.paste(img, (110, 0))
        ImageDraw.Draw(canvas).text((4, img.height // 2 - 6), name, fill="black")
        rows.append(canvas)
    sheet = Image.new("RGB", (max(r.width for r in rows), sum(r.height + 4 for r in rows)), "white")
    y = 0
    for r in rows:
        sheet.paste(r, (0, y))
        y += r.height + 4
    path.parent.mkdir(parents=True, exist_ok=True)
    sheet.save(path)


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--cameras", nargs="+", default=["front45", "steep65", "top85"],
                        choices=sorted(CANDIDATES))
    parser.add_argument("--instances", type=int, nargs="+", default=[0, 1, 2, 3, 4],
                        help="instances per task for the image measures and the plan rank")
    parser.add_argument("--oracle-instances", type=int, nargs="*", default=[0, 1, 2],
                        help="instances per task for the oracle's control trials")
    parser.add_argument("-n", "--num-samples", type=int, default=50)
    parser.add_argument("--json", type=Path, default=Path("outputs/camera-study/study.json"))
    parser.add_argument("--sheet", type=Path, help="contact sheet PNG")
    # internal: one camera in this process
    parser.add_argument("--one", action="store_true", help=argparse_suppress())
    parser.add_argument("--name", help=argparse_suppress())
    parser.add_argument("--pose", help=argparse_suppress())
    parser.add_argument("--fovy", type=float, help=argparse_suppress())
    parser.add_argument("--sheet-npz", help=argparse_suppress())
    parser.add_argument("--out-json", help=argparse_suppress())
    args = parser.parse_args()
    if args.one:
        write_json_atomic(args.out_json, measure_camera(args))
        return
    from vp2.data.suite import TaskSuite

    points = must_see_points(TaskSuite.load())
    out_dir = args.json.parent
    out_dir.mkdir(parents=True, exist_ok=True)
    results, parts = [], []
    for name in args.cameras:
        cand = CANDIDATES[name]
        pos, lookat = fit_camera(cand, points)
        part = out_dir / f"{name}.json"
        npz = out_dir / f"{name}-sheet.npz"
        if not part.exists():
            print(f"camera {name}: pos {pos} lookat {lookat} fovy {cand.fovy}", flush=True)
            subprocess.run(
                [sys.executable, "-m", __spec__.name, "--one", "--name", name,
                 "--pose", json.dumps([pos, lookat]), "--fovy", str(cand.fovy),
                 "--instances", *map(str, args.instances),
                 "--oracle-instances", *map(str, args.oracle_instances),
                 "-n", str(args.num_samples), "--sheet-npz", str(npz), "--out-json", str(part)],
                check=True,
            )
        result = json.loads(part.read_text())
        results.append(result)
        parts.append((name, npz))
        print(json.dumps(summarise(result)), flush=True)
    write_json_atomic(args.json, {
        "command": vars(args) | {"json": str(args.json), "sheet": str(args.sheet)},
        "summary": [summarise(r) for r in results],
        "cameras": results,
    })
    if args.sheet:
        write_sheet(args.sheet, parts, first_only=True)


def argparse_suppress():
    import argparse

    return argparse.SUPPRESS


if __name__ == "__main__":
    main()
