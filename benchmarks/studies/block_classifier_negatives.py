"""Do exploration frames stop a block classifier taking a half-hidden block for a fallen one?

    MUJOCO_GL=egl OMP_NUM_THREADS=1 .venv/bin/python -m benchmarks.studies.block_classifier_negatives \\
        --data data/robodesk-blocks-100x-64px --out outputs/block-negatives \\
        [--tasks flat_block_off_table] [--rollouts 8] [--steps 4000]

The off-table blocks' classifiers are trained on scripted pushes, in which a block that leaves
the camera's view has fallen. The planner finds poses that hide half the block behind the
raised arm, and the classifier scores them above real success (``block_trial_trace``). SPEC
§9 leaves the classifiers' data free, so this study adds frames of the kind the planner visits:
*exploration* rollouts from the initial states of tuning instances (#10 and up, never the
reported #0–#9), the zero action and then 14 actions drawn by the planner's own sampler
(SPEC §5's correlated noise around a zero mean), labelled as the dataset labels its frames
(the progress label from the dense reward, which is 0 where the block stays on the desk).

Per task it trains two classifiers with the shipped settings (the progress label, the network
and steps of the shipped file): **base**, on the dataset's training trajectories, and
**explore**, on those plus the exploration rollouts of tuning instances #10–#21. Both are scored
on (1) the dataset's held-out trajectories (accuracy against the paper's label, as the shipped
metrics), (2) the held-out exploration rollouts of #22–#29 (the share of frames with the block
on the desk that score as success), and (3) the executed frames of the committed oracle trials
that failed (``results/oracle/samples-50`` and ``results/oracle/spec``), every one
of them with the block on the desk: the share scored as success and the largest logit. The shipped
classifier is scored beside them. With ``--mined``, a third classifier, **mined**, adds
the frames of the oracle's own trials on tuning instances (hard negatives: the poses a planner
finds against the classifier), repeated ``--mined-repeat`` times. Each classifier is written
to ``--out/<variant>/<task>.pt``,
so ``VP2_CLASSIFIERS_DIR=--out/explore`` plans with it. About 5 CPU-minutes per task (rollouts
and two trainings), 10 with ``--width 2`` (the upright block's).
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any

import numpy as np
import torch

from benchmarks import common
from vp2.classifiers.checkpoint import load_classifier, read_classifier_checkpoint, save_classifier
from vp2.classifiers.data import (
    FrameSet,
    load_frames,
    progress_targets,
    progress_threshold,
)
from vp2.classifiers.registry import ASSETS_DIR
from vp2.classifiers.train import (
    ClassifierTrainConfig,
    classification_metrics,
    predict_logits,
    train_classifier,
)
from vp2.data.suite import TaskSuite
from vp2.envs.robodesk import DENSE_LABEL_THRESHOLD, OFF_TABLE_BELOW
from vp2.planning.samplers import CorrelatedNoiseSampler
from vp2.run.run_dir import TRIALS_FILE, RunDir, read_trials
from vp2.spec import SIGMA
from vp2.utils.io import write_json_atomic

TRAIN_INSTANCES = range(10, 22)
HELDOUT_INSTANCES = range(22, 30)
STEPS = 15
_RESULTS = Path(__file__).resolve().parents[2] / "results"
RECORDS = (_RESULTS / "oracle" / "samples-50", _RESULTS / "oracle" / "spec")


def rollout(inst, actions: np.ndarray) -> dict[str, np.ndarray]:
    """Frames (64 px), paper labels and whether the block is on the desk, per frame, of
    ``actions`` from the instance's initial state (frame 0 is the initial one)."""
    env = inst.make_env(observation_size=None)
    env.track_dense_reward = True
    target = inst.task.split("/")[1].removesuffix("_off_table")
    try:
        frames, positive, on_desk = [env.render(64)], [False], [True]
        on_desk[0] = env.body_pos(target)[2] >= OFF_TABLE_BELOW
        for action in actions:
            _, _, _, _, info = env.step(env.check_action(action))
            frames.append(env.render(64))
            positive.append(info["dense_reward"] >= DENSE_LABEL_THRESHOLD)
            on_desk.append(env.body_pos(target)[2] >= OFF_TABLE_BELOW)
    finally:
        env.close()
    return {"images": np.stack(frames), "positive": np.array(positive),
            "on_desk": np.array(on_desk)}  # fmt: skip


def as_frameset(parts: list[dict[str, np.ndarray]], first_id: int) -> FrameSet:
    """Rollouts (:func:`rollout`) as one progress-label :class:`FrameSet`, trajectory ids
    counted from ``first_id`` (clear of the dataset's)."""
    return FrameSet(
        np.concatenate([r["images"] for r in parts]),
        np.concatenate([r["positive"] for r in parts]),
        np.concatenate([np.full(len(r["positive"]), first_id + i) for i, r in enumerate(parts)]),
        np.concatenate([np.arange(len(r["positive"])) for r in parts]),
        np.concatenate([progress_targets(r["positive"]) for r in parts]),
        progress_threshold(),
    )  # fmt: skip


def exploration(task: str, instances, rollouts: int, seed: int) -> tuple[FrameSet, np.ndarray]:
    """Exploration rollouts from the instances' initial states, as a progress-label
    :class:`FrameSet`, and each frame's on-desk flag."""
    suite = TaskSuite.load()
    sampler = CorrelatedNoiseSampler()
    generator = torch.Generator().manual_seed(seed)
    parts = []
    for index in instances:
        inst = suite.get(task, index)
        plans = sampler.sample(torch.zeros(STEPS - 1, 5), SIGMA["robodesk"], rollouts, generator)
        for plan in plans.double().numpy():
            parts.append(rollout(inst, np.concatenate([np.zeros((1, 5)), plan])))
    return as_frameset(parts, 10_000), np.concatenate([r["on_desk"] for r in parts])


def trial_frames(task: str) -> np.ndarray:
    """The executed frames, block on the desk, of the committed failed oracle trials of
    ``task`` (``RECORDS``)."""
    suite = TaskSuite.load()
    out = []
    for run in RECORDS:
        for record in read_trials(run):
            if record["task"] != task or record["success"] or record.get("error"):
                continue
            r = rollout(suite.get(task, record["instance"]), np.asarray(record["actions"]))
            out.append(r["images"][r["on_desk"]])
    return np.concatenate(out)


def mined(task: str, runs: list[Path], repeat: int) -> FrameSet | None:
    """Frames of the oracle's own trials on tuning instances (``runs``: trial files with the
    executed actions, e.g. ``classifier_weight_tuning``'s), labelled as the dataset's, each
    repeated ``repeat`` times."""
    suite = TaskSuite.load()
    parts = []
    for run in runs:
        for line in RunDir(run).trials_file.read_text().splitlines():
            record = json.loads(line)
            if record["task"] != task or "actions" not in record:
                continue
            if record["instance"] < 10:
                raise SystemExit(f"{run}: instance #{record['instance']} is a reported one; "
                                 "mine tuning instances (#10 and up) only")  # fmt: skip
            r = rollout(suite.get(task, record["instance"]), np.asarray(record["actions"]))
            parts.append(r)
    return as_frameset(parts * repeat, 20_000) if parts else None


def concat(a: FrameSet, b: FrameSet) -> FrameSet:
    return FrameSet(
        np.concatenate([a.images, b.images]), np.concatenate([a.labels, b.labels]),
        np.concatenate([a.trajectories, b.trajectories]), np.concatenate([a.steps, b.steps]),
        np.concatenate([a.training_targets(), b.training_targets()]), a.threshold,
    )  # fmt: skip


def score(model, valid: FrameSet, explore: FrameSet, explore_desk: np.ndarray,
          trials: np.ndarray) -> dict[str, Any]:  # fmt: skip
    """The three scores the module names."""
    t = valid.threshold
    held = classification_metrics(predict_logits(model, valid.images), valid.labels, t)
    on_desk = predict_logits(model, explore.images[explore_desk])
    trial = predict_logits(model, trials)
    return {
        "heldout_accuracy": held["accuracy"],
        "heldout_recall": held["recall"],
        "explore_on_desk_frames": int(len(on_desk)),
        "explore_false_success": float((on_desk > t).mean()),
        "explore_logit_p99": float(np.percentile(on_desk, 99)),
        "trial_frames": int(len(trial)),
        "trial_false_success": float((trial > t).mean()),
        "trial_logit_max": float(trial.max()),
    }


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__)
    parser.add_argument("--data", type=Path, required=True, help="vp2 collect robodesk dataset")
    parser.add_argument("--tasks", nargs="+", default=["flat_block_off_table"])
    parser.add_argument("--rollouts", type=int, default=8, help="per tuning instance")
    parser.add_argument("--steps", type=int, help="training steps (default: the shipped file's)")
    parser.add_argument("--mined", type=Path, nargs="*", default=[],
                        help="directories of oracle trials on tuning instances with their "
                        f"actions ({TRIALS_FILE}): a third variant adds their frames")
    parser.add_argument("--mined-repeat", type=int, default=10)
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)
    results = {}
    for task in args.tasks:
        full = f"robodesk/{task}"
        shipped_path = ASSETS_DIR / f"{task}.pt"
        shipped_meta = read_classifier_checkpoint(shipped_path)["meta"]
        training = shipped_meta["training"]
        config = ClassifierTrainConfig(**{
            k: training[k] for k in dataclasses.asdict(ClassifierTrainConfig()) if k in training
        })  # fmt: skip
        if args.steps:
            config = dataclasses.replace(config, steps=args.steps)
        train = load_frames(args.data, task, "train", "progress")
        valid = load_frames(args.data, task, "valid", "progress")
        explore_train, _ = exploration(full, TRAIN_INSTANCES, args.rollouts, seed=0)
        explore_held, desk_held = exploration(full, HELDOUT_INSTANCES, args.rollouts, seed=1)
        trials = trial_frames(full)
        print(f"{full}: {len(train)} training frames, {len(explore_train)} exploration frames "
              f"({int(explore_train.labels.sum())} positive), {len(trials)} failed-trial frames",
              flush=True)  # fmt: skip
        rows = {"shipped": score(load_classifier(shipped_path), valid, explore_held, desk_held,
                                 trials)}  # fmt: skip
        variants = [("base", train), ("explore", concat(train, explore_train))]
        hard = mined(full, args.mined, args.mined_repeat) if args.mined else None
        if hard is not None:
            print(f"  mined: {len(hard) // args.mined_repeat} frames from the tuning trials, "
                  f"x{args.mined_repeat}", flush=True)  # fmt: skip
            variants.append(("mined", concat(concat(train, explore_train), hard)))
        for variant, frames in variants:
            model = train_classifier(frames, config, log_every=10**9)
            rows[variant] = score(model, valid, explore_held, desk_held, trials)
            meta = {**shipped_meta, "heldout": None, "date": None,
                    "command": f"python -m {__spec__.name} (variant {variant})",
                    "data": {"dataset": str(args.data), "exploration": variant == "explore"}}
            save_classifier(args.out / variant / f"{task}.pt", model, meta)
            print(f"  {variant}: {json.dumps(rows[variant])}", flush=True)
        print(f"  shipped: {json.dumps(rows['shipped'])}", flush=True)
        results[full] = {"config": dataclasses.asdict(config), "rows": rows}
        write_json_atomic(args.out / "results.json", {"command": vars(args) | {
            "data": str(args.data), "out": str(args.out)}, "results": results})  # fmt: skip


if __name__ == "__main__":
    main()
