"""Model specs: parsing the five forms of ``--model``, checking them before any trial, and
loading models from ``package.module:factory`` specs, YAML files with ``_target_`` and the
model zoo (``zoo:NAME``)."""

from __future__ import annotations

import dataclasses
import random
import re
import sys
from pathlib import Path

import pytest
import torch

from tests.models.test_zoo import shipped_zoo_names
from vp2.models import CheckpointSpec, build_model, model_entry, write_model_checkpoint
from vp2.models.baselines import RepeatLastFrame
from vp2.models.contract import CheckedPredictor, unwrap
from vp2.models.simulator import SimulatorModel
from vp2.models.zoo import CHECKPOINT_FILE, get_card
from vp2.models.zoo import ZOO_PREFIX as ZOO_PREFIX_OF_THE_ZOO
from vp2.models.zoo_entries import add_to_zoo
from vp2.run.model_spec import (
    ZOO_PREFIX,
    ModelSpec,
    PluginError,
    check_spec,
    describe_spec,
    instantiate,
    load_plugin,
    model_identity,
    resolve_model,
)


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
        ("", "expected a built-in name"),
        ("svg_prime:", "expected NAME:CHECKPOINT"),
        ("svg_prim:runs/x", r"NAME:CHECKPOINT \(NAME: fitvid, .*svg_prime\)"),
        (":factory", "expected a built-in name"),
        ("pkg.mod:", "expected a built-in name"),
        ("pkg/mod:make", "expected a built-in name"),
    ],
)
def test_bad_specs_fail_with_the_reason(spec, match):
    with pytest.raises(PluginError, match=match):
        check_spec(spec)


@pytest.mark.parametrize(
    ("text", "kind", "target", "path"),
    [
        ("simulator", "builtin", "vp2.models.simulator:SimulatorModel", None),
        ("oracle", "builtin", "vp2.models.simulator:SimulatorModel", None),
        ("repeat_last_frame", "builtin", "vp2.models.baselines:RepeatLastFrame", None),
        ("svg_prime:runs/a:b", "checkpoint", None, Path("runs/a:b")),
        ("fitvid:/abs/step_00000004.pt", "checkpoint", None, Path("/abs/step_00000004.pt")),
        ("pkg.mod:make", "factory", "pkg.mod:make", None),
        ("mymodule:Maker.build", "factory", "mymodule:Maker.build", None),
        ("configs/model.yaml", "yaml", None, Path("configs/model.yaml")),
        ("svg_prime:m.yml", "yaml", None, Path("svg_prime:m.yml")),  # a file name wins
    ],
)
def test_parse_the_four_forms(text, kind, target, path):
    spec = ModelSpec.parse(text)
    assert (spec.text, spec.kind, spec.target, spec.path) == (text, kind, target, path)
    assert str(spec) == text and describe_spec(text) == describe_spec(spec) == kind
    if kind == "checkpoint":
        name = text.partition(":")[0]
        assert spec.checkpoint == CheckpointSpec(name, path)
    else:
        assert spec.checkpoint is None
    with pytest.raises(dataclasses.FrozenInstanceError):
        spec.kind = "yaml"  # type: ignore[misc]


@pytest.fixture(scope="module")
def fitvid_run(tmp_path_factory):
    """A run directory with a checkpoint of a tiny FitVid."""
    run = tmp_path_factory.mktemp("fitvid_run")
    model = build_model("fitvid", "mini", action_dim=4, image_size=32, seed=1)
    write_model_checkpoint(run / "checkpoints" / "step_00000002.pt", {"model": model_entry(model)})
    return run


def _corrupt(path: Path, run: Path) -> None:
    path.write_bytes(random.Random(0).randbytes(4096))


def _truncated(path: Path, run: Path) -> None:
    good = run / "checkpoints" / "step_00000002.pt"
    path.write_bytes(good.read_bytes()[:1000])


def _other_family(path: Path, run: Path) -> None:
    path.write_bytes((run / "checkpoints" / "step_00000002.pt").read_bytes())


@pytest.mark.parametrize(
    ("make", "what"),
    [
        (_corrupt, "is not a vp2 checkpoint (not a readable PyTorch file: UnpicklingError"),
        (_truncated, "is not a vp2 checkpoint (not a readable PyTorch file: failed reading zip"),
        (_other_family, "holds a 'fitvid' model, not 'svg_prime'"),
    ],
    ids=["corrupt", "truncated", "other_family"],
)
def test_a_bad_checkpoint_is_one_line_naming_the_file(make, what, fitvid_run, tmp_path):
    path = tmp_path / "model.pt"
    make(path, fitvid_run)
    spec = f"svg_prime:{path}"
    with pytest.raises(PluginError) as info:
        check_spec(spec)
    assert str(info.value).startswith(f"model {spec!r}: {path} {what}")
    assert "\n" not in str(info.value) and "weights_only" not in str(info.value)
    with pytest.raises(PluginError) as built:  # the same error where a worker builds it
        resolve_model(spec, {}, env="robodesk", action_dim=5, device="cpu")
    assert str(built.value) == str(info.value)


def test_a_checkpoint_spec_checks_and_loads(fitvid_run):
    check_spec(f"fitvid:{fitvid_run}")
    model = resolve_model(f"fitvid:{fitvid_run}", {}, env="tabletop", action_dim=4, device="cpu")
    assert model.name == "fitvid" and not model.training
    with pytest.raises(PluginError, match="a checkpoint is loaded by resolve_model"):
        load_plugin(f"fitvid:{fitvid_run}")


def test_yaml_without_target_is_rejected(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("image_size: 64\n")
    with pytest.raises(PluginError, match="_target_"):
        load_plugin(str(path))
    with pytest.raises(PluginError, match="cannot read"):
        load_plugin(str(tmp_path / "missing.yaml"))


SHIPPED_ZOO = "zoo:svg_prime-tiny-robodesk"


def test_parse_a_zoo_name_to_its_cards_family_and_checkpoint():
    spec = ModelSpec.parse(SHIPPED_ZOO)
    card = get_card("svg_prime-tiny-robodesk")
    assert (spec.kind, spec.text, spec.path) == ("zoo", SHIPPED_ZOO, card.checkpoint_path)
    assert spec.checkpoint == CheckpointSpec("svg_prime", card.checkpoint_path)
    assert spec.zoo is not None and spec.zoo.sha256 == card.sha256
    assert describe_spec(SHIPPED_ZOO) == "zoo" and ZOO_PREFIX == ZOO_PREFIX_OF_THE_ZOO == "zoo:"
    check_spec(SHIPPED_ZOO)
    with pytest.raises(PluginError, match="a checkpoint is loaded by resolve_model"):
        load_plugin(SHIPPED_ZOO)


def test_a_zoo_model_resolves_and_its_identity_names_the_entry():
    model = resolve_model(SHIPPED_ZOO, {}, env="robodesk", action_dim=5, device="cpu")
    identity = model_identity(SHIPPED_ZOO, {}, model)
    assert identity["spec"] == SHIPPED_ZOO and identity["name"] == "svg_prime"
    assert identity["zoo"] == {
        "name": "svg_prime-tiny-robodesk", "family": "svg_prime", "preset": "m0.25k0.25",
        "sha256": get_card("svg_prime-tiny-robodesk").sha256}
    assert "zoo" not in model_identity("repeat_last_frame", {}, RepeatLastFrame(action_dim=5))


def test_an_unknown_or_altered_zoo_entry_is_refused(tmp_path, monkeypatch):
    with pytest.raises(PluginError, match="model 'zoo:nope': no model 'nope' in the zoo at .*"
                       f"known: {re.escape(', '.join(shipped_zoo_names()))};"):
        check_spec("zoo:nope")
    model = build_model("fitvid", "mini", action_dim=4, image_size=32, seed=1)
    write_model_checkpoint(tmp_path / "m.pt", {
        "model": model_entry(model), "step": 1,
        "train_config": {"model": "fitvid", "preset": "mini", "dataset": "d", "out_dir": "r"},
        "dataset": {"config": {"env": "tabletop"}}})
    add_to_zoo(tmp_path / "m.pt", "mini", None, tmp_path / "zoo")
    monkeypatch.setenv("VP2_ZOO_DIR", str(tmp_path / "zoo"))
    check_spec("zoo:mini")
    with (tmp_path / "zoo" / "mini" / CHECKPOINT_FILE).open("ab") as f:
        f.write(b"\0")
    for call in (lambda: check_spec("zoo:mini"),
                 lambda: resolve_model("zoo:mini", {}, env="tabletop", action_dim=4,
                                       device="cpu")):
        with pytest.raises(PluginError, match="zoo model 'mini': the checkpoint .* does not "
                           "match its card"):
            call()


# --------------------------------------------------------------------------- ensembles

TINY = "zoo:svg_prime-tiny-tabletop"


def test_an_ensemble_parses_its_members_and_resolves_to_an_ensemble_model():
    text = f"ensemble({TINY}, repeat_last_frame)"
    spec = ModelSpec.parse(text)
    assert spec.kind == "ensemble" and spec.text == text
    assert [(m.text, m.kind) for m in spec.members] == [(TINY, "zoo"), ("repeat_last_frame",
                                                                         "builtin")]
    check_spec(spec)
    model = resolve_model(spec, {}, env="tabletop", action_dim=4, device="cpu")
    ensemble = unwrap(model)
    assert ensemble.labels == [TINY, "repeat_last_frame"]
    assert (ensemble.action_dim, ensemble.num_future, ensemble.image_size) == (4, 10, 64)
    identity = model_identity(spec, {}, model)
    assert identity["class"] == "vp2.models.ensemble.EnsembleModel" and identity["spec"] == text
    assert [m["spec"] for m in identity["ensemble"]] == [TINY, "repeat_last_frame"]
    assert identity["ensemble"][0]["zoo"]["name"] == "svg_prime-tiny-tabletop"
    # No other form reads an ensemble: a factory, a checkpoint or a zoo name has no '('.
    assert ModelSpec.parse("ensemble:make").kind == "factory"


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (f"ensemble({TINY})", f"model 'ensemble({TINY})': 1 member; an ensemble is "
         "ensemble(SPEC,SPEC,...), e.g. ensemble(zoo:a,zoo:b)"),
        (f"ensemble({TINY},,{TINY})", f"model 'ensemble({TINY},,{TINY})': member 2 is empty; "),
        (f"ensemble({TINY},{TINY}", f"model 'ensemble({TINY},{TINY}': no closing ')'; "),
        (f"ensemble({TINY},zoo:nope)", f"ensemble member 2 of 'ensemble({TINY},zoo:nope)': "
         "model 'zoo:nope': no model 'nope' in the zoo"),
        (f"ensemble({TINY},svg_prime:/no/such.pt)", f"ensemble member 2 of 'ensemble({TINY},"
         "svg_prime:/no/such.pt)': model 'svg_prime:/no/such.pt': no checkpoint at /no/such.pt"),
        (f"ensemble(oracle,{TINY})", f"ensemble member 1 of 'ensemble(oracle,{TINY})', "
         "'oracle': an ensemble member predicts from frames (not the simulator, not an ensemble)"),
        (f"ensemble({TINY},zoo:svg_prime-tiny-robodesk)", f"model 'ensemble({TINY},"
         "zoo:svg_prime-tiny-robodesk)': ensemble member 'zoo:svg_prime-tiny-robodesk' was "
         f"trained on robodesk, member '{TINY}' was trained on tabletop; members must agree on "
         "the environment and on num_context, num_future, action_dim, image_size"),
    ],
)
def test_a_bad_ensemble_is_one_line_naming_the_member(text, message):
    with pytest.raises(PluginError) as error:
        check_spec(text)
    assert str(error.value).startswith(message) and "\n" not in str(error.value)
