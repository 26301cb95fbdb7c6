"""The ``vp2`` command line: flags map onto the library's configs."""

from __future__ import annotations

import dataclasses

import pytest

from vp2 import cli, spec
from vp2.benchmark.config import AGENTS, RunConfig
from vp2.cli import run as run_cmd
from vp2.planning import OPTIMIZERS
from vp2.planning.planner import COST_MODES
from vp2.utils.executors.base import EXECUTORS


def _run_args(*extra: str):
    return cli.build_parser().parse_args(["run", "--out", "runs/x", *extra])


def test_run_defaults_equal_runconfig_defaults():
    config = run_cmd.run_config_from_args(_run_args("--model", "repeat_last_frame"))
    expected = RunConfig(model="repeat_last_frame", out="runs/x")
    assert config == expected


def test_run_has_one_flag_per_runconfig_field():
    parser = cli.build_parser()
    run_parser = parser._subparsers._group_actions[0].choices["run"]  # noqa: SLF001
    dests = {a.dest for a in run_parser._actions}  # noqa: SLF001
    # Negated booleans: save_gifs <- --no-gifs, progress <- --no-progress.
    renamed = {"save_gifs": "no_gifs", "progress": "no_progress", "model_args": "model_arg"}
    for field in dataclasses.fields(RunConfig):
        assert renamed.get(field.name, field.name) in dests, field.name


def _run_parser():
    return cli.build_parser()._subparsers._group_actions[0].choices["run"]  # noqa: SLF001


def test_run_choices_match_library():
    """The parser's literal choices (it does not import torch to list them) are the library's."""
    choices = {a.dest: set(a.choices) for a in _run_parser()._actions if a.choices}  # noqa: SLF001
    assert choices == {
        "optimizer": set(OPTIMIZERS),
        "agent": set(AGENTS),
        "cost": set(COST_MODES),
        "executor": set(EXECUTORS),
    }
    config = run_cmd.run_config_from_args(_run_args("--agent", "random"))
    assert config.agent == "random"


def test_run_defaults_are_the_spec():
    defaults = {a.dest: a.default for a in _run_parser()._actions}  # noqa: SLF001
    assert defaults["gamma"] == spec.GAMMA
    assert defaults["num_steps"] == spec.NUM_CONTROL_STEPS
    assert len(defaults["seeds"]) == spec.MIN_SEEDS
    assert defaults["num_samples"] is None  # resolved per task: spec.num_samples_for


def test_run_flags_are_passed_through():
    config = run_cmd.run_config_from_args(_run_args(
        "--model", "simulator", "--model-arg", "num_workers=2", "--tasks", "tabletop",
        "--num-instances", "3", "--seeds", "4", "5", "6", "--optimizer", "cem",
        "--num-samples", "50", "--no-gifs", "--resume", "--workers", "2", "--stop-on-success"))
    assert config.model_args == {"num_workers": 2}
    assert config.tasks == ("tabletop",) and config.num_instances == 3
    assert config.seeds == (4, 5, 6) and config.optimizer == "cem" and config.num_samples == 50
    assert not config.save_gifs and config.resume and config.workers == 2
    assert config.stop_on_success


def test_run_bad_input_is_a_clear_error(capsys):
    assert cli.main(["run", "--out", "runs/x"]) == 2
    assert "--model is required" in capsys.readouterr().err
    assert cli.main(["run", "--out", "runs/x", "--model", "repeat_last_frame",
                     "--seeds", "1", "1"]) == 2
    assert "seeds must be distinct" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli.main(["run", "--out", "runs/x", "--optimizer", "adam"])
