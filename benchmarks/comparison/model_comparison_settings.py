"""The model comparison's settings and bookkeeping, shared by its stages.

What :mod:`benchmarks.comparison.model_comparison` compares (:data:`FAMILIES`, their
:class:`TrainStage` s, the :data:`BASELINES`), its :class:`Settings`, the checks that turn the
command line's ``--extra``, ``--seeds-for`` and ``--data`` into them, and the bookkeeping every
stage shares: ``log.jsonl`` (:class:`StageLog`) and the settings a finished output was made with
(:func:`done_record`).
"""

from __future__ import annotations

import dataclasses
import datetime
import json
import os
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import torch

from benchmarks import common
from vp2.data.storage import DatasetError, load_manifest
from vp2.run.model_spec import ModelSpec
from vp2.utils.io import json_safe


@dataclasses.dataclass(frozen=True)
class TrainStage:
    """One model a family trains.

    Attributes:
        model: Registered model name.
        preset: Its size preset.
        overrides: Model config overrides (as ``vp2 train --model-arg``).
        share: Its share of the family's time budget.
        tokenizer: Whether it takes the previous stage's checkpoint as ``tokenizer_checkpoint``
            (MaskViT's transformer).
    """

    model: str
    preset: str
    overrides: tuple[tuple[str, Any], ...] = ()
    share: float = 1.0
    tokenizer: bool = False


#: The families compared and what each trains, in order; the last stage is the predictor
#: that is evaluated. SVG′ is shrunk as the shipped model is (M = K = 0.125, 1.65 M parameters).
FAMILIES: dict[str, tuple[TrainStage, ...]] = {
    "svg_prime": (TrainStage("svg_prime", "m0.25k0.25", (("m", 0.125), ("k", 0.125))),),
    "fitvid": (TrainStage("fitvid", "mini"),),
    "struct_vrnn": (TrainStage("struct_vrnn", "small"),),
    "mcvd": (TrainStage("mcvd", "tiny"),),
    "maskvit": (
        TrainStage("maskvit_tokenizer", "tiny", share=1 / 3),
        TrainStage("maskvit", "tiny", share=2 / 3, tokenizer=True),
    ),
}
#: The baselines run beside the families (label -> run settings); only repeat-last-frame
#: predicts frames, so only it has metrics.
BASELINES: dict[str, dict[str, Any]] = {
    "repeat_last_frame": {"model": "repeat_last_frame"},
    "random": {"model": "none", "agent": "random", "save_gifs": False},
}
#: Steps of a budgeted training run: far more than any budget buys, so the budget ends it.
STEP_CAP = 10_000_000


@dataclasses.dataclass(frozen=True)
class Settings:
    """The comparison's settings (from the command line, :func:`settings_from_args`; the flag
    of each field has its name, e.g. ``--num-samples``). ``device`` is resolved (``cpu``,
    ``cuda``), ``threads`` is torch's thread count, ``command`` rebuilds the comparison."""

    out: Path
    data: Path
    docs: Path | None  # where the page is also published (None: only under out)
    notes: Path | None  # Markdown file the page links in its "Reading" section
    publish_only: bool  # rebuild study, report and page from what is on disk; run nothing
    budget_minutes: float
    families: tuple[str, ...]
    extras: tuple[tuple[str, str], ...]  # (label, model spec): evaluated, not trained here
    tasks: tuple[str, ...]
    num_instances: int
    seeds: tuple[int, ...]
    seeds_for: tuple[tuple[str, tuple[int, ...]], ...]  # (run, seeds): fewer seeds for a run
    num_samples: int
    num_steps: int
    batch_size: int
    device: str  # resolved: "cpu", "cuda", "cuda:1", ...
    threads: int
    workers: int  # trial processes of `vp2 run`
    loader_workers: int  # DataLoader processes of `vp2 train`
    eval_interval: int
    eval_batches: int
    ckpt_interval: int
    log_interval: int
    metrics_clips: int
    lpips: tuple[str, ...]
    fvd: bool
    conditioning_clips: int
    conditioning_samples: int
    diagnose_clips: int | None  # None: vp2 diagnose's default (what its predictor was fitted on)
    diagnose_instances: int | None  # instances per task probed; None: vp2 diagnose's default
    skip_train: bool
    smoke: bool
    command: str
    records: Path | None = None  # this part's committed evidence (benchmarks.comparison.records)

    def seeds_of(self, name: str) -> tuple[int, ...]:
        """The control-run seeds of run ``name``: ``--seeds``, unless ``--seeds-for`` gives
        it fewer (a slow model's runs on a subset)."""
        return dict(self.seeds_for).get(name, self.seeds)

    def run_order(self) -> list[str]:
        """The order the runs go in: the baselines (minutes), the extra models, the families."""
        return [*BASELINES, *dict(self.extras), *self.families]

    def table_names(self) -> list[str]:
        """Every run, in the order of the page's columns and the report's runs."""
        return [*self.families, *dict(self.extras), *BASELINES]

    def predictor_names(self) -> list[str]:
        """What predicts frames, so has metrics: families, extra models, repeat-last-frame."""
        return [*self.families, *dict(self.extras), "repeat_last_frame"]


# --------------------------------------------------------------------------- bookkeeping


class StageLog:
    """``log.jsonl``: one line per stage and invocation (what was found done, what ran)."""

    def __init__(self, out: Path):
        self.path = out / "log.jsonl"
        self.invocation = datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")

    def add(self, stage: str, name: str, status: str, **extra: Any) -> None:
        line = {"invocation": self.invocation, "stage": stage, "name": name, "status": status}
        line.update(extra)
        print(f"[{stage}] {name}: {status} {json.dumps(extra) if extra else ''}", flush=True)
        with self.path.open("a") as f:  # one short line per write: a kill loses at most it
            f.write(json.dumps(line) + "\n")


def done_record(path: Path, settings: dict[str, Any]) -> dict[str, Any] | None:
    """The record at ``path`` if a stage completed it with ``settings``; ``None`` if absent.

    Raises:
        ValueError: it was made with other settings (results would mix).
    """
    if not path.is_file():
        return None
    record = json.loads(path.read_text())
    saved = record.get("settings") or {}
    settings = json_safe(settings)
    if saved != settings:
        changed = sorted(k for k in {**saved, **settings} if saved.get(k) != settings.get(k))
        raise ValueError(
            f"{path} was made with other settings ({', '.join(changed)}: "
            f"{[saved.get(k) for k in changed]} vs now {[settings.get(k) for k in changed]}); "
            "use another --out or delete it"
        )
    return record


def device_name(device: str) -> str:
    """The device in words: the GPU's name, or the CPU's model and core count."""
    if device.startswith("cuda"):
        return f"{device} ({torch.cuda.get_device_name(torch.device(device))})"
    return f"cpu ({common.cpu_name()}, {os.cpu_count()} cores)"


# --------------------------------------------------------------------------- the command line's checks


def parse_extras(items: Sequence[str], families: Sequence[str]) -> tuple[tuple[str, str], ...]:
    """``LABEL=MODEL`` items -> ``((label, model), ...)``.

    Raises:
        ValueError: an item without ``=``, an empty side, or a label that is already taken.
    """
    taken = {*families, *BASELINES}
    extras: list[tuple[str, str]] = []
    for item in items:
        label, sep, spec = item.partition("=")
        label, spec = label.strip(), spec.strip()
        if not sep or not label or not spec:
            raise ValueError(f"--extra {item!r}: expected LABEL=MODEL, e.g. shipped=svg_prime:model.pt")
        if label in taken:
            raise ValueError(f"--extra {item!r}: the label {label!r} is already used; pick another")
        taken.add(label)
        extras.append((label, spec))
    return tuple(extras)


def parse_seeds_for(
    items: Sequence[str], names: Sequence[str], seeds: Sequence[int]
) -> tuple[tuple[str, tuple[int, ...]], ...]:
    """``RUN=S[,S...]`` items -> ``((run, seeds), ...)``; ``names`` are the runs there are.

    Raises:
        ValueError: an item that is not ``RUN=SEEDS``, a run there is not, a run given twice,
            or seeds that are not integers of ``--seeds``.
    """
    out: dict[str, tuple[int, ...]] = {}
    for item in items:
        name, sep, value = item.partition("=")
        name = name.strip()
        try:
            chosen = tuple(int(x) for x in value.split(",") if x.strip())
        except ValueError:
            chosen = ()
        if not sep or not name or not chosen:
            raise ValueError(f"--seeds-for {item!r}: expected RUN=SEEDS, e.g. mcvd=0 or mcvd=0,1")
        if name not in names:
            raise ValueError(
                f"--seeds-for {item!r}: no run {name!r} in this comparison; the runs are "
                f"{', '.join(names)}"
            )
        if name in out:
            raise ValueError(f"--seeds-for {item!r}: {name} is given seeds twice; give it once")
        outside = sorted(set(chosen) - set(seeds))
        if outside:
            raise ValueError(
                f"--seeds-for {item!r}: seed(s) {outside} are not among --seeds "
                f"{' '.join(map(str, seeds))}; a run may only drop seeds, so its column "
                "compares with the others on the seeds they share"
            )
        out[name] = tuple(sorted(set(chosen)))
    return tuple(out.items())


#: The dataset of a comparison that names none.
DEFAULT_DATA = Path("data/robodesk-300x-64px")


def dataset_env(data: Path) -> str:
    """The environment a dataset was collected in (its manifest's), with a clear error."""
    try:
        manifest = load_manifest(data)
    except DatasetError as exc:
        raise ValueError(f"--data {data}: {exc}") from exc
    return str(manifest.get("config", {}).get("env", "robodesk"))


def extra_env(label: str, spec: str, envs: Sequence[str]) -> tuple[str, str]:
    """``(label without its @ENV, env)`` of an extra model in a comparison over ``envs``: the
    environment after ``@`` in its label, else its zoo card's.

    Raises:
        ValueError: neither says, or the environment has no dataset here.
    """
    label, _, env = label.partition("@")
    if not env:
        parsed = ModelSpec.parse(spec)
        if parsed.kind != "zoo":
            raise ValueError(
                f"--extra {label}={spec}: with a dataset per environment, say which "
                f"environment it plans in: --extra {label}@ENV={spec} (ENV: {', '.join(envs)})")
        env = parsed.zoo.env
    if env not in envs:
        raise ValueError(f"--extra {label}={spec}: it plans in {env}, and no --data is a {env} "
                         f"dataset (the datasets' environments: {', '.join(envs)})")
    return label, env
