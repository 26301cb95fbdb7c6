"""A zoo card's measured sections from the files that measured them: ``control`` from `vp2 run`
directories, ``metrics`` from a `vp2 metrics` result (``vp2 zoo add --control/--metrics``).

The card's format is :mod:`vp2.models.zoo`'s; these functions only read results the benchmark
and the metrics stage wrote, so a card says exactly what those runs measured.
"""

from __future__ import annotations

import json
import os
import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from vp2.data.suite import SUITE_FORMAT
from vp2.oracle.build import run_command
from vp2.run.results import is_ok
from vp2.run.run_dir import CONFIG_FILE, RunDir, read_trials


def _run_settings(run_dir: Path) -> dict[str, Any]:
    run = RunDir(run_dir)
    if not run.config_file.is_file():
        raise ValueError(f"--control {run_dir}: no {CONFIG_FILE}; give the directory of a vp2 run")
    return run.settings()


def _planner_samples(record: dict[str, Any]) -> int:
    """The planner samples of a trial: a full record's ``agent.planner``, or the top-level
    ``num_samples`` of a compact one (the copies ``results/`` keeps)."""
    planner = (record.get("agent") or {}).get("planner") or {}
    value = planner.get("num_samples", record.get("num_samples"))
    if value is None:
        raise ValueError(
            f"trial {record.get('task')} #{record.get('instance')} seed {record.get('seed')}: "
            "its record names no planner samples (agent.planner.num_samples or num_samples)"
        )
    return int(value)


def control_section(run_dirs: Sequence[str | os.PathLike[str]], env: str) -> dict[str, Any]:
    """The card's ``control`` row of ``env``: successes over the finished ``env`` trials of the
    run directories (the latest record per trial), with seeds, instances per task, planner
    samples, steps, suite (the shipped suite's format, or the run's suite file), the tasks solved
    and the commands.

    Raises:
        ValueError: a directory that is not a run, runs with different planner samples or
            steps, or no finished ``env`` trial.
    """
    records: dict[tuple[str, int, int], dict[str, Any]] = {}
    commands, samples, steps, suites = [], set(), set(), set()
    for run_dir in map(Path, run_dirs):
        settings = _run_settings(run_dir)
        commands.append(run_command(settings, run_dir, full_out=True))
        suites.add(settings.get("suite") or SUITE_FORMAT)
        for record in read_trials(run_dir):
            if str(record.get("task", "")).startswith(f"{env}/") and is_ok(record):
                records[(record["task"], int(record["instance"]), int(record["seed"]))] = record
                samples.add(_planner_samples(record))
                steps.add(int(record["num_steps"]))
    if not records:
        raise ValueError(f"--control {', '.join(map(str, run_dirs))}: no finished {env} trial")
    if len(samples) > 1 or len(steps) > 1:
        raise ValueError(f"--control: the runs differ in planner samples {sorted(samples)} or "
                         f"steps {sorted(steps)}; a card's control row is one protocol")
    trials = list(records.values())
    suite = suites.pop() if len(suites) == 1 else None
    tasks = sorted({r["task"] for r in trials})
    per_task = {t: {k[1] for k in records if k[0] == t} for t in tasks}
    return {
        "successes": sum(bool(r["success"]) for r in trials),
        "trials": len(trials),
        "seeds": sorted({int(r["seed"]) for r in trials}),
        "instances": min(len(v) for v in per_task.values()),
        "samples": samples.pop(),
        "steps": steps.pop(),
        "tasks": len(tasks),
        "suite": suite,
        "solved": sorted({r["task"] for r in trials if r["success"]}),
        "date": max(str(r.get("finished_at", "")) for r in trials)[:10] or None,
        "command": " ; ".join(commands),
    }


def control_sections(run_dirs: Sequence[str | os.PathLike[str]]) -> dict[str, dict[str, Any]]:
    """The card's ``control``: one row per environment the runs' finished trials cover."""
    envs = sorted({
        str(r.get("task", "")).split("/")[0] for d in run_dirs for r in read_trials(Path(d))
        if is_ok(r)
    })  # fmt: skip
    if not envs:
        raise ValueError(f"--control {', '.join(map(str, run_dirs))}: no finished trial")
    return {env: control_section(run_dirs, env) for env in envs}


def metrics_section(path: str | os.PathLike[str]) -> dict[str, Any]:
    """The card's ``metrics`` from a `vp2 metrics` result file: FVD, LPIPS (AlexNet, else
    VGG), SSIM, PSNR and MSE (``null`` where not measured), the clips and the command."""
    from vp2.models.zoo import METRICS

    try:
        result = json.loads(Path(path).read_text())
        values = result["metrics"]
    except (OSError, json.JSONDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"--metrics {path}: not a vp2 metrics result ({exc})") from None
    section: dict[str, Any] = {m: values.get(m) for m in METRICS}
    section["lpips"] = values.get("lpips_alex", values.get("lpips_vgg"))
    section = {k: None if v is None else round(float(v), 5) for k, v in section.items()}
    settings = result.get("settings", {})
    args = ["vp2", "metrics", "--model", str(result.get("model", {}).get("spec", "?")),
            "--data", str(result.get("dataset")), "--num-clips", str(result.get("num_clips")),
            "--seed", str(result.get("seed"))]  # fmt: skip
    if not settings.get("fvd", True):
        args.append("--no-fvd")
    if settings.get("lpips_nets") is not None:
        args += ["--lpips", *settings["lpips_nets"]] if settings["lpips_nets"] else ["--lpips"]
    section["command"] = shlex.join(args)
    section["note"] = (
        f"{result.get('num_clips')} clips of the {result.get('split', 'valid')} split of "
        f"{result.get('dataset')}, {result.get('future')} frames predicted from "
        f"{result.get('context')}"
        + (f"; LPIPS with {'AlexNet' if 'lpips_alex' in values else 'VGG'}"
           if section["lpips"] is not None else "")
        + ("; FVD not measured (--no-fvd)" if not settings.get("fvd", True) else "")
        + (f"; not measured: {', '.join(sorted(result['skipped']))}"
           if result.get("skipped") else "")
    )  # fmt: skip
    return section


__all__ = ["control_section", "control_sections", "metrics_section"]
