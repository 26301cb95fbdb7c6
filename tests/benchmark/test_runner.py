"""The runner: records, GIFs, resume after SIGKILL, errors and retries, dead workers."""

from __future__ import annotations

import datetime
import json
import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import imageio.v3 as iio
import pytest

from tests.benchmark import tiny_suite_path
from vp2.benchmark.runner import ModelFailure, run_benchmark
from vp2.planning.planner import PlannerConfig
from vp2.run.config import RunConfig
from vp2.run.model_spec import parse_model_args
from vp2.run.results import trial_key
from vp2.run.run_dir import RunDir, read_config, read_trials

REPO = Path(__file__).resolve().parents[2]
STEPS = 3


def _config(tmp_path: Path, name: str, **overrides) -> RunConfig:
    kwargs = dict(
        model="repeat_last_frame",
        out=str(tmp_path / name),
        suite=str(tiny_suite_path()),
        seeds=(0, 1),
        num_steps=STEPS,
        planner=PlannerConfig(num_samples=8),
        progress=False,
    )
    kwargs.update(overrides)
    return RunConfig(**kwargs)


def _outcomes(records):
    """What must not depend on how a run was executed: key -> (success, flags, actions)."""
    return {
        trial_key(r): (r["success"], tuple(r["success_steps"]), json.dumps(r["actions"]))
        for r in records
    }


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """An uninterrupted in-process run: 2 tabletop instances x 3 seeds."""
    tmp = tmp_path_factory.mktemp("reference")
    return run_benchmark(_config(tmp, "run", seeds=(0, 1, 2), save_predictions=True))


def test_run_writes_records_gifs_config_and_summary(reference):
    run_dir = reference.run_dir
    assert reference.num_run == 6 and reference.num_skipped == 0 and reference.num_errors == 0
    records = read_trials(run_dir)
    assert sorted(trial_key(r) for r in records) == sorted(
        ("tabletop/push_sphere", i, s) for i in (0, 1) for s in (0, 1, 2)
    )
    for r in records:
        assert r["error"] is None and r["attempts"] == 1
        assert r["cost"] == "pixel" and r["num_steps"] == STEPS
        assert (
            r["model"]["name"] == "repeat_last_frame" and r["model"]["spec"] == "repeat_last_frame"
        )
        assert r["vp2_version"] and len(r["timings"]["planning_s"]) == STEPS - 1
        assert r["success"] == (r["instance"] == 0)  # by construction of the tiny suite
        gif = iio.imread(run_dir / r["gif"], index=None)
        assert gif.shape == (STEPS + 1, 128, 256, 3)  # execution | goal, upscaled x2
        plan = iio.imread(run_dir / r["plan_gif"], index=None)
        assert plan.shape == (STEPS - 1, 128, 11 * 128, 3)  # 10 predictions | goal
    assert read_config(run_dir) == reference.config
    (row,) = reference.summary.tasks
    assert row.mean == 0.5 and row.per_seed == {0: 0.5, 1: 0.5, 2: 0.5}
    text = (run_dir / "summary.md").read_text()
    assert "tabletop/push_sphere" in text and "num_steps=3 (SPEC: 15)" in text
    assert json.loads((run_dir / "summary.json").read_text())["mean"] == 0.5


def test_existing_run_needs_resume_and_the_same_protocol(reference, tmp_path):
    cfg = reference.config
    with pytest.raises(FileExistsError, match="resume"):
        run_benchmark(cfg)
    with pytest.raises(ValueError, match="num_samples: 8 -> 16"):
        run_benchmark(replace(cfg, resume=True, planner=PlannerConfig(num_samples=16)))
    with pytest.raises(ValueError, match="optimizer: 'mppi' -> 'cem'"):
        run_benchmark(replace(cfg, resume=True, planner=PlannerConfig("cem", num_samples=8)))
    again = run_benchmark(replace(cfg, resume=True))
    assert again.num_run == 0 and again.num_skipped == 6 and len(again.records) == 6


def test_a_run_that_stopped_before_any_trial_does_not_block_its_directory(tmp_path):
    cfg = _config(tmp_path, "stopped")
    run_dir = RunDir.prepare(cfg).path  # what a run writes before its first trial
    assert (run_dir / "config.yaml").exists() and not (run_dir / "trials.jsonl").exists()
    # no --resume needed, settings may change
    RunDir.prepare(replace(cfg, planner=PlannerConfig(num_samples=16)))
    assert read_config(run_dir).planner.num_samples == 16
    (run_dir / "trials.jsonl").write_text(json.dumps({"task": "t", "seed": 0}) + "\n")
    with pytest.raises(FileExistsError, match="1 recorded trial\\(s\\): add --resume"):
        RunDir.prepare(cfg)


def test_a_directory_of_other_files_is_not_taken_for_a_run(tmp_path):
    cfg = _config(tmp_path, "notes")
    Path(cfg.out).mkdir(parents=True)
    (Path(cfg.out) / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match="is not empty and is not a vp2 run directory"):
        RunDir.prepare(cfg)
    with pytest.raises(FileExistsError, match="not a vp2 run directory"):  # resume or not
        RunDir.prepare(replace(cfg, resume=True))
    assert sorted(p.name for p in Path(cfg.out).iterdir()) == ["notes.txt"]
    Path(_config(tmp_path, "empty").out).mkdir(parents=True)  # an empty one is fine
    RunDir.prepare(_config(tmp_path, "empty"))


def test_resume_after_sigkill_runs_every_trial_exactly_once(reference, tmp_path):
    cfg = _config(tmp_path, "killed", seeds=(0, 1, 2), save_predictions=True)
    trials = Path(cfg.out) / "trials.jsonl"
    script = (
        "import json, sys\n"
        "from vp2.benchmark import RunConfig, run_benchmark\n"
        "run_benchmark(RunConfig.from_dict(json.loads(sys.argv[1])))\n"
    )
    env = {**os.environ, "PYTHONPATH": f"{REPO}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    proc = subprocess.Popen(
        [sys.executable, "-c", script, json.dumps(cfg.to_dict())],
        cwd=REPO,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and proc.poll() is None:
            if trials.exists() and trials.read_bytes().count(b"\n") >= 2:
                break
            time.sleep(0.02)
        assert proc.poll() is None, "the run finished (or died) before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    done_before = len(read_trials(trials))
    assert 2 <= done_before < 6
    # A write cut short by the kill leaves a partial last line; resume must drop it.
    with open(trials, "ab") as fh:
        fh.write(b'{"task": "tabletop/push_sph')
    resumed = run_benchmark(replace(cfg, resume=True))
    assert resumed.num_skipped == done_before and resumed.num_run == 6 - done_before
    keys = [trial_key(r) for r in read_trials(trials)]
    assert len(keys) == len(set(keys)) == 6
    assert trials.read_bytes().endswith(b"\n")
    assert _outcomes(resumed.records) == _outcomes(reference.records)


def test_resume_with_more_seeds_runs_only_the_new_keys(reference, tmp_path):
    first = run_benchmark(_config(tmp_path, "grow", seeds=(0,)))
    assert first.num_run == 2
    grown = run_benchmark(_config(tmp_path, "grow", seeds=(0, 2), resume=True))
    assert grown.num_skipped == 2 and grown.num_run == 2
    expected = {k: v for k, v in _outcomes(reference.records).items() if k[2] in (0, 2)}
    assert _outcomes(grown.records) == expected


def test_trials_outside_the_runs_seeds_are_named_and_not_counted(reference, tmp_path):
    from vp2.report.runs import load_runs
    from vp2.report.study import load_entry

    run_dir = tmp_path / "shrink"
    run_dir.mkdir()
    # Seeds 0-2 on disk (instance 0 succeeds, 1 fails), the config asks for seed 2 only.
    lines = (reference.run_dir / "trials.jsonl").read_text()
    (run_dir / "trials.jsonl").write_text(lines)
    shrunk = run_benchmark(_config(tmp_path, "shrink", seeds=(2,), resume=True))
    assert shrunk.num_run == 0 and shrunk.num_skipped == 2
    assert sorted(trial_key(r) for r in shrunk.records) == [
        ("tabletop/push_sphere", 0, 2), ("tabletop/push_sphere", 1, 2)
    ]
    assert shrunk.summary.tasks[0].per_seed == {2: 0.5}
    (note,) = [w for w in shrunk.summary.warnings if "not counted" in w]
    assert note.startswith("4 trial(s) in") and "tabletop/push_sphere #0 seed 0" in note
    assert "not counted" in (run_dir / "summary.md").read_text()
    ours, outside = RunDir(run_dir).split_trials()
    assert len(ours) == 2 and sorted(r["seed"] for r in outside) == [0, 0, 1, 1]
    (view,) = load_runs([run_dir])
    assert len(view.records) == 2 and view.outside == note and note in view.summary.warnings
    entry = load_entry("m", run_dir, _metrics_file(tmp_path))
    assert len(entry.records) == 2 and entry.outside == note
    # A directory whose config covers all its trials has no note.
    assert RunDir(reference.run_dir).split_trials()[1] == [] and load_runs([reference.run_dir])[0].outside is None


def _metrics_file(tmp_path: Path) -> Path:
    path = tmp_path / "metrics.json"
    path.write_text(json.dumps({"metrics": {"ssim": 0.5}}))
    return path


def test_resume_refuses_trials_of_a_changed_task_suite(tmp_path):
    import dataclasses

    from vp2.data.suite import TaskSuite

    suite_file = tmp_path / "suite.npz"
    suite = TaskSuite.load(tiny_suite_path())
    suite.save(suite_file)
    first = run_benchmark(_config(tmp_path, "run", suite=str(suite_file), seeds=(0,)))
    assert first.num_run == 2
    shas = {r["instance"]: r["instance_sha"] for r in first.records}
    assert shas == {i.index: i.fingerprint for i in suite}
    # The same file, one goal image changed (as a new vp2 release might ship): refused.
    changed = [
        dataclasses.replace(i, goal_image=255 - i.goal_image) if i.index == 1 else i for i in suite
    ]
    TaskSuite(changed, seed=suite.seed).save(suite_file)
    with pytest.raises(ValueError, match=r"tabletop/push_sphere#1.*suite changed"):
        run_benchmark(_config(tmp_path, "run", suite=str(suite_file), seeds=(0, 1), resume=True))
    assert len(read_trials(tmp_path / "run")) == 2  # nothing lost, nothing added


@pytest.mark.parametrize(
    ("model", "match"),
    [
        ("tests.benchmark:NaNModel", "output: expected finite values, got .* NaN"),
        ("tests.benchmark:WrongShapeModel", r"output: expected shape \(8, 10, 3, 64, 64\)"),
    ],
)
def test_a_failing_model_is_recorded_as_an_error_and_finished_trials_survive(
    tmp_path, model, match
):
    # The model fails on instance 1 only (env seed 102).
    cfg = _config(
        tmp_path, "bad", model=model, model_args={"bad_seed": 102}, max_retries=1, seeds=(0,)
    )
    result = run_benchmark(cfg)
    by_key = {trial_key(r): r for r in result.records}
    assert len(by_key) == 2 and result.num_errors == 1
    for (_, index, _), r in by_key.items():
        if index == 1:
            assert r["success"] is None and r["error"]["type"] == "ModelContractError"  # a ValueError
            assert r["error"]["where"] == "trial"
            assert "Traceback" in r["error"]["traceback"]
            assert re.search(match, r["error"]["message"])
            assert r["error"]["model_failure"]["field"] == "predict output"
            assert r["attempts"] == 2 and len(r["previous_errors"]) == 1
        else:
            assert r["error"] is None and r["success"] is True
    (row,) = result.summary.tasks
    # Errors count neither as success nor failure: the one finished trial, solved.
    assert row.num_errors == 1 and row.per_seed == {0: 1.0} and row.num_trials == 1
    assert any("ended in an error" in w for w in result.summary.warnings)


def test_a_transient_error_is_retried(tmp_path):
    marker = tmp_path / "failed-once"
    cfg = _config(
        tmp_path,
        "flaky",
        seeds=(0,),
        model="tests.benchmark:FlakyModel",
        model_args={"bad_seed": 102, "marker": str(marker)},
    )
    result = run_benchmark(cfg)
    r = {trial_key(r): r for r in result.records}[("tabletop/push_sphere", 1, 0)]
    assert r["error"] is None and r["attempts"] == 2
    assert r["previous_errors"][0]["message"] == "transient failure"


def test_a_model_that_cannot_be_built_stops_the_run(tmp_path):
    cfg = _config(tmp_path, "broken", model="tests.benchmark:broken_factory")
    with pytest.raises(
        RuntimeError, match="could not build the model .* checkpoint weights not found"
    ):
        run_benchmark(cfg)
    assert read_trials(cfg.out) == []
    with pytest.raises(ValueError, match="cannot import module"):
        run_benchmark(_config(tmp_path, "missing", model="no_such_pkg.models:build"))


def test_a_model_that_does_not_fit_the_run_is_refused_before_any_trial(tmp_path):
    wrong_dim = _config(
        tmp_path, "dim", model="tests.benchmark:repeat_factory", model_args={"action_dim": 5}
    )
    with pytest.raises(ModelFailure, match=r"action_dim 5, but the tabletop tasks have 4-D"):
        run_benchmark(wrong_dim)
    no_grad = _config(tmp_path, "grad", planner=PlannerConfig("lbfgs"))
    with pytest.raises(ModelFailure, match="lbfgs optimizer needs gradients .* repeat_last_frame"):
        run_benchmark(no_grad)
    assert read_trials(wrong_dim.out) == [] and read_trials(no_grad.out) == []


def test_a_broken_model_stops_the_run_and_resume_continues_after_the_fix(tmp_path):
    fixed = tmp_path / "fixed"
    fixed.touch()
    cfg = _config(
        tmp_path, "run", model="tests.benchmark:NaNUntilFixed",
        model_args={"fixed": str(fixed)}, seeds=(0,), num_instances=1,
    )
    assert run_benchmark(cfg).num_errors == 0  # one finished trial
    fixed.unlink()  # the model breaks: the new seed's trial fails, and its retry
    more = replace(cfg, seeds=(0, 1), resume=True)
    with pytest.raises(ModelFailure) as info:
        run_benchmark(more)
    message = str(info.value)
    assert "nan_until_fixed" in message and "predict output: expected finite values" in message
    assert 'docs/evaluation.md, "Plugins"' in message and "--resume" in message
    assert [trial_key(r) for r in read_trials(cfg.out)] == [("tabletop/push_sphere", 0, 0)]
    fixed.touch()
    result = run_benchmark(more)
    assert result.num_run == 1 and result.num_skipped == 1 and result.num_errors == 0


def test_vp2_run_exits_at_once_on_a_model_returning_nan(tmp_path):
    out = tmp_path / "nan"
    proc = subprocess.run(
        [sys.executable, "-m", "vp2.cli", "run", "--model", "tests.benchmark:NaNModel",
         "--suite", str(tiny_suite_path()), "--seeds", "0", "1", "--num-steps", str(STEPS),
         "--num-samples", "8", "--no-progress", "--out", str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 3, proc.stderr
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("vp2 run: error: stopped: model nan_model")
    assert "output: expected finite values" in last and "first 2 trial attempts" in last
    assert read_trials(out) == []


def test_finished_at_is_stamped_when_the_trial_ends(tmp_path):
    # 2 planning steps of a model that takes 1.5 s per call: the trial lasts > 3 s.
    cfg = _config(tmp_path, "slow", seeds=(0,), num_instances=1,
                  model="tests.benchmark:SlowModel", model_args={"delay": 1.5})
    started = datetime.datetime.now(datetime.timezone.utc)
    (record,) = run_benchmark(cfg).records
    finished = datetime.datetime.fromisoformat(record["finished_at"])
    assert record["timings"]["total_s"] > 3.0
    # ISO seconds truncate up to 1 s; a stamp taken at the trial's start would be < 1 s late.
    assert (finished - started).total_seconds() >= record["timings"]["total_s"] - 1.0


def test_random_agent_runs_without_a_model(tmp_path):
    result = run_benchmark(_config(tmp_path, "random", agent="random", model="-", seeds=(0,)))
    assert {r["cost"] for r in result.records} == {"none"}
    assert all(r["model"]["spec"] == "random_actions" for r in result.records)


def test_config_validation_and_model_args():
    with pytest.raises(ValueError, match="agent"):
        RunConfig(model="x", out="y", agent="greedy").validate()
    with pytest.raises(ValueError, match="unknown task"):
        RunConfig(model="x", out="y", tasks=("tabletop/push_moon",)).validate()
    RunConfig(model="x", out="y", tasks=("robodesk", "tabletop/push_sphere")).validate()
    assert parse_model_args(["num_workers=2", "name=foo", "sizes=[1, 2]", "flag=true"]) == {
        "num_workers": 2,
        "name": "foo",
        "sizes": [1, 2],
        "flag": True,
    }
    cfg = RunConfig(model="x", out="y", seeds=(3, 4), tasks=("robodesk",))
    assert RunConfig.from_dict(cfg.to_dict()) == cfg
    assert RunConfig(model="x", out="y").deviations() == []


@pytest.mark.slow  # three pools of spawned workers (~1-2 min on 2 cores)
def test_a_dead_worker_is_isolated_and_charged_to_its_trial(reference, tmp_path):
    # KillerModel SIGKILLs its process on instance 1 (env seed 102); elsewhere it behaves as
    # repeat_last_frame, so the other trials must match the in-process reference.
    cfg = _config(
        tmp_path,
        "pool",
        model="tests.benchmark:KillerModel",
        model_args={"bad_seed": 102},
        workers=2,
        max_retries=1,
    )
    result = run_benchmark(cfg)
    by_key = {trial_key(r): r for r in result.records}
    assert len(by_key) == 4
    for key, r in by_key.items():
        if key[1] == 1:
            assert r["error"]["type"] == "WorkerDied" and r["attempts"] == 2
        else:
            assert r["error"] is None
            assert _outcomes([r]) == {key: _outcomes(reference.records)[key]}
