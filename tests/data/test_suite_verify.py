"""``vp2 tasks verify``: a suite made on this machine verifies; any changed bit is named. ``vp2 tasks
generate`` checks its arguments first."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vp2.cli import main
from vp2.data.suite import TaskSuite, generate_instance, instance_seed
from vp2.data.suite_verify import verify_suite


@pytest.fixture(scope="module")
def local_suite() -> TaskSuite:
    """One instance each of a RoboDesk and a tabletop task, generated here."""
    instances = []
    for task in ("robodesk/push_red", "tabletop/push_sphere"):
        attempt = 0
        while (inst := generate_instance(task, instance_seed(2023, task, attempt), 0)) is None:
            attempt += 1
        instances.append(inst)
    return TaskSuite(instances, seed=2023)


def _tampered(suite: TaskSuite, task: str, **changes) -> TaskSuite:
    return TaskSuite([dataclasses.replace(i, **changes) if i.task == task else i for i in suite],
                     seed=suite.seed)


def test_a_suite_made_here_verifies(local_suite):
    report = verify_suite(local_suite, regenerate=1, progress=False)
    assert report.ok and (report.replayed, report.regenerated) == (2, 2)


def test_a_changed_goal_state_and_goal_image_are_named(local_suite):
    inst = local_suite.for_task("tabletop/push_sphere")[0]
    goal = inst.goal_state.copy()
    goal[3] = np.nextafter(goal[3], np.inf)  # one bit of one element
    report = verify_suite(_tampered(local_suite, inst.task, goal_state=goal), regenerate=0,
                          progress=False)
    assert [(m.key, m.check, m.field) for m in report.mismatches] == [
        ("tabletop/push_sphere#0", "replay", "goal_state")]
    assert report.mismatches[0].detail.startswith(f"1 of {goal.size} elements, largest ")
    image = local_suite.for_task("robodesk/push_red")[0].goal_image.copy()
    image[5, 7, 1] ^= 1
    report = verify_suite(_tampered(local_suite, "robodesk/push_red", goal_image=image),
                          regenerate=0, progress=False)
    assert [str(m) for m in report.mismatches] == [
        "robodesk/push_red#0: replay: goal_image differs (1 of 12288 elements, largest 1)"]


def test_a_changed_action_is_found_by_regeneration(local_suite):
    inst = local_suite.for_task("robodesk/push_red")[0]
    actions = inst.actions.copy()
    actions[0, 0] += 1e-12
    report = verify_suite(_tampered(local_suite, inst.task, actions=actions), replay=False,
                          progress=False)
    assert [(m.check, m.field) for m in report.mismatches] == [("regenerate", "actions")]


def test_the_command_exits_1_on_a_mismatch(local_suite, tmp_path, capsys):
    good, bad = tmp_path / "good.npz", tmp_path / "bad.npz"
    local_suite.save(good)
    inst = local_suite.for_task("tabletop/push_sphere")[0]
    goal = inst.goal_state.copy()
    goal[3] += 1e-6
    _tampered(local_suite, inst.task, goal_state=goal).save(bad)
    assert main(["tasks", "verify", "--suite", str(good), "--no-progress"]) == 0
    out = capsys.readouterr().out
    assert "2 replayed, 2 regenerated; every instance reproduced bit for bit" in out
    assert main(["tasks", "verify", "--suite", str(bad), "--no-progress", "--regenerate", "0"]) == 1
    out = capsys.readouterr().out
    assert "MISMATCH tabletop/push_sphere#0: replay: goal_state differs" in out
    assert "1 instance(s) differ on this machine" in out


def test_generate_checks_its_arguments_before_generating(tmp_path, capsys):
    out = tmp_path / "new" / "dir" / "suite.npz"
    assert main(["tasks", "generate", "--tasks", "robodesk/push_rd", "--out", str(out)]) == 2
    assert "unknown task categories robodesk/push_rd" in capsys.readouterr().err
    # --count 0 once meant "the SPEC's counts": 310 instances.
    assert main(["tasks", "generate", "--count", "0", "--out", str(out)]) == 2
    assert "--count must be >= 1, got 0" in capsys.readouterr().err
    assert not out.parent.exists()
    assert main(["tasks", "generate", "--tasks", "robodesk/push_red", "--count", "1",
                 "--workers", "1", "--out", str(out)]) == 0  # its folder is made first
    suite = TaskSuite.load(out)
    assert suite.tasks == ["robodesk/push_red"] and len(suite.for_task("robodesk/push_red")) == 1
