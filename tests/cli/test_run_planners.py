"""``vp2 run`` end to end with an ensemble of zoo models and with every planner, and the
planner settings only some optimizers read (``--num-elites``, ``--lr``, ...)."""

from __future__ import annotations

import inspect
import json
import math

import pytest
import yaml

from tests.benchmark import tiny_suite_path
from vp2 import cli
from vp2.cli import run as run_cmd
from vp2.planning import CEM, CEMGD, LBFGS
from vp2.planning.planner import PlannerConfig

TINY = "zoo:svg_prime-tiny-tabletop"  # differentiable, 1.6 M parameters
ENSEMBLE = f"ensemble({TINY},zoo:fitvid-tabletop-15min)"


def _run(out, model: str, *extra: str, steps: int = 2) -> list[str]:
    return ["run", "--model", model, "--suite", str(tiny_suite_path()), "--tasks",
            "tabletop/push_sphere", "--num-instances", "1", "--seeds", "0", "--num-steps",
            str(steps), "--num-samples", "8", "--no-gifs", "--no-progress", "--no-precheck",
            "--out", str(out), *extra]


def _record(out) -> dict:
    (line,) = (out / "trials.jsonl").read_text().splitlines()
    return json.loads(line)


def test_vp2_run_and_report_plan_with_an_ensemble_of_two_zoo_models(tmp_path, capsys):
    out = tmp_path / "ensemble"
    assert cli.main(_run(out, ENSEMBLE, steps=3)) == 0
    record = _record(out)
    assert record["error"] is None and record["num_steps"] == 3
    # The record says it was an ensemble, with its members, and each step's member draws.
    assert record["model"]["class"] == "vp2.models.ensemble.EnsembleModel"
    assert [m["spec"] for m in record["model"]["ensemble"]] == [
        TINY, "zoo:fitvid-tabletop-15min"
    ]
    assert [m["name"] for m in record["model"]["ensemble"]] == ["svg_prime", "fitvid"]
    ensemble = record["agent"]["ensemble"]
    assert ensemble["members"] == [TINY, "zoo:fitvid-tabletop-15min"] and ensemble["lam"] == 0.01
    assert len(ensemble["steps"]) == 2  # the first step executes the zero action
    assert all(sum(s["draws"]) == 8 and s["best_member"] in (0, 1) for s in ensemble["steps"])
    assert all(math.isfinite(s) for s in record["scores"])
    config = yaml.safe_load((out / "config.yaml").read_text())
    assert config["config"]["model"] == ENSEMBLE
    assert any("is an ensemble" in d for d in config["spec_deviations"])
    capsys.readouterr()
    assert cli.main(["report", str(out), "--out", str(tmp_path / "r.html")]) == 0
    assert ENSEMBLE in (tmp_path / "r.html").read_text()


@pytest.mark.parametrize(
    ("optimizer", "flags", "expected"),
    [
        ("mppi", [], {"num_samples": 8}),
        ("cem", ["--num-elites", "3", "--num-iterations", "2"],
         {"num_samples": 8, "num_elites": 3, "num_iterations": 2}),
        ("cem_gd", ["--num-samples-first", "8", "--num-elites", "3", "--num-iterations", "1",
                    "--num-refined", "2", "--lr", "0.02", "--grad-steps", "2"],
         {"num_samples": 8, "num_samples_first": 8, "num_elites": 3, "num_iterations": 1,
          "num_refined": 2, "lr": 0.02, "max_steps": 2}),
        ("lbfgs", ["--lr", "0.07", "--grad-steps", "1"], {"lr": 0.07, "num_steps": 1}),
    ],
)
def test_every_planner_plans_with_a_differentiable_zoo_model(optimizer, flags, expected,
                                                            tmp_path, capsys):
    out = tmp_path / optimizer
    assert cli.main(_run(out, TINY, "--optimizer", optimizer, *flags)) == 0
    record = _record(out)
    assert record["error"] is None and record["success"] in (True, False)
    planner = record["agent"]["planner"]
    assert planner["optimizer"] == optimizer
    assert {k: planner[k] for k in expected} == expected
    (score,) = record["scores"]  # one planning step
    assert math.isfinite(score)


def test_a_setting_the_optimizer_does_not_read_stops_the_run_before_it_starts(tmp_path, capsys):
    out = tmp_path / "x"
    assert cli.main(_run(out, TINY, "--num-elites", "5")) == 2
    err = capsys.readouterr().err
    assert err == ("vp2 run: error: planner setting num_elites=5 is read by cem and cem_gd, not "
                   "by mppi: drop it or plan with cem or cem_gd\n")
    assert cli.main(_run(out, TINY, "--optimizer", "lbfgs", "--grad-steps", "0")) == 2
    assert capsys.readouterr().err == ("vp2 run: error: planner setting grad_steps must be an "
                                       "integer >= 1, got 0\n")
    assert not out.exists()


def test_a_gradient_planner_names_the_ensemble_member_without_gradients(tmp_path, capsys):
    model = f"ensemble({TINY},repeat_last_frame)"
    assert cli.main(_run(tmp_path / "x", model, "--optimizer", "lbfgs")) == 3
    err = capsys.readouterr().err
    assert err.startswith(f"vp2 run: error: model '{model}' cannot run these tasks: the lbfgs "
                          "optimizer needs gradients of the predictions with respect to the "
                          "actions, but model ensemble (member 'repeat_last_frame') returned "
                          "predictions")
    assert err.count("\n") == 1


def test_a_bad_ensemble_member_is_one_line_before_any_trial(tmp_path, capsys):
    model = f"ensemble({TINY},zoo:no-such-model)"
    assert cli.main(_run(tmp_path / "x", model)) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"vp2 run: error: ensemble member 2 of '{model}': model "
                          "'zoo:no-such-model': no model 'no-such-model' in the zoo")
    assert err.count("\n") == 1 and not (tmp_path / "x").exists()


def test_vp2_diagnose_refuses_an_ensemble_in_one_line(capsys):
    model = f"ensemble({TINY},repeat_last_frame)"
    assert cli.main(["diagnose", "--model", model]) == 2
    assert capsys.readouterr().err == (
        f"vp2 diagnose: error: model '{model}': an ensemble is not diagnosed as one model; "
        f"diagnose each member on its own (--model {TINY}, --model repeat_last_frame)\n"
    )


def test_the_planner_flags_build_the_planner_and_their_help_names_the_class_defaults():
    args = cli.build_parser().parse_args(
        ["run", "--out", "o", "--model", TINY, "--optimizer", "cem_gd", "--num-elites", "4",
         "--num-samples-first", "100", "--num-refined", "3", "--lr", "0.05", "--grad-steps",
         "9"]
    )
    assert run_cmd.run_config_from_args(args).planner == PlannerConfig(
        "cem_gd", num_elites=4, num_samples_first=100, num_refined=3, lr=0.05, grad_steps=9
    )

    def default(cls, argument):
        return inspect.signature(cls).parameters[argument].default

    helps = {key.partition(".")[2]: flag.help for key, flag in run_cmd.FLAGS.items()
             if key.startswith("planner.") and flag is not None}
    assert f"(default {default(CEM, 'num_elites')})" in helps["num_elites"]
    assert default(CEM, "num_elites") == default(CEMGD, "num_elites")
    assert f"(default {default(CEMGD, 'num_samples_first')};" in helps["num_samples_first"]
    assert f"default {default(CEMGD, 'num_samples')})" in helps["num_samples_first"]
    assert f"(default {default(CEMGD, 'num_refined')})" in helps["num_refined"]
    assert f"(default {default(CEMGD, 'lr')});" in helps["lr"]
    assert f"(default {default(LBFGS, 'lr')};" in helps["lr"]
    assert f"(default {default(CEMGD, 'max_steps')});" in helps["grad_steps"]
    assert f"(default {default(LBFGS, 'num_steps')})" in helps["grad_steps"]
    assert f"cem and cem_gd {default(CEM, 'num_iterations')})" in helps["num_iterations"]
