"""Helpers shared by the scripts under ``benchmarks/``.

* How a script is run, and on what: :func:`argument_parser` (its usage line names
  ``python -m``), :func:`command_line`, :func:`cpu_name`, :func:`timestamp` and
  :func:`print_header` (the lines a timing starts with).
* :func:`suite_planning_step`: one planning step on a suite instance, to time.
* The original simulators that vp2 re-implements, for side-by-side comparisons: the
  ``robodesk`` package (:func:`robodesk_package`, :func:`load_package_state`,
  :func:`rebind_package_gl`) and robosuite's tabletop world (:func:`load_into_world`).

Only the standard library is imported at module level: a script sets ``MUJOCO_GL`` before
MuJoCo is first imported, and the JAX side of ``benchmarks.fidelity.i3d_jax_agreement`` runs
in an environment without vp2's dependencies.
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import shlex
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import numpy as np

    from vp2.envs._tabletop_stepper import LeanStepper
    from vp2.envs._tabletop_world import TabletopWorld
    from vp2.envs.tabletop import TabletopEnv


# ---- how a script was run ---------------------------------------------------------------------
def prog(module: str) -> str:
    """The program name of a script's usage line: how it runs from the repository root."""
    return f"python -m {module}"


def argument_parser(module: str, doc: str, full_doc: bool = False) -> argparse.ArgumentParser:
    """The command-line parser of the script ``module`` (its ``__spec__.name``): the usage line
    names ``python -m module``; the description is the first line of its docstring ``doc``, or
    with ``full_doc`` the whole docstring as written (usage examples included)."""
    if full_doc:
        return argparse.ArgumentParser(
            prog=prog(module),
            description=doc,
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
    return argparse.ArgumentParser(prog=prog(module), description=doc.splitlines()[0])


def command_line(module: str, argv: Sequence[str] | None = None) -> str:
    """The command that runs ``module`` with ``argv`` (default: this process's arguments)."""
    return shlex.join(["python", "-m", module, *(sys.argv[1:] if argv is None else argv)])


def cpu_name() -> str:
    """The CPU model from /proc/cpuinfo where there is one."""
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def timestamp() -> str:
    """The local date and time to the second, ISO 8601 (no UTC offset)."""
    return datetime.datetime.now().isoformat(timespec="seconds")


def print_header(module: str, machine: str) -> None:
    """Prints the lines a timing starts with: the command, the date, the machine (the CPU, its
    cores, then ``machine``: e.g. torch's version and threads) and the load average."""
    print(f"command: {command_line(module)}")
    print(f"date: {datetime.datetime.now().astimezone().isoformat(timespec='seconds')}")
    print(f"machine: {cpu_name()}, {os.cpu_count()} CPU cores, {machine}")
    print(f"load average before: {os.getloadavg()[0]:.2f}")


# ---- the robodesk package ---------------------------------------------------------------------
def robodesk_package(task: str) -> Any:
    """The original ``robodesk.RoboDesk`` of ``task`` with vp2's settings (50 physics steps per
    action, 64x64 images); Pillow's removed ``Image.ANTIALIAS``, which it still uses, is
    restored as LANCZOS."""
    import robodesk
    from PIL import Image

    if not hasattr(Image, "ANTIALIAS"):  # the package's Pillow bug, patched for the comparison
        Image.ANTIALIAS = Image.Resampling.LANCZOS
    return robodesk.RoboDesk(task=task, action_repeat=50, image_size=64)


def load_package_state(package: Any, state: np.ndarray) -> None:
    """Puts the package's physics (and the copy its inverse kinematics uses) into ``state``: a
    MuJoCo integration state, or a vp2 ``RoboDeskEnv`` state, which starts with one."""
    import mujoco

    integration = mujoco.mjtState.mjSTATE_INTEGRATION
    n = mujoco.mj_stateSize(package.physics.model.ptr, integration)
    package.physics.set_state(state[:n], integration)
    package.physics.forward()
    package.physics_copy.data.qpos[:] = package.physics.data.qpos


def rebind_package_gl(package: Any) -> None:
    """Makes the package's next render re-bind its GL context.

    dm_control remembers which GL context it made current on a thread and skips
    ``eglMakeCurrent`` when it thinks its own is still current; our renderer makes its own
    context current on the same thread, after which the package silently renders into the
    wrong context (a wrong image, fast). Forgetting dm_control's record forces the re-bind.
    """
    from dm_control._render import base

    contexts = getattr(package.physics, "_contexts", None)
    if contexts is None:
        return
    thread = contexts.gl._render_executor.thread
    current = base._CURRENT_CONTEXT_FOR_THREAD.pop(thread, None)
    if current is not None:
        base._CURRENT_THREAD_FOR_CONTEXT.pop(current, None)


# ---- robosuite's tabletop world ---------------------------------------------------------------
def load_into_world(env: TabletopEnv, world: TabletopWorld, stepper: LeanStepper) -> None:
    """Copies ``env``'s full state (textures and controller state included) into ``world``."""
    import mujoco
    import numpy as np

    from vp2.envs.tabletop import OBJECT_NAMES

    integration = mujoco.mjtState.mjSTATE_INTEGRATION
    state = env.get_state()
    n = mujoco.mj_stateSize(env._model, integration)
    mujoco.mj_setState(world.sim.model._model, world.sim.data._data, state[:n], integration)
    world.set_textures(state[n : n + len(OBJECT_NAMES)].astype(np.int64))
    stepper.set_controller_state(state[n + len(OBJECT_NAMES) :])
    mujoco.mj_forward(world.sim.model._model, world.sim.data._data)


def deterministic_package_ik() -> None:
    """Gives the ``robodesk`` package's dm_control IK vp2's CPU-independent least-squares step
    and norms (:func:`vp2.envs._ik.make_dm_control_ik_deterministic`)."""
    from vp2.envs._ik import make_dm_control_ik_deterministic

    make_dm_control_ik_deterministic()


# ---- one planning step ------------------------------------------------------------------------
def suite_planning_step(task: str, model_for: Any, num_samples: int) -> Any:
    """``step()``: one ``PlanningAgent.act`` of ``model_for(action_dim)`` (e.g. a model class)
    with ``num_samples`` samples on the shipped suite's instance #0 of ``task`` after one zero
    action (trial seed 0, the CPU), a new agent each call, so that repeated calls time the same
    step."""
    import numpy as np

    from vp2.data.suite import TaskSuite
    from vp2.envs import make_env_from_metadata
    from vp2.planning import Observation, PlannerConfig, PlanningAgent

    inst = TaskSuite.load().get(task, 0)
    env = make_env_from_metadata(inst.env_meta)
    env.reset_to(inst.init_state)
    frames = [env.render(64)]
    zero = np.zeros(env.action_dim)
    env.step(zero)
    frames.append(env.render(64))
    obs = Observation(step=1, frames=np.stack(frames), last_action=zero,
                      env_meta=inst.env_meta, state=env.get_state())
    model = model_for(env.action_dim)

    def step() -> tuple[np.ndarray, dict[str, Any]]:
        agent = PlanningAgent(model, planner=PlannerConfig(num_samples=num_samples), device="cpu")
        agent.reset(task, inst.goal_image, seed=0)
        return agent.act(obs)

    return step
