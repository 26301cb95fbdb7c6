"""Silences third-party import-time notices a vp2 user cannot act on, in one place.

Imported first by ``vp2/__init__.py``, before any simulator package, so it holds in every
process (spawned trial workers and Ray actors import ``vp2`` too). Only these messages go;
everything else those packages log or warn, and all of vp2's own warnings, still shows:

* robosuite: "No private macro file found!" (+ its two follow-up lines), "Could not import
  robosuite_models" and "Could not load the mink-based whole-body IK" (vp2 uses neither its
  macros file, its extra robots nor its whole-body IK). robosuite resets its logger's level
  while importing, so a logging filter (which it keeps) drops them rather than a level;
* gym: "Gym has been unmaintained since 2022 ..." (the ``gym_notices`` print of
  ``import gym``; vp2 does not use gym, the ``robodesk`` package imports it);
* glfw: "The DISPLAY environment variable is missing" and other GLFW error warnings (vp2
  renders with EGL or OSMesa, never through GLFW, which ``mujoco.viewer`` imports).
"""

from __future__ import annotations

import logging
import sys
import warnings

#: Starts of the robosuite log messages that are dropped.
ROBOSUITE_NOTICES: tuple[str, ...] = (
    "No private macro file found",
    "It is recommended to use a private macro file",
    "To setup, run:",
    "Could not import robosuite_models",
    "Could not load the mink-based whole-body IK",
)


class _DropNotices(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        return not str(record.msg).startswith(ROBOSUITE_NOTICES)


def silence_third_party_notices() -> None:
    """Installs the filters (idempotent)."""
    logger = logging.getLogger("robosuite_logs")  # robosuite's ROBOSUITE_DEFAULT_LOGGER
    if not any(isinstance(f, _DropNotices) for f in logger.filters):
        logger.addFilter(_DropNotices())
    # GLFW reports errors as warnings from its own module (its error callback).
    warnings.filterwarnings("ignore", module="glfw")
    warnings.filterwarnings("ignore", message=r".*DISPLAY environment variable")
    if "gym" not in sys.modules:
        try:  # gym prints the notice of its version from this table, if present
            import gym_notices.notices as gym_notices
        except Exception:  # not installed (no gym): nothing to silence
            return
        gym_notices.notices.clear()


silence_third_party_notices()
