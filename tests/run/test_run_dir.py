"""The run directory type and the run's configuration: its file names (spelled in
``vp2.run.run_dir`` only), the one config.yaml form (nested) and the conversion of the old
flat one as it is read, the trials a config covers, summaries, resuming an old directory, and
what the suite lacks."""

from __future__ import annotations

import ast
import dataclasses
import json
import logging
import sys
from pathlib import Path

import pytest
import yaml

from tests.benchmark import tiny_suite_path
from vp2 import spec
from vp2.benchmark.runner import run_benchmark
from vp2.planning.planner import PlannerConfig
from vp2.run import run_dir as run_dir_module
from vp2.run.config import PROTOCOL_FIELDS, RunConfig, flat_settings, planner_of
from vp2.run.results import summarize
from vp2.run.run_dir import RunDir, nest_legacy_config, read_config

TASK = "tabletop/push_sphere"


def _config(tmp_path: Path, **overrides) -> RunConfig:
    kwargs = dict(model="repeat_last_frame", out=str(tmp_path / "run"), suite=str(tiny_suite_path()),
                  seeds=(0,), num_steps=3, planner=PlannerConfig(num_samples=8), save_gifs=False,
                  progress=False)
    kwargs.update(overrides)
    return RunConfig(**kwargs)


def _flatten(config_yaml: Path) -> None:
    """Rewrites ``config.yaml`` in the flat form of run directories written before the
    planner was nested (and without ``sigma``/``options``, which did not exist)."""
    data = yaml.safe_load(config_yaml.read_text())
    planner = data["config"].pop("planner")
    flat = {}
    for key, value in data["config"].items():
        flat[key] = value
        if key == "seeds":
            flat.update({k: planner[k] for k in ("optimizer", "num_samples", "gamma",
                                                 "num_iterations")})
    data["config"] = flat
    config_yaml.write_text(yaml.safe_dump(data, sort_keys=False))


def _record(instance: int, seed: int, success: bool = True) -> dict:
    return {"task": TASK, "instance": instance, "seed": seed, "success": success, "error": None,
            "cost": "pixel"}


# --------------------------------------------------------------------------- RunConfig


def test_runconfig_nests_the_planner():
    nested = RunConfig(model="m", out="o", planner=PlannerConfig("cem", num_samples=8))
    with pytest.raises(TypeError):
        RunConfig(model="m", out="o", num_samples=8)  # one owner: the planner's fields
    assert dataclasses.replace(nested, resume=True).planner == nested.planner
    assert RunConfig(model="m", out="o").planner == PlannerConfig()


def test_runconfig_round_trips_and_old_flat_mappings_are_nested_first():
    config = RunConfig(model="m", out="o", tasks=("robodesk",), seeds=(3, 4),
                       planner=PlannerConfig("mppi", 8, 0.1, 2, sigma=(0.1, 0.2), options={"a": 1}))
    data = config.to_dict()
    unset = dict.fromkeys(["num_elites", "num_samples_first", "num_refined", "lr", "grad_steps"])
    assert data["planner"] == {"optimizer": "mppi", "num_samples": 8, "gamma": 0.1,
                               "num_iterations": 2, **unset, "sigma": [0.1, 0.2],
                               "options": {"a": 1}}
    # A config.yaml written before the planner had those settings reads as the same config.
    before = data | {"planner": {k: v for k, v in data["planner"].items() if k not in unset}}
    assert RunConfig.from_dict(before) == config
    assert "num_samples" not in data and data["tasks"] == ["robodesk"]
    assert RunConfig.from_dict(data) == config
    assert RunConfig.from_dict(json.loads(json.dumps(data))) == config
    assert RunConfig.from_dict(yaml.safe_load(yaml.safe_dump(data))) == config
    # The flat form of older run directories: converted to the nested one (in one place),
    # then the same config; RunConfig itself reads only the nested form.
    old = {k: v for k, v in data.items() if k != "planner"} | {
        "optimizer": "mppi", "num_samples": 8, "gamma": 0.1, "num_iterations": 2}
    expected = dataclasses.replace(config, planner=PlannerConfig("mppi", 8, 0.1, 2))
    assert nest_legacy_config(old)["planner"] == {"optimizer": "mppi", "num_samples": 8,
                                                  "gamma": 0.1, "num_iterations": 2}
    assert RunConfig.from_dict(nest_legacy_config(old)) == expected
    assert nest_legacy_config(data) is data  # the nested form is left as it is
    assert RunConfig.from_dict(nest_legacy_config({"model": "m", "out": "o",
                                                   "num_samples": 8})).planner == (
        PlannerConfig(num_samples=8))
    with pytest.raises(ValueError, match=r"unknown RunConfig field\(s\) \['num_samples'\]"):
        RunConfig.from_dict({"model": "m", "out": "o", "num_samples": 8})
    assert flat_settings(data)["num_samples"] == 8 and flat_settings(old) == old
    assert planner_of(data) == config.planner and planner_of(old) == expected.planner
    with pytest.raises(ValueError, match=r"unknown RunConfig field\(s\) \['nope'\]"):
        RunConfig.from_dict({**data, "nope": 1})
    with pytest.raises(ValueError, match=r"unknown PlannerConfig field\(s\) \['nope'\]"):
        RunConfig.from_dict({**data, "planner": {"nope": 1}})
    with pytest.raises(ValueError, match="given twice"):
        nest_legacy_config({**data, "num_samples": 9})
    assert nest_legacy_config({**data, "num_samples": 8})["planner"] == data["planner"]


def test_deviations_are_the_same_lines_as_before_the_nesting():
    config = RunConfig(model="m", out="o", num_steps=3, seeds=(0,), cost="pixel_only",
                       planner=PlannerConfig("cem", num_samples=8, num_iterations=2))
    assert config.deviations() == [
        "num_steps=3 (SPEC: 15)",
        "num_samples=8 (SPEC: 200, 800 for open_slide/open_drawer)",
        "optimizer=cem (SPEC: mppi)",
        "num_iterations=2 (SPEC: 1)",
        "cost=pixel_only (SPEC: RoboDesk uses its success classifier)",
        "1 seed(s) (SPEC: at least 3 control runs)",
    ]
    assert RunConfig(model="m", out="o", planner=PlannerConfig(gamma=0.1)).deviations() == [
        "gamma=0.1 (SPEC: 0.05)"]
    assert RunConfig(model="m", out="o", agent="random",
                     planner=PlannerConfig("cem")).deviations() == []
    assert RunConfig(model="m", out="o").deviations() == []
    # Settings without a flag, which a RunConfig could not hold before, are named too.
    assert RunConfig(model="m", out="o", planner=PlannerConfig(sigma=(0.1,) * 4,
                                                        options={"x": 1})).deviations() == [
        "sigma=[0.1, 0.1, 0.1, 0.1] (SPEC: the environment's, vp2.spec.SIGMA)",
        "optimizer options {'x': 1} (SPEC: none)",
    ]


def test_protocol_lists_the_planners_fields_one_by_one():
    protocol = RunConfig(model="m", out="o").protocol()
    assert list(protocol) == ["model", "model_args", "agent", "suite", "optimizer",
                              "num_samples", "gamma", "num_iterations", "num_elites",
                              "num_samples_first", "num_refined", "lr", "grad_steps", "sigma",
                              "options", "cost", "num_steps"]
    assert protocol["gamma"] == spec.GAMMA and "planner" in PROTOCOL_FIELDS


def test_reading_a_config_does_not_load_torch(tmp_path):
    import subprocess

    RunDir.prepare(_config(tmp_path))
    code = (
        "import sys; from vp2.run.run_dir import RunDir; "
        f"run = RunDir({str(tmp_path / 'run')!r}); "
        "assert run.settings()['num_samples'] == 8 and run.deviations(); "
        "assert run.config().planner.num_samples == 8; print('torch' in sys.modules)"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"  # PlannerConfig is plain data (vp2.planning.config)


# --------------------------------------------------------------------------- RunDir


def test_a_run_dir_reads_both_config_forms(tmp_path):
    config = _config(tmp_path)
    run = RunDir.prepare(config)
    assert run.path == tmp_path / "run" and run.config_file == run.path / "config.yaml"
    assert (run.trials_file.name, run.summary_file.name, run.summary_json.name,
            run.gif_dir.name) == ("trials.jsonl", "summary.md", "summary.json", "gifs")
    # The on-disk format of the other files (docs/evaluation.md, run directory layout).
    assert [str(p.relative_to(run.path)) for p in (
        run.report_file, run.precheck_file, run.diagnosis_file,
        run.gif_path("robodesk/push_red", 7, 1), run.gif_path("robodesk/push_red", 7, 1, plan=True),
        run.partial_path("tabletop/push_sphere", 3, 2),
    )] == ["report.html", "precheck.json", "diagnose.json", "gifs/robodesk_push_red/i007_s1.gif",
           "gifs/robodesk_push_red/i007_s1_plan.gif", "partial/tabletop_push_sphere_i003_s2.npz"]
    assert run_dir_module.diagnosis_partial_path(run.diagnosis_file) == (
        run.path / "diagnose.partial.json")
    stored = yaml.safe_load(run.config_file.read_text())
    assert stored["config"]["planner"]["num_samples"] == 8  # written nested
    assert run.config() == config == read_config(run.path)
    assert run.deviations() == config.deviations() == stored["spec_deviations"]
    assert run.settings()["num_samples"] == 8 and "planner" not in run.settings()
    _flatten(run.config_file)
    assert "planner" not in yaml.safe_load(run.config_file.read_text())["config"]
    assert run.config() == config and run.settings()["num_samples"] == 8
    assert RunDir(tmp_path / "none").settings() == {}
    with pytest.raises(FileNotFoundError, match="not a vp2 run directory"):
        RunDir(tmp_path / "none").check_is_run()


def test_a_run_dir_splits_the_trials_its_config_covers(tmp_path):
    run = RunDir.prepare(_config(tmp_path, seeds=(0, 1), num_instances=1))
    lines = [_record(0, 0), _record(0, 1), _record(1, 0), _record(0, 5)]
    run.trials_file.write_text("".join(json.dumps(r) + "\n" for r in lines))
    ours, outside = run.split_trials()
    assert ours == lines[:2] and outside == lines[2:]
    records, note = run.counted_trials()
    assert records == ours and note.startswith(f"2 trial(s) in {run.trials_file} are outside")
    assert "(e.g. tabletop/push_sphere #1 seed 0)" in note
    assert run.split_trials([(TASK, 0, 5)]) == ([lines[3]], lines[:3])
    _flatten(run.config_file)  # an old directory splits the same way
    assert run.split_trials() == (ours, outside)
    run.config_file.write_text("config: {model: m}\n")  # unreadable as a RunConfig: all count
    assert run.split_trials() == (lines, []) and run.counted_trials() == (lines, None)


def test_a_run_dir_writes_its_summaries(tmp_path):
    run = RunDir(tmp_path / "run")
    run.path.mkdir()
    run.write_summary(summarize([_record(0, 0), _record(1, 0, success=False)]))
    assert json.loads(run.summary_json.read_text())["mean"] == 0.5
    text = run.summary_file.read_text()
    assert text.startswith("## vp2 run run\n") and "| tabletop/push_sphere | 50.0 |" in text


def test_an_old_flat_run_dir_resumes_as_the_same_protocol(tmp_path):
    config = _config(tmp_path)
    first = run_benchmark(config)
    assert first.num_run == 2
    _flatten(Path(config.out) / "config.yaml")
    again = run_benchmark(dataclasses.replace(config, resume=True))
    assert again.num_run == 0 and again.num_skipped == 2
    assert "planner" in yaml.safe_load((Path(config.out) / "config.yaml").read_text())["config"]
    _flatten(Path(config.out) / "config.yaml")
    with pytest.raises(ValueError, match=r"\(num_samples: 8 -> 16\)"):
        run_benchmark(dataclasses.replace(config, resume=True,
                                          planner=PlannerConfig(num_samples=16)))


def test_more_instances_than_the_suite_has_is_said(tmp_path, caplog):
    config = _config(tmp_path, num_instances=1000, tasks=("tabletop",))
    with caplog.at_level(logging.WARNING, logger="vp2.benchmark.runner"):
        result = run_benchmark(config)
    assert result.num_run == 2
    assert ("--num-instances 1000: tabletop/push_sphere has 2 instances in the suite; running "
            "those 2") in caplog.messages
    assert ("--tasks tabletop: the suite has no instances of tabletop/push_large_cube, "
            "tabletop/push_small_cube, tabletop/push_cylinder; running its other 1 task "
            "category") in caplog.messages
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="vp2.benchmark.runner"):
        run_benchmark(_config(tmp_path, out=str(tmp_path / "two"), num_instances=2))
    assert not [m for m in caplog.messages if m.startswith("--")]


# --------------------------------------------------------------------------- the old config form

#: A ``config.yaml`` as vp2 0.1.0 wrote it before the planner's settings were nested: the
#: optimizer's fields beside the others, no ``sigma``/``options``, ``trial_timeout`` or
#: ``precheck`` (``{out}`` and ``{suite}`` are filled in).
LEGACY_CONFIG_YAML = """\
vp2_version: 0.1.0
written_at: '2025-01-01T00:00:00+00:00'
spec_deviations:
- 'num_steps=3 (SPEC: 15)'
- 'num_samples=8 (SPEC: 200, 800 for open_slide/open_drawer)'
- '1 seed(s) (SPEC: at least 3 control runs)'
config:
  model: repeat_last_frame
  out: {out}
  model_args: {{}}
  agent: planning
  suite: {suite}
  tasks: []
  num_instances: null
  seeds:
  - 0
  optimizer: mppi
  num_samples: 8
  gamma: 0.05
  num_iterations: null
  cost: auto
  num_steps: 3
  stop_on_success: false
  workers: 1
  executor: local
  address: null
  num_cpus_per_worker: 1.0
  num_gpus_per_worker: 0.0
  device: null
  max_retries: 1
  resume: false
  retry_errors: false
  save_gifs: false
  save_predictions: false
  oracle: null
  progress: false
"""


def test_a_legacy_flat_config_yaml_reads_reports_and_resumes_as_the_nested_form(tmp_path):
    from vp2 import cli

    config = _config(tmp_path)
    assert run_benchmark(config).num_run == 2  # writes the nested form
    run = RunDir(config.out)
    nested = yaml.safe_load(run.config_file.read_text())
    nested_settings, nested_stored = run.settings(), run.stored()
    legacy = LEGACY_CONFIG_YAML.format(out=config.out, suite=config.suite)
    run.config_file.write_text(legacy)
    assert "planner" not in yaml.safe_load(run.config_file.read_text())["config"]
    # Opens as the same RunConfig, and every reader sees the nested form.
    assert run.config() == config == read_config(run.path)
    stored = run.stored()
    assert stored["config"]["planner"] == {"optimizer": "mppi", "num_samples": 8, "gamma": 0.05,
                                           "num_iterations": None}
    assert {k: v for k, v in stored["config"].items() if k != "planner"} == {
        k: v for k, v in nested_stored["config"].items()
        if k not in ("planner", "trial_timeout", "precheck")}
    # The legacy form predates the sigma/options records and the planner fields added since
    # (CEM's elites, CEM-GD's and L-BFGS's steps): they are absent, not defaulted.
    newer = ("sigma", "options", "trial_timeout", "precheck", "num_elites", "num_samples_first",
             "num_refined", "lr", "grad_steps")
    assert run.settings() == {k: v for k, v in nested_settings.items() if k not in newer}
    assert run.deviations() == nested["spec_deviations"] == config.deviations()
    # `vp2 report` on it.
    out = tmp_path / "report.html"
    assert cli.main(["report", str(run.path), "--out", str(out)]) == 0
    assert "mppi, 8 samples, 3 steps, cost auto" in out.read_text()
    # A resume keeps its trials and rewrites the file in the nested form only.
    again = run_benchmark(dataclasses.replace(config, resume=True))
    assert again.num_run == 0 and again.num_skipped == 2
    rewritten = yaml.safe_load(run.config_file.read_text())["config"]
    assert rewritten == {**nested["config"], "resume": True}
    assert "num_samples" not in rewritten and run.config() == dataclasses.replace(config,
                                                                                  resume=True)


# --------------------------------------------------------------------------- one owner of the names

#: String literals outside ``vp2.run.run_dir`` that equal or hold a run directory's file name
#: but name no file of a run directory: (file, name) -> why.
NOT_RUN_FILES = {
    ("src/vp2/diagnose/verdicts.py", "partial"): "a verdict's status, not the partial folder",
}


def _literals(path: Path) -> list[tuple[int, str]]:
    """The string literals of a module (f-string parts included), its docstrings left out."""
    tree = ast.parse(path.read_text())
    docstrings = {
        id(node.body[0].value) for node in ast.walk(tree)
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
        and node.body and isinstance(node.body[0], ast.Expr)
        and isinstance(node.body[0].value, ast.Constant)
    }
    return [(node.lineno, node.value) for node in ast.walk(tree)
            if isinstance(node, ast.Constant) and isinstance(node.value, str)
            and id(node) not in docstrings]


def test_run_directory_file_names_are_spelled_only_in_run_dir():
    root = Path(__file__).resolve().parents[2]
    owner = Path(run_dir_module.__file__).resolve()
    assert owner == root / "src/vp2/run/run_dir.py"
    # Names too short to find inside text are matched whole; the others anywhere in a literal.
    whole = {run_dir_module.GIF_DIR, run_dir_module.PARTIAL_DIR, run_dir_module.PLAN_GIF_SUFFIX,
             run_dir_module.PARTIAL_SUFFIX}
    inside = [n for n in run_dir_module.RUN_FILE_NAMES if n not in whole]
    assert "trials.jsonl" in inside and "config.yaml" in inside and "gifs" in whole
    found, allowed = [], set()
    for path in sorted([*(root / "src").rglob("*.py"), *(root / "benchmarks").rglob("*.py")]):
        if path.resolve() == owner:
            continue
        rel = str(path.relative_to(root))
        for line, text in _literals(path):
            for name in [n for n in inside if n in text] + [n for n in whole if text == n]:
                if (rel, name) in NOT_RUN_FILES:
                    allowed.add((rel, name))
                else:
                    found.append(f"{rel}:{line}: {name!r} in {text[:60]!r}")
    assert not found, (
        "run directory file names spelled outside vp2.run.run_dir (use its constants or RunDir's "
        "paths):\n" + "\n".join(found))
    assert allowed == set(NOT_RUN_FILES)  # no stale allow-list entry
