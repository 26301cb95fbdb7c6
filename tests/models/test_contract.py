"""The model contract, checked over every registered model and size preset."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import ClassVar

import pytest
import torch

from vp2.models import (
    DEFAULT_MAX_BATCH_SIZE,
    CheckedModel,
    FitVidConfig,
    ModelContractError,
    TrainingDefaults,
    VideoPredictor,
    all_variants,
    build_model,
    checked,
    load_model_spec,
    make_config,
    model_from_config,
    parse_model_spec,
    parse_overrides,
    predict_in_chunks,
)
from vp2.models.contract import REQUIRED_ATTRIBUTES, gradient_problem, model_failure
from vp2.models.registry import MODELS

# The big variants cost seconds to minutes per forward on a CPU (MCVD default/small sample
# 100 diffusion steps); their contract runs with `slow`.
HEAVY = {
    ("svg_prime", "m1k1"),
    ("svg_prime", "m2k2"),
    ("mcvd", "default"),
    ("mcvd", "small"),
    ("maskvit", "default"),
    ("maskvit", "small"),
    ("struct_vrnn", "default"),
}
VARIANTS = [
    pytest.param(name, preset, marks=pytest.mark.slow)
    if (name, preset) in HEAVY
    else (name, preset)
    for name, preset in all_variants()
]

# Reference parameter counts (model-specs §1, §2), for tabletop's 4-D actions.
REFERENCE_PARAMS = {
    ("svg_prime", "m0.25k0.25"): 5.8e6,
    ("svg_prime", "m0.5k0.5"): 21.5e6,
    ("svg_prime", "m1k1"): 83e6,
    ("svg_prime", "m2k2"): 325e6,
    ("fitvid", "default"): 10.4e6,
    ("fitvid", "small_encoder"): 6.6e6,
    ("fitvid", "mini"): 1.5e6,
}
# Models whose original layer sizes are not documented (model-specs §3-§5 give only totals
# that our layouts do not reproduce: Struct-VRNN ~17 M, MCVD ~56 M): their counts are pinned
# to our own layouts (exactly, A = 4), so an accidental architecture change is caught.
OWN_PARAMS = {
    ("struct_vrnn", "default"): 7_515_395,
    ("struct_vrnn", "small"): 599_763,
    ("struct_vrnn", "tiny"): 103_339,
    ("mcvd", "default"): 45_038_159,
    ("mcvd", "small"): 2_936_367,
    ("mcvd", "tiny"): 1_599_119,
    ("maskvit", "default"): 30_480_932,
    ("maskvit", "small"): 4_199_844,
    ("maskvit", "tiny"): 301_652,
    ("maskvit_tokenizer", "default"): 4_070_436,
    ("maskvit_tokenizer", "small"): 707_236,
    ("maskvit_tokenizer", "tiny"): 175_700,
}


def _inputs(batch: int, action_dim: int = 4, size: int = 64, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    frames = torch.rand(batch, 2, 3, size, size, generator=g)  # (B, 2, 3, H, W)
    actions = torch.rand(batch, 11, action_dim, generator=g) * 2 - 1  # (B, 11, A)
    return frames, actions


def test_every_variant_has_a_reference_parameter_count():
    assert set(REFERENCE_PARAMS) | set(OWN_PARAMS) == set(all_variants())


@pytest.mark.parametrize(("name", "preset"), sorted({**REFERENCE_PARAMS, **OWN_PARAMS}))
def test_parameter_counts_match_reference(name, preset):
    config = make_config(name, preset, action_dim=4)
    with torch.device("meta"):  # counts shapes without allocating 325 M parameters
        model = MODELS[name].model_class(config)
    count = model.num_parameters()
    expected = {**REFERENCE_PARAMS, **OWN_PARAMS}[(name, preset)]
    assert count == pytest.approx(expected, rel=0.05 if (name, preset) in REFERENCE_PARAMS
                                  else 0), count


@pytest.mark.parametrize(("name", "preset"), VARIANTS)
def test_predict_contract(name, preset):
    model = build_model(name, preset, action_dim=4)
    assert model.name == name and isinstance(model, MODELS[name].model_class)
    assert checked(model) is model  # a VideoPredictor checks its own calls: never wrapped
    assert (model.num_context, model.num_future, model.action_dim, model.image_size) == (
        2,
        10,
        4,
        64,
    )
    assert model.max_batch_size >= 1
    frames, actions = _inputs(2)
    out = model.predict(frames, actions, generator=torch.Generator().manual_seed(1))
    assert out.shape == (2, 10, 3, 64, 64)
    assert out.dtype == torch.float32 and out.device == frames.device
    assert 0.0 <= float(out.min()) and float(out.max()) <= 1.0
    assert out.grad_fn is None  # no graph by default
    assert model.training  # predict runs in eval mode but restores the mode
    # Deterministic given the generator's seed (and with the default generator).
    again = model.predict(frames, actions, generator=torch.Generator().manual_seed(1))
    torch.testing.assert_close(out, again, rtol=0, atol=0)
    torch.testing.assert_close(
        model.predict(frames, actions), model.predict(frames, actions), rtol=0, atol=0
    )
    # ... and stochastic: another seed samples other latents (the MaskViT tokenizer's
    # predict is a deterministic reconstruction baseline and declares it).
    other = model.predict(frames, actions, generator=torch.Generator().manual_seed(2))
    assert torch.equal(out, other) != getattr(model, "stochastic", True)


@pytest.mark.parametrize(("name", "preset"), [("svg_prime", "m0.25k0.25"), ("fitvid", "mini")])
def test_same_seed_same_weights(name, preset):
    a = build_model(name, preset, seed=3)
    b = build_model(name, preset, seed=3)
    c = build_model(name, preset, seed=4)
    state = torch.get_rng_state()
    for (k, va), vb in zip(a.state_dict().items(), b.state_dict().values(), strict=True):
        torch.testing.assert_close(va, vb, rtol=0, atol=0, msg=k)
    assert any(
        not torch.equal(va, vc) for va, vc in zip(a.parameters(), c.parameters(), strict=True)
    )
    assert torch.equal(state, torch.get_rng_state())  # building never touched global RNG


@pytest.mark.parametrize(("name", "preset"), [("svg_prime", "m0.25k0.25"), ("fitvid", "mini")])
def test_gradients_to_actions_for_gradient_planners(name, preset):
    model = build_model(name, preset, action_dim=4, image_size=32)
    frames, actions = _inputs(2, size=32)
    leaf = actions.clone().requires_grad_(True)
    out = model.predict(frames, leaf)  # grad=None: follows the input's requires_grad
    assert out.grad_fn is not None
    (grad,) = torch.autograd.grad(out.square().sum(), leaf)
    assert grad.shape == actions.shape
    assert float(grad[:, 1:].abs().sum()) > 0  # candidate actions influence the prediction
    assert all(p.grad is None for p in model.parameters())
    assert model.predict(frames, leaf, grad=False).grad_fn is None


@pytest.fixture(scope="module")
def tiny_fitvid():
    return build_model("fitvid", "mini", action_dim=4, image_size=32)


@pytest.mark.parametrize(
    ("field", "make", "message"),
    [
        ("context_frames", lambda f, a: (f[:, :1], a), r"shape \(B, 2, 3, 32, 32\)"),
        ("context_frames", lambda f, a: (f[..., :16], a), r"got \(2, 2, 3, 32, 16\)"),
        ("context_frames", lambda f, a: ((f * 255).to(torch.uint8), a), "divide uint8"),
        ("context_frames", lambda f, a: (f * 2, a), r"values in \[0, 1\]"),
        (
            "context_frames",
            lambda f, a: (f.index_fill(0, torch.tensor([1]), float("nan")), a),
            "NaN",
        ),
        ("context_frames", lambda f, a: (f.numpy(), a), "torch.Tensor"),
        ("actions", lambda f, a: (f, a[:, :10]), r"shape \(B, 11, 4\)"),
        ("actions", lambda f, a: (f, a[..., :3]), r"got \(2, 11, 3\)"),
        ("actions", lambda f, a: (f, a * 3), r"values in \[-1, 1\]"),
        ("actions", lambda f, a: (f, a.index_fill(0, torch.tensor([0]), float("inf"))), "inf"),
        ("actions", lambda f, a: (f, a[:1]), "batch size 2"),
        ("actions", lambda f, a: (f, a.long()), "floating point"),
    ],
)
def test_bad_inputs_name_the_model_and_field(tiny_fitvid, field, make, message):
    frames, actions = _inputs(2, size=32)
    bad_frames, bad_actions = make(frames, actions)
    with pytest.raises(ValueError, match=message) as info:
        tiny_fitvid.predict(bad_frames, bad_actions)
    assert str(info.value).startswith(f"fitvid.predict: {field}: expected")


class _FakeModel:
    """A non-network implementation of the interface (like the simulator oracle)."""

    name = "fake"
    num_context, num_future, action_dim, image_size, max_batch_size = 2, 10, 4, 32, 3

    def __init__(self, output=None):
        self.output, self.batches = output, []

    def predict(self, context_frames, actions, *, generator=None, grad=None):
        self.batches.append(context_frames.shape[0])
        if self.output is not None:
            return self.output
        # Deterministic: the last context frame, brightened by the summed actions.
        shift = actions[:, 1:, :1, None, None].cumsum(1) * 0.01  # (B, 10, 1, 1, 1)
        return (context_frames[:, -1:] + shift).clamp(0, 1)


def test_checked_model_validates_inputs_and_outputs():
    frames, actions = _inputs(2, size=32)
    good = CheckedModel(_FakeModel())
    assert (good.name, good.max_batch_size, good.image_size) == ("fake", 3, 32)
    assert good.predict(frames, actions).shape == (2, 10, 3, 32, 32)
    with pytest.raises(ValueError, match="fake.predict: actions: expected"):
        good.predict(frames, actions * 2)
    for output, message in [
        (torch.zeros(2, 9, 3, 32, 32), r"output: expected shape \(2, 10, 3, 32, 32\)"),
        (torch.full((2, 10, 3, 32, 32), float("nan")), "output: expected finite"),
        (torch.full((2, 10, 3, 32, 32), 1.5), r"output: expected values in \[0, 1\]"),
        (
            torch.zeros(2, 10, 3, 32, 32, dtype=torch.float64),
            "output: expected dtype torch.float32",
        ),
    ]:
        with pytest.raises(ValueError, match=message):
            CheckedModel(_FakeModel(output)).predict(frames, actions)
    with pytest.raises(
        TypeError, match="object does not implement VideoPredictionModel: missing num_context"
    ):
        CheckedModel(object())


@pytest.mark.parametrize("missing", REQUIRED_ATTRIBUTES)
def test_checked_names_a_missing_attribute(missing):
    attrs = {"num_context": 2, "num_future": 10, "action_dim": 4, "image_size": 32}
    attrs["predict"] = lambda self, context, actions: context[:, -1:].expand(-1, 10, -1, -1, -1)
    del attrs[missing]
    incomplete = type("Incomplete", (), attrs)()
    with pytest.raises(TypeError, match=f"Incomplete does not implement VideoPredictionModel: "
                       f"missing {missing} "):
        checked(incomplete)


class _Minimal:
    """Only what the README asks of a model: four attributes and predict(context, actions)."""

    num_context, num_future, image_size, action_dim = 2, 10, 32, 4

    def __init__(self):
        self.grad_enabled: list[bool] = []

    def predict(self, context, actions):
        self.grad_enabled.append(torch.is_grad_enabled())
        drift = 0.01 * actions[:, 1:, 0].cumsum(1)  # (B, 10)
        return (context[:, -1:] + drift[:, :, None, None, None]).clamp(0, 1)


def test_a_minimal_model_gets_the_interface_defaults():
    model = checked(_Minimal())
    assert checked(model) is model  # wrapped once
    assert model.name == "_Minimal" and model.max_batch_size == DEFAULT_MAX_BATCH_SIZE
    frames, actions = _inputs(3, size=32)
    # generator and grad are not passed to a predict that does not declare them.
    out = model.predict(frames, actions, generator=torch.Generator(), grad=False)
    assert out.shape == (3, 10, 3, 32, 32) and model.model.grad_enabled == [False]
    assert predict_in_chunks(model, frames, actions, chunk_size=2).shape == (3, 10, 3, 32, 32)
    model.max_batch_size = 7  # attributes are written through to the model
    assert model.model.max_batch_size == 7 and model.max_batch_size == 7
    assert gradient_problem(model) is None
    # A model's own exception is marked as a model-boundary failure; so is a bad output.
    with pytest.raises(ModelContractError) as info:
        checked(_FakeModel(torch.zeros(3, 9, 3, 32, 32))).predict(frames, actions)
    assert model_failure(info.value) == {
        "model": "fake", "field": "predict output", "expected": "shape (3, 10, 3, 32, 32)",
        "got": "(3, 9, 3, 32, 32)",
    }
    with pytest.raises(ModelContractError, match="_Minimal.predict: actions: expected shape"):
        model.predict(frames, actions[..., :1])

    class Raising(_Minimal):
        def predict(self, context, actions):
            raise RuntimeError("CUDA out of memory")

    with pytest.raises(RuntimeError) as info:
        checked(Raising()).predict(frames, actions)
    assert model_failure(info.value) == {
        "model": "Raising", "field": "predict() call", "expected": "no exception",
        "got": "RuntimeError: CUDA out of memory",
    }
    assert model_failure(RuntimeError("a simulator error")) is None


def test_gradient_problem_names_why():
    from vp2.models.baselines import RepeatLastFrame

    assert "without a gradient" in gradient_problem(RepeatLastFrame(action_dim=4, image_size=32))

    class Declared(_Minimal):
        differentiable = False

    assert gradient_problem(Declared()) == "declares differentiable = False"


def test_predict_in_chunks_honours_max_batch_size():
    fake = _FakeModel()
    frames, actions = _inputs(8, size=32)
    out = predict_in_chunks(fake, frames, actions)
    assert fake.batches == [3, 3, 2]
    torch.testing.assert_close(out, fake.predict(frames, actions))
    fake.batches.clear()
    predict_in_chunks(fake, frames, actions, chunk_size=5)
    assert fake.batches == [5, 3]


def test_predict_in_chunks_on_a_network(tiny_fitvid):
    frames, actions = _inputs(5, size=32)
    tiny_fitvid.max_batch_size = 2
    try:
        out = predict_in_chunks(tiny_fitvid, frames, actions)
    finally:
        tiny_fitvid.max_batch_size = 200
    assert out.shape == (5, 10, 3, 32, 32)
    # The first chunk draws the same noise as an unchunked call with the default generator.
    torch.testing.assert_close(out[:2], tiny_fitvid.predict(frames[:2], actions[:2]))


def test_subclass_contract_is_checked_at_definition():
    with pytest.raises(TypeError, match="`name`"):

        class Nameless(VideoPredictor):
            config_class: ClassVar[type] = FitVidConfig
            training_defaults: ClassVar[TrainingDefaults] = TrainingDefaults()

            def _predict(self, context_frames, actions, generator):
                return context_frames

            def _compute_loss(self, frames, actions, generator, frame_loss):
                raise NotImplementedError

    @dataclasses.dataclass
    class NoSizes:
        beta: float = 0.0

    with pytest.raises(TypeError, match="action_dim"):

        class Sizeless(VideoPredictor):
            name: ClassVar[str] = "sizeless"
            config_class: ClassVar[type] = NoSizes
            training_defaults: ClassVar[TrainingDefaults] = TrainingDefaults()

            def _predict(self, context_frames, actions, generator):
                return context_frames

            def _compute_loss(self, frames, actions, generator, frame_loss):
                raise NotImplementedError


def test_registry_presets_and_overrides():
    config = make_config("svg_prime", "m0.5k0.5", beta="1e-3", action_dim="4")
    assert (config.m, config.k, config.beta, config.action_dim) == (0.5, 0.5, 1e-3, 4)
    fitvid = make_config("fitvid", "mini", **parse_overrides(["stage_sizes=2,1,1,1"]))
    assert fitvid.stage_sizes == (2, 1, 1, 1) and fitvid.num_base_filters == 8
    with pytest.raises(ValueError, match="unknown model 'svg'; registered: fitvid, .*svg_prime"):
        make_config("svg")
    with pytest.raises(ValueError, match="unknown preset 'huge' of fitvid"):
        make_config("fitvid", "huge")
    with pytest.raises(ValueError, match=r"unknown SVGPrimeConfig field\(s\) \['M'\]"):
        make_config("svg_prime", M=2)
    with pytest.raises(ValueError, match="beta='big'"):
        make_config("svg_prime", beta="big")
    with pytest.raises(ValueError, match="expected KEY=VALUE"):
        parse_overrides(["beta"])
    with pytest.raises(ValueError, match="multiple of 8"):
        make_config("svg_prime", image_size=36)
    # Configs from checkpoints are plain dicts.
    model = model_from_config("fitvid", {**dataclasses.asdict(fitvid), "stage_sizes": [1, 1, 1, 1]})
    assert model.config.stage_sizes == (1, 1, 1, 1)


def test_parse_model_spec(tmp_path):
    assert parse_model_spec("svg_prime:runs/a:b") == ("svg_prime", Path("runs/a:b"))
    with pytest.raises(ValueError, match="expected NAME:CHECKPOINT"):
        parse_model_spec("svg_prime")
    with pytest.raises(ValueError, match="unknown model"):
        parse_model_spec("nosuchmodel:x")
    with pytest.raises(FileNotFoundError, match="no checkpoint"):
        load_model_spec(f"fitvid:{tmp_path}")


def test_checkpoint_inference_overrides(tmp_path):
    from vp2.models.checkpoint import write_model_checkpoint
    from vp2.run.model_spec import PluginError
    from vp2.run.model_spec import resolve_model as build_spec

    model = build_model("mcvd", "tiny", seed=3)
    path = write_model_checkpoint(
        tmp_path / "step_00000001.pt",
        {"model": {"name": "mcvd", "config": model.config_dict(), "state_dict": model.state_dict()}},
    )
    loaded = load_model_spec(f"mcvd:{path}", device="cpu", overrides={"sampling_steps": "2"})
    assert loaded.config.sampling_steps == 2 and model.config.sampling_steps == 10
    for a, b in zip(loaded.state_dict().values(), model.state_dict().values(), strict=True):
        assert torch.equal(a, b)
    # Through the runner's model-spec path, as `vp2 run --model mcvd:CKPT --model-arg ...`.
    via_spec = build_spec(
        f"mcvd:{path}", {"sampling_steps": 4}, env="robodesk", action_dim=5, device="cpu"
    )
    assert via_spec.config.sampling_steps == 4
    with pytest.raises(PluginError, match="change the mcvd architecture"):
        build_spec(f"mcvd:{path}", {"base_channels": 8}, env="robodesk", action_dim=5, device="cpu")
    with pytest.raises(ValueError, match="sampling_stepz"):
        load_model_spec(f"mcvd:{path}", device="cpu", overrides={"sampling_stepz": 2})
