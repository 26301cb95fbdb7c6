"""A whole simulator-oracle trial plans the same actions, bit for bit, whatever kernels the
CPU-dispatched libraries pick.

The variables below make the libraries choose the code other CPUs get (see
``tests/envs/test_cross_cpu.py`` for the simulation path alone): ATen's kernels
(``ATEN_CPU_CAPABILITY``: the sampler's normal draws, reductions, ``exp``), oneDNN's
convolutions (``ONEDNN_MAX_CPU_ISA``: the success classifier), MKL's and OpenBLAS's BLAS
kernels, NumPy's SIMD loops, numba's and llvmpipe's code generation. Each variant runs the
first control steps of a RoboDesk trial with its success classifier in the cost and of a
tabletop trial in a fresh process; the executed actions must equal the machine's own.
"""

from __future__ import annotations

import os
import textwrap

import pytest

from tests.cpu_variants import NO_AVX512, run_under

VARIANTS = {
    "own": {},
    # An AVX2 machine (a Zen 2/3 or a Haswell) as far as every library can be told.
    "avx2_machine": {
        "ATEN_CPU_CAPABILITY": "avx2",
        "ONEDNN_MAX_CPU_ISA": "AVX2",
        "MKL_ENABLE_INSTRUCTIONS": "AVX2",
        "OPENBLAS_CORETYPE": "Haswell",
        "NPY_DISABLE_CPU_FEATURES": NO_AVX512,
        "NUMBA_CPU_NAME": "haswell",
        "GALLIUM_OVERRIDE_CPU_CAPS": "avx",
    },
    # The oldest kernels each library still has: ATen's scalar ones, oneDNN's SSE4.1, ...
    "sse_kernels": {
        "ATEN_CPU_CAPABILITY": "default",
        "ONEDNN_MAX_CPU_ISA": "SSE41",
        "MKL_ENABLE_INSTRUCTIONS": "SSE4_2",
        "OPENBLAS_CORETYPE": "Nehalem",
        "NPY_DISABLE_CPU_FEATURES": f"AVX AVX2 FMA3 F16C {NO_AVX512}",
        "NUMBA_CPU_NAME": "generic",
    },
}
#: Planner samples and control steps per trial: the zero action, then two planned steps.
SAMPLES, STEPS = 8, 3

_SCRIPT = textwrap.dedent(
    f"""
    import json
    import torch
    from vp2.run.trial import ControlTrial
    from vp2.data.suite import TaskSuite
    from vp2.envs import TABLETOP_TASKS, env_class
    from vp2.models.simulator import SimulatorModel
    from vp2.planning import PlannerConfig, PlanningAgent

    torch.set_num_threads(1)
    out, suite = {{}}, TaskSuite.load()
    for task in ("robodesk/push_red", f"tabletop/{{TABLETOP_TASKS[0]}}"):
        model = SimulatorModel(env_class(task.split("/")[0]).action_dim)
        agent = PlanningAgent(model, planner=PlannerConfig(num_samples={SAMPLES}), device="cpu")
        result = ControlTrial(suite.get(task, 0), agent, seed=0, num_steps={STEPS}).run()
        out[task] = {{"cost": agent.cost_kind,
                     "actions": [[float(x).hex() for x in a] for a in result.actions]}}
    print(json.dumps(out))
    """
)


@pytest.mark.slow
def test_oracle_trials_plan_the_same_actions_under_every_cpu_variant(tmp_path):
    """About 40 s per variant on 2 cores."""
    results = {
        name: run_under(_SCRIPT, overrides, os.fspath(tmp_path / name))
        for name, overrides in VARIANTS.items()
    }
    own = results["own"]
    assert own["robodesk/push_red"]["cost"] == "pixel+classifier"  # the classifier planned
    for trial in own.values():
        assert len(trial["actions"]) == STEPS and float.fromhex(trial["actions"][1][0]) != 0
    mismatches = {
        name: sorted(t for t in own if got[t] != own[t])
        for name, got in results.items()
        if got != own
    }
    assert not mismatches, mismatches
