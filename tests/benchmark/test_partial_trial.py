"""A trial cut off mid-way resumes at the step it reached and ends exactly as the uninterrupted
trial (vp2.run.partial): by hand through ControlTrial, and through a run whose first
attempt of a trial dies after two steps."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from tests.benchmark import tiny_suite_path
from vp2.benchmark import worker
from vp2.benchmark.runner import run_benchmark
from vp2.data.suite import TaskSuite
from vp2.planning import PlannerConfig, PlanningAgent, RandomActions
from vp2.run.config import RunConfig
from vp2.run.model_spec import resolve_model
from vp2.run.partial import (
    PartialMismatch,
    PartialTrial,
    load_partial,
    save_partial,
)
from vp2.run.run_dir import RunDir, read_trials
from vp2.run.trial import ControlTrial

TASK = "tabletop/push_sphere"
STEPS = 5


class Cut(Exception):
    """The process 'dies' after a checkpoint."""


@pytest.fixture(scope="module")
def instance():
    return TaskSuite.load(tiny_suite_path()).get(TASK, 1)


@pytest.fixture(scope="module")
def oracle_agent():
    model = resolve_model("simulator", {}, env="tabletop", action_dim=4, device="cpu")
    yield PlanningAgent(model, PlannerConfig(num_samples=4))
    model.close()


def _trial(instance, agent, **kwargs) -> ControlTrial:
    return ControlTrial(instance, agent, seed=3, num_steps=STEPS, checkpoint_every_s=0, **kwargs)


def _cut_after(steps: int, saved: list[PartialTrial]):
    def checkpoint(partial: PartialTrial) -> None:
        saved.append(partial)
        if partial.steps == steps:
            raise Cut
    return checkpoint


def test_a_resumed_oracle_trial_ends_as_the_uninterrupted_one(instance, oracle_agent, tmp_path):
    whole = _trial(instance, oracle_agent).run()
    saved: list[PartialTrial] = []
    with pytest.raises(Cut):
        _trial(instance, oracle_agent, checkpoint=_cut_after(3, saved)).run()
    assert [p.steps for p in saved] == [1, 2, 3]
    # through the file, as a worker keeps it
    path = RunDir(tmp_path).partial_path(TASK, 1, 3)
    save_partial(path, saved[-1])
    partial = load_partial(path)
    np.testing.assert_array_equal(partial.actions, whole.actions[:3])
    resumed = _trial(instance, oracle_agent, resume=partial)
    result = resumed.run()
    assert resumed.resumed_steps == 3
    np.testing.assert_array_equal(result.actions, whole.actions)  # bit for bit
    assert result.success_steps == whole.success_steps
    assert result.scores == whole.scores and len(result.planning_times) == STEPS - 1
    np.testing.assert_array_equal(result.frames, whole.frames)
    assert result.total_time >= partial.elapsed
    # the warm start and generators matter: without the agent's state the plans differ
    stale = dataclasses.replace(partial, agent_state=saved[0].agent_state)
    assert not np.array_equal(_trial(instance, oracle_agent, resume=stale).run().actions,
                              whole.actions)


def test_a_partial_trial_of_other_settings_or_that_does_not_replay_is_refused(
        instance, oracle_agent):
    saved: list[PartialTrial] = []
    with pytest.raises(Cut):
        _trial(instance, oracle_agent, checkpoint=_cut_after(2, saved), meta={"m": 1}).run()
    partial = saved[-1]
    with pytest.raises(PartialMismatch, match="made with other m"):
        _trial(instance, oracle_agent, resume=partial, meta={"m": 2}).run()
    other_seed = ControlTrial(instance, oracle_agent, seed=4, num_steps=STEPS, resume=partial,
                              meta={"m": 1})
    with pytest.raises(PartialMismatch, match="made with other seed"):
        other_seed.run()
    wrong = dataclasses.replace(partial, success_steps=[True, True])
    with pytest.raises(PartialMismatch, match=r"gave the success flags \[False, False\]"):
        _trial(instance, oracle_agent, resume=wrong, meta={"m": 1}).run()


def test_the_random_agent_resumes_and_unreadable_files_are_ignored(instance, tmp_path, caplog):
    agent = RandomActions(4)
    whole = _trial(instance, agent).run()
    saved: list[PartialTrial] = []
    with pytest.raises(Cut):
        _trial(instance, agent, checkpoint=_cut_after(2, saved)).run()
    path = tmp_path / "p.npz"
    save_partial(path, saved[-1])  # the generator's 128-bit state goes through JSON
    result = _trial(instance, agent, resume=load_partial(path)).run()
    np.testing.assert_array_equal(result.actions, whole.actions)
    path.write_bytes(b"not a zip")
    assert load_partial(path) is None and "unreadable partial trial" in caplog.text
    assert load_partial(tmp_path / "absent.npz") is None


def test_a_run_resumes_a_trial_whose_first_attempt_died_mid_way(tmp_path, monkeypatch):
    config = RunConfig(
        model="simulator", tasks=(TASK,), num_instances=1, seeds=(0,), suite=str(tiny_suite_path()),
        planner=PlannerConfig(num_samples=4), num_steps=4, save_gifs=False, progress=False,
        device="cpu", out=str(tmp_path / "whole"))  # fmt: skip
    run_benchmark(config)
    (whole,) = read_trials(tmp_path / "whole")

    monkeypatch.setattr("vp2.run.partial.CHECKPOINT_EVERY_S", 0.0)
    real_save, calls = worker.save_partial, []

    def dying_save(path, partial):
        real_save(path, partial)
        calls.append(partial.steps)
        if len(calls) == 2:  # the first attempt dies once it has saved two steps
            raise RuntimeError("killed")

    monkeypatch.setattr(worker, "save_partial", dying_save)
    cut = dataclasses.replace(config, out=str(tmp_path / "cut"), max_retries=1)
    run_benchmark(cut)
    (record,) = read_trials(tmp_path / "cut")
    assert record["error"] is None and record["attempts"] == 2
    assert record["previous_errors"][0]["message"] == "killed"
    assert record["resumed_at_step"] == 2 and calls == [1, 2, 3, 4]
    assert record["actions"] == whole["actions"] and record["success"] == whole["success"]
    assert not RunDir(tmp_path / "cut").partial_path(TASK, 0, 0).exists()  # recorded: deleted
