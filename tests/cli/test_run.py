"""The ``vp2`` command line: flags map onto the library's configs."""

from __future__ import annotations

import dataclasses

import pytest

from vp2 import cli, spec
from vp2.cli import run as run_cmd
from vp2.cli._fields import NOT_A_FLAG, dest
from vp2.planning import OPTIMIZERS
from vp2.planning.planner import COST_MODES, PlannerConfig
from vp2.run.config import AGENTS, RunConfig
from vp2.utils.executors.base import EXECUTORS


def _run_args(*extra: str):
    return cli.build_parser().parse_args(["run", "--out", "runs/x", *extra])


def test_run_defaults_equal_runconfig_defaults():
    config = run_cmd.run_config_from_args(_run_args("--model", "repeat_last_frame"))
    expected = RunConfig(model="repeat_last_frame", out="runs/x")
    assert config == expected


def test_run_has_one_flag_per_runconfig_field():
    run_parser = cli.build_parser()._subparsers._group_actions[0].choices["run"]  # noqa: SLF001
    dests = {a.dest for a in run_parser._actions}  # noqa: SLF001
    planner = {f"planner.{f.name}" for f in dataclasses.fields(PlannerConfig)}
    fields = {f.name for f in dataclasses.fields(RunConfig) if f.name != "planner"} | planner
    assert set(run_cmd.FLAGS) == fields  # every field has an entry, in RunConfig's order
    flags = {k: f for k, f in run_cmd.FLAGS.items() if f is not NOT_A_FLAG}
    assert set(flags) == fields - {"planner.sigma", "planner.options"}
    assert {dest(k, f) for k, f in flags.items()} <= dests
    # Negated booleans: save_gifs <- --no-gifs, progress <- --no-progress; the planner's
    # fields keep their flags' names.
    assert dest("save_gifs", flags["save_gifs"]) == "no_gifs"
    assert dest("planner.num_samples", flags["planner.num_samples"]) == "num_samples"


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
    assert defaults["num_samples"] is None  # resolved per task: Task.num_samples (vp2.envs.tasks.TASKS)


def test_run_flags_are_passed_through():
    config = run_cmd.run_config_from_args(_run_args(
        "--model", "simulator", "--model-arg", "num_workers=2", "--tasks", "tabletop",
        "--num-instances", "3", "--seeds", "4", "5", "6", "--optimizer", "cem",
        "--num-samples", "50", "--no-gifs", "--resume", "--workers", "2", "--stop-on-success"))
    assert config.model_args == {"num_workers": 2}
    assert config.tasks == ("tabletop",) and config.num_instances == 3
    assert config.seeds == (4, 5, 6) and config.planner == PlannerConfig("cem", num_samples=50)
    assert not config.save_gifs and config.resume and config.workers == 2
    assert config.stop_on_success


def test_run_bad_input_is_a_clear_error(capsys, tmp_path):
    assert cli.main(["run", "--out", "runs/x"]) == 2
    assert "--model is required" in capsys.readouterr().err
    assert cli.main(["run", "--out", "runs/x", "--model", "repeat_last_frame",
                     "--seeds", "1", "1"]) == 2
    assert "seeds must be distinct" in capsys.readouterr().err
    # A negative seed is refused before any trial (it used to record every trial as an error).
    assert cli.main(["run", "--out", str(tmp_path / "x"), "--model", "repeat_last_frame",
                     "--seeds", "0", "-1"]) == 2
    assert "every seed must be a non-negative integer, got -1" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    with pytest.raises(SystemExit):
        cli.main(["run", "--out", "runs/x", "--optimizer", "adam"])


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["--model", "m"], dict(model="m")),
        (["--agent", "random"], dict(model="none", agent="random")),
        (
            ["--model", "simulator", "--model-arg", "num_workers=2", "--model-arg", "a=[1, 2]",
             "--suite", "s.npz", "--tasks", "tabletop", "robodesk/push_red", "--num-instances",
             "3", "--seeds", "4", "5", "--optimizer", "cem", "--num-samples", "50", "--gamma",
             "0.1", "--num-iterations", "2", "--cost", "pixel_only", "--num-steps", "5",
             "--stop-on-success", "--workers", "2", "--executor", "ray", "--address", "auto",
             "--num-cpus-per-worker", "2", "--num-gpus-per-worker", "0.5", "--device", "cpu",
             "--max-retries", "3", "--resume", "--retry-errors", "--no-gifs",
             "--save-predictions", "--oracle", "o", "--no-progress"],
            dict(model="simulator", model_args={"num_workers": 2, "a": [1, 2]}, suite="s.npz",
                 tasks=("tabletop", "robodesk/push_red"), num_instances=3, seeds=(4, 5),
                 planner=PlannerConfig("cem", 50, 0.1, 2), cost="pixel_only", num_steps=5,
                 stop_on_success=True, workers=2, executor="ray", address="auto",
                 num_cpus_per_worker=2.0, num_gpus_per_worker=0.5, device="cpu",
                 max_retries=3, resume=True, retry_errors=True, save_gifs=False,
                 save_predictions=True, oracle="o", progress=False),
        ),
    ],
)
def test_the_generated_parser_gives_the_runconfig_of_the_hand_written_one(argv, expected):
    """What the hand-written flag-to-field code built, field by field (before the flags were
    generated from the fields)."""
    config = run_cmd.run_config_from_args(_run_args(*argv))
    assert config == RunConfig(out="runs/x", **expected)
    assert isinstance(config.tasks, tuple) and isinstance(config.seeds, tuple)


def test_main_flags_build_the_main_job_config(monkeypatch, tmp_path):
    from vp2.benchmark.main_job import MainJobConfig
    from vp2.cli import main_job

    seen = []
    monkeypatch.setattr(main_job, "run_main_job", lambda c, after_run=None: seen.append(c) or ("", ""))
    out = str(tmp_path / "m")
    for argv in ([], ["--out", out, "--num-instances", "3", "--seeds", "1", "2", "--tasks",
                      "robodesk", "--model-samples", "0", "--workers", "1", "--agents", "random",
                      "--fresh"]):
        assert main_job.run_from_args(cli.build_parser().parse_args(["main", *argv])) == 0
    assert seen == [
        MainJobConfig(),
        MainJobConfig(out=out, num_instances=3, seeds=(1, 2), tasks=("robodesk",),
                      model_samples=None, workers=1, agents=("random",), resume=False),
    ]
