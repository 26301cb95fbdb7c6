"""Loading models from ``package.module:factory`` specs and YAML files with ``_target_``."""

from __future__ import annotations

import sys

import pytest
import torch

from vp2.benchmark.model_spec import (
    PluginError,
    check_spec,
    describe_spec,
    instantiate,
    load_plugin,
    model_identity,
    resolve_model,
)
from vp2.models.baselines import RepeatLastFrame
from vp2.models.contract import CheckedPredictor, unwrap
from vp2.models.simulator import SimulatorModel


def test_module_factory_with_args_and_context():
    model = load_plugin(
        "tests.benchmark:repeat_factory",
        {"image_size": 32},
        context={"action_dim": 4, "env": "tabletop", "device": "cpu"},
    )
    # The factory declares action_dim (filled from the context) but not env or device.
    assert isinstance(model, RepeatLastFrame) and model.action_dim == 4 and model.image_size == 32
    # Explicit arguments win over the context.
    model = load_plugin("tests.benchmark:repeat_factory", {"action_dim": 5}, {"action_dim": 4})
    assert model.action_dim == 5
    # Classes are factories too.
    assert load_plugin("vp2.models.baselines:RepeatLastFrame", {"action_dim": 3}).action_dim == 3


def test_builtin_names():
    assert isinstance(load_plugin("repeat_last_frame", context={"action_dim": 5}), RepeatLastFrame)
    oracle = resolve_model("oracle", {"num_workers": 1}, env="robodesk", action_dim=5, device="cpu")
    # The resolver returns the model checked (one wrapping point), attributes passed through.
    assert isinstance(oracle, CheckedPredictor) and isinstance(unwrap(oracle), SimulatorModel)
    assert oracle.action_dim == 5 and oracle.name == "simulator"
    oracle.num_workers = 1  # written through (the runner sets it in trial processes)
    assert unwrap(oracle).num_workers == 1
    assert describe_spec("simulator") == "builtin"
    assert describe_spec("svg_prime:runs/x") == "checkpoint"
    assert describe_spec("m.yaml") == "yaml" and describe_spec("pkg.mod:f") == "factory"


def test_yaml_target_with_nested_targets_and_overrides(tmp_path):
    path = tmp_path / "model.yaml"
    path.write_text("_target_: tests.benchmark:repeat_factory\nimage_size: 48\n")
    model = resolve_model(str(path), {}, env="tabletop", action_dim=4, device="cpu")
    assert isinstance(unwrap(model), RepeatLastFrame)
    assert (model.action_dim, model.image_size) == (4, 48)
    model = resolve_model(str(path), {"image_size": 16}, env="tabletop", action_dim=4, device="cpu")
    assert model.image_size == 16  # run arguments override the file
    # Nested targets are built first; the dotted target form works as well.
    nested = instantiate(
        {
            "_target_": "builtins.dict",
            "inner": {"_target_": "fractions:Fraction", "numerator": 1, "denominator": 2},
            "k": [3],
        }
    )
    assert nested == {"inner": 0.5, "k": [3]}
    check_spec(str(path))


def test_torch_modules_are_moved_and_put_in_eval_mode(tmp_path):
    path = tmp_path / "lin.yaml"
    path.write_text("_target_: torch.nn:Linear\nin_features: 2\nout_features: 3\n")
    module = resolve_model(str(path), {}, env="tabletop", action_dim=4, device="cpu", check=False)
    assert isinstance(module, torch.nn.Linear) and not module.training
    identity = model_identity(str(path), {}, module)
    assert identity["class"] == "torch.nn.modules.linear.Linear" and identity["num_parameters"] == 9
    # Checked (the default), an object without the interface's attributes is refused.
    with pytest.raises(TypeError, match="Linear does not implement VideoPredictionModel"):
        resolve_model(str(path), {}, env="tabletop", action_dim=4, device="cpu")


def test_a_module_in_the_current_directory_resolves(tmp_path, monkeypatch):
    (tmp_path / "vp2_cwd_plugin.py").write_text(
        "from vp2.models.baselines import RepeatLastFrame\n"
        "class Plain(RepeatLastFrame):\n"
        "    name = None\n"
        "def make(action_dim):\n"
        "    return Plain(action_dim)\n"
    )
    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in ("", str(tmp_path))])
    monkeypatch.delitem(sys.modules, "vp2_cwd_plugin", raising=False)
    check_spec("vp2_cwd_plugin:make")
    model = resolve_model("vp2_cwd_plugin:make", {}, env="tabletop", action_dim=4, device="cpu")
    assert model.name == "Plain" and sys.path[-1] == str(tmp_path)  # appended, not first
    identity = model_identity("vp2_cwd_plugin:make", {}, model)
    assert identity["name"] == "Plain" and identity["class"] == "vp2_cwd_plugin.Plain"
    sys.modules.pop("vp2_cwd_plugin", None)


@pytest.mark.parametrize(
    ("spec", "match"),
    [
        ("no_such_pkg.models:build", "cannot import module 'no_such_pkg.models'"),
        ("vp2.models.baselines:NoSuchModel", "has no attribute 'NoSuchModel'"),
        ("just_a_name", "expected a built-in name"),
        ("svg_prime:/nonexistent/run", "no checkpoint at"),
    ],
)
def test_bad_specs_fail_with_the_reason(spec, match):
    with pytest.raises(PluginError, match=match):
        check_spec(spec)


def test_yaml_without_target_is_rejected(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("image_size: 64\n")
    with pytest.raises(PluginError, match="_target_"):
        load_plugin(str(path))
    with pytest.raises(PluginError, match="cannot read"):
        load_plugin(str(tmp_path / "missing.yaml"))
