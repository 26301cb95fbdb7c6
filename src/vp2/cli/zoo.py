"""``vp2 zoo list|show|add|fill``: the model zoo, trained checkpoints by name (docs/models.md)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

NAME = "zoo"
HELP = "the model zoo: trained models by name (--model zoo:NAME)"
DESCRIPTION = (
    "The model zoo: trained checkpoints shipped by name, each with a card (family, preset, "
    "parameters, dataset, steps, budget, device, action conditioning, metrics, control, the "
    "commands that rebuilt it). Use one with `vp2 run --model zoo:NAME` (docs/models.md, "
    "'The model zoo'). The zoo is vp2/assets/zoo, or $VP2_ZOO_DIR."
)
NOT_MEASURED = "not measured"


def configure_parser(p: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Adds the ``vp2 zoo`` sub-commands to ``p`` (a sub-parser) and returns it."""
    sub = p.add_subparsers(dest="zoo_command", required=True)
    zoo_help = "the zoo's folder (default: $VP2_ZOO_DIR, else vp2/assets/zoo)"
    listing = sub.add_parser("list", help="one line per model")
    show = sub.add_parser("show", help="a model's whole card")
    show.add_argument("name", help="the model's zoo name")
    show.add_argument("--json", action="store_true", help="the card as JSON")
    add = sub.add_parser(
        "add",
        help="make a zoo entry of a trained checkpoint",
        description="Make a zoo entry of a checkpoint of `vp2 train`: NAME/model.pt (an "
        "inference-only export) and NAME/card.json. The card's family, preset, parameters, "
        "dataset, steps and training command come from the checkpoint; the measured fields "
        "(action_conditioning, metrics, control) and budget, device, notes from --card-from, "
        "control and metrics also from --control / --metrics, else null (listed as not "
        "measured).",
    )
    add.add_argument("checkpoint", type=Path, help="checkpoint file or training run directory")
    add.add_argument("--name", required=True, help="the entry's name (--model zoo:NAME)")
    add.add_argument("--card-from", type=Path, metavar="JSON",
                     help="card fields to add: a JSON mapping (e.g. a card of `vp2 zoo show "
                     "NAME --json` with the measured fields filled)")
    fill = sub.add_parser(
        "fill",
        help="fill an entry's control or metrics from the runs that measured them",
        description="Rewrite the control and/or metrics of an entry's card from `vp2 run` "
        "directories and a `vp2 metrics` result; the checkpoint is not touched (and must still "
        "match the card). A control row replaces the card's row of its environment.",
    )
    fill.add_argument("name", help="the entry's name")
    for command in (add, fill):
        command.add_argument("--control", nargs="+", type=Path, metavar="RUN_DIR",
                             help="fill the card's control from these `vp2 run` directories "
                             "(one row per environment: successes over their finished trials, "
                             "the protocol, the commands)")
        command.add_argument("--metrics", type=Path, metavar="FILE",
                             help="fill the card's metrics from this `vp2 metrics` result")
    fill.add_argument("--note", help="a note for the rows filled (e.g. which comparison ran them)")
    add.add_argument("--float32", action="store_true",
                     help="keep float32 weights (default: float16, half the size)")
    add.add_argument("--force", action="store_true", help="replace an entry of that name")
    for command in (listing, show, add, fill):
        command.add_argument("--zoo", type=Path, default=None, metavar="DIR", help=zoo_help)
    return p


def run_from_args(args: argparse.Namespace) -> int:
    if args.zoo_command == "list":
        print(list_table(args.zoo))
    elif args.zoo_command == "show":
        from vp2.models.zoo import get_card

        card = get_card(args.name, args.zoo, verify=False)
        print(json.dumps(card.to_json(), indent=2) if args.json else show_card(card))
    elif args.zoo_command == "fill":
        _fill(args)
    else:
        _add(args)
    return 0


def _fill(args: argparse.Namespace) -> None:
    from vp2.models.zoo import get_card
    from vp2.models.zoo_entries import fill_card

    if args.control is None and args.metrics is None:
        raise ValueError("vp2 zoo fill: give --control RUN_DIR... and/or --metrics FILE")
    get_card(args.name, args.zoo, verify=False)  # an unknown name before reading any run
    sections = _measured_from_files({}, args.control, args.metrics)
    if args.note:
        for row in (sections.get("control") or {}).values():
            row["note"] = args.note
        if "metrics" in sections:
            sections["metrics"]["note"] = f"{sections['metrics']['note']}; {args.note}"
    card = fill_card(args.name, sections, args.zoo)
    for env, row in (sections.get("control") or {}).items():
        print(f"{card.name}: control on {env} {row['successes']}/{row['trials']}")
    if "metrics" in sections:
        m = card.metrics
        shown = ", ".join(f"{k} {m[k]:.4g}" for k in ("fvd", "lpips", "ssim") if m.get(k) is not None)
        print(f"{card.name}: metrics {shown or 'none measured'}")


def _add(args: argparse.Namespace) -> None:
    from vp2.models.zoo_entries import add_to_zoo
    from vp2.training.export import export_checkpoint

    given: Any = None
    if args.card_from is not None:
        try:
            given = json.loads(args.card_from.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise ValueError(f"--card-from {args.card_from}: cannot read it as JSON ({exc})") from None
        if not isinstance(given, dict):
            raise ValueError(f"--card-from {args.card_from}: expected a JSON mapping of card fields")
    given = _measured_from_files(dict(given or {}), args.control, args.metrics)
    card = add_to_zoo(
        args.checkpoint, args.name, given, args.zoo, force=args.force,
        write=lambda src, dst: export_checkpoint(src, dst, half=not args.float32),
    )
    print(f"zoo entry {card.name}: {card.directory} ({card.family}, {_params(card.parameters)} "
          f"parameters, {card.env}); use it with --model {card.spec}")
    missing, unrecorded = card.not_measured(), card.not_recorded()
    if missing:
        print(f"not measured (null): {', '.join(missing)}")
    if unrecorded:
        print(f"not recorded (null): {', '.join(unrecorded)}")
    if missing or unrecorded:
        print(f"fill them: `vp2 zoo show {card.name} --json` gives the card; add the fields and "
              f"run this command again with --card-from FILE --force")


def _measured_from_files(
    given: dict[str, Any], control: list[Path] | None, metrics: Path | None
) -> dict[str, Any]:
    """``given`` with ``control`` / ``metrics`` read from run directories / a metrics file."""
    from vp2.report.cards import control_sections, metrics_section

    for flag, field, value in (("--control", "control", control), ("--metrics", "metrics", metrics)):
        if value is not None and given.get(field) is not None:
            raise ValueError(f"{flag} and --card-from both give the card's {field}; keep one")
    if control is not None:
        given["control"] = control_sections(control)
    if metrics is not None:
        given["metrics"] = metrics_section(metrics)
    return given


def _params(n: int) -> str:
    return f"{n / 1e6:.2f} M"


def _conditioning(card: Any) -> str:
    ac = card.action_conditioning
    if ac is None:
        return NOT_MEASURED
    if "trajectory_interval" in ac:  # the honest interval: clips of one trajectory correlate
        low, high = ac["trajectory_interval"]
        return f"{ac['ratio']:.2f}x [{low:.2f}, {high:.2f}] over {ac['trajectories']} trajectories"
    low, high = ac["interval"]
    return f"{ac['ratio']:.2f}x [{low:.2f}, {high:.2f}] over clips"


def _control(card: Any) -> str:
    if not card.control:
        return NOT_MEASURED
    return "; ".join(f"{env} {row['successes']}/{row['trials']} "
                     f"({100 * row['successes'] / row['trials']:.0f}%)"
                     for env, row in card.control.items())


def _metrics(card: Any) -> str:
    from vp2.models.zoo import METRICS

    measured = [m for m in METRICS if card.metrics and card.metrics.get(m) is not None]
    return " ".join(measured) if measured else NOT_MEASURED


def list_table(directory: Path | None = None) -> str:
    """``vp2 zoo list``: one row per entry; a line per entry whose checkpoint fails its card."""
    from vp2.models.zoo import ZooError, list_zoo, zoo_dir

    root = directory if directory is not None else zoo_dir()
    cards = list_zoo(root)
    if not cards:
        return f"the zoo at {root} is empty (add a model: vp2 zoo add CHECKPOINT --name NAME)"
    head = ("name", "family", "preset", "env", "params", "action conditioning", "metrics",
            "control")
    rows = [(c.name, c.family, str(c.preset), c.env, _params(c.parameters), _conditioning(c),
             _metrics(c), _control(c)) for c in cards]
    widths = [max(len(r[i]) for r in (head, *rows)) for i in range(len(head))]
    lines = ["  ".join(v.ljust(w) for v, w in zip(row, widths, strict=True)).rstrip()
             for row in (head, *rows)]
    for card in cards:
        try:
            card.verify()
        except ZooError as err:
            lines.append(f"! {err}")
    lines.append(f"\n{len(cards)} model(s) in {root}; a card: vp2 zoo show NAME; run one: "
                 "vp2 run --model zoo:NAME")
    return "\n".join(lines)


def _value(value: Any, absent: str, indent: str) -> list[str]:
    """A card value as text lines: scalars inline, mappings and lists one item a line."""
    if value is None:
        return [absent]
    if isinstance(value, dict):
        lines = [""]
        for key, item in value.items():
            nested = _value(item, NOT_MEASURED if key in ("fvd", "lpips", "ssim", "psnr", "mse")
                            else "not recorded", indent + "  ")
            lines.append(f"{indent}  {key}: {nested[0]}".rstrip())
            lines += nested[1:]
        return lines
    if isinstance(value, list) and any(isinstance(v, dict | list) for v in value):
        return ["", *(f"{indent}  - {json.dumps(v)}" for v in value)]
    if isinstance(value, list) and any(" " in str(v) for v in value):
        return ["", *(f"{indent}  {v}" for v in value)]
    if isinstance(value, list):
        return [", ".join(str(v) for v in value)]
    return [str(value)]


def show_card(card: Any) -> str:
    """``vp2 zoo show NAME``: the whole card, one field a line (sections indented)."""
    from vp2.models.zoo import FIELDS, MEASURED, ZooError

    try:
        card.verify()
        state = "matches the card"
    except ZooError as err:
        state = f"DOES NOT MATCH: {err}"
    lines = [
        f"{card.name}: {card.family} ({card.preset}), {card.parameters:,} parameters "
        f"({_params(card.parameters)}), {card.env}",
        f"use: vp2 run --model {card.spec}",
        f"card: {card.directory / 'card.json'}",
        f"checkpoint file: {card.checkpoint_path} (sha256 {card.sha256}; {state})",
        f"action conditioning: {_conditioning(card)}; control: {_control(card)}",
    ]
    for key in FIELDS:
        if key in ("name", "family", "checkpoint", "sha256"):
            continue
        absent = NOT_MEASURED if key in MEASURED else "not recorded"
        value = _value(getattr(card, key), absent, "")
        lines.append(f"{key}: {value[0]}".rstrip())
        lines += value[1:]
    missing = card.not_measured()
    if missing:
        lines.append(f"not measured: {', '.join(missing)}")
    return "\n".join(lines)
