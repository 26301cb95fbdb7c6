"""``vp2 diagnose``: whether a model can plan, in minutes (docs/diagnose.md)."""

from __future__ import annotations

import argparse
from pathlib import Path

from vp2.cli._fields import Flag, add_flags, build
from vp2.cli.metrics import model_slug
from vp2.diagnose.model import DiagnoseConfig
from vp2.run.model_spec import ENSEMBLE_PREFIX, ModelSpec, parse_model_args
from vp2.run.run_dir import DIAGNOSIS_FILE, DIAGNOSIS_PARTIAL_SUFFIX, diagnosis_partial_path

NAME = "diagnose"
HELP = "whether a model can plan, in minutes: action conditioning, its cost's ranking (docs/diagnose.md)"
DESCRIPTION = (
    "Measures, without a control run, what decides whether a model can plan: whether its "
    "predictions depend on the actions (held-out clips), and at the first planning step of a "
    "few suite instances where the scripted plan ranks under its cost, whether the ranking "
    "repeats across the model's noise, whether the scores move MPPI's weights, and whether the "
    "model ranks the candidates as the simulator does. Prints a "
    "verdict per measure and writes a JSON report (docs/diagnose.md)."
)

#: One entry per :class:`~vp2.diagnose.model.DiagnoseConfig` field, and ``--out``.
FLAGS: dict[str, Flag | None] = {
    "model": Flag(
        required=True,
        help="model spec, as vp2 run takes it: simulator | repeat_last_frame | NAME:CHECKPOINT | "
        "zoo:NAME | package.module:factory | file.yaml (an ensemble(...): diagnose each member)",
    ),
    "env": Flag(
        choices=["robodesk", "tabletop"],
        help="environment (default: the one the checkpoint was trained on where it says, else "
        "robodesk)",
    ),
    "model_args": Flag(
        "--model-arg",
        action="append",
        default=[],
        metavar="KEY=VALUE",
        help="model factory argument, repeatable; VALUE parsed as YAML",
        convert=parse_model_args,
    ),
    "data": Flag(metavar="DIR", help="dataset of the held-out clips (default: the one "
                 "`vp2 collect ENV` writes)"),
    "suite": Flag(help="task suite file (default: the shipped suite)"),
    "clips": Flag(help="held-out clips of the action-conditioning measure (0: skip it; "
                  "default: %(default)s)"),
    "sampling_seeds": Flag(help="model noise seeds per clip (default: %(default)s)"),
    "instances_per_task": Flag(help="first instances of each task probed at their first "
                               "planning step (0: skip; default: %(default)s)"),
    "num_samples": Flag(help="planner samples per step (default: %(default)s)"),
    "seed": Flag(help="control-run seed of the probed trials and seed of the clip choice"),
    "oracle_agreement": Flag(
        "--no-oracle-agreement",
        negate=True,
        help="skip scoring the probed candidates with the simulator (the agreement measure); "
        "its scores are cached under $VP2_CACHE_DIR/diagnose-oracle",
    ),
    "device": Flag(help="torch device (default: CUDA if available)"),
    "progress": Flag("--no-progress", negate=True, help="no progress bar"),
    "out": Flag(
        metavar="FILE",
        default=None,
        cli_only=True,
        help=f"report JSON (default: runs/diagnose/<model-slug>-<env>/{DIAGNOSIS_FILE}); the "
        f"measurements of an unfinished diagnosis wait beside it in "
        f"<name>{DIAGNOSIS_PARTIAL_SUFFIX}, and re-running the same command goes on from them",
    ),
}


def default_out(spec: str, env: str) -> Path:
    """``runs/diagnose/<model-slug>-<env>/diagnose.json``."""
    return Path("runs") / "diagnose" / f"{model_slug(spec)}-{env}" / DIAGNOSIS_FILE


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 diagnose`` flags to ``p`` (one per :data:`FLAGS` entry)."""
    add_flags(p, DiagnoseConfig, FLAGS)
    return p


def run_from_args(args: argparse.Namespace) -> int:
    """Runs ``vp2 diagnose``: prints a line per measure and writes the report."""
    from vp2.diagnose.model import (
        diagnose_env,
        diagnose_model,
        format_report,
        report_path,
        write_report,
    )

    config = build(DiagnoseConfig, args, FLAGS)
    config.validate()
    if config.model.startswith(ENSEMBLE_PREFIX):
        members = ModelSpec.parse(config.model).members
        raise ValueError(
            f"model {config.model!r}: an ensemble is not diagnosed as one model; diagnose each "
            f"member on its own ({', '.join(f'--model {m.text}' for m in members)})"
        )
    out = report_path(args.out or default_out(config.model, diagnose_env(config)[0]))
    partial = diagnosis_partial_path(out)
    report = diagnose_model(config, partial=partial)
    write_report(out, report)
    partial.unlink(missing_ok=True)
    print("\n".join(format_report(report)))
    print(f"wrote {out}")
    return 0

