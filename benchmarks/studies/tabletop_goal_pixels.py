"""The tabletop task suite's goal images: a contact sheet, and the pixels each object covers.

For every tabletop instance of a suite, a segmentation render of its goal state from the
benchmark camera at 64x64 (visual geoms only) counts the visible pixels of each object; the
table gives, per category, the median over its instances of the pushed object's pixels and of
every object's. ``--sheet`` writes a PNG of the first ``--per-category`` goal images of each
category (one row per category, 2x nearest-neighbour).

Usage::

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.studies.tabletop_goal_pixels \\
        [--suite FILE] [--sheet docs/tabletop-goals.png] [--per-category 6]
"""

from __future__ import annotations

import mujoco
import numpy as np
from PIL import Image

from benchmarks import common
from vp2.data.suite import TaskSuite
from vp2.envs import TABLETOP_TASKS
from vp2.envs.tabletop import OBJECT_NAMES, TabletopEnv


def object_pixels(env: TabletopEnv, state: np.ndarray) -> list[int]:
    """Visible pixels of each object at ``state`` (64x64 segmentation of the benchmark camera)."""
    env.reset_to(state)
    model, data = env._model, env._data
    renderer = mujoco.Renderer(model, 64, 64)
    renderer.enable_segmentation_rendering()
    option = mujoco.MjvOption()
    option.geomgroup[:] = 0
    option.geomgroup[1] = 1  # robosuite's visual geoms
    mujoco.mj_kinematics(model, data)
    mujoco.mj_camlight(model, data)
    renderer.update_scene(data, camera=env.scene.render.camera, scene_option=option)
    geom = renderer.render()[..., 0]
    renderer.close()
    body = np.where(geom >= 0, model.geom_bodyid[np.clip(geom, 0, model.ngeom - 1)], -1)
    return [int((body == model.body(f"{n}_main").id).sum()) for n in OBJECT_NAMES]


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--suite", default=None, help="suite file (default: the shipped suite)")
    parser.add_argument("--sheet", default=None, help="write the contact sheet PNG here")
    parser.add_argument("--per-category", type=int, default=6)
    args = parser.parse_args()
    suite = TaskSuite.load(args.suite)
    print("| category | pushed object, px in the goal image (median) | every object's px "
          "(median: large cube, small cube, cylinder, sphere) |\n|---|---|---|")
    rows = []
    with TabletopEnv(TABLETOP_TASKS[0], observation_size=None) as env:
        for task in TABLETOP_TASKS:
            insts = suite.for_task(f"tabletop/{task}")
            px = np.array([object_pixels(env, inst.goal_state) for inst in insts])
            k = OBJECT_NAMES.index(task.removeprefix("push_"))
            every = ", ".join(f"{v:g}" for v in np.median(px, axis=0))
            print(f"| {task} | {np.median(px[:, k]):g} | {every} |")
            rows.append(np.concatenate([i.goal_image for i in insts[: args.per_category]], axis=1))
    if args.sheet:
        sheet = np.concatenate(rows, axis=0)
        Image.fromarray(sheet).resize((sheet.shape[1] * 2, sheet.shape[0] * 2), Image.NEAREST).save(
            args.sheet, optimize=True
        )
        print(f"wrote {args.sheet}")


if __name__ == "__main__":
    main()
