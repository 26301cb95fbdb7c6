"""Do larger tabletop objects let the pixel cost see the push? Object scales compared by the oracle.

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.studies.tabletop_object_scale \\
        --scales 1 1.5 2 --instances 5 --oracle-instances 3 --out outputs/object-scale

The camera study (``benchmarks.studies.tabletop_camera_study``) found the arm 86–97% of the
start-to-goal squared pixel error in every view, and the oracle solving 1–3 of 12 whatever the
camera. SPEC §1.2 names the four objects, not their sizes. Per scale, in its own process, on a
variant of the tabletop scene (:func:`scaled_scene`: every object's size scaled, so the scripted
policy, placement and rest heights follow; the instances' metadata, and so the oracle's
environments, carry that scene):

* instances are generated as the suite generates them (``vp2.data.suite.generate_instance``,
  the suite's seeds, accepted in attempt order; at scale 1 they are the shipped suite's);
* **image measures** on the first ``--instances`` per task: the pushed object's pixels at 64x64,
  the push in pixels, the arm's and the objects' shares of the initial-to-goal squared error;
* **scripted-plan rank** among the SPEC sampler's 50 first-step candidates under the pixel cost
  (1 = the cost's favourite);
* **oracle trials** (MPPI, ``--num-samples``, seed 0, stop on success) on the first
  ``--oracle-instances`` per task, with the pushed object's closest and final distance to its
  goal. Scale 1's trials are the shipped ``samples-50`` table's (read from ``results/``, not
  rerun) when ``--reuse-scale1`` is given.

Results: ``<out>/scale-<s>.jsonl`` (one line per instance; an interrupted study resumes after the
last instance written), ``<out>/summary.md``, and ``<out>/sheet-<s>.png`` (initial frame and goal
image of instance #0 of each task).
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from benchmarks import common  # noqa: E402
from benchmarks.studies.tabletop_camera_study import TASKS  # noqa: E402

SIZE = 64


def scaled_scene(scale: float):
    """The default tabletop scene with every object's size multiplied by ``scale``."""
    from vp2.envs.tabletop_scene import DEFAULT_SCENE

    objects = tuple(
        dataclasses.replace(obj, size=tuple(v * scale for v in obj.size))
        for obj in DEFAULT_SCENE.objects
    )
    return dataclasses.replace(DEFAULT_SCENE, objects=objects)


def instances_at_scale(task: str, count: int, env):
    """The first ``count`` accepted instances of ``task`` in ``env`` (a scene variant's), as
    ``generate_suite`` accepts them."""
    from vp2.data.suite import SUITE_SEED, generate_instance, instance_seed

    found, attempt = [], 0
    while len(found) < count:
        if attempt > 20 * count:
            raise RuntimeError(f"{task}: only {len(found)} instances in {attempt} attempts")
        inst = generate_instance(task, instance_seed(SUITE_SEED, task, attempt), env=env)
        attempt += 1
        if inst is not None:
            found.append(dataclasses.replace(inst, index=len(found)))
    return found


def measure_scale(args) -> None:
    """One scale, in this process: appends a line per instance to ``args.out_jsonl``."""
    import torch

    from benchmarks.studies.scripted_plan_rank import (
        first_step_candidates,
        predict_from_start,
        rank_of_last,
        scripted_plan,
    )
    from benchmarks.studies.tabletop_camera_study import project, segmentation
    from vp2.spec import NUM_FUTURE as HORIZON

    scene = scaled_scene(args.scale)
    from vp2.envs.tabletop import OBJECT_NAMES, TabletopEnv
    from vp2.models.simulator import SimulatorModel
    from vp2.planning.agent import PlanningAgent, frames_to_tensor
    from vp2.planning.config import PlannerConfig
    from vp2.planning.planner import build_cost
    from vp2.run.trial import ControlTrial

    torch.set_num_threads(1)
    out = Path(args.out_jsonl)
    done = set()
    if out.exists():
        done = {(r["task"], r["instance"]) for r in map(json.loads, out.read_text().splitlines())}
    pose = (scene.camera.pos, scene.camera.lookat, scene.camera.fovy)
    sheet = []
    for task in TASKS:
        pushed = OBJECT_NAMES.index(task.split("push_")[1])
        env = TabletopEnv(task.split("/")[1], observation_size=None, scene=scene)
        insts = instances_at_scale(task, max(args.instances, args.oracle_instances), env)
        for inst in insts:
            env.reset_to(inst.init_state)
            if inst.index == 0:
                sheet.append(np.concatenate([env.render(SIZE), inst.goal_image], axis=1))
            if (task, inst.index) in done:
                continue
            seg_init, seg_goal = (
                segmentation(env, inst.init_state),
                segmentation(env, inst.goal_state),
            )
            env.reset_to(inst.init_state)
            init_image = env.render(SIZE)
            p0 = TabletopEnv.object_positions_from_state(inst.init_state)[pushed]
            p1 = TabletopEnv.object_positions_from_state(inst.goal_state)[pushed]
            px = project(np.stack([p0, p1]), *pose)
            sq = (((init_image.astype(float) - inst.goal_image.astype(float)) / 255.0) ** 2).sum(-1)
            arm = (seg_init == 5) | (seg_goal == 5)
            objects = ((seg_init >= 1) & (seg_init <= 4)) | ((seg_goal >= 1) & (seg_goal <= 4))
            row = {
                "scale": args.scale,
                "task": task,
                "instance": inst.index,
                "fingerprint": inst.fingerprint,
                "scripted_actions": len(inst.actions),
                "object_px_init": int((seg_init == pushed + 1).sum()),
                "object_px_goal": int((seg_goal == pushed + 1).sum()),
                "push_m": float(np.linalg.norm(p1 - p0)),
                "push_px": float(np.linalg.norm(px[1] - px[0])),
                "arm_share_sse": float(sq[arm].sum() / max(sq.sum(), 1e-12)),
                "object_share_sse": float(sq[objects & ~arm].sum() / max(sq.sum(), 1e-12)),
            }
            if inst.index < args.instances:
                candidates = first_step_candidates(
                    "tabletop", inst.actions.shape[1], args.num_samples
                )
                plans = torch.cat([candidates, scripted_plan(inst.actions, HORIZON)[None]])
                frames = predict_from_start(inst, plans)
                goal = frames_to_tensor(inst.goal_image, torch.device("cpu"))
                cost, _ = build_cost(task, goal, "auto")
                with torch.no_grad():
                    score = cost.score(frames).double().numpy()
                row["rank"], row["of"] = rank_of_last(score), len(plans)
            if inst.index < args.oracle_instances and not args.no_oracle:
                start = time.perf_counter()
                model = SimulatorModel(inst.actions.shape[1])
                agent = PlanningAgent(model, PlannerConfig(num_samples=args.num_samples))
                result = ControlTrial(inst, agent, seed=0, stop_on_success=True, env=env).run()
                model.close()
                env.reset_to(inst.init_state)
                dists = []
                for action in result.actions:
                    env.step(np.asarray(action))
                    dists.append(float(np.linalg.norm(env.object_positions()[pushed] - p1)))
                row.update(
                    oracle_success=bool(result.success),
                    oracle_steps=len(result.actions),
                    oracle_final_m=dists[-1],
                    oracle_closest_m=min(dists),
                    oracle_seconds=round(time.perf_counter() - start, 1),
                )
            with out.open("a") as f:
                f.write(json.dumps(row) + "\n")
            print(f"[scale {args.scale:g}] " + json.dumps(row), flush=True)
        env.close()
    from PIL import Image

    Image.fromarray(np.concatenate(sheet, axis=0)).resize(
        (4 * SIZE * 2, 4 * SIZE * len(sheet)), Image.NEAREST
    ).save(Path(args.out_jsonl).with_name(f"sheet-{args.scale:g}.png"))


def shipped_scale1(rows: list[dict], first: int) -> dict[tuple[str, int], bool]:
    """The shipped samples-50 table's oracle success of the scale-1 instances it holds, among
    each task's first ``first`` (the instances the other scales' trials ran on)."""
    from vp2.run.run_dir import RunDir

    path = RunDir("results/oracle/samples-50").trials_file
    found = {}
    for line in path.read_text().splitlines():
        r = json.loads(line)
        found[(r["task"], int(r["instance"]))] = (bool(r["success"]), r.get("instance_sha"))
    out = {}
    for row in rows:
        hit = found.get((row["task"], row["instance"]))
        if row["instance"] < first and hit is not None and hit[1] in (None, row["fingerprint"]):
            out[(row["task"], row["instance"])] = hit[0]
    return out


def summary_markdown(by_scale: dict[float, list[dict]], command: str, oracle_instances: int) -> str:
    lines = [
        "# Tabletop object scale",
        "",
        f"Command: `{command}`",
        "",
        "Medians over instances; oracle: solved / trials (50 samples, seed 0).",
        "",
        "| scale | task | object px | push px | arm share of SSE | objects' share | "
        "scripted-plan rank | oracle |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for scale, rows in sorted(by_scale.items()):
        shipped = shipped_scale1(rows, oracle_instances) if scale == 1 else {}
        for task in TASKS:
            rs = [r for r in rows if r["task"] == task]
            if not rs:
                continue
            ranks = [r["rank"] for r in rs if "rank" in r]
            rank = "–" if not ranks else f"{np.median(ranks):.0f} of {rs[0].get('of', 51)}"
            trials = [r["oracle_success"] for r in rs if "oracle_success" in r]
            note = ""
            if not trials and shipped:
                trials = [v for (t, _), v in shipped.items() if t == task]
                note = " (shipped table)"
            def med(key: str, rs: list[dict] = rs) -> float:
                return float(np.median([r[key] for r in rs]))

            lines.append(
                f"| {scale:g} | {task.split('/')[1]} | {med('object_px_goal'):.0f} | "
                f"{med('push_px'):.1f} | {med('arm_share_sse'):.0%} | {med('object_share_sse'):.0%} | "
                f"{rank} | "
                f"{'–' if not trials else f'{sum(trials)}/{len(trials)}{note}'} |"
            )
    return "\n".join(lines) + "\n"


def shipped_by_distance(bins: Sequence[float] = (0.0, 0.1, 0.2, 0.31)) -> str:
    """The shipped samples-50 table's tabletop trials by the pushed object's start-to-goal
    distance (from the shipped suite's states; no simulation): solved / trials per bin."""
    from vp2.data.suite import TaskSuite
    from vp2.envs.tabletop import OBJECT_NAMES, TabletopEnv
    from vp2.run.run_dir import RunDir

    suite = TaskSuite.load()
    rows = []
    for line in RunDir("results/oracle/samples-50").trials_file.read_text().splitlines():
        r = json.loads(line)
        if not r["task"].startswith("tabletop/"):
            continue
        inst = suite.get(r["task"], int(r["instance"]))
        k = OBJECT_NAMES.index(r["task"].split("push_")[1])
        p0 = TabletopEnv.object_positions_from_state(inst.init_state)[k]
        p1 = TabletopEnv.object_positions_from_state(inst.goal_state)[k]
        rows.append((float(np.linalg.norm(p1 - p0)), bool(r["success"]), r["task"]))
    lines = [
        "| start-to-goal distance | solved | categories |",
        "|---|---|---|",
    ]
    for lo, hi in zip(bins[:-1], bins[1:], strict=True):
        inside = [x for x in rows if lo <= x[0] < hi]
        cats = sorted({t.split("push_")[1] for _, _, t in inside})
        lines.append(
            f"| {lo:.2f}–{hi:.2f} m | {sum(s for _, s, _ in inside)}/{len(inside)} | "
            f"{', '.join(cats)} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--scales", type=float, nargs="+", default=[1.0, 1.5, 2.0])
    parser.add_argument(
        "--instances", type=int, default=5, help="per task, image measures and rank"
    )
    parser.add_argument("--oracle-instances", type=int, default=3, help="per task, oracle trials")
    parser.add_argument(
        "--no-oracle-at",
        type=float,
        nargs="*",
        default=[1.0],
        help="scales whose oracle trials are not run (scale 1: the shipped table)",
    )
    parser.add_argument("-n", "--num-samples", type=int, default=50)
    parser.add_argument("--out", type=Path, default=Path("outputs/object-scale"))
    parser.add_argument("--by-distance", action="store_true",
                        help="print the shipped scale-1 trials by push distance; run nothing")
    parser.add_argument("--summary-only", action="store_true",
                        help="rewrite summary.md from the scales' files; run nothing")
    parser.add_argument("--one", action="store_true", help=argparse_suppress())
    parser.add_argument("--scale", type=float, help=argparse_suppress())
    parser.add_argument("--no-oracle", action="store_true", help=argparse_suppress())
    parser.add_argument("--out-jsonl", help=argparse_suppress())
    args = parser.parse_args()
    if args.one:
        measure_scale(args)
        return
    if args.by_distance:
        print(shipped_by_distance())
        return
    args.out.mkdir(parents=True, exist_ok=True)
    by_scale = {}
    for scale in args.scales:
        part = args.out / f"scale-{scale:g}.jsonl"
        command = [sys.executable, "-m", __spec__.name, "--one", "--scale", str(scale),
                   "--instances", str(args.instances),
                   "--oracle-instances", str(args.oracle_instances),
                   "-n", str(args.num_samples), "--out-jsonl", str(part)]  # fmt: skip
        if scale in args.no_oracle_at:
            command.append("--no-oracle")
        if not args.summary_only:
            subprocess.run(command, check=True)
        by_scale[scale] = [json.loads(x) for x in part.read_text().splitlines()]
        (args.out / "summary.md").write_text(
            summary_markdown(
                by_scale, common.command_line(__spec__.name, None), args.oracle_instances
            )
        )
    print((args.out / "summary.md").read_text())


def argparse_suppress():
    import argparse

    return argparse.SUPPRESS


if __name__ == "__main__":
    main()
