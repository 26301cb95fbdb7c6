"""The README's main job: runs each agent, resumes, and tabulates them side by side."""

from __future__ import annotations

from pathlib import Path

import pytest

from tests.benchmark import tiny_suite_path
from vp2.benchmark import main_job
from vp2.benchmark.main_job import MainJobConfig, run_main_job
from vp2.run.run_dir import read_trials


def _config(tmp_path: Path, **overrides) -> MainJobConfig:
    kwargs = dict(out=str(tmp_path / "main"), suite=str(tiny_suite_path()), num_steps=3,
                  workers=1, agents=("repeat_last_frame", "random"))
    kwargs.update(overrides)
    return MainJobConfig(**kwargs)


def test_main_job_runs_each_agent_and_writes_the_table(tmp_path, monkeypatch):
    monkeypatch.setenv("VP2_ORACLE_ASSET", str(tmp_path / "absent.json"))  # no shipped oracle
    table, path = run_main_job(_config(tmp_path), gallery=False)
    rows = [line for line in table.splitlines() if line.startswith("| tabletop/")]
    assert rows == [line for line in rows if line.count("|") == 4]
    assert len(rows) == 1 and rows[0].startswith("| tabletop/push_sphere |")
    assert "repeat_last_frame" in table.splitlines()[0] and "random actions" in table
    assert path.read_text().count("| tabletop/push_sphere |") == 1
    assert "(1 trials run)" in path.read_text()
    for name in ("repeat_last_frame", "random"):
        records = read_trials(tmp_path / "main" / name)
        assert [(r["task"], r["instance"], r["seed"]) for r in records] == [
            ("tabletop/push_sphere", 0, 0)
        ]
        assert len(records[0]["success_steps"]) == 3
    # Re-running resumes: nothing is run twice.
    _, path = run_main_job(_config(tmp_path), gallery=False)
    assert len(read_trials(tmp_path / "main" / "random")) == 1
    assert "(0 trials run, 1 done earlier)" in path.read_text()


def test_shipped_models_run_only_on_their_envs(tmp_path, monkeypatch):
    monkeypatch.setenv("VP2_ZOO_DIR", str(tmp_path))  # a user's zoo does not hide the package's
    assert main_job.shipped_model_envs() == ("robodesk", "tabletop")  # both are in the package
    assert main_job.shipped_card("tabletop").name == "svg_prime-tabletop-m0.0625-60min"
    assert main_job.shipped_card("tabletop").parameters == 512_867
    assert main_job.shipped_card("robodesk").checkpoint_path.name == "svg_prime_tiny_robodesk.pt"
    runs = main_job._run_configs(MainJobConfig(agents=("model",)))  # noqa: SLF001
    assert runs["svg_prime"].tasks == ("robodesk", "tabletop")
    assert runs["svg_prime"].model == "vp2.benchmark.main_job:shipped_model"
    # The zoo entries are model arguments, so part of the protocol a resume checks.
    assert runs["svg_prime"].model_args == {
        "robodesk": "svg_prime-tiny-robodesk", "tabletop": "svg_prime-tabletop-m0.0625-60min"}
    assert "model_args" in runs["svg_prime"].protocol()
    assert runs["svg_prime"].planner.num_samples == 50
    monkeypatch.setattr(main_job, "shipped_model_envs", lambda: ("robodesk",))
    runs = main_job._run_configs(  # noqa: SLF001
        _config(tmp_path, agents=("model",), tasks=("tabletop",)))
    assert runs == {}  # no task of an environment with a shipped model
    runs = main_job._run_configs(  # noqa: SLF001
        _config(tmp_path, agents=("model", "random"), tasks=("robodesk/push_red", "tabletop")))
    assert runs["svg_prime"].tasks == ("robodesk/push_red",)
    assert runs["random actions"].tasks == ("robodesk/push_red", "tabletop")


def test_the_model_agent_plans_each_environment_with_its_own_checkpoint(tmp_path, monkeypatch):
    for env, action_dim in (("robodesk", 5), ("tabletop", 4)):
        model = main_job.shipped_model(env, action_dim)
        assert type(model).__name__ == "SVGPrime" and model.action_dim == action_dim
    table, _ = run_main_job(_config(tmp_path, agents=("model",)), gallery=False)
    (record,) = read_trials(tmp_path / "main" / "model")
    assert (record["task"], record["error"]) == ("tabletop/push_sphere", None)
    assert record["model"]["spec"] == "vp2.benchmark.main_job:shipped_model"
    assert record["model"]["name"] == "svg_prime" and len(record["success_steps"]) == 3
    assert "| task | svg_prime |" in table
    # A run made with other shipped models does not resume with these.
    monkeypatch.setitem(main_job.SHIPPED_MODELS, "tabletop", "svg_prime-tiny-tabletop")
    with pytest.raises(ValueError, match="different protocol settings.*svg_prime-tiny-tabletop"):
        run_main_job(_config(tmp_path, agents=("model",)), gallery=False)


def test_a_bad_setting_is_refused_before_anything_is_written(tmp_path):
    config = MainJobConfig(out=str(tmp_path / "main"), seeds=(-1,), suite=str(tiny_suite_path()))
    with pytest.raises(ValueError, match="every seed must be a non-negative integer, got -1"):
        run_main_job(config)
    assert not (tmp_path / "main").exists()
