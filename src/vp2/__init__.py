"""vp2: a control-centric benchmark for action-conditioned video prediction models."""

import vp2._quiet  # noqa: F401 (first: silences third-party import notices, see its docstring)
from vp2.envs import ENV_NAMES, TASK_NAMES, make_env

__version__ = "0.1.0"

__all__ = ["ENV_NAMES", "TASK_NAMES", "__version__", "make_env"]
