"""Dynamics equivalence of vp2's RoboDeskEnv with ``robodesk.RoboDesk(action_repeat=50)``.

Usage::

    MUJOCO_GL=egl .venv/bin/python -m benchmarks.fidelity.robodesk_equivalence [--trajectories 20]

For every task and trajectory: draw an initial state with our env, copy it into the package's
physics, apply the same 35 random actions (uniform in [-1, 1]) to both, and after every env
step compare the robot's joint positions (rad), the three objects' positions (m) and the whole
MuJoCo integration state (bit for bit). The package's rendering is switched off for the
comparison (it is not dynamics, and it costs most of its step time).

Control experiment (``--chaos``): the package against itself, with one copy's first joint
perturbed by 1e-12 rad at the start. Contacts make RoboDesk trajectories chaotic, so a
re-implementation that differs from the package in the last bit of any number diverges like
this control does; a zero deviation above means every operation of the original was
reproduced, not approximated. The control is repeated with contacts disabled
(``mjDSBL_CONTACT``), where the same perturbation stays microscopic.

A rendering check compares the package's own 64x64 image (its ``Image.ANTIALIAS`` patched to
LANCZOS) with ours at full quality on a few states, to show the camera and crop are the same.
"""

from __future__ import annotations

import logging
import os
import platform

os.environ.setdefault("MUJOCO_GL", "egl")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks import common  # noqa: E402
from vp2.envs.rendering import Renderer, mean_abs_error  # noqa: E402
from vp2.envs.robodesk import OBJECTS, RENDER_SPEC, TASKS, RoboDeskEnv  # noqa: E402

_INTEGRATION = mujoco.mjtState.mjSTATE_INTEGRATION
STEPS = 35


def _package(task: str):
    package = common.robodesk_package(task)
    package._get_obs = lambda: None  # no rendering during the comparison
    package.reset()
    return package


def _objects(data) -> np.ndarray:
    return np.array([data.body(name).xpos for name in OBJECTS])


def compare(task: str, trajectories: int, seed: int) -> dict[str, float]:
    """Max deviations of our env from the package over ``trajectories`` random rollouts."""
    env = RoboDeskEnv(task, seed=seed, observation_size=None)
    package = _package(task)
    n = mujoco.mj_stateSize(env.model, _INTEGRATION)
    joint_dev = object_dev = 0.0
    identical = total = 0
    rng = np.random.default_rng(seed)
    for _ in range(trajectories):
        env.reset()
        common.load_package_state(package, env.get_state()[:n])
        for action in rng.uniform(-1.0, 1.0, size=(STEPS, 5)):
            env.step(action)
            package.step(action)
            ours, theirs = env.data, package.physics.data
            joint_dev = max(joint_dev, float(np.abs(ours.qpos[:9] - theirs.qpos[:9]).max()))
            object_dev = max(
                object_dev, float(np.linalg.norm(_objects(ours) - _objects(theirs), axis=1).max())
            )
            identical += int(
                np.array_equal(env.get_state()[:n], package.physics.get_state(_INTEGRATION))
            )
            total += 1
    env.close()
    return dict(joints=joint_dev, objects=object_dev, identical=identical / total)


def chaos(task: str, trajectories: int, seed: int, contacts: bool) -> dict[str, float]:
    """The package against itself after a 1e-12 rad perturbation of joint 1."""
    env = RoboDeskEnv(task, seed=seed, observation_size=None)
    a, b = _package(task), _package(task)
    if not contacts:
        for p in (a, b):
            p.physics.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    n = mujoco.mj_stateSize(env.model, _INTEGRATION)
    joint_dev = object_dev = 0.0
    rng = np.random.default_rng(seed)
    for _ in range(trajectories):
        env.reset()
        state = env.get_state()[:n]
        common.load_package_state(a, state)
        perturbed = state.copy()
        perturbed[1] += 1e-12  # qpos[0] (state[0] is the time)
        common.load_package_state(b, perturbed)
        for action in rng.uniform(-1.0, 1.0, size=(STEPS, 5)):
            a.step(action)
            b.step(action)
            da, db = a.physics.data, b.physics.data
            joint_dev = max(joint_dev, float(np.abs(da.qpos[:9] - db.qpos[:9]).max()))
            object_dev = max(
                object_dev, float(np.linalg.norm(_objects(da) - _objects(db), axis=1).max())
            )
    env.close()
    return dict(joints=joint_dev, objects=object_dev)


def render_check(states: int, seed: int) -> float:
    """MAE between the package's 64x64 image and ours at full quality, same states."""
    package = common.robodesk_package("push_red")
    package.reset()
    env = RoboDeskEnv("push_red", seed=seed, observation_size=None)
    ours = Renderer(env.model, RENDER_SPEC.full_quality())
    n = mujoco.mj_stateSize(env.model, _INTEGRATION)
    rng = np.random.default_rng(seed)
    errors = []
    for _ in range(states):
        env.reset()
        for action in rng.uniform(-0.5, 0.5, size=(3, 5)):
            env.step(action)
        common.load_package_state(package, env.get_state()[:n])
        common.rebind_package_gl(package)
        errors.append(mean_abs_error(package.render(), ours.render(env.data, 64)))
    ours.close()
    env.close()
    package.physics.free()  # before interpreter exit tears EGL down
    return float(np.mean(errors))


def main() -> None:
    parser = common.argument_parser(__spec__.name, __doc__, full_doc=True)
    parser.add_argument("--trajectories", type=int, default=20, help="random rollouts per task")
    parser.add_argument(
        "--chaos", type=int, default=5, help="rollouts per task of the control (0: skip)"
    )
    parser.add_argument("--render-states", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--package-ik", choices=["deterministic", "as-is"], default="deterministic",
        help="the package's IK with vp2's CPU-independent least-squares step and norms "
        "(default), or as shipped (its last bits then depend on the CPU's OpenBLAS kernel)",
    )
    args = parser.parse_args()
    if args.package_ik == "deterministic":
        common.deterministic_package_ik()
    # dm_control's IK logs every non-converged solve (random actions drive the arm into its
    # joint limits); both implementations take the same path there, the log is noise.
    logging.getLogger("absl").setLevel(logging.ERROR)
    print("# RoboDesk dynamics: vp2 RoboDeskEnv vs robodesk.RoboDesk(action_repeat=50)")
    print(
        f"# {common.timestamp()}  {platform.node()}  "
        f"cpus={os.cpu_count()}  mujoco={mujoco.__version__}"
    )
    print(
        f"# {args.trajectories} trajectories x {STEPS} uniform random actions per task; "
        f"max over all env steps; the package's IK: {args.package_ik}"
    )
    print(f"{'task':26s} {'joints (rad)':>13s} {'objects (m)':>12s} {'bit-identical steps':>20s}")
    for i, task in enumerate(TASKS):
        r = compare(task, args.trajectories, args.seed + i)
        print(
            f"{task:26s} {r['joints']:13.3g} {r['objects']:12.3g} {r['identical']:19.1%}",
            flush=True,
        )
    if args.chaos:
        print(
            f"# control: the package vs itself, joint 1 perturbed by 1e-12 rad, {args.chaos} "
            "trajectories per task"
        )
        print(
            f"{'task':26s} {'joints (rad)':>13s} {'objects (m)':>12s} {'no contacts: joints':>20s} {'objects':>9s}"
        )
        for i, task in enumerate(TASKS):
            with_contacts = chaos(task, args.chaos, args.seed + i, contacts=True)
            without = chaos(task, args.chaos, args.seed + i, contacts=False)
            print(
                f"{task:26s} {with_contacts['joints']:13.3g} {with_contacts['objects']:12.3g} "
                f"{without['joints']:20.3g} {without['objects']:9.3g}",
                flush=True,
            )
    if args.render_states:
        mae = render_check(args.render_states, args.seed)
        print(
            f"# camera check: package image vs ours (full quality), {args.render_states} states: "
            f"MAE {mae:.2f}/255"
        )


if __name__ == "__main__":
    main()
