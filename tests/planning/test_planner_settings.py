"""``planner_settings`` is recorded in every trial record: its output is pinned, key order and
value types included, for every optimizer on a large-sample RoboDesk task, a RoboDesk task and a
tabletop task, with and without each override. The expected dicts (``golden/planner_settings.json``) were
captured from the if/elif ``planner_settings`` before each optimizer owned its settings."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from vp2.planning.planner import PlannerConfig, build_optimizer, planner_settings

TASK = "tabletop/push_sphere"


def _configs(task: str) -> dict[str, dict]:
    width = 4 if task.startswith("tabletop/") else 5
    return {
        "default": {},
        "num_samples": {"num_samples": 8},
        "num_iterations": {"num_iterations": 2},
        "options": {"options": {"num_elites": 4, "num_samples": 5}},
        "all": {
            "num_samples": 16,
            "num_iterations": 3,
            "gamma": 0.5,
            "sigma": (0.25,) * width,
            "options": {"num_elites": 4},
        },
    }


#: ``"OPTIMIZER TASK CASE"`` -> the settings dict, or the error message.
EXPECTED: dict[str, dict | str] = json.loads(
    (Path(__file__).parent / "golden" / "planner_settings.json").read_text()
)


@pytest.mark.parametrize("key", list(EXPECTED))
def test_planner_settings_are_pinned(key):
    optimizer, task, case = key.split()
    config = PlannerConfig(optimizer=optimizer, **_configs(task)[case])
    expected = EXPECTED[key]
    if isinstance(expected, str):  # a message: the call must raise it
        with pytest.raises(ValueError) as error:
            planner_settings(task, config)
        assert str(error.value) == expected
        return
    settings = planner_settings(task, config)
    # repr sees key order and value types (int/float, list/tuple), as a trial record does.
    assert repr(settings) == repr(expected)


def test_planner_settings_errors_are_pinned():
    with pytest.raises(ValueError, match="^unknown optimizer 'adam'; choose one of mppi, cem, "):
        planner_settings("no/such_task", PlannerConfig(optimizer="adam"))
    with pytest.raises(ValueError, match="^unknown task 'no/such_task'; registered tasks are: "):
        planner_settings("no/such_task", PlannerConfig(optimizer="lbfgs"))
    for optimizer in ("mppi", "cem", "cem_gd", "lbfgs"):
        with pytest.raises(
            ValueError, match=r"^tabletop/push_sphere: sigma has 2 entries, the action has 4$"
        ):
            planner_settings("tabletop/push_sphere", PlannerConfig(optimizer, sigma=(0.1, 0.1)))


def test_the_fields_only_some_optimizers_read_set_their_arguments():
    tuned = {"num_elites": 3, "num_samples_first": 9, "num_refined": 2, "lr": 0.07,
             "grad_steps": 4}
    settings = planner_settings(TASK, PlannerConfig("cem_gd", **tuned))
    assert {k: settings[k] for k in ("num_elites", "num_samples_first", "num_refined", "lr",
                                     "max_steps")} == {
        "num_elites": 3, "num_samples_first": 9, "num_refined": 2, "lr": 0.07, "max_steps": 4
    }
    assert planner_settings(TASK, PlannerConfig("lbfgs", lr=0.07, grad_steps=4)) == {
        "optimizer": "lbfgs", "lr": 0.07, "num_steps": 4
    }
    assert planner_settings(TASK, PlannerConfig("cem", num_elites=3))["num_elites"] == 3
    # options still override (they are the optimizer's own keyword arguments).
    assert planner_settings(TASK, PlannerConfig("lbfgs", lr=0.07, options={"lr": 0.01}))[
        "lr"] == 0.01
    built = build_optimizer(TASK, PlannerConfig("cem_gd", **tuned))
    assert (built.num_elites, built.num_samples_first, built.num_refined, built.lr,
            built.max_steps) == (3, 9, 2, 0.07, 4)


@pytest.mark.parametrize(
    ("config", "message"),
    [
        (PlannerConfig("mppi", num_elites=5), "planner setting num_elites=5 is read by cem and "
         "cem_gd, not by mppi: drop it or plan with cem or cem_gd"),
        (PlannerConfig("cem", lr=0.05), "planner setting lr=0.05 is read by cem_gd and lbfgs, "
         "not by cem: drop it or plan with cem_gd or lbfgs"),
        (PlannerConfig("lbfgs", num_samples_first=8), "planner setting num_samples_first=8 is "
         "read by cem_gd, not by lbfgs: drop it or plan with cem_gd"),
        (PlannerConfig("lbfgs", lr=0.0), "planner setting lr must be a number > 0, got 0.0"),
        (PlannerConfig("cem_gd", grad_steps=0), "planner setting grad_steps must be an integer "
         ">= 1, got 0"),
        (PlannerConfig("cem", num_elites=2.5), "planner setting num_elites must be an integer "
         ">= 1, got 2.5"),
    ],
)
def test_a_field_the_optimizer_does_not_read_or_out_of_range_is_refused(config, message):
    with pytest.raises(ValueError) as error:
        planner_settings(TASK, config)
    assert str(error.value) == message
