"""MuJoCo's C functions, callable from numba-compiled code.

Compiled loops (:mod:`vp2.envs._substep_kernel`, :mod:`vp2.envs._robodesk_kernel`) call MuJoCo by
symbol: each function is bound with ``llvmlite`` to the shared library the ``mujoco`` package has
already loaded (one instance, so the model's and data's raw addresses -- ``MjModel._address``,
``MjData._address`` -- are valid in it). Binding by name, not by address, lets numba cache the
code that calls them: the address is bound when the cache is loaded, not baked in.

Pointers travel as 64-bit unsigned integers (:data:`P`): the raw addresses of ``mjModel``,
``mjData`` and arrays (``array.ctypes.data`` inside compiled code).
"""

from __future__ import annotations

import ctypes
import os

import llvmlite.binding as llvm
import mujoco
from numba import types


def _load_mujoco() -> ctypes.CDLL:
    """The MuJoCo shared library the ``mujoco`` package uses (already loaded: one instance)."""
    folder = os.path.dirname(mujoco.__file__)
    name = f"libmujoco.so.{mujoco.__version__}"
    path = os.path.join(folder, name)
    if not os.path.exists(path):
        candidates = sorted(f for f in os.listdir(folder) if f.startswith("libmujoco"))
        if not candidates:
            raise ImportError(
                f"the mujoco package in {folder} ships no libmujoco shared library; "
                "reinstall it with `pip install mujoco==3.8.0`"
            )
        path = os.path.join(folder, candidates[0])
    return ctypes.CDLL(path)


LIB = _load_mujoco()
#: A pointer argument: a raw address as a 64-bit unsigned integer.
P = types.uintp


def external(name: str, result: types.Type, *args: types.Type) -> types.ExternalFunction:
    """The C function ``name`` of MuJoCo's library, with its result and argument types."""
    llvm.add_symbol(name, ctypes.cast(getattr(LIB, name), ctypes.c_void_p).value)
    return types.ExternalFunction(name, result(*args))


# The functions more than one compiled loop calls.
mj_step1 = external("mj_step1", types.void, P, P)
mj_step2 = external("mj_step2", types.void, P, P)
mj_jacSite = external("mj_jacSite", types.void, P, P, P, P, types.intc)
