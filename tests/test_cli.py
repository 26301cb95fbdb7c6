"""The ``vp2`` command line: flags map onto the library's configs."""

from __future__ import annotations

import dataclasses

import pytest

from vp2 import cli
from vp2.benchmark.runner import AGENTS, RunConfig
from vp2.planning import OPTIMIZERS


def _run_args(*extra: str):
    return cli.build_parser().parse_args(["run", "--out", "runs/x", *extra])


def test_run_defaults_equal_runconfig_defaults():
    config = cli.run_config_from_args(_run_args("--model", "repeat_last_frame"))
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


def test_run_choices_match_library():
    assert set(cli.RUN_OPTIMIZERS) == set(OPTIMIZERS)
    config = cli.run_config_from_args(_run_args("--agent", "random"))
    assert config.agent == "random" and set(AGENTS) == {"planning", "random"}


def test_run_flags_are_passed_through():
    config = cli.run_config_from_args(_run_args(
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
