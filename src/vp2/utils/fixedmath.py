"""Small-vector arithmetic that gives the same bits on every x86-64 CPU.

Why this module exists: NumPy hands ``np.dot``/``@``/``np.linalg.norm`` of float64 vectors and
small matrices to OpenBLAS, which picks its kernels by CPU at run time (``OPENBLAS_CORETYPE``:
Haswell, SkylakeX, ...); the kernels sum in different orders and with or without FMA, so the
last bits depend on the machine. NumPy also dispatches float64 ``tan``, ``tanh``, ``arctan``,
``arctan2``, ``exp``, ``log``, ``power``... to SIMD implementations (AVX-512 SVML, AVX2) that
round differently from each other. In the simulation path (an action to the next state, the
scripted policies, the task suite) a last-bit difference grows through the contacts into a
different trajectory.

The functions here use only IEEE-754 basic operations in a fixed order (Python floats, or
element-wise NumPy ufuncs: ``+ - * /`` and ``sqrt`` are correctly rounded at every SIMD width)
and the C library's ``math`` functions, which do not depend on NumPy's dispatch. (glibc's
``sin``/``cos``/``atan2``/``tanh`` pick an FMA variant on CPUs that have FMA; MuJoCo's own
quaternion integration calls them too, so bit-identity holds across CPUs with FMA, i.e. every
x86-64 CPU since 2013 that runs MuJoCo's AVX build.)
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np


def dot(a: Sequence[float] | np.ndarray, b: Sequence[float] | np.ndarray) -> float:
    """``sum(a[i] * b[i])`` summed left to right."""
    s = 0.0
    for x, y in zip(_floats(a), _floats(b), strict=True):
        s += x * y
    return s


def norm(v: Sequence[float] | np.ndarray) -> float:
    """Euclidean norm, ``sqrt`` of the squares summed left to right."""
    s = 0.0
    for x in _floats(v):
        s += x * x
    return math.sqrt(s)


def matvec(m: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``m @ v`` for a small ``(r, c)`` matrix: column terms added left to right (element-wise)."""
    m = np.asarray(m, np.float64)
    v = np.asarray(v, np.float64)
    out = m[:, 0] * v[0]
    for k in range(1, m.shape[1]):
        out = out + m[:, k] * v[k]
    return out


def rows_norm(x: np.ndarray) -> np.ndarray:
    """``np.linalg.norm(x, axis=-1)`` with the squares added left to right (element-wise)."""
    x = np.asarray(x, np.float64)
    s = x[..., 0] * x[..., 0]
    for k in range(1, x.shape[-1]):
        s = s + x[..., k] * x[..., k]
    return np.sqrt(s)


def _floats(v: Sequence[float] | np.ndarray) -> list[float]:
    return np.asarray(v, np.float64).ravel().tolist()
