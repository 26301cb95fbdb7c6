"""The run directories a report shows: read, labelled, and normalised by an oracle."""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from vp2.oracle.shipped import is_oracle_config, load_shipped_oracle, summarize_run
from vp2.run.config import planner_of
from vp2.run.results import Summary, summarize
from vp2.run.run_dir import RunDir

PathLike = str | os.PathLike[str]


@dataclasses.dataclass
class RunView:
    """A run directory as the report sees it.

    Attributes:
        run_dir: The directory.
        label: Model label (unique among the report's runs).
        config: The ``config`` mapping of ``config.yaml`` in the flat form, the planner's
            fields beside the others (:meth:`~vp2.run.run_dir.RunDir.settings`; empty
            if the file is missing).
        deviations: Its departures from the SPEC protocol.
        records: Trial records.
        summary: Scores, normalised when an oracle run is known.
        is_oracle: Whether the run is a simulator-oracle run.
        oracle_source: Where the normalisation came from (``None``: not normalised).
        oracle_note: Why a shipped oracle exists but normalises none of the run's tasks (no
            table at its planner samples, another render spec, ...), one line.
        outside: The note on trials in the directory that its config does not cover, which
            are not counted (:meth:`~vp2.run.run_dir.RunDir.split_trials`); ``None``:
            none.
        diagnosis: The model's diagnosis found in the directory, one entry per environment
            (:func:`read_diagnosis`); empty when there is none.
    """

    run_dir: Path
    label: str
    config: dict[str, Any]
    deviations: list[str]
    records: list[dict[str, Any]]
    summary: Summary
    is_oracle: bool
    oracle_source: str | None = None
    oracle_note: str | None = None
    outside: str | None = None
    diagnosis: list[dict[str, Any]] = dataclasses.field(default_factory=list)


def read_diagnosis(run_dir: PathLike) -> list[dict[str, Any]]:
    """The diagnosis a run directory holds, one entry per environment: from ``diagnose.json``
    (``vp2 diagnose --model M --out RUN_DIR``: every measure and the predicted score) where
    present, else from ``precheck.json`` (what ``vp2 run`` measured before its first trial:
    action conditioning only).

    Each entry: ``env``, ``source`` (``"vp2 diagnose"`` or ``"vp2 run pre-check"``),
    ``conditioning`` (``ratio``, ``ci``, ``clips``, ``status``, ``text``, or ``None``),
    ``scripted`` (``median_rank``, ``of``, ``top_fraction``, or ``None``), ``agreement``
    (with the simulator: ``instances``, ``median_rho``, ``best_in_top_fraction``, or ``None``),
    ``predicted`` and
    ``predicted_reason`` (``None`` for a pre-check).
    """
    run = RunDir(run_dir)
    full = run.diagnosis_file
    if full.is_file():
        report = json.loads(full.read_text())
        cond = report.get("action_conditioning") or {}
        verdict = (report.get("verdicts") or {}).get("action_conditioning") or {}
        scripted = (report.get("planning") or {}).get("scripted_plan") or {}
        agreement = (report.get("planning") or {}).get("oracle_agreement") or {}
        return [{
            "env": report.get("env"),
            "source": "vp2 diagnose",
            "conditioning": None if "ratio" not in cond else {
                "ratio": cond["ratio"], "ci": cond.get("ci"), "clips": cond.get("clips"),
                "status": verdict.get("status"), "text": verdict.get("text"),
            },
            "scripted": scripted if scripted.get("instances") else None,
            "agreement": agreement if agreement.get("instances") else None,
            "predicted": report.get("predicted_control_score"),
            "predicted_reason": report.get("predicted_control_score_reason"),
        }]  # fmt: skip
    pre = run.precheck_file
    if not pre.is_file():
        return []
    out = []
    for m in json.loads(pre.read_text()).get("precheck", []):
        verdict = m.get("verdict") or {}
        out.append({
            "env": m.get("env"),
            "source": "vp2 run pre-check",
            "conditioning": {
                "ratio": m.get("ratio"), "ci": m.get("ci"), "clips": m.get("clips"),
                "status": verdict.get("status"), "text": verdict.get("text"),
            },
            "scripted": None,
            "agreement": None,
            "predicted": None,
            "predicted_reason": None,
        })  # fmt: skip
    return out


def model_label(config: Mapping[str, Any]) -> str:
    """A run's model as the report names it: the model spec, or the random baseline."""
    if config.get("agent") == "random":
        return "random actions"
    spec = str(config.get("model") or "unknown model")
    args = config.get("model_args") or {}
    if args:
        spec += " (" + ", ".join(f"{k}={v}" for k, v in sorted(args.items())) + ")"
    return spec


def load_runs(
    run_dirs: Sequence[PathLike], labels: Sequence[str | None] | None = None
) -> list[RunView]:
    """Reads the runs, labels them uniquely and normalises their scores.

    ``labels``: one per run directory (``None`` or empty: the model spec, :func:`model_label`).

    An oracle run among ``run_dirs`` normalises every other run; otherwise a run's own
    ``oracle`` setting is used if that directory exists, else the shipped oracle's table of
    the run's planner samples (per task, :meth:`~vp2.oracle.shipped.ShippedOracle.
    match`).

    Raises:
        FileNotFoundError: a directory that is not a run (no ``trials.jsonl``).
    """
    if labels is not None and len(labels) != len(run_dirs):
        raise ValueError(
            f"{len(labels)} label(s) for {len(run_dirs)} run director(ies): give one per run "
            "('-' keeps a run's default label)"
        )
    runs = []
    for i, d in enumerate(run_dirs):
        run = RunDir(d)
        run.check_is_run()
        config = run.settings()
        records, note = run.counted_trials()
        runs.append(
            RunView(
                run.path,
                (labels[i] if labels else None) or model_label(config),
                config,
                run.deviations(),
                records,
                summarize(records),
                is_oracle_config(config),
                outside=note,
                diagnosis=read_diagnosis(run.path),
            )
        )
    counts: dict[str, int] = {}
    for r in runs:
        counts[r.label] = counts.get(r.label, 0) + 1
    for r in runs:
        if counts[r.label] > 1:
            r.label = f"{r.label} [{r.run_dir.name}]"
    oracle = next((r for r in runs if r.is_oracle), None)
    shipped = None
    if any(not r.is_oracle for r in runs) and oracle is None:
        shipped = load_shipped_oracle()
    for r in runs:
        if r.is_oracle:
            continue
        if oracle is not None:
            r.oracle_source = f"oracle run {oracle.label} ({oracle.run_dir})"
            r.summary = summarize(r.records, oracle.records, oracle_source=r.oracle_source)
        elif r.config.get("oracle") and Path(r.config["oracle"]).exists():
            r.summary = summarize_run(r.records, oracle_run=r.config["oracle"])
            r.oracle_source = r.summary.oracle_source
        else:
            # Without a shipped oracle the section says so once, not every run's notes.
            r.summary = summarize_run(r.records, shipped=shipped, note_missing=False,
                                      planner=planner_of(r.config))
            r.oracle_source = r.summary.oracle_source
            r.oracle_note = r.summary.oracle_note
    for r in runs:
        if r.outside:
            r.summary.warnings.append(r.outside)
    return runs
