"""``planner_settings`` is recorded in every trial record: its output is pinned, key order and
value types included, for every optimizer on a large-sample RoboDesk task, a RoboDesk task and a
tabletop task, with and without each override. The expected dicts (``golden/planner_settings.json``) were
captured from the if/elif ``planner_settings`` before each optimizer owned its settings."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from vp2.planning.planner import PlannerConfig, planner_settings


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
