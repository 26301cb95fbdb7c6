"""Train the models of the paper's analyses at one equal budget: Table 1's loss variants and the
ensemble's members (docs/paper.md).

Every variant is a ``vp2 train`` run with the zoo's recipe for its family (the preset and
model settings of ``benchmarks.comparison``'s ``FAMILIES``, batch 8, the family's own learning
rate, no validation during training) for the same number of steps; variants differ only in
the loss (MSE, + LPIPS-VGG × 1, + LPIPS-VGG × 10: the paper's loss used VGG features) or
the seed. Runs go in parallel processes
(``--jobs``), each resumable; each finished run is exported (float16, inference only) to
``OUT/export/<name>.pt`` and described in ``OUT/variants.json`` (steps reached, minutes,
device). ``--pack DIR`` also writes the exports and ``variants.json`` as tar files of at most
15 MiB each, which is how they come back from a lent GPU machine::

    python -m benchmarks.paper.train_variants --data data/robodesk-20x-64px \\
        --out outputs/paper/train --jobs 9 --device cuda
    python -m benchmarks.paper.train_variants --list

Table 1's variants exist for both environments (``svg-robodesk-mse-s0``,
``svg-tabletop-mse-s0``, ...); the ensemble's members for RoboDesk. Each ``--data`` dataset
serves the variants of its environment (read from its manifest); without ``--only``, every
variant of the given datasets' environments trains.

The same command on a CPU trains the same variants (about 2 core-hours each at 6,000 steps
with MSE; the LPIPS-VGG loss costs far more on a CPU).
"""

from __future__ import annotations

import dataclasses
import json
import os
import subprocess
import sys
import tarfile
import time
from collections.abc import Mapping, Sequence
from pathlib import Path

from benchmarks.common import argument_parser, command_line

#: Steps of every variant: about the zoo's 120-core-minute round (SVG' 5,995, FitVid 5,764).
STEPS = 6000
BATCH_SIZE = 8


@dataclasses.dataclass(frozen=True)
class Variant:
    """One training run: a family with the zoo's recipe, a loss and a seed."""

    name: str
    family: str
    preset: str
    model_args: tuple[str, ...] = ()
    perceptual_weight: float = 0.0
    seed: int = 0
    env: str = "robodesk"

    def train_args(self, data: str, out: Path, steps: int, device: str,
                   max_minutes: float | None) -> list[str]:
        args = ["train", "--model", self.family, "--preset", self.preset,
                "--data", data, "--steps", str(steps), "--batch-size", str(BATCH_SIZE),
                "--seed", str(self.seed), "--out", str(out), "--device", device,
                "--no-amp", "--workers", "0", "--eval-interval", "0", "--ckpt-interval", "1000",
                "--keep-checkpoints", "1", "--log-interval", "100", "--no-tensorboard",
                "--no-progress"]
        if self.model_args:
            args += ["--model-arg", *self.model_args]
        if self.perceptual_weight:
            args += ["--perceptual", "lpips_vgg", "--perceptual-weight", f"{self.perceptual_weight:g}"]
        if max_minutes is not None:
            args += ["--max-minutes", f"{max_minutes:g}"]
        if (out / "checkpoints").is_dir() and any((out / "checkpoints").glob("step_*.pt")):
            args.append("--resume")
        return args


SVG = ("svg_prime", "m0.25k0.25", ("m=0.125", "k=0.125"))
FITVID = ("fitvid", "mini", ())
#: The environments of Table 1's variants (the ensemble's members are RoboDesk's).
ENVS = ("robodesk", "tabletop")


def _variants() -> dict[str, Variant]:
    found: list[Variant] = []
    for env in ENVS:
        for family, preset, margs in (SVG, FITVID):
            short = "svg" if family == "svg_prime" else family
            for weight, tag in ((0.0, "mse"), (1.0, "lpips1"), (10.0, "lpips10")):
                found.append(Variant(f"{short}-{env}-{tag}-s0", family, preset, margs, weight, 0,
                                     env))
    # The ensemble's members: SVG' with MSE, seeds 0 (the Table 1 MSE run) to 3.
    for seed in (1, 2, 3):
        found.append(Variant(f"svg-robodesk-mse-s{seed}", *SVG, 0.0, seed))
    return {v.name: v for v in found}


VARIANTS = _variants()


def train_all(names: Sequence[str], data: Mapping[str, str], out: Path, jobs: int, steps: int,
              device: str, max_minutes: float | None) -> dict[str, dict]:
    """Runs the variants ``names`` (``jobs`` at a time) on ``data[variant.env]``, exports each;
    returns their records."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "export").mkdir(exist_ok=True)
    (out / "logs").mkdir(exist_ok=True)
    pending = list(names)
    running: dict[str, tuple[subprocess.Popen, float]] = {}
    records: dict[str, dict] = {}
    while pending or running:
        while pending and len(running) < jobs:
            name = pending.pop(0)
            run_dir = out / "runs" / name
            variant = VARIANTS[name]
            cmd = [sys.executable, "-m", "vp2.cli", *variant.train_args(
                data[variant.env], run_dir, steps, device, max_minutes)]
            log = open(out / "logs" / f"{name}.log", "a")  # noqa: SIM115 - closed with the process
            running[name] = (subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT,
                                              env=child_env(jobs)), time.time())
            print(f"started {name}", flush=True)
        time.sleep(2)
        for name, (proc, start) in list(running.items()):
            if proc.poll() is None:
                continue
            del running[name]
            records[name] = finish(name, out, proc.returncode, time.time() - start, device)
            print(f"finished {name}: {records[name]}", flush=True)
    return records


def child_env(jobs: int) -> dict[str, str]:
    """The environment of a training process: the machine's cores shared between the ``jobs``
    processes, where torch would start one thread per core in each. With torch's default
    threads, 9 runs on a 16-core H200 machine made 0.75-0.95 steps/s each, FitVid without
    LPIPS as slowly as SVG' with it, which points at the CPU side (docs/findings/paper.md)."""
    threads = str(max(1, (os.cpu_count() or 1) // max(1, jobs)))
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env.setdefault(var, threads)
    return env


def finish(name: str, out: Path, returncode: int, seconds: float, device: str) -> dict:
    """Exports a finished run and returns what ``variants.json`` records of it."""
    record = {**dataclasses.asdict(VARIANTS[name]), "returncode": returncode,
              "wall_seconds": round(seconds, 1), "device": device_label(device)}
    if returncode != 0:
        return record
    from vp2.models.checkpoint import read_model_checkpoint
    from vp2.training.export import export_checkpoint

    dst = export_checkpoint(out / "runs" / name, out / "export" / f"{name}.pt")
    record["steps"] = int(read_model_checkpoint(dst).get("step", -1))
    return record


def device_label(device: str) -> str:
    import torch

    if device.startswith("cuda") and torch.cuda.is_available():
        return f"{device} ({torch.cuda.get_device_name(0)})"
    import platform

    return f"cpu ({platform.processor() or platform.machine()}, {os.cpu_count()} cores)"


def pack(out: Path, dest: Path, limit: int = 15 * 2**20) -> list[Path]:
    """Writes ``variants.json``, the exports and the training logs' metrics as tar files of at
    most ``limit`` bytes each."""
    dest.mkdir(parents=True, exist_ok=True)
    files = [out / "variants.json", *sorted((out / "export").glob("*.pt")),
             *sorted((out / "runs").glob("*/metrics.csv"))]
    groups: list[list[Path]] = [[]]
    size = 0
    for f in files:
        if groups[-1] and size + f.stat().st_size > limit:
            groups.append([])
            size = 0
        groups[-1].append(f)
        size += f.stat().st_size
    written = []
    for i, group in enumerate(groups):
        path = dest / f"variants-{i}.tar"
        with tarfile.open(path, "w") as tar:
            for f in group:
                tar.add(f, arcname=str(f.relative_to(out)))
        written.append(path)
    return written


def datasets_by_env(paths: Sequence[str]) -> dict[str, str]:
    """``{env: path}`` of the datasets, each environment read from the dataset's manifest.

    Raises:
        ValueError: a path that is not a dataset, or two datasets of one environment.
    """
    from vp2.data.storage import DatasetError, load_manifest

    found: dict[str, str] = {}
    for path in paths:
        if not Path(path).is_dir():
            raise ValueError(f"--data {path}: no dataset there (make it with `vp2 collect ENV`)")
        try:
            env = load_manifest(path)["config"]["env"]
        except (DatasetError, KeyError) as exc:
            raise ValueError(f"--data {path}: {exc}") from exc
        if env in found:
            raise ValueError(f"--data: two {env} datasets ({found[env]}, {path}); give one")
        found[env] = path
    return found


def variants_for(only: Sequence[str] | None, data: Mapping[str, str]) -> list[str]:
    """The variants to train: ``only``, each of whose environment needs a dataset in ``data``;
    by default every variant of ``data``'s environments.

    Raises:
        ValueError: a variant of an environment without a dataset.
    """
    if only is None:
        return [n for n, v in VARIANTS.items() if v.env in data]
    missing = sorted({VARIANTS[n].env for n in only} - set(data))
    if missing:
        raise ValueError(f"--only: no --data for {', '.join(missing)} (give its dataset, e.g. "
                         f"data/{missing[0]}-...-64px)")
    return list(only)


def main(argv: Sequence[str] | None = None) -> int:
    ap = argument_parser(__spec__.name, __doc__, full_doc=True)
    ap.add_argument("--data", nargs="+", default=["data/robodesk-20x-64px"],
                    help="datasets, at most one per environment (its variants train on it)")
    ap.add_argument("--out", default="outputs/paper/train")
    ap.add_argument("--only", nargs="+", choices=sorted(VARIANTS), help="these variants only")
    ap.add_argument("--jobs", type=int, default=1, help="runs at a time")
    ap.add_argument("--steps", type=int, default=STEPS)
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--max-minutes", type=float, default=None,
                    help="stop a run early at this many minutes (recorded: steps reached)")
    ap.add_argument("--pack", type=Path, help="also write the results as tar files here")
    ap.add_argument("--list", action="store_true", help="print the variants and exit")
    args = ap.parse_args(argv)
    if args.list:
        for v in VARIANTS.values():
            print(f"{v.name}: vp2 " + " ".join(v.train_args(f"DATA[{v.env}]", Path("RUN"),
                                                           args.steps, args.device, None)))
        return 0
    try:
        data = datasets_by_env(args.data)
        names = variants_for(args.only, data)
    except ValueError as exc:
        ap.error(str(exc))
    out = Path(args.out)
    records = train_all(names, data, out, args.jobs, args.steps, args.device,
                        args.max_minutes)
    index = out / "variants.json"
    old = json.loads(index.read_text()) if index.exists() else {}
    old.update({"command": command_line(__spec__.name), "steps": args.steps, "batch_size": BATCH_SIZE})
    old.setdefault("variants", {}).update(records)
    index.write_text(json.dumps(old, indent=1, sort_keys=True) + "\n")
    if args.pack:
        for p in pack(out, args.pack):
            print(p)
    failed = [n for n, r in records.items() if r["returncode"] != 0]
    if failed:
        print(f"failed: {failed} (logs in {out / 'logs'})", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
