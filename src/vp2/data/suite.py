"""The task suite: 310 fixed task instances (SPEC §2), generated with fixed seeds and shipped.

A :class:`TaskInstance` is an initial simulator state, a goal state and its 64×64 goal image,
the scripted actions that reach the goal from the initial state, and the environment
metadata.

Instances start along scripted trajectories (SPEC §2), as in the original
release: the task's noise-free scripted policy runs from a randomised reset for at most
:data:`HORIZON` steps; ``k`` is the first step at which the success criterion holds; a look-back
``L`` is drawn per instance from :data:`LOOKBACK_RANGE` (it ends at
:data:`MAX_INSTANCE_ACTIONS` = 12, two actions short of a trial's 14, so instances differ in
difficulty); the initial state is the state at ``s = max(0, k - L)`` and the goal the state at
``k`` -- or one settling step later if it still succeeds and the instance stays within 12
actions. The stored actions are those from ``s`` to the goal, so replaying them reaches success
in at most 12 actions (tested). An instance whose initial state already satisfies the success
criterion is rejected. On the tabletop, whose criterion is relative to the goal, the goal is,
as in the original release, where the push ended: the policy runs all :data:`HORIZON` steps,
the trajectory must pass the original's keep filter (the task's object moved more than
:data:`KEEP_MOTION`, none fell off), and ``k`` is the first step within the criterion of the
end state (:func:`_tabletop_trajectory`). A tabletop instance must also need the agent
(:func:`_solved_without_intent`): it is rejected when holding the zero action for a trial's
steps reaches the goal (an object still rolling or settling), or when uniform random actions,
as the benchmark's random baseline draws them, reach it in any of :data:`RANDOM_CHECK_TRIES`
tries. Measured (``benchmarks.studies.tabletop_trivial_solves``, 4 fresh random tries per
instance): on suite v4, which had neither rule, 7 of the 100 tabletop instances were solved by
the zero action alone and random actions solved 17.2% of the tries (69 of 400); on suite v5,
none and 4.2% (17 of 400) (docs/findings/tabletop-original.md). RoboDesk, whose random
baseline solves 2 of 70 trials without them, has neither rule.

Generation is deterministic: attempt ``k`` of a task uses a seed derived from
``(suite seed, task, k)``, attempts are accepted in order, and the file is written with fixed
zip timestamps, so regenerating with the same seeds reproduces the shipped file bit for bit.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import io
import json
import zipfile
import zlib
from collections.abc import Iterator, Sequence
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from tqdm.auto import tqdm

from vp2.data.policies.tabletop import FELL_OFF, KEEP_MOTION
from vp2.envs import ENV_TASKS, TASK_NAMES, TASKS, make_env, split_name
from vp2.envs.base import Env
from vp2.envs.cache import EnvCache
from vp2.spec import NUM_CONTROL_STEPS
from vp2.utils.executors import Executor, LocalExecutor
from vp2.utils.fixedmath import norm
from vp2.utils.io import atomic_path

#: Instances per task category (SPEC §2): 30 per RoboDesk task, 25 per tabletop category
#: (``Task.suite_instances`` of :data:`vp2.envs.tasks.TASKS`).
SUITE_COUNTS: dict[str, int] = {name: task.suite_instances for name, task in TASKS.items()}
SUITE_SEED = 2023
GOAL_IMAGE_SIZE = 64
HORIZON = 35
#: Actions a control trial of :data:`vp2.spec.NUM_CONTROL_STEPS` steps can choose: the first of
#: its steps executes the zero action. The suite's acceptance depends on it.
TRIAL_FREE_ACTIONS = NUM_CONTROL_STEPS - 1
#: The most scripted actions an instance's goal may take to reach from its initial state
#: (SPEC §2: two actions of slack below a trial's 14).
MAX_INSTANCE_ACTIONS = TRIAL_FREE_ACTIONS - 2
#: The look-back ``L`` (scripted actions between the initial state and the first success) is
#: drawn uniformly from this inclusive range per instance.
LOOKBACK_RANGE = (4, MAX_INSTANCE_ACTIONS)
#: Random-action tries that must all fail for a tabletop instance to be accepted.
RANDOM_CHECK_TRIES = 4
SUITE_FORMAT = "vp2-task-suite/5"
SHIPPED_SUITE = "task_suite.npz"


@dataclasses.dataclass(frozen=True)
class TaskInstance:
    """One task instance of the benchmark."""

    task: str  # registered task category, e.g. "robodesk/push_red"
    index: int  # index within its category
    seed: int  # the seed it was generated from
    init_state: np.ndarray  # (S,) float64
    goal_state: np.ndarray  # (S,) float64
    goal_image: np.ndarray  # (64, 64, 3) uint8
    actions: np.ndarray  # (k, A) float64: scripted actions from init_state to goal_state
    env_meta: dict[str, Any]
    #: Step of the scripted trajectory the initial state was taken at (``s`` in SPEC §2).
    start_step: int = 0

    @property
    def key(self) -> str:
        return f"{self.task}#{self.index}"

    @property
    def fingerprint(self) -> str:
        """A short hash of what a trial on this instance sees: its key, initial and goal states
        and goal image. Trial records carry it, so a run resumed after the suite changed (a new
        ``vp2`` release, another ``--suite``) is refused instead of mixing instances."""
        h = hashlib.sha256(self.key.encode())
        for array in (self.init_state, self.goal_state, self.goal_image):
            h.update(np.ascontiguousarray(array).tobytes())
        return h.hexdigest()[:16]

    def make_env(self, **overrides: Any) -> Env:
        """An environment rebuilt from the instance's metadata, reset to its initial state."""
        from vp2.envs import make_env_from_metadata

        env = make_env_from_metadata(self.env_meta, **overrides)
        env.reset_to(self.init_state)
        env.set_goal(self.goal_state)
        return env


class TaskSuite:
    """An ordered collection of task instances, grouped by task category."""

    def __init__(self, instances: Sequence[TaskInstance], seed: int = SUITE_SEED):
        self.instances = list(instances)
        self.seed = seed

    def __len__(self) -> int:
        return len(self.instances)

    def __iter__(self) -> Iterator[TaskInstance]:
        return iter(self.instances)

    @property
    def tasks(self) -> list[str]:
        return list(dict.fromkeys(i.task for i in self.instances))

    def for_task(self, task: str) -> list[TaskInstance]:
        split_name(task)
        return [i for i in self.instances if i.task == task]

    def select(
        self, names: Sequence[str] = (), num_instances: int | None = None
    ) -> list[TaskInstance]:
        """The instances of some task categories, the first ``num_instances`` of each, in the
        canonical task order (what a benchmark run covers).

        Args:
            names: Task categories or environment names (an environment: those of its task
                categories the suite has); empty: every task category of the suite.
            num_instances: Instances per task category (``None``: all). A category with
                fewer gives what it has; the caller says so.

        Raises:
            ValueError: the suite has none of ``names``, or a named task category is missing.
        """
        wanted: list[str] = []
        for name in names or self.tasks:
            wanted += [f"{name}/{t}" for t in ENV_TASKS[name]] if name in ENV_TASKS else [name]
        missing = [t for t in wanted if t not in self.tasks]
        if names and missing == wanted:
            raise ValueError(f"the suite has none of the tasks {list(names)}; it has {self.tasks}")
        if missing and names and not all(t in ENV_TASKS for t in names):
            raise ValueError(f"tasks {missing} are not in the suite (it has {self.tasks})")
        out = []
        for task in sorted((t for t in wanted if t in self.tasks), key=TASK_NAMES.index):
            insts = sorted(self.for_task(task), key=lambda i: i.index)
            out += insts[:num_instances] if num_instances else insts
        return out

    def get(self, task: str, index: int) -> TaskInstance:
        for inst in self.instances:
            if inst.task == task and inst.index == index:
                return inst
        raise KeyError(f"no instance {task}#{index} in the suite")

    # ---- file format: a zip of .npy arrays and one JSON, with fixed timestamps ------------
    def save(self, path: str | Path) -> None:
        """Writes the suite deterministically (same content -> same bytes)."""
        meta = {"format": SUITE_FORMAT, "seed": self.seed, "tasks": {}}
        arrays: dict[str, np.ndarray] = {}
        for t_id, task in enumerate(self.tasks):
            insts = self.for_task(task)
            max_len = max(len(i.actions) for i in insts)
            adim = insts[0].actions.shape[1]
            actions = np.full((len(insts), max_len, adim), np.nan)
            for j, inst in enumerate(insts):
                actions[j, : len(inst.actions)] = inst.actions
            prefix = f"t{t_id:02d}"
            arrays[f"{prefix}_init_states"] = np.stack([i.init_state for i in insts])
            arrays[f"{prefix}_goal_states"] = np.stack([i.goal_state for i in insts])
            arrays[f"{prefix}_goal_images"] = np.stack([i.goal_image for i in insts])
            arrays[f"{prefix}_actions"] = actions
            meta["tasks"][task] = {
                "prefix": prefix,
                "indices": [i.index for i in insts],
                "seeds": [i.seed for i in insts],
                "num_actions": [len(i.actions) for i in insts],
                "start_steps": [i.start_step for i in insts],
                "env_meta": [i.env_meta for i in insts],
            }
        with atomic_path(path) as tmp, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
            for name in sorted(arrays):
                buf = io.BytesIO()
                np.lib.format.write_array(buf, np.ascontiguousarray(arrays[name]), allow_pickle=False)
                zf.writestr(_zipinfo(f"{name}.npy"), buf.getvalue())
            zf.writestr(_zipinfo("meta.json"), json.dumps(meta, sort_keys=True, indent=1))

    @classmethod
    def load(cls, path: str | Path | None = None, *, format: str = SUITE_FORMAT) -> TaskSuite:  # noqa: A002
        """Loads a suite file; ``None`` loads the suite shipped with the package.

        ``format``: the version the file must be; an earlier version's file (the same layout
        since ``vp2-task-suite/3``) loads when it is named, e.g. to compare two suites.
        """
        if path is None:
            ref = resources.files("vp2") / "assets" / SHIPPED_SUITE
            if not ref.is_file():
                raise FileNotFoundError(
                    f"the shipped task suite is missing from the package ({ref}); regenerate "
                    "it with `vp2 tasks generate`"
                )
            with resources.as_file(ref) as p:
                return cls.load(p, format=format)
        try:
            with zipfile.ZipFile(path) as zf:
                meta = json.loads(zf.read("meta.json"))
            with np.load(path, allow_pickle=False) as z:
                if meta.get("format") != format:
                    raise ValueError(f"format {meta.get('format')!r}, expected {format!r}")
                instances = []
                # Categories in the order they were saved (JSON keys are sorted by name).
                for task, tm in sorted(meta["tasks"].items(), key=lambda kv: kv[1]["prefix"]):
                    p = tm["prefix"]
                    init, goal = z[f"{p}_init_states"], z[f"{p}_goal_states"]
                    images, actions = z[f"{p}_goal_images"], z[f"{p}_actions"]
                    for j, idx in enumerate(tm["indices"]):
                        instances.append(
                            TaskInstance(
                                task=task,
                                index=idx,
                                seed=tm["seeds"][j],
                                init_state=init[j],
                                goal_state=goal[j],
                                goal_image=images[j],
                                actions=actions[j, : tm["num_actions"][j]],
                                env_meta=tm["env_meta"][j],
                                start_step=tm["start_steps"][j],
                            )
                        )
        except (OSError, KeyError, ValueError, zipfile.BadZipFile) as exc:
            raise ValueError(f"{path}: not a readable vp2 task suite ({exc})") from exc
        return cls(instances, seed=meta["seed"])


def _zipinfo(name: str) -> zipfile.ZipInfo:
    info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = 0o644 << 16
    return info


def instance_seed(suite_seed: int, task: str, attempt: int) -> int:
    ss = np.random.SeedSequence([suite_seed, zlib.crc32(task.encode()), attempt])
    return int(ss.generate_state(1, np.uint32)[0])


# The environments of the last few tasks, per process (closed when a suite is generated).
_ENVS = EnvCache(4)


def _env(task: str) -> Env:
    return _ENVS.get_or_make(task, lambda: make_env(task, observation_size=None))


def generate_instance(
    task: str, seed: int, index: int = -1, env: Env | None = None
) -> TaskInstance | None:
    """Tries to make one instance from ``seed``; ``None`` if it is rejected.

    Runs the noise-free scripted policy from a randomised reset (module docstring) and takes
    the initial state ``L`` actions before its first success. Rejected when the policy does not
    succeed within :data:`HORIZON` steps, or when the initial state already succeeds.

    ``env``: the environment of ``task`` to run in (e.g. one built from another tabletop scene;
    its metadata goes into the instance); default: this process's cached default build.
    """
    from vp2.data.policies import make_task_policy

    if env is None:
        env = _env(task)
    elif env.name != task:
        raise ValueError(f"generate_instance: the env is {env.name!r}, not the task {task!r}")
    reset_seed, policy_seed, lookback_seed, check_seed = np.random.SeedSequence(seed).generate_state(4)
    lookback = int(np.random.default_rng(lookback_seed).integers(LOOKBACK_RANGE[0], LOOKBACK_RANGE[1] + 1))
    env.reset(seed=int(reset_seed))
    policy = make_task_policy(env, np.random.default_rng(policy_seed))
    policy.reset()
    if split_name(task)[0] == "tabletop":
        found = _tabletop_trajectory(env, policy)
        if found is None:
            return None
        states, actions, target = found
    else:
        target = policy.goal_state()
        if env.is_success(target):
            return None
        states, actions = [env.get_state()], []
        for _ in range(HORIZON):
            action = env.check_action(policy.act())
            env.step(action)
            actions.append(action)
            states.append(env.get_state())
            if env.is_success(target):
                break
        else:
            return None
    success_step = len(actions)
    start = max(0, success_step - lookback)
    # One more scripted step lets a falling block land or a pushed object settle; it is
    # kept only if the state still succeeds and the instance stays within the action limit.
    if success_step - start < MAX_INSTANCE_ACTIONS:
        action = env.check_action(policy.act())
        env.step(action)
        if env.is_success(target):
            actions.append(action)
            states.append(env.get_state())
        else:
            env.reset_to(states[-1])
    goal_state = states[-1]
    goal_image = env.render(GOAL_IMAGE_SIZE)
    init_state = states[start]
    env.reset_to(init_state)
    if env.is_success(goal_state):  # e.g. a tabletop object already within 5 cm of its goal
        return None
    if split_name(task)[0] == "tabletop" and _solved_without_intent(
        env, init_state, goal_state, int(check_seed)
    ):
        return None
    return TaskInstance(
        task=task,
        index=index,
        seed=seed,
        init_state=init_state,
        goal_state=goal_state,
        goal_image=goal_image,
        actions=np.asarray(actions[start:], np.float64),
        env_meta=env.serialize(),
        start_step=start,
    )


def random_action_tries(rng: np.random.Generator, tries: int, action_dim: int) -> np.ndarray:
    """``(tries, NUM_CONTROL_STEPS, action_dim)`` uniform random actions in ``[-1, 1]``, each try
    starting with the trial's zero action, as the benchmark's random baseline plays a trial."""
    actions = rng.uniform(-1.0, 1.0, (tries, NUM_CONTROL_STEPS, action_dim))
    actions[:, 0] = 0.0
    return actions


def first_success(env: Env, init_state: np.ndarray, goal_state: np.ndarray, actions: np.ndarray) -> int | None:
    """The index of the first of ``actions``, stepped from ``init_state``, after which the
    state is within the success criterion of ``goal_state``; ``None`` if none is."""
    env.reset_to(init_state)
    for step, action in enumerate(actions):
        env.step(action)
        if env.is_success(goal_state):
            return step
    return None


def _solved_without_intent(env: Env, init_state: np.ndarray, goal_state: np.ndarray, seed: int) -> bool:
    """Whether a trial reaches ``goal_state`` from ``init_state`` without aiming: holding the
    zero action for :data:`~vp2.spec.NUM_CONTROL_STEPS` steps, or any of
    :data:`RANDOM_CHECK_TRIES` random-action tries drawn from ``seed``
    (:func:`random_action_tries`). Leaves ``env`` at ``init_state``."""
    zero = np.zeros((1, NUM_CONTROL_STEPS, env.action_dim))
    tries = random_action_tries(np.random.default_rng(seed), RANDOM_CHECK_TRIES, env.action_dim)
    try:
        return any(first_success(env, init_state, goal_state, actions) is not None
                   for actions in np.concatenate([zero, tries]))
    finally:
        env.reset_to(init_state)


def _succeeds(env: Env, state: np.ndarray, goal: np.ndarray) -> bool:
    env.reset_to(state)
    return env.is_success(goal)


def _tabletop_trajectory(env: Env, policy: Any) -> tuple[list, list, np.ndarray] | None:
    """The tabletop's scripted trajectory up to its first success against its end state.

    As in the original release, the goal is where the push ended, not where it aimed: the
    policy runs :data:`HORIZON` steps; the trajectory is rejected unless the task's object moved
    more than :data:`KEEP_MOTION` in xy and no object fell off (:data:`FELL_OFF`); ``k`` is the
    first step whose state satisfies the success criterion against the end state. Returns the
    states ``0 .. k``, the actions ``1 .. k`` and the end state; the env is left at state ``k``
    and the policy at step ``k``. ``None`` when rejected.
    """
    start_positions = env.object_positions()
    states, actions = [env.get_state()], []
    for _ in range(HORIZON):
        action = env.check_action(policy.act())
        env.step(action)
        actions.append(action)
        states.append(env.get_state())
    end = env.object_positions()
    k = policy.object_index
    if (
        norm(end[k, :2] - start_positions[k, :2]) <= KEEP_MOTION
        or np.abs(end[:, 2] - start_positions[:, 2]).max() > FELL_OFF
    ):
        return None
    target = states[-1]
    step = next(t for t in range(len(states)) if _succeeds(env, states[t], target))
    if step == 0:
        return None
    # Back to step k: the policy's next action is step k + 1's (the settling step's).
    env.reset_to(states[step])
    policy.step_count = step
    return states[: step + 1], actions[:step], target


def _attempt(job: tuple[str, int, int]) -> TaskInstance | None:
    task, suite_seed, attempt = job
    return generate_instance(task, instance_seed(suite_seed, task, attempt))


def generate_suite(
    counts: dict[str, int] | None = None,
    seed: int = SUITE_SEED,
    workers: int | None = None,
    progress: bool = True,
    max_attempts_factor: int = 10,
    executor: Executor | None = None,
) -> TaskSuite:
    """Generates a task suite (by default the canonical one, SPEC §2).

    Attempts are made in batches in parallel, but accepted strictly in attempt order, so the
    result does not depend on ``workers`` or on the ``executor`` that runs them (default:
    local worker processes, ``workers`` of them).
    """
    counts = dict(SUITE_COUNTS if counts is None else counts)
    for task in counts:
        split_name(task)
    executor = LocalExecutor(workers) if executor is None else executor
    order = sorted(counts, key=TASK_NAMES.index)
    accepted: dict[str, list[TaskInstance]] = {t: [] for t in order}
    next_attempt = dict.fromkeys(order, 0)
    with (
        tqdm(total=sum(counts.values()), unit="inst", desc="task suite", disable=not progress) as bar,
        contextlib.closing(_ENVS),  # the environments this process used (workers=1)
    ):
        # Rounds: every task still short of instances gets a block of attempts (sized by its
        # shortfall only, never by `workers`, so the result is the same for any pool size).
        while any(len(accepted[t]) < counts[t] for t in order):
            jobs = []
            for task in order:
                short = counts[task] - len(accepted[task])
                if short <= 0:
                    continue
                if next_attempt[task] >= max_attempts_factor * counts[task]:
                    raise RuntimeError(
                        f"{task}: only {len(accepted[task])} of {counts[task]} instances after "
                        f"{next_attempt[task]} attempts; the scripted policy fails too often"
                    )
                block = short + short // 4 + 1
                jobs += [(task, seed, k) for k in range(next_attempt[task], next_attempt[task] + block)]
                next_attempt[task] += block
            results = {(job[0], job[2]): inst for job, inst in executor.imap_unordered(_attempt, jobs)}
            for task, _, k in jobs:  # accept strictly in attempt order
                inst = results[(task, k)]
                if inst is not None and len(accepted[task]) < counts[task]:
                    accepted[task].append(dataclasses.replace(inst, index=len(accepted[task])))
                    bar.update(1)
    instances = [inst for task in order for inst in accepted[task]]
    return TaskSuite(instances, seed=seed)


def replay_instance(instance: TaskInstance) -> tuple[bool, bool]:
    """Replays an instance's scripted actions; returns (initially successful, finally successful)."""
    env = _env(instance.task)
    env.reset_to(instance.init_state)
    initially = env.is_success(instance.goal_state)
    for action in instance.actions:
        env.step(action)
    return initially, env.is_success(instance.goal_state)
