"""Where did a failed off-table-block trial go? Its executed steps against the scripted push.

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.studies.block_trial_trace \\
        --run results/oracle/spec --tasks robodesk/flat_block_off_table \\
        [--instances 1 2] [--json outputs/diagnosis/block-trace.json]

A trial that never pushes its block off the desk failed either because the planner never found
the states that lead there (the *search*), or because the cost prefers states that do not (the
*cost*: a false optimum). This study tells the two apart without planning again. For each
trial record of a RoboDesk ``*_off_table`` task in ``--run``, it steps the environment through
the trial's executed actions from the instance's initial state, and through the instance's
scripted actions (after the same zero first action), and measures every frame:

* the block's progress along the scripted push: its horizontal displacement projected on the
  direction the scripted trajectory moves it, as a fraction of that trajectory's displacement
  at its first success (1 = as far as the scripted push takes it when it falls);
* the block's height, the hand's distance to the block, whether the other objects moved, and
  how many of the 64x64 frame's pixels show the block (those that change when it is taken
  out of the scene; the arm can hide it);
* the frame's planning cost (SPEC §6: ``w_pix`` × pixel SSE to the goal + ``w_cls`` × −logit,
  the terms the planner sums over a plan's frames) and the logit, with the registered
  classifier (the shipped one, or ``$VP2_CLASSIFIERS_DIR``'s for a trial planned with another)
  at the weight the trial's record names.

Each failed trial gets a verdict: *neighbour moved* (the block fell, or went as far as the
scripted push takes it, but another object moved, which the success rule forbids); *false
optimum* (the trial reached a frame the cost scores at least as well as the scripted push's
first success frame, with the block still on the desk: the cost prefers something that is not
success); *short* (no frame scored as well as success: the cost pointed the right way and the
planner did not get there). Seconds per trial (no planning; 15 + ≤ 13 frames).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import torch

from benchmarks import common
from benchmarks.studies.classifier_weight_tuning import with_weight
from vp2.data.suite import TaskSuite
from vp2.envs.robodesk import OBJECTS, OFF_TABLE_BELOW
from vp2.envs.tasks import get_task
from vp2.planning.agent import frames_to_tensor
from vp2.planning.planner import build_cost
from vp2.run.run_dir import TRIALS_FILE, read_trials
from vp2.utils.io import write_json_atomic


def visible_pixels(inst, target: str, states: list[np.ndarray]) -> list[int]:
    """Pixels of the 64x64 frame that change when ``target`` is taken out of the scene (moved
    10 m below the desk), per state: how much of the block the camera sees."""
    env = inst.make_env(observation_size=None)
    try:
        adr = env._object_qadr[OBJECTS.index(target)] + 2  # the free joint's z
        out = []
        for state in states:
            env.reset_to(state)
            seen = env.render(64).astype(int)
            env.data.qpos[adr] -= 10.0
            mujoco.mj_kinematics(env.model, env.data)
            hidden = env.render(64).astype(int)
            out.append(int((np.abs(seen - hidden).max(axis=-1) > 8).sum()))
        return out
    finally:
        env.close()


def trace(inst, actions: np.ndarray, cost) -> list[dict[str, Any]]:
    """Per frame (the initial one, then one per action): block position, hand distance,
    others moved, success, and the frame's cost terms."""
    task = get_task(inst.task)
    env = inst.make_env(observation_size=None)
    try:
        env.reset_to(inst.init_state)
        env.set_goal(inst.goal_state)
        others = [o for o in OBJECTS if o != task.target]
        start = env.original_object_positions
        rows, frames, states = [], [], []
        for k in range(len(actions) + 1):
            if k:
                env.step(env.check_action(actions[k - 1]))
            block = env.body_pos(task.target)
            rows.append({
                "step": k,
                "block": block.tolist(),
                "hand_to_block": float(np.linalg.norm(env.end_effector_pos - block)),
                "others_moved": [o for o in others
                                 if np.linalg.norm(env.body_pos(o) - start[o]) >= 0.01],
                "success": bool(env.is_success(inst.goal_state)),
            })  # fmt: skip
            frames.append(frames_to_tensor(env.render(64), torch.device("cpu")))
            states.append(env.get_state())
    finally:
        env.close()
    for row, pixels in zip(rows, visible_pixels(inst, task.target, states), strict=True):
        row["block_pixels"] = pixels
    batch = torch.stack(frames)[:, None]  # (T, 1, 3, 64, 64): each frame its own "plan"
    with torch.no_grad():
        terms = [t.double().numpy() for t in cost.breakdown(batch)]
    weight = cost.terms[1][0]
    for k, row in enumerate(rows):
        row["pixel_term"] = float(terms[0][k])
        row["classifier_term"] = float(terms[1][k])
        row["logit"] = float(-terms[1][k] / weight)
        row["cost"] = float(terms[0][k] + terms[1][k])
    return rows


def add_progress(rows: list[dict[str, Any]], start: np.ndarray, push: np.ndarray) -> None:
    """``progress``: horizontal displacement along ``push`` (the scripted displacement at its
    first success), as a fraction of it."""
    length = float(np.linalg.norm(push))
    for row in rows:
        moved = np.asarray(row["block"][:2]) - start
        row["progress"] = float(moved @ push / length**2) if length else 0.0


def summarise(inst, record: dict[str, Any], cost) -> dict[str, Any]:
    """The trial's trace and the scripted one's, with the comparisons the module names."""
    zero = np.zeros((1, inst.actions.shape[1]))
    scripted = trace(inst, np.concatenate([zero, inst.actions]), cost)
    executed = trace(inst, np.asarray(record["actions"], dtype=np.float64), cost)
    first = next((r["step"] for r in scripted if r["success"]), len(scripted) - 1)
    start = np.asarray(scripted[0]["block"][:2])
    push = np.asarray(scripted[first]["block"][:2]) - start
    add_progress(scripted, start, push)
    add_progress(executed, start, push)
    best = min(executed, key=lambda r: r["cost"])
    # the scripted frames from three steps before the first success up to it
    near = [r for r in scripted if first - 3 <= r["step"] <= first]
    return {
        "task": inst.task,
        "instance": inst.index,
        "success": bool(record["success"]),
        "scripted_success_step": first,
        "executed": executed,
        "scripted": scripted,
        "max_progress": max(r["progress"] for r in executed),
        "best_cost_step": best["step"],
        "best_cost": best["cost"],
        "scripted_near_success_cost": [r["cost"] for r in near],
        "verdict": verdict(executed, scripted[first], bool(record["success"])),
    }


def verdict(executed: list[dict[str, Any]], success_frame: dict[str, Any], solved: bool) -> str:
    """How a trial ended: ``solved``; ``neighbour moved`` (the block fell, or went further
    than the scripted push, but another object moved); ``false optimum`` (a frame scored at
    least as well as the scripted push's first success frame while the block stayed on the
    desk); ``short`` (no frame scored as well as success)."""
    if solved:
        return "solved"
    if any(r["block"][2] < OFF_TABLE_BELOW or r["progress"] >= 1.0 for r in executed):
        return "neighbour moved"
    if min(r["cost"] for r in executed) <= success_frame["cost"]:
        return "false optimum"
    return "short"


def planned_weight(record: dict[str, Any]) -> float | None:
    """The classifier weight the trial planned with, where its record says (a ``vp2 run``
    record's agent, or ``classifier_weight_tuning``'s ``weight``)."""
    if "weight" in record:
        return float(record["weight"])
    weight = (record.get("agent") or {}).get("classifier", {}).get("weight")
    return None if weight is None else float(weight)


def print_summary(s: dict[str, Any]) -> None:
    print(f"\n{s['task']}#{s['instance']}: trial {'solved' if s['success'] else 'failed'}; "
          f"scripted push first succeeds at step {s['scripted_success_step']}")  # fmt: skip
    print("| trace | step | progress | block z | block pixels | hand-block (m) | others moved | "
          "logit | pixel term | cost |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|---|")
    for name in ("scripted", "executed"):
        for r in s[name]:
            print(f"| {name} | {r['step']} | {r['progress']:+.2f} | {r['block'][2]:.3f} | "
                  f"{r['block_pixels']} | {r['hand_to_block']:.3f} | {','.join(r['others_moved']) or '-'} | "
                  f"{r['logit']:+.2f} | {r['pixel_term']:.0f} | {r['cost']:.0f} |")  # fmt: skip
    best, success = s["executed"][s["best_cost_step"]], s["scripted"][s["scripted_success_step"]]
    print(f"largest progress of the trial: {s['max_progress']:+.2f}; its best frame (step "
          f"{s['best_cost_step']}: logit {best['logit']:+.2f}, block pixels "
          f"{best['block_pixels']} of {s['executed'][0]['block_pixels']}, others moved: "
          f"{','.join(best['others_moved']) or '-'}) costs {s['best_cost']:.0f}, the scripted "
          f"success frame's logit {success['logit']:+.2f}; the scripted frames up to "
          f"success cost {', '.join(f'{c:.0f}' for c in s['scripted_near_success_cost'])}; "
          f"verdict: {s['verdict']}")  # fmt: skip


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--run", type=Path, required=True, help=f"a run directory ({TRIALS_FILE})")
    parser.add_argument("--tasks", nargs="+", default=["robodesk/flat_block_off_table"])
    parser.add_argument("--instances", type=int, nargs="*", help="default: every record's")
    parser.add_argument("--json", type=Path, help="also write the traces here")
    args = parser.parse_args()
    for task in args.tasks:
        if get_task(task).success != "off_table":
            parser.error(f"--tasks {task}: not an off-table block task")
    torch.set_num_threads(1)
    suite = TaskSuite.load()
    out = []
    for record in read_trials(args.run):
        if record["task"] not in args.tasks or record.get("error"):
            continue
        if args.instances and record["instance"] not in args.instances:
            continue
        inst = suite.get(record["task"], record["instance"])
        if record.get("instance_sha") and record["instance_sha"] != inst.fingerprint:
            parser.error(f"{inst.key}: the record's instance is not the shipped suite's")
        goal = frames_to_tensor(inst.goal_image, torch.device("cpu"))
        if (weight := planned_weight(record)) is not None:
            with_weight(record["task"], weight)
        cost, kind = build_cost(record["task"], goal, "spec")
        summary = summarise(inst, record, cost)
        print_summary(summary)
        out.append(summary)
    if args.json:
        write_json_atomic(args.json, {"command": vars(args) | {"json": str(args.json),
                                                               "run": str(args.run)},
                                      "trials": out})  # fmt: skip


if __name__ == "__main__":
    main()
