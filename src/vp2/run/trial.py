"""One control trial: an agent acting on one task instance for 15 steps (SPEC §4).

The trial resets the environment to the instance's initial state, executes the zero action
(so that two context frames exist), then asks the agent for an action at every remaining
step. After every step the success criterion is judged from the simulator state; the trial
succeeds if it holds at any step. Images are only what the agent sees, never the judge.

:func:`time_limit` bounds a trial's wall-clock time (``vp2 run --trial-timeout``): past it,
:class:`TrialTimeout` is raised where the trial is.
"""

from __future__ import annotations

import contextlib
import dataclasses
import signal
import threading
import time
import zlib
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from vp2.data.suite import TaskInstance
from vp2.envs.base import Env
from vp2.planning.agent import Agent, Observation, check_agent_for_env
from vp2.run import partial as partial_module
from vp2.run.partial import (
    PartialMismatch,
    PartialTrial,
    check_resumable,
)
from vp2.spec import NUM_CONTROL_STEPS


def trial_seed(task: str, index: int, seed: int) -> int:
    """The seed of trial ``(task, instance index, control-run seed)``.

    A function of the trial's key only, so a trial's result never depends on which worker ran
    it, in which order, or whether the run was resumed.
    """
    ss = np.random.SeedSequence([seed, zlib.crc32(task.encode()), index])
    return int(ss.generate_state(1, np.uint32)[0])


class TrialTimeout(BaseException):
    """A trial ran past its time limit (:func:`time_limit`).

    A ``BaseException``, like ``KeyboardInterrupt``: a model's ``except Exception`` does not
    swallow it, and it is no failure at the model boundary
    (:func:`vp2.models.contract.model_failure`).
    """


def can_time_limit() -> bool:
    """Whether :func:`time_limit` works here: in the main thread of a process with SIGALRM."""
    return hasattr(signal, "setitimer") and threading.current_thread() is threading.main_thread()


@contextlib.contextmanager
def time_limit(seconds: float | None, flag: str = "--trial-timeout") -> Iterator[None]:
    """Raises :class:`TrialTimeout` in the body once it has run ``seconds`` of wall-clock time
    (``None``: no limit).

    A ``SIGALRM`` timer whose handler raises: it interrupts Python code, ``time.sleep`` and
    waits (on a lock, a future, a pipe) at once, and a call in C (a long tensor operation, a
    simulator step) when it returns to Python; a C call that never returns is not
    interrupted. The previous ``SIGALRM`` handler is restored afterwards. The message names
    the limit (``flag``) and the time the body had run, e.g. ``"trial exceeded
    --trial-timeout 30 s after 30.2 s"``.

    Raises:
        RuntimeError: a limit is set and :func:`can_time_limit` is false (not the main thread).
    """
    if seconds is None:
        yield
        return
    if not can_time_limit():
        raise RuntimeError(
            f"{flag} needs the trial to run in the main thread of its process (it uses SIGALRM)"
        )
    start = time.perf_counter()

    def expire(signum: int, frame: Any) -> None:
        elapsed = time.perf_counter() - start
        raise TrialTimeout(f"trial exceeded {flag} {seconds:g} s after {elapsed:.1f} s")

    previous = signal.signal(signal.SIGALRM, expire)
    try:
        signal.setitimer(signal.ITIMER_REAL, seconds)
        yield
    finally:
        try:
            signal.setitimer(signal.ITIMER_REAL, 0)
        finally:  # also if the alarm went off just now
            signal.signal(signal.SIGALRM, previous)


@dataclasses.dataclass
class TrialResult:
    """The outcome of one control trial.

    Attributes:
        task: Task category.
        instance: Instance index within the category.
        seed: Control-run seed.
        success: Whether the success criterion held at any step.
        success_steps: ``(num_steps,)`` success after each step.
        actions: ``(num_steps, A)`` executed actions (after clipping to [-1, 1]).
        frames: ``(num_steps + 1, H, W, 3)`` uint8 observations, the initial one first.
        goal_image: ``(H, W, 3)`` uint8 goal at the agent's resolution.
        predicted_frames: ``(num_planning_steps, T, H, W, 3)`` uint8 predictions of the
            chosen plans, if the agent recorded them.
        planning_times: Seconds of each planning step (``agent.act``).
        env_time: Seconds spent stepping and rendering the environment.
        total_time: Seconds of the whole trial (environment construction excluded).
        cost_kind: How plans were scored (:data:`vp2.planning.planner.CostKind`).
        agent: The agent's settings for this trial (:meth:`Agent.describe`).
        scores: Best score the optimizer found at each planning step (``None`` if none).
    """

    task: str
    instance: int
    seed: int
    success: bool
    success_steps: list[bool]
    actions: np.ndarray
    frames: np.ndarray
    goal_image: np.ndarray
    predicted_frames: np.ndarray | None
    planning_times: list[float]
    env_time: float
    total_time: float
    cost_kind: str
    agent: dict[str, Any]
    scores: list[float | None]

    @property
    def first_success_step(self) -> int | None:
        """Index of the first step after which the task was solved, or ``None``."""
        return next((i for i, s in enumerate(self.success_steps) if s), None)

    def record(self) -> dict[str, Any]:
        """The JSON-able fields of a ``trials.jsonl`` record (arrays as lists)."""
        return {
            "task": self.task,
            "instance": self.instance,
            "seed": self.seed,
            "success": self.success,
            "success_steps": list(self.success_steps),
            "first_success_step": self.first_success_step,
            "num_steps": len(self.success_steps),
            "actions": self.actions.tolist(),
            "cost": self.cost_kind,
            "agent": self.agent,
            "scores": self.scores,
            "timings": {
                "planning_s": self.planning_times,
                "planning_mean_s": float(np.mean(self.planning_times))
                if self.planning_times
                else 0.0,
                "env_s": self.env_time,
                "total_s": self.total_time,
            },
        }


def goal_image_at(instance: TaskInstance, env: Env, size: int) -> np.ndarray:
    """The instance's goal image at ``size`` pixels: the shipped one, or at another
    resolution re-rendered from the goal state in ``env`` (which is left in that state)."""
    if instance.goal_image.shape[0] == size:
        return instance.goal_image
    env.reset_to(instance.goal_state)
    return env.render(size)


class ControlTrial:
    """Runs one agent on one task instance.

    Args:
        instance: The task instance.
        agent: The agent (planning agent, or a baseline with the same interface).
        seed: Control-run seed; the agent's randomness comes from :func:`trial_seed`.
        num_steps: Control steps (SPEC: 15; fewer only for tests).
        stop_on_success: Stop at the first successful step. Success is "at any step", so the
            outcome is the same; the remaining steps and their frames are skipped.
        env: An environment built from ``instance.env_meta`` to reuse (it is reset to the
            instance's initial state); ``None`` builds one and closes it afterwards.
        checkpoint: Called with the trial so far (a :class:`~vp2.run.partial.
            PartialTrial`) after a control step, when ``checkpoint_every_s`` seconds of the
            trial have passed since the last call; ``None``: never. Only agents with a
            ``trial_state`` method are checkpointed.
        resume: A partial trial of this trial to go on from: its actions are stepped again
            (their success flags must come out the same), the agent gets its state back, and
            planning goes on from the next step. Raises
            :class:`~vp2.run.partial.PartialMismatch` when it was made with other
            settings (``meta``) or does not replay.
        meta: What identifies this trial's settings beyond the trial's own (the model, the
            software), stored in checkpoints and compared with ``resume``'s.
        checkpoint_every_s: See ``checkpoint`` (``None``:
            :data:`~vp2.run.partial.CHECKPOINT_EVERY_S`).
    """

    def __init__(
        self,
        instance: TaskInstance,
        agent: Agent,
        seed: int,
        num_steps: int = NUM_CONTROL_STEPS,
        stop_on_success: bool = False,
        env: Env | None = None,
        checkpoint: Callable[[PartialTrial], None] | None = None,
        resume: PartialTrial | None = None,
        meta: dict[str, Any] | None = None,
        checkpoint_every_s: float | None = None,
    ) -> None:
        if num_steps < 2:
            raise ValueError(f"a trial needs at least 2 control steps, got {num_steps}")
        self.instance = instance
        self.agent = agent
        self.seed = seed
        self.num_steps = num_steps
        self.stop_on_success = stop_on_success
        self._env = env
        self.checkpoint = checkpoint if hasattr(agent, "trial_state") else None
        self.resume = resume
        self.meta = dict(meta or {})
        self.checkpoint_every_s = (
            partial_module.CHECKPOINT_EVERY_S if checkpoint_every_s is None else checkpoint_every_s
        )
        #: Control steps that were stepped again from ``resume`` rather than planned.
        self.resumed_steps = 0

    def trial_meta(self) -> dict[str, Any]:
        """The settings a checkpoint of this trial is made with (after the agent's reset)."""
        inst = self.instance
        return {
            "task": inst.task, "instance": inst.index, "instance_sha": inst.fingerprint,
            "seed": self.seed, "num_steps": self.num_steps,
            "stop_on_success": self.stop_on_success, "agent": self.agent.describe(),
            **self.meta,
        }  # fmt: skip

    def run(self) -> TrialResult:
        """Plays the trial; exceptions of the agent or the simulator propagate."""
        inst = self.instance
        env = self._env if self._env is not None else inst.make_env(observation_size=None)
        try:
            return self._run(env)
        finally:
            if self._env is None:
                env.close()

    def _run(self, env: Env) -> TrialResult:
        inst, agent = self.instance, self.agent
        check_agent_for_env(agent, env.action_dim, inst.task)
        size = agent.image_size
        start = time.perf_counter()
        goal_image = goal_image_at(inst, env, size)
        env.reset_to(inst.init_state)
        env.set_goal(inst.goal_state)
        agent.reset(inst.task, goal_image, trial_seed(inst.task, inst.index, self.seed))
        env_time = 0.0
        t0 = time.perf_counter()
        frames = [env.render(size)]
        env_time += time.perf_counter() - t0
        actions: list[np.ndarray] = []
        success_steps: list[bool] = []
        planning_times: list[float] = []
        scores: list[float | None] = []
        predicted: list[np.ndarray] = []
        env_meta = inst.env_meta
        meta = self.trial_meta() if (self.checkpoint or self.resume) else {}
        earlier = 0.0  # seconds the resumed partial trial had run
        if self.resume is not None:
            part = self.resume
            check_resumable(part, meta)
            t0 = time.perf_counter()
            for action in part.actions:  # the simulator is deterministic: the same states
                env.step(action)
                success_steps.append(bool(env.is_success(inst.goal_state)))
                frames.append(env.render(size))
                actions.append(np.asarray(action, dtype=np.float64))
            env_time += time.perf_counter() - t0
            if success_steps != [bool(x) for x in part.success_steps]:
                raise PartialMismatch(
                    f"stepping the partial trial's {len(actions)} actions again gave the success "
                    f"flags {success_steps}, the partial trial recorded {part.success_steps}"
                )
            agent.load_trial_state(part.agent_state)
            planning_times, scores = list(part.planning_times), list(part.scores)
            predicted = list(part.predicted)
            earlier, env_time = part.elapsed, env_time + part.env_time
            self.resumed_steps = len(actions)
        last_write = time.perf_counter()
        for step in range(len(actions), self.num_steps):
            if self.stop_on_success and any(success_steps):  # also a resumed, solved trial
                break
            if step == 0:
                action = np.zeros(env.action_dim)  # SPEC §4: the first step executes zero
            else:
                observation = Observation(
                    step=step,
                    frames=np.stack(frames),
                    last_action=actions[-1],
                    env_meta=env_meta,
                    state=env.get_state(),
                )
                t0 = time.perf_counter()
                action, info = agent.act(observation)
                planning_times.append(time.perf_counter() - t0)
                scores.append(info.get("best_score"))
                if "predicted_frames" in info:
                    predicted.append(info["predicted_frames"])
            action = env.check_action(action)  # the executed (clipped) action is recorded
            t0 = time.perf_counter()
            env.step(action)
            success_steps.append(bool(env.is_success(inst.goal_state)))
            frames.append(env.render(size))
            env_time += time.perf_counter() - t0
            actions.append(action)
            now = time.perf_counter()
            if self.checkpoint is not None and now - last_write >= self.checkpoint_every_s:
                self.checkpoint(PartialTrial(
                    meta=meta, actions=np.stack(actions), success_steps=list(success_steps),
                    planning_times=list(planning_times), scores=list(scores),
                    predicted=list(predicted), agent_state=agent.trial_state(),
                    env_time=env_time, elapsed=earlier + now - start,
                ))  # fmt: skip
                last_write = time.perf_counter()
        return TrialResult(
            task=inst.task,
            instance=inst.index,
            seed=self.seed,
            success=any(success_steps),
            success_steps=success_steps,
            actions=np.stack(actions),
            frames=np.stack(frames),
            goal_image=goal_image,
            predicted_frames=np.stack(predicted) if predicted else None,
            planning_times=planning_times,
            env_time=env_time,
            total_time=earlier + time.perf_counter() - start,
            cost_kind=agent.cost_kind,
            agent=agent.describe(),
            scores=scores,
        )
