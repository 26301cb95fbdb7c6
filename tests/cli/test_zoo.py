"""``vp2 zoo list|show|add`` and ``vp2 run --model zoo:NAME``."""

from __future__ import annotations

import json
import shlex

import pytest
import torch

from tests.models.test_zoo import make_checkpoint, shipped_zoo_names
from vp2 import cli
from vp2.models.checkpoint import read_model_checkpoint
from vp2.models.zoo import CHECKPOINT_FILE, FIELDS, get_card
from vp2.models.zoo_entries import train_command
from vp2.run.run_dir import read_trials

SHIPPED = "svg_prime-tiny-robodesk"


def _vp2(capsys, *argv: str) -> tuple[int, str, str]:
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_list_shows_the_shipped_model(capsys, monkeypatch):
    monkeypatch.delenv("VP2_ZOO_DIR", raising=False)
    code, out, _ = _vp2(capsys, "zoo", "list")
    assert code == 0
    head = out.splitlines()[0]
    (row,) = [line for line in out.splitlines() if line.startswith(SHIPPED + " ")]
    assert head.split() == ["name", "family", "preset", "env", "params", "action",
                            "conditioning", "metrics", "control"]
    assert row.split() == [SHIPPED, "svg_prime", "m0.25k0.25", "robodesk", "1.65", "M",
                           "1.60x", "[1.49,", "1.72]", "over", "clips", "fvd", "lpips", "ssim", "psnr", "mse", "robodesk",
                           "30/63", "(48%)"]
    assert "!" not in out  # every entry's checkpoint matches its card
    # The zoo training's SVG' after 30 core-minutes, with its card from the files that measured it.
    (row,) = [line for line in out.splitlines() if line.startswith("svg_prime-robodesk-30min ")]
    assert row.split()[6:] == ["1.32x", "[1.20,", "1.45]", "over", "clips", "lpips", "ssim", "psnr", "mse",
                               "robodesk", "6/14", "(43%)"]
    # The shipped tabletop model: its card names vp2 main's checkpoint file.
    (row,) = [line for line in out.splitlines() if line.startswith("svg_prime-tiny-tabletop ")]
    assert row.split()[3:] == ["tabletop", "1.65", "M", "1.16x", "[1.06,", "1.32]", "over", "10",
                               "trajectories", "not", "measured", "tabletop", "1/4", "(25%)"]
    assert get_card("svg_prime-tiny-tabletop").checkpoint_path.name == "svg_prime_tiny_tabletop.pt"
    # FitVid after 60 core-minutes of the RoboDesk zoo training.
    (row,) = [line for line in out.splitlines() if line.startswith("fitvid-robodesk-60min ")]
    assert row.split()[1:] == ["fitvid", "mini", "robodesk", "1.52", "M", "1.23x", "[1.14,",
                               "1.33]", "over", "clips", "lpips", "ssim", "psnr", "mse", "robodesk", "1/7",
                               "(14%)"]
    # A second tabletop family: FitVid after 15 core-minutes of the zoo training.
    (row,) = [line for line in out.splitlines() if line.startswith("fitvid-tabletop-15min ")]
    assert row.split()[1:] == ["fitvid", "mini", "tabletop", "1.52", "M", "1.00x", "[1.00,",
                               "1.00]", "over", "10", "trajectories", "not", "measured", "not",
                               "measured"]


def test_show_prints_the_whole_card(capsys):
    code, out, _ = _vp2(capsys, "zoo", "show", SHIPPED)
    assert code == 0
    assert out.startswith(f"{SHIPPED}: svg_prime (m0.25k0.25), 1,648,955 parameters (1.65 M), "
                          "robodesk\n")
    assert f"use: vp2 run --model zoo:{SHIPPED}" in out and "matches the card" in out
    for field in FIELDS:
        if field not in ("name", "family", "checkpoint", "sha256"):
            assert f"\n{field}:" in out, field
    assert "  fvd: 442.01548" in out and "  lpips: 0.0463" in out and "  mse: 0.00538" in out
    assert "--clips 128 --samples 3" in out
    assert "--num-instances 3 --seeds 0 1 2 --num-samples 50 --out outputs/comparison-zoo" in out
    code, out, _ = _vp2(capsys, "zoo", "show", SHIPPED, "--json")
    assert json.loads(out) == json.loads((get_card(SHIPPED).directory / "card.json").read_text())


def test_unknown_names_are_errors_that_list_the_zoo(capsys, tmp_path):
    code, _, err = _vp2(capsys, "zoo", "show", "nope")
    assert code == 2 and "vp2 zoo: error: no model 'nope' in the zoo at" in err
    assert f"known: {', '.join(shipped_zoo_names())};" in err
    code, _, err = _vp2(capsys, "run", "--model", "zoo:nope", "--out", str(tmp_path / "r"),
                        "--no-progress")
    assert code == 2 and "vp2 run: error: model 'zoo:nope': no model 'nope'" in err
    assert not (tmp_path / "r").exists()


def test_run_a_zoo_model_and_its_records_name_the_entry(capsys, tmp_path):
    """One RoboDesk instance (push_red #0 of the shipped suite), 2 steps, 4 samples."""
    out = tmp_path / "run"
    code, _, err = _vp2(capsys, "run", "--model", f"zoo:{SHIPPED}", "--tasks",
                        "robodesk/push_red", "--num-instances", "1", "--seeds", "0",
                        "--num-steps", "2", "--num-samples", "4", "--no-gifs", "--no-progress",
                        "--out", str(out))
    assert code == 0, err
    (record,) = read_trials(out)
    assert record["error"] is None and (record["task"], record["instance"]) == (
        "robodesk/push_red", 0)
    assert len(record["success_steps"]) == 2
    model = record["model"]
    assert model["spec"] == f"zoo:{SHIPPED}" and model["name"] == "svg_prime"
    assert model["zoo"] == {"name": SHIPPED, "family": "svg_prime", "preset": "m0.25k0.25",
                            "sha256": get_card(SHIPPED).sha256}
    assert model["num_parameters"] == get_card(SHIPPED).parameters


def test_add_then_list_show_and_load(capsys, tmp_path, monkeypatch):
    source = make_checkpoint(tmp_path / "run" / "checkpoints" / "step_00000003.pt")
    zoo = tmp_path / "zoo"
    monkeypatch.setenv("VP2_ZOO_DIR", str(zoo))
    measured = tmp_path / "measured.json"
    measured.write_text(json.dumps({"action_conditioning": {
        "ratio": 1.25, "interval": [1.1, 1.4], "clips": 64, "command": "python -m x"}}))
    code, out, err = _vp2(capsys, "zoo", "add", str(tmp_path / "run"), "--name", "tiny",
                          "--card-from", str(measured))
    assert code == 0, err
    assert f"zoo entry tiny: {zoo / 'tiny'} (struct_vrnn" in out and "--model zoo:tiny" in out
    assert "not measured (null): metrics, control\n" in out
    assert "not recorded (null): device, dataset.made_with, budget.cores, budget.date\n" in out
    # An inference-only float16 export of the checkpoint.
    shipped = read_model_checkpoint(zoo / "tiny" / CHECKPOINT_FILE)
    assert "optimizer" not in shipped and shipped["exported"] == {"half": True, "from_step": 3}
    weights = next(iter(shipped["model"]["state_dict"].values()))
    assert weights.dtype == torch.float16
    code, out, _ = _vp2(capsys, "zoo", "list")
    (row,) = [line for line in out.splitlines() if line.startswith("tiny ")]
    assert row.split()[1:] == ["struct_vrnn", "tiny", "robodesk", "0.09", "M", "1.25x", "[1.10,",
                               "1.40]", "over", "clips", "not", "measured", "not", "measured"]
    code, out, _ = _vp2(capsys, "zoo", "show", "tiny")
    assert "control: not measured" in out and "device: not recorded" in out
    # Known: refused without --force; --float32 keeps the weights as trained.
    code, _, err = _vp2(capsys, "zoo", "add", str(source), "--name", "tiny")
    assert code == 2 and "already has 'tiny'" in err
    # Filling a field later: the card as JSON, a figure added, the same command again.
    code, out, _ = _vp2(capsys, "zoo", "show", "tiny", "--json")
    card = json.loads(out)
    card["control"] = {"robodesk": {"successes": 2, "trials": 4, "seeds": [0, 1], "instances": 2,
                                    "samples": 4, "command": "vp2 run ..."}}
    measured.write_text(json.dumps(card))
    code, out, _ = _vp2(capsys, "zoo", "add", str(source), "--name", "tiny", "--float32",
                        "--force", "--card-from", str(measured))
    assert code == 0 and "not measured (null): metrics\n" in out
    assert get_card("tiny").action_conditioning["ratio"] == 1.25
    assert get_card("tiny").control["robodesk"]["successes"] == 2
    state = read_model_checkpoint(zoo / "tiny" / CHECKPOINT_FILE)["model"]["state_dict"]
    trained = read_model_checkpoint(source)["model"]["state_dict"]
    assert all(torch.equal(state[k], v) for k, v in trained.items())  # --float32: as trained
    code, _, _ = _vp2(capsys, "zoo", "add", str(source), "--name", "tiny", "--force")
    assert code == 0 and get_card("tiny").control is None  # a new card: nothing carried over
    code, _, err = _vp2(capsys, "zoo", "add", str(source), "--name", "other", "--card-from",
                        str(measured))
    assert code == 2 and "the card of 'tiny', not of 'other'" in err


def test_a_changed_checkpoint_is_flagged_by_list_and_refused_by_run(capsys, tmp_path,
                                                                     monkeypatch):
    zoo = tmp_path / "zoo"
    monkeypatch.setenv("VP2_ZOO_DIR", str(zoo))
    code, _, _ = _vp2(capsys, "zoo", "add", str(make_checkpoint(tmp_path / "m.pt")), "--name",
                      "tiny")
    assert code == 0
    make_checkpoint(zoo / "tiny" / CHECKPOINT_FILE, seed=9)
    code, out, _ = _vp2(capsys, "zoo", "list")
    assert code == 0 and "! zoo model 'tiny': the checkpoint" in out
    code, out, _ = _vp2(capsys, "zoo", "show", "tiny")
    assert "DOES NOT MATCH" in out
    code, _, err = _vp2(capsys, "run", "--model", "zoo:tiny", "--tasks", "robodesk/push_red",
                        "--out", str(tmp_path / "r"), "--no-progress")
    assert code == 2 and "does not match its card" in err and not (tmp_path / "r").exists()


def test_bad_card_json_is_a_clear_error(capsys, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text("[1, 2]")
    code, _, err = _vp2(capsys, "zoo", "add", str(make_checkpoint(tmp_path / "m.pt")), "--name",
                        "t", "--card-from", str(bad), "--zoo", str(tmp_path / "zoo"))
    assert code == 2 and "expected a JSON mapping of card fields" in err


@pytest.mark.parametrize("overrides", [{}, {"perceptual": "lpips_vgg", "perceptual_weight": 10.0,
                                            "tasks": ["robodesk/push_red"], "amp": False}])
def test_the_cards_training_command_is_a_vp2_train_command_line(overrides):
    config = {"model": "fitvid", "preset": "mini", "model_overrides": {"rnn_size": "32"},
              "dataset": "data/my data", "out_dir": "runs/x", "steps": 10, "batch_size": 4,
              "seed": 2, "lr": 1e-3, "max_minutes": 30.0, "max_trajectories": 100,
              "optimizer": "adamw", "weight_decay": 0.01, "grad_clip": 1.0, **overrides}
    argv = shlex.split(train_command(config))
    assert argv[:2] == ["vp2", "train"]
    args = cli.build_parser().parse_args(argv[1:])
    assert (args.model, args.preset, args.model_arg, str(args.data)) == (
        "fitvid", "mini", ["rnn_size=32"], "data/my data")
    assert (args.steps, args.batch_size, args.seed, args.lr, args.max_minutes) == (
        10, 4, 2, 1e-3, 30.0)
    assert (args.num_trajectories, args.optimizer, args.weight_decay, args.grad_clip) == (
        100, "adamw", 0.01, 1.0)
    assert args.perceptual == overrides.get("perceptual")
    assert args.perceptual_weight == overrides.get("perceptual_weight")
    assert args.tasks == overrides.get("tasks", args.tasks) and str(args.out) == "runs/x"
    assert args.amp is overrides.get("amp")


def test_add_fills_control_and_metrics_from_their_files(capsys, tmp_path):
    from tests.report.test_cards import _trial, make_run

    run = make_run(tmp_path / "run", [_trial("robodesk/push_red", 0, 0, True),
                                      _trial("robodesk/push_red", 1, 0, False)])
    metrics = tmp_path / "metrics.json"
    metrics.write_text(json.dumps({"metrics": {"ssim": 0.8, "mse": 0.01}, "model": {"spec": "m"},
                                   "dataset": "d", "num_clips": 8, "seed": 0,
                                   "settings": {"fvd": False, "lpips_nets": []}}))
    zoo = tmp_path / "zoo"
    code, out, err = _vp2(capsys, "zoo", "add", str(make_checkpoint(tmp_path / "m.pt")), "--name",
                          "t", "--control", str(run), "--metrics", str(metrics), "--zoo", str(zoo))
    assert code == 0, err
    assert "not measured (null): action_conditioning, metrics.fvd, metrics.lpips, metrics.psnr\n" in out
    card = get_card("t", zoo)
    assert card.control["robodesk"]["successes"] == 1 and card.control["robodesk"]["trials"] == 2
    assert (card.metrics["ssim"], card.metrics["lpips"], card.metrics["fvd"]) == (0.8, None, None)
    given = tmp_path / "given.json"
    given.write_text(json.dumps({"metrics": {"ssim": 0.5}}))
    code, _, err = _vp2(capsys, "zoo", "add", str(tmp_path / "m.pt"), "--name", "u", "--metrics",
                        str(metrics), "--card-from", str(given), "--zoo", str(zoo))
    assert code == 2 and "--metrics and --card-from both give the card's metrics" in err


def test_a_reader_that_goes_away_ends_the_listing_quietly():
    # `vp2 zoo list | head -1`, deterministically: the pipe's reading end is closed before the
    # listing is written, so the first write fails (EPIPE).
    import os
    import subprocess
    import sys

    read, write = os.pipe()
    os.close(read)
    try:
        proc = subprocess.run([sys.executable, "-c", "from vp2.cli import main; "
                               "raise SystemExit(main())", "zoo", "list"], stdout=write,
                              stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write)
    assert proc.returncode == 141 and "Traceback" not in proc.stderr, proc.stderr


def test_fill_rewrites_the_measured_sections_and_leaves_the_checkpoint(capsys, tmp_path):
    from tests.report.test_cards import _trial, make_run

    zoo = tmp_path / "zoo"
    code, _, err = _vp2(capsys, "zoo", "add", str(make_checkpoint(tmp_path / "m.pt")), "--name",
                        "t", "--zoo", str(zoo))
    assert code == 0, err
    before = (zoo / "t" / CHECKPOINT_FILE).read_bytes()
    desk = make_run(tmp_path / "desk", [_trial("robodesk/push_red", 0, 0, True),
                                        _trial("robodesk/push_red", 1, 0, False)])
    table = make_run(tmp_path / "table", [_trial("tabletop/push_sphere", 0, 0, False)],
                     tasks=("tabletop",))
    metrics = tmp_path / "metrics.json"
    metrics.write_text(json.dumps({"metrics": {"fvd": 321.0, "ssim": 0.8}, "model": {"spec": "m"},
                                   "dataset": "d", "num_clips": 8, "seed": 0,
                                   "settings": {"fvd": True, "lpips_nets": []}}))
    code, out, err = _vp2(capsys, "zoo", "fill", "t", "--control", str(desk), "--metrics",
                          str(metrics), "--note", "the comparison's run", "--zoo", str(zoo))
    assert code == 0, err
    assert "t: control on robodesk 1/2\n" in out and "t: metrics fvd 321, ssim 0.8\n" in out
    # A later run of the other environment adds its row and keeps the first.
    code, _, err = _vp2(capsys, "zoo", "fill", "t", "--control", str(table), "--zoo", str(zoo))
    assert code == 0, err
    card = get_card("t", zoo)
    assert card.control["robodesk"]["successes"] == 1
    assert card.control["robodesk"]["note"] == "the comparison's run"
    assert card.control["tabletop"]["trials"] == 1 and card.metrics["fvd"] == 321.0
    assert (zoo / "t" / CHECKPOINT_FILE).read_bytes() == before  # the checkpoint untouched
    code, _, err = _vp2(capsys, "zoo", "fill", "t", "--zoo", str(zoo))
    assert code == 2 and "give --control RUN_DIR... and/or --metrics FILE" in err
    # A misspelt name is named first, whatever the runs hold.
    code, _, err = _vp2(capsys, "zoo", "fill", "tt", "--control", str(tmp_path), "--zoo", str(zoo))
    assert code == 2 and "no model 'tt' in the zoo" in err and "known: t;" in err
    (zoo / "t" / CHECKPOINT_FILE).write_bytes(before + b"x")  # changed after the card
    code, _, err = _vp2(capsys, "zoo", "fill", "t", "--metrics", str(metrics), "--zoo", str(zoo))
    assert code == 2 and "does not match its card" in err
