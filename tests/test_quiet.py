"""Importing vp2 and building its environments prints no third-party notices (vp2._quiet)."""

from __future__ import annotations

import subprocess
import sys

from vp2._quiet import ROBOSUITE_NOTICES

SCRIPT = """
import logging, warnings
import vp2
for task in ("tabletop/push_sphere", "robodesk/push_red"):
    vp2.make_env(task, seed=0).close()
import gym  # what the robodesk package imports; vp2 itself does not
warnings.warn("(65544) b'X11: The DISPLAY environment variable is missing'")
# Everything else still shows: robosuite's other messages, anyone's own warnings.
logging.getLogger("robosuite_logs").warning("robosuite still talks")
warnings.warn("vp2 still warns")
"""


def test_no_third_party_notices_on_stderr():
    proc = subprocess.run(
        [sys.executable, "-c", SCRIPT], capture_output=True, text=True, timeout=300
    )
    assert proc.returncode == 0, proc.stderr
    for notice in (*ROBOSUITE_NOTICES, "Gym has been unmaintained", "DISPLAY environment"):
        assert notice not in proc.stderr, proc.stderr
    assert "robosuite still talks" in proc.stderr and "vp2 still warns" in proc.stderr
