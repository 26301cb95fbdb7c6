"""The simulation path gives the same bits whatever kernels the CPU-dispatched libraries pick.

A machine cannot run another CPU, but the libraries that choose code by CPU at run time can be
forced to the choices other CPUs make: OpenBLAS (numpy's and scipy's, ``OPENBLAS_CORETYPE``),
NumPy's SIMD loops (``NPY_DISABLE_CPU_FEATURES``), numba's code generation
(``NUMBA_CPU_NAME``) and Mesa llvmpipe's (``GALLIUM_OVERRIDE_CPU_CAPS``). Each variant, in a fresh process (fresh mesh
cache), regenerates the first instance of every task category (``None`` where the task's
scripted policy finds none from that seed) and rolls every category's env out from a seeded
reset with fixed random actions, rendering each step; states, actions and images must be
identical to the machine's own defaults.
"""

from __future__ import annotations

import os
import textwrap

import pytest

from tests.cpu_variants import NO_AVX512, run_under

VARIANTS = {
    "own": {},
    "openblas_nehalem": {"OPENBLAS_CORETYPE": "Nehalem"},
    "openblas_haswell": {"OPENBLAS_CORETYPE": "Haswell"},
    "numpy_avx2": {"NPY_DISABLE_CPU_FEATURES": NO_AVX512},
    "numba_generic": {"NUMBA_CPU_NAME": "generic"},
    # An AVX2 machine as far as every library can be told so at once.
    "avx2_machine": {
        "OPENBLAS_CORETYPE": "Haswell",
        "NPY_DISABLE_CPU_FEATURES": NO_AVX512,
        "NUMBA_CPU_NAME": "haswell",
        "GALLIUM_OVERRIDE_CPU_CAPS": "avx",
    },
}

_SCRIPT = textwrap.dedent(
    """
    import hashlib, json
    import numpy as np
    from vp2.data.suite import TaskSuite, generate_instance
    from vp2.envs import make_env
    out, suite = {}, TaskSuite.load()
    for task in suite.tasks:
        seed = suite.for_task(task)[0].seed
        inst = generate_instance(task, seed, index=0)
        h = hashlib.sha256()
        if inst is None:
            h.update(b"none")
        else:
            for a in (inst.init_state, inst.goal_state, inst.goal_image, inst.actions):
                h.update(np.ascontiguousarray(a).tobytes())
        with make_env(task, seed=seed, observation_size=64) as env:
            obs, _ = env.reset(seed=seed)
            h.update(env.get_state().tobytes() + obs.tobytes())
            dim = env.action_space.shape[0]
            for a in np.random.default_rng(seed).uniform(-1, 1, (3, dim)):
                obs, *_ = env.step(a)
                h.update(env.get_state().tobytes() + obs.tobytes())
        out[task] = h.hexdigest()
    print(json.dumps(out))
    """
)


@pytest.mark.slow
def test_first_instances_are_identical_under_every_cpu_variant(tmp_path):
    """About 40 s per variant on 2 cores."""
    results = {
        name: run_under(_SCRIPT, overrides, os.fspath(tmp_path / name))
        for name, overrides in VARIANTS.items()
    }
    reference = results["own"]
    mismatches = {
        name: sorted(t for t in reference if got[t] != reference[t])
        for name, got in results.items()
        if got != reference
    }
    assert not mismatches, mismatches
