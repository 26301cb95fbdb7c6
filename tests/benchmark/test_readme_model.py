"""The README's "Evaluate a model" example, as written: its model file through `vp2 run` from
the model's folder, its YAML file, and the Python API. Also: `vp2 run` prints no third-party
notices."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.benchmark import tiny_suite_path
from vp2._quiet import ROBOSUITE_NOTICES
from vp2.benchmark import RunConfig, run_benchmark
from vp2.planning.config import PlannerConfig
from vp2.run.run_dir import read_trials

REPO = Path(__file__).resolve().parents[2]
#: A cheap run: 1 tabletop instance, 1 seed, 2 control steps, 4 planner samples.
CHEAP = ["--suite", "SUITE", "--tasks", "tabletop/push_sphere", "--num-instances", "1",
         "--seeds", "0", "--num-steps", "2", "--num-samples", "4", "--no-gifs", "--no-progress"]
THIRD_PARTY_NOTICES = (*ROBOSUITE_NOTICES, "Gym has been unmaintained", "DISPLAY environment")


def _readme_block(lang: str, first_line: str) -> str:
    text = (REPO / "README.md").read_text()
    section = text.split("### Evaluate a model", 1)[1].split("\n## ", 1)[0]
    blocks = re.findall(rf"```{lang}\n(.*?)```", section, re.S)
    (block,) = [b for b in blocks if b.startswith(first_line)]
    return block


@pytest.fixture
def model_dir(tmp_path, monkeypatch):
    """The README's mymodule.py and mymodel.yaml in a folder that is the current directory."""
    (tmp_path / "mymodule.py").write_text(_readme_block("python", "# mymodule.py"))
    (tmp_path / "mymodel.yaml").write_text(_readme_block("yaml", "# mymodel.yaml"))
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", list(sys.path))  # the resolver appends the cwd
    yield tmp_path
    sys.modules.pop("mymodule", None)


def _cheap(**overrides) -> dict:
    kwargs = dict(suite=str(tiny_suite_path()), tasks=("tabletop/push_sphere",), num_instances=1,
                  seeds=(0,), num_steps=2, planner=PlannerConfig(num_samples=4), save_gifs=False,
                  progress=False)
    return {**kwargs, **overrides}


def test_readme_model_through_vp2_run_from_its_folder(model_dir):
    vp2_script = Path(sys.executable).with_name("vp2")
    # `make test` installs vp2 into the venv, so the script is always there (CI included).
    assert vp2_script.exists(), f"no vp2 console script next to {sys.executable}; pip install -e ."
    # As in the README (the model file's folder is the current directory), cheap settings.
    args = [a.replace("SUITE", str(tiny_suite_path())) for a in CHEAP]
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    proc = subprocess.run(
        [str(vp2_script), "run", "--model", "mymodule:make_model", "--model-arg", "speed=0.02",
         *args, "--out", "runs/mine"],
        cwd=model_dir, env=env, capture_output=True, text=True, timeout=600,
    )
    assert proc.returncode == 0, proc.stderr
    (record,) = read_trials(model_dir / "runs/mine")
    assert record["error"] is None and record["model"]["name"] == "DriftModel"
    assert record["model"]["args"] == {"speed": 0.02}
    for notice in THIRD_PARTY_NOTICES:
        assert notice not in proc.stderr, proc.stderr


def test_readme_model_through_its_yaml_file_and_the_python_api(model_dir):
    from_yaml = run_benchmark(RunConfig(model="mymodel.yaml", out="runs/yaml", **_cheap()))
    assert from_yaml.num_run == 1 and from_yaml.num_errors == 0
    assert from_yaml.records[0]["model"]["class"] == "mymodule.DriftModel"
    # The README's Python call, with the cheap settings of a test.
    snippet = _readme_block("python", "from vp2.benchmark import")
    assert 'RunConfig(model="mymodule:make_model"' in snippet
    result = run_benchmark(RunConfig(model="mymodule:make_model", out="runs/py", **_cheap()))
    assert result.num_run == 1 and result.num_errors == 0
    # The toy model is differentiable in the actions: gradient-based planners accept it.
    grad = run_benchmark(RunConfig(model="mymodule:make_model", out="runs/gd",
                                   **_cheap(planner=PlannerConfig("cem_gd", num_samples=4))))
    assert grad.num_errors == 0
