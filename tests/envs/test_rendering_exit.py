"""GL contexts at interpreter exit: no EGL tracebacks, whatever else rendered."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

# A vp2 renderer first, then dm_control (what the `robodesk` package renders with) creates
# its own EGL context and registers its eglTerminate exit hook after ours: that hook runs
# first and terminates the display our contexts live on.
SCRIPT = textwrap.dedent(
    """
    import vp2
    env = vp2.make_env("tabletop/push_sphere", seed=0)
    env.reset(seed=0)
    assert env.render(16).shape == (16, 16, 3)
    from dm_control import mujoco as dm_mujoco
    physics = dm_mujoco.Physics.from_xml_string(
        "<mujoco><worldbody><light pos='0 0 1'/><geom size='0.1'/></worldbody></mujoco>"
    )
    assert physics.render(8, 8).shape == (8, 8, 3)
    print("rendered")
    """
)


def test_no_egl_errors_at_exit_after_another_library_rendered():
    env = {**os.environ, "MUJOCO_GL": "egl", "OMP_NUM_THREADS": "1"}
    out = subprocess.run(
        [sys.executable, "-c", SCRIPT], capture_output=True, text=True, env=env, timeout=300
    )
    assert out.returncode == 0, out.stderr[-2000:]
    assert "rendered" in out.stdout
    assert "EGLError" not in out.stderr and "Exception ignored" not in out.stderr, out.stderr[-2000:]
