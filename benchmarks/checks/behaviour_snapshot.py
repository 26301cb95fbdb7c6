"""Snapshot of vp2's observable behaviour, to prove a restructuring changed nothing.

Writes into OUT: every ``--help`` text, the trial records of a small multi-task, multi-seed
``vp2 run`` of the repeat-last-frame baseline, the random agent and the simulator oracle (timings
removed), and, for every model family, the weights of a 2-step training run and its predictions
on a fixed batch (as SHA-256 digests). Run it before and after a change and compare::

    python -m benchmarks.checks.behaviour_snapshot --out outputs/snapshot-before
    ... change ...
    python -m benchmarks.checks.behaviour_snapshot --out outputs/snapshot-after \\
        --work outputs/snapshot-before/work
    diff -r outputs/snapshot-before/result outputs/snapshot-after/result

``--skip-models`` / ``--skip-runs`` leave parts out. The working directory (datasets, runs) is
``OUT/work``; only ``OUT/result`` is meant to be compared.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

from benchmarks.common import argument_parser
from vp2.run.run_dir import RunDir

VP2 = [sys.executable, "-m", "vp2.cli"]
#: Keys of a trial record that are timings or host facts, not behaviour.
VOLATILE = {"wall_time", "timings", "time", "elapsed", "hostname", "host", "started", "finished",
            "seconds", "duration", "pid", "worker", "finished_at", "started_at",
            "written_at", "train_seconds"}
FAMILIES = {"svg_prime": "m0.25k0.25", "fitvid": "mini", "struct_vrnn": "tiny",
            "mcvd": "tiny", "maskvit_tokenizer": "tiny"}


def sh(args: list[str], **kw) -> subprocess.CompletedProcess:
    return subprocess.run(args, capture_output=True, text=True, **kw)


def helps(result: Path) -> None:
    from vp2.cli import COMMAND_MODULES

    out = result / "help"
    out.mkdir(parents=True, exist_ok=True)
    commands = [[]] + [[name] for name in COMMAND_MODULES] + [["tasks", s] for s in
                                                     ("generate", "list", "show")]
    for cmd in commands:
        p = sh(VP2 + cmd + ["--help"], env={**os.environ, "COLUMNS": "100"})
        name = "_".join(cmd) or "vp2"
        (out / f"{name}.txt").write_text(p.stdout + p.stderr)


def strip(obj):
    if isinstance(obj, dict):
        return {k: strip(v) for k, v in sorted(obj.items())
                if k not in VOLATILE and not k.endswith("_seconds") and not k.endswith("_time")
                and not k.endswith("_s")}
    if isinstance(obj, list):
        return [strip(v) for v in obj]
    return obj


def runs(result: Path, work: Path) -> None:
    out = result / "runs"
    out.mkdir(parents=True, exist_ok=True)
    common = ["--tasks", "robodesk/push_red", "robodesk/open_drawer", "tabletop/push_sphere",
              "--num-instances", "1", "--seeds", "0", "1", "--num-steps", "3", "--no-progress",
              "--workers", "1"]
    plans = {
        "repeat_last_frame": ["--model", "repeat_last_frame", "--num-samples", "16"],
        "random": ["--agent", "random"],
        "simulator": ["--model", "simulator", "--num-samples", "6"],
    }
    for label, extra in plans.items():
        run_dir = work / "runs" / label
        if run_dir.exists():
            shutil.rmtree(run_dir)
        p = sh(VP2 + ["run", "--out", str(run_dir)] + common + extra)
        (out / f"{label}.log").write_text(f"rc={p.returncode}\n")
        trials = RunDir(run_dir).trials_file
        lines = trials.read_text().splitlines() if trials.exists() else []
        records = sorted((strip(json.loads(line)) for line in lines),
                         key=lambda r: json.dumps(r, sort_keys=True))
        (out / f"{label}.trials.json").write_text(json.dumps(records, indent=1, sort_keys=True))
        print(f"run {label}: rc {p.returncode}, {len(records)} trials", flush=True)
        if p.returncode:
            print(p.stderr[-2000:], flush=True)


def digest(t) -> str:
    import torch

    t = t.detach().cpu().contiguous()
    if t.dtype == torch.bfloat16:
        t = t.float()
    return hashlib.sha256(t.numpy().tobytes()).hexdigest()[:16]


def tensors(node, prefix: str = "") -> dict[str, str]:
    """Every tensor in a nested checkpoint payload, by its key path, as a digest; other leaves
    (configs, step counters) by their repr."""
    import torch

    if torch.is_tensor(node):
        return {prefix: digest(node)}
    if isinstance(node, dict):
        out: dict[str, str] = {}
        for k, v in sorted(node.items(), key=lambda kv: str(kv[0])):
            out.update(tensors(v, f"{prefix}/{k}"))
        return out
    if isinstance(node, (list, tuple)) and any(torch.is_tensor(v) or isinstance(v, dict)
                                               for v in node):
        out = {}
        for i, v in enumerate(node):
            out.update(tensors(v, f"{prefix}[{i}]"))
        return out
    if isinstance(node, float | int | str | bool | type(None)):
        return {prefix: repr(node)}
    return {prefix: type(node).__name__}


def models(result: Path, work: Path) -> None:
    import torch

    out = result / "models"
    out.mkdir(parents=True, exist_ok=True)
    data = work / "data-robodesk"
    if not (data / "COMPLETE").exists() and not any(data.glob("*.h5")):
        p = sh(VP2 + ["collect", "robodesk", "-n", "2", "--out", str(data), "--workers", "1"])
        assert p.returncode == 0, p.stderr[-2000:]
    from vp2.models.registry import load_model

    g = torch.Generator().manual_seed(0)
    context = torch.rand(2, 2, 3, 64, 64, generator=g)
    for family, preset in FAMILIES.items():
        run_dir = work / "train" / family
        if run_dir.exists():
            shutil.rmtree(run_dir)
        p = sh(VP2 + ["train", "--model", family, "--preset", preset, "--data", str(data),
                      "--steps", "2", "--batch-size", "2", "--out", str(run_dir), "--no-progress",
                      "--no-tensorboard", "--eval-interval", "2", "--eval-batches", "1",
                      "--workers", "0", "--seed", "3"])
        lines = {"rc": p.returncode}
        if p.returncode:
            lines["stderr"] = p.stderr[-1500:]
            print(family, p.stderr[-1500:], flush=True)
        else:
            ckpts = sorted(run_dir.rglob("*.pt"))
            for ck in ckpts:
                state = torch.load(ck, map_location="cpu", weights_only=False)
                lines[f"checkpoint:{ck.relative_to(run_dir)}"] = tensors(state)
            if family != "maskvit_tokenizer":
                try:
                    model = load_model(str(run_dir), device="cpu")
                    torch.manual_seed(0)
                    actions = torch.rand(2, model.num_context + model.num_future - 1,
                                         model.action_dim, generator=g) * 2 - 1
                    with torch.no_grad():
                        lines["prediction"] = digest(model.predict(context, actions))
                except Exception as exc:  # noqa: BLE001 - recorded, compared
                    lines["prediction_error"] = repr(exc)[:300]
        (out / f"{family}.json").write_text(json.dumps(lines, indent=1, sort_keys=True))
        print(f"model {family}: rc {p.returncode}", flush=True)
    shipped = load_model("src/vp2/assets/models/svg_prime_tiny_robodesk.pt", device="cpu")
    torch.manual_seed(0)
    actions = torch.rand(2, 11, shipped.action_dim, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        (out / "shipped_svg_prime.txt").write_text(digest(shipped.predict(context, actions)))


def main() -> int:
    ap = argument_parser(__spec__.name, __doc__, full_doc=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--skip-models", action="store_true")
    ap.add_argument("--skip-runs", action="store_true")
    ap.add_argument("--skip-help", action="store_true")
    ap.add_argument("--work", help="working directory (default: OUT/work); share it between the "
                    "two snapshots so that recorded paths (the dataset's) are the same")
    args = ap.parse_args()
    out = Path(args.out)
    result, work = out / "result", Path(args.work) if args.work else out / "work"
    work.mkdir(parents=True, exist_ok=True)
    if not args.skip_help:
        helps(result)
    if not args.skip_models:
        models(result, work)
    if not args.skip_runs:
        runs(result, work)
    return 0


if __name__ == "__main__":
    sys.exit(main())
