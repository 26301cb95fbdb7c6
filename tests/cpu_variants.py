"""Running a script in a fresh process as if on another CPU: the libraries that choose their
kernels by CPU at run time are told which to use through environment variables (the
cross-CPU tests of the stepping path and of whole oracle trials)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

#: NumPy's AVX-512 dispatch targets (``NPY_DISABLE_CPU_FEATURES``).
NO_AVX512 = "AVX512F AVX512CD AVX512_SKX AVX512_CLX AVX512_CNL AVX512_ICL"


def run_under(script: str, env_overrides: dict[str, str], cache: str) -> dict:
    """The JSON that ``script`` prints last, run with ``env_overrides``, its own vp2 cache
    ``cache`` (fresh mesh cache) and one OpenMP thread."""
    env = {**os.environ, **env_overrides, "VP2_CACHE_DIR": cache, "OMP_NUM_THREADS": "1"}
    proc = subprocess.run(
        [sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(proc.stdout.strip().splitlines()[-1])
