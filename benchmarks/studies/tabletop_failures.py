"""Why did the tabletop oracle trials fail? Their executed actions replayed, object by object.

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.studies.tabletop_failures \\
        --table results/oracle/samples-50 --out outputs/tabletop-failures

Success on the tabletop is the *maximum* over the four objects of the distance to the goal
(< 5 cm, SPEC §1.2), so a trial can fail in ways the success flag does not tell apart. Each
committed trial record (``results/oracle/<table>/trials.jsonl``) holds the executed actions;
stepping them from the instance's initial state gives every object's distance to its goal after
every step (no planning, no rendering: seconds per trial). A failed trial is put in the first
class that fits:

* ``pushed off``: the pushed object left the table (it ends 10 cm lower than it started);
* ``untouched``: the pushed object never got 5 mm closer to its goal than it started;
* ``neighbour disturbed``: the pushed object was within 5 cm at some step, but at every such
  step another object was not (success needs all four);
* ``short``: the pushed object got closer, never within 5 cm (a ball that rolls past its goal
  without stopping within 5 cm is here: its closest and final distances tell it apart).

A replay that does not reproduce the record's outcome is reported as such (the record's success
flag against the replay's), so the classes are of trials this machine reproduces.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np

from benchmarks import common
from vp2.run.run_dir import TRIALS_FILE, RunDir, read_trials
from vp2.utils.io import write_json_atomic

#: Success threshold of the tabletop (SPEC §1.2), metres.
THRESHOLD = 0.05
#: How much closer than at the start the pushed object must come to count as touched, metres.
TOUCHED = 0.005
#: Classes of a failed trial, in the order they are tested.
CLASSES = ("pushed off", "untouched", "neighbour disturbed", "short")


def distances(record: dict, suite=None) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
    """``(steps + 1, 4)`` every object's distance to its goal after every executed action (row
    0: the initial state), ``(steps + 1, 4)`` object heights, the pushed object's index, and
    ``(steps + 1, 4)``: the hand's distance to its position in the goal state, then its x, y, z."""
    from vp2.data.suite import TaskSuite
    from vp2.envs.tabletop import OBJECT_NAMES, TabletopEnv

    suite = suite or TaskSuite.load()
    inst = suite.get(record["task"], int(record["instance"]))
    if inst.fingerprint != record["instance_sha"]:
        raise ValueError(f"{record['task']}#{record['instance']}: another suite version")
    goal = TabletopEnv.object_positions_from_state(inst.goal_state)
    env = inst.make_env(observation_size=None)
    try:
        env.reset_to(inst.goal_state)
        hand_goal = env.end_effector_position().copy()
        env.reset_to(inst.init_state)
        rows, hands = [env.object_positions().copy()], [env.end_effector_position().copy()]
        for action in np.asarray(record["actions"], dtype=np.float64):
            env.step(env.check_action(action))
            rows.append(env.object_positions().copy())
            hands.append(env.end_effector_position().copy())
    finally:
        env.close()
    pos = np.stack(rows)
    pushed = OBJECT_NAMES.index(record["task"].split("push_")[1])
    hands = np.stack(hands)
    hand = np.concatenate([np.linalg.norm(hands - hand_goal[None], axis=-1)[:, None], hands], 1)
    return np.linalg.norm(pos - goal[None], axis=-1), pos[..., 2], pushed, hand


def classify(dist: np.ndarray, height: np.ndarray, pushed: int) -> str:
    """The class of a trial (``"solved"`` when every object is within the threshold at some
    step), from :func:`distances`' arrays."""
    if (dist.max(axis=1) < THRESHOLD).any():
        return "solved"
    d = dist[:, pushed]
    if height[-1, pushed] < height[0, pushed] - 0.1:
        return "pushed off"
    if d.min() > d[0] - TOUCHED:
        return "untouched"
    if (d < THRESHOLD).any():  # not solved: at each such step another object was out
        return "neighbour disturbed"
    return "short"


def analyse(table: Path) -> list[dict]:
    from vp2.data.suite import TaskSuite

    suite = TaskSuite.load()
    out = []
    records = [r for r in read_trials(table) if r["task"].startswith("tabletop/")]
    for i, record in enumerate(records):
        dist, height, pushed, hand = distances(record, suite)
        label = classify(dist, height, pushed)
        d = dist[:, pushed]
        others = np.delete(dist, pushed, axis=1)
        out.append({
            "task": record["task"], "instance": int(record["instance"]),
            "recorded_success": bool(record["success"]), "replayed": label,
            "reproduced": (label == "solved") == bool(record["success"]),
            "start_cm": round(100 * float(d[0]), 1), "closest_cm": round(100 * float(d.min()), 1),
            "final_cm": round(100 * float(d[-1]), 1),
            "neighbour_max_cm": round(100 * float(others.max()), 1),
            "hand_start_cm": round(100 * float(hand[0, 0]), 1),
            "hand_closest_cm": round(100 * float(hand[:, 0].min()), 1),
            "hand_rise_cm": round(100 * float(hand[:, 3].max() - hand[0, 3]), 1),
        })
        print(f"[{i + 1}/{len(records)}] {record['task']}#{record['instance']}: {label} "
              f"(pushed object {out[-1]['start_cm']} → closest {out[-1]['closest_cm']} → "
              f"final {out[-1]['final_cm']} cm)", flush=True)
    return out


def markdown(rows: list[dict], command: str) -> str:
    tasks = sorted({r["task"] for r in rows})
    labels = ("solved", *CLASSES)
    lines = [f"Command: `{command}`", "",
             "| category | " + " | ".join(labels) + " |",
             "|---|" + "---|" * len(labels)]
    for task in [*tasks, "all"]:
        rs = [r for r in rows if task in ("all", r["task"])]
        c = Counter(r["replayed"] for r in rs)
        name = "**all**" if task == "all" else task.split("/")[1]
        lines.append(f"| {name} | " + " | ".join(str(c.get(k, 0)) for k in labels) + " |")
    failed = [r for r in rows if r["replayed"] != "solved"]
    if failed:
        def med(key: str) -> float:
            return float(np.median([r[key] for r in failed]))
        lines += ["", f"Failed trials ({len(failed)}), medians: pushed object "
                  f"{med('start_cm'):.1f} cm from its goal at the start, closest {med('closest_cm'):.1f} "
                  f"cm; the hand {med('hand_start_cm'):.1f} cm from its goal position at the start, "
                  f"closest {med('hand_closest_cm'):.1f} cm; its highest rise above its start "
                  f"{med('hand_rise_cm'):.1f} cm."]
    bad = [r for r in rows if not r["reproduced"]]
    lines += ["", f"Replays that do not reproduce the recorded outcome: {len(bad)} of {len(rows)}."]
    lines += ["", "| trial | class | pushed object: start / closest / final (cm) | "
              "farthest neighbour (cm) | hand to its goal position: start / closest (cm) | "
              "hand's highest rise (cm) |", "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['task'].split('/')[1]} #{r['instance']} | {r['replayed']} | "
                     f"{r['start_cm']} / {r['closest_cm']} / {r['final_cm']} | "
                     f"{r['neighbour_max_cm']} | {r['hand_start_cm']} / {r['hand_closest_cm']} | "
                     f"{r['hand_rise_cm']} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    p = common.argument_parser(__spec__.name, __doc__)
    p.add_argument("--table", type=Path, default=Path("results/oracle/samples-50"),
                   help=f"a folder with {TRIALS_FILE} (a shipped table's records or a run)")
    p.add_argument("--out", type=Path, default=Path("outputs/tabletop-failures"))
    args = p.parse_args(argv)
    if not RunDir(args.table).trials_file.is_file():
        raise SystemExit(f"--table {args.table} has no {TRIALS_FILE}")
    rows = analyse(args.table)
    args.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out / "failures.json", rows)
    text = markdown(rows, common.command_line(__spec__.name, argv))
    (args.out / "failures.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
