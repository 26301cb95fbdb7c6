"""The measurements of ``vp2 diagnose`` (:mod:`vp2.diagnose.model`), one function each.

* :func:`held_out_clips` and :func:`conditioning_errors`: per-clip prediction error under each
  clip's true actions and under another clip's (a derangement), on the valid split of a
  dataset; :func:`ratio_statistics` turns the pairs into the ratio shuffled / true with a 95%
  bootstrap interval over clips and one over trajectories (:func:`held_out_trajectories`,
  :func:`trajectory_interval`), the clips won by the true actions and the sign test's p.
* :func:`probe_instance`: a trial's first planning step on one task instance. The planner's
  sampler draws the candidates the trial would draw, the instance's scripted plan is appended,
  and the model and the task's cost score the batch twice, with two model seeds. Per instance:
  the scripted plan's rank, the repeatability of the ranking (Spearman's ρ between the two
  scorings), γ · the scores' spread, the effective sample size of MPPI's weights, and the
  direction in which the weights move the plan. Given the simulator (the oracle), also its
  **agreement** with the model (:func:`simulator_agreement`): Spearman's ρ between the model's
  and the simulator's scores of the same candidates, and whether the candidate the simulator
  scores best is in the model's top tenth. The simulator's scores do not depend on the model,
  so they are cached on disk (:func:`oracle_cache_dir`).
* :func:`spearman`, :func:`effective_sample_size`, :func:`cross_task_cosine`: the statistics.

Nothing here decides what a number means: the thresholds and verdicts are in
:mod:`vp2.diagnose.model`.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch

import vp2
from vp2 import spec
from vp2.data.loader import ClipDataset, select_clips
from vp2.data.suite import TaskInstance
from vp2.models.contract import predict_in_chunks
from vp2.planning.agent import PlanningAgent, frames_to_tensor
from vp2.planning.config import PlannerConfig
from vp2.planning.optimizers.mppi import mppi_weights
from vp2.planning.samplers import broadcast_std
from vp2.run.trial import goal_image_at, trial_seed
from vp2.utils.io import atomic_path, cache_dir

log = logging.getLogger(__name__)

#: A pixel "changes" when its true value moves more than this between the last context frame
#: and a future frame (any channel); the static background dilutes the plain MSE.
MOVING_PIXEL = 0.05
#: Bootstrap resamples of the ratio's interval.
BOOTSTRAP_RESAMPLES = 2000
#: Action dimensions whose net motion gives the plan's direction: x, y, z.
DIRECTION_DIMS = 3
#: The simulator's best candidate counts as "in the model's top" within this fraction.
AGREEMENT_TOP_FRACTION = 0.10
#: The simulator's scores of `vp2 diagnose`'s default probes on both environments (2 instances
#: per task, seed 0, 50 samples), shipped so that a first diagnosis does not pay for them; the
#: files of ``VP2_CACHE_DIR=DIR vp2 diagnose --model repeat_last_frame --env ENV``'s
#: ``DIR/diagnose-oracle`` (docs/diagnose.md).
SHIPPED_ORACLE_SCORES = Path(__file__).resolve().parents[1] / "assets" / "diagnose_oracle"


# --------------------------------------------------------------------------- held-out clips


def held_out_clips(
    data: str | Path, num_clips: int, seed: int, context: int, future: int
) -> tuple[torch.Tensor, torch.Tensor]:
    """A seeded sample of the dataset's ``valid`` clips: ``frames (N, context + future, 3, H,
    W)`` in [0, 1] and ``actions (N, context + future - 1, A)`` float32."""
    dataset = ClipDataset(data, split="valid", context=context, future=future)
    try:
        items = [dataset[i] for i in select_clips(len(dataset), num_clips, seed)]
    finally:
        dataset.close()
    frames = torch.stack([it["frames"] for it in items])
    return frames, torch.stack([it["actions"] for it in items]).float()


def held_out_trajectories(
    data: str | Path, num_clips: int, seed: int, context: int, future: int
) -> np.ndarray:
    """The trajectory of each clip :func:`held_out_clips` returns with the same arguments, as
    ``(N,)`` integers (equal for clips of one trajectory); reads no frames."""
    dataset = ClipDataset(data, split="valid", context=context, future=future)
    try:
        chosen = select_clips(len(dataset), num_clips, seed)
        return np.array([dataset.trajectory(i) for i in chosen], dtype=np.int64)
    finally:
        dataset.close()


def derangement(n: int, rng: np.random.Generator) -> np.ndarray:
    """A random permutation of ``range(n)`` that moves every element (``n >= 2``)."""
    if n < 2:
        raise ValueError(f"shuffling actions between clips needs at least 2 clips, got {n}")
    while True:
        perm = rng.permutation(n)
        if not np.any(perm == np.arange(n)):
            return perm


def conditioning_errors(
    model: Any,
    frames: torch.Tensor,
    actions: torch.Tensor,
    sampling_seeds: int,
    seed: int,
    device: torch.device,
    on_call: Any = None,
) -> dict[str, np.ndarray]:
    """Per-clip errors under the true and the shuffled actions, averaged over sampling seeds.

    Args:
        model: A checked model (:func:`vp2.models.contract.checked`).
        frames: ``(N, C + T, 3, H, W)`` clips in [0, 1].
        actions: ``(N, C + T - 1, A)`` their actions.
        sampling_seeds: Model noise seeds per clip (``seed``, ``seed + 1``, ...).
        seed: Seeds the derangement and the model noise.
        device: Where the model predicts.
        on_call: Called with no argument after every model call (progress).

    Returns:
        ``true``, ``shuffled`` (per-pixel MSE) and ``true_moving``, ``shuffled_moving`` (MSE
        on the pixels that change, :data:`MOVING_PIXEL`), each ``(N,)``.
    """
    c = int(model.num_context)
    context, future = frames[:, :c].to(device), frames[:, c:].to(device)
    moving = ((future - context[:, -1:]).abs().amax(dim=2, keepdim=True) > MOVING_PIXEL).float()
    perm = torch.from_numpy(derangement(len(frames), np.random.default_rng(seed)))
    out: dict[str, list[np.ndarray]] = {
        "true": [], "shuffled": [], "true_moving": [], "shuffled_moving": []
    }
    for s in range(sampling_seeds):
        for name, acts in (("true", actions), ("shuffled", actions[perm])):
            generator = torch.Generator().manual_seed(seed + s)
            with torch.no_grad():
                pred = predict_in_chunks(model, context, acts.to(device), generator=generator)
            err = (pred.to(device).float() - future).square()  # (N, T, 3, H, W)
            out[name].append(err.mean(dim=(1, 2, 3, 4)).cpu().numpy())
            moved = (moving.sum(dim=(1, 2, 3, 4)) * err.shape[2]).clamp(min=1)
            out[f"{name}_moving"].append(((err * moving).sum(dim=(1, 2, 3, 4)) / moved).cpu().numpy())
            if on_call is not None:
                on_call()
    return {k: np.mean(v, axis=0).astype(np.float64) for k, v in out.items()}


def _ratio(shuffled: np.ndarray, true: np.ndarray) -> np.ndarray:
    """``shuffled / true`` elementwise; 1 where both are 0, ``inf`` where only ``true`` is."""
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.asarray(shuffled, np.float64) / np.asarray(true, np.float64)
    both_zero = (np.asarray(true) == 0) & (np.asarray(shuffled) == 0)
    return np.where(both_zero, 1.0, r)


def trajectory_interval(
    true: np.ndarray, shuffled: np.ndarray, trajectory: np.ndarray, seed: int = 0
) -> list[float]:
    """95% bootstrap interval of ``mean(shuffled) / mean(true)`` that resamples whole
    trajectories (each draw takes a trajectory with all of its clips), :data:`BOOTSTRAP_RESAMPLES`
    times. Clips cut from one trajectory are not independent draws, so this interval is the
    honest one when the clips come from a few trajectories; one trajectory gives a point."""
    trajectory = np.asarray(trajectory)
    if len(trajectory) != len(true):
        raise ValueError(f"{len(trajectory)} trajectory ids for {len(true)} clips")
    groups = [np.flatnonzero(trajectory == g) for g in np.unique(trajectory)]
    rng = np.random.default_rng(seed)
    true, shuffled = np.asarray(true, np.float64), np.asarray(shuffled, np.float64)
    ratios = np.empty(BOOTSTRAP_RESAMPLES)
    for b in range(BOOTSTRAP_RESAMPLES):
        rows = np.concatenate([groups[i] for i in rng.integers(0, len(groups), len(groups))])
        ratios[b] = _ratio(shuffled[rows].mean(), true[rows].mean())
    return [float(np.quantile(ratios, 0.025)), float(np.quantile(ratios, 0.975))]


def ratio_statistics(
    true: np.ndarray, shuffled: np.ndarray, seed: int = 0, trajectory: np.ndarray | None = None
) -> dict[str, Any]:
    """The ratio of mean errors shuffled / true with a 95% bootstrap interval over clips (the
    clips resampled with replacement, :data:`BOOTSTRAP_RESAMPLES` times), the clips whose true
    actions gave the lower error, and the two-sided exact sign test's p on those pairs. Given
    each clip's ``trajectory``, also ``trajectories`` (how many) and ``trajectory_ci``
    (:func:`trajectory_interval`)."""
    n = len(true)
    idx = np.random.default_rng(seed).integers(0, n, size=(BOOTSTRAP_RESAMPLES, n))
    boot = _ratio(shuffled[idx].mean(axis=1), true[idx].mean(axis=1))
    wins = int(np.sum(true < shuffled))
    ties = int(np.sum(true == shuffled))
    m = n - ties
    k = min(wins, m - wins)
    # Two-sided exact sign test: P(X <= k) + P(X >= m - k) for X ~ Binomial(m, 1/2).
    tail = sum(math.comb(m, j) for j in range(k + 1)) / 2.0**m if m else 1.0
    return {
        "ratio": float(_ratio(shuffled.mean(), true.mean())),
        "ci": [float(np.quantile(boot, 0.025)), float(np.quantile(boot, 0.975))],
        "mse_true": float(true.mean()),
        "mse_shuffled": float(shuffled.mean()),
        "wins": wins,
        "ties": ties,
        "clips": n,
        "sign_p": min(1.0, 2.0 * tail),
        **({} if trajectory is None else {
            "trajectories": int(len(np.unique(trajectory))),
            "trajectory_ci": trajectory_interval(true, shuffled, trajectory, seed),
        }),
    }


# --------------------------------------------------------------------------- statistics


def _average_ranks(x: np.ndarray) -> np.ndarray:
    """Ranks 1..n of ``x``, ties given their average rank."""
    order = np.argsort(x, kind="stable")
    ranks = np.empty(len(x), np.float64)
    ranks[order] = np.arange(1, len(x) + 1)
    for value in np.unique(x):
        tied = x == value
        if tied.sum() > 1:
            ranks[tied] = ranks[tied].mean()
    return ranks


def spearman(a: np.ndarray, b: np.ndarray) -> float | None:
    """Spearman's ρ (average ranks for ties); ``None`` where a side is constant."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if len(a) < 2 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return None
    ra, rb = _average_ranks(a), _average_ranks(b)
    return float(np.corrcoef(ra, rb)[0, 1])


def effective_sample_size(weights: np.ndarray) -> float:
    """Kish's effective sample size ``1 / Σ w²`` of normalised weights (``N`` when equal, 1 when
    one sample has all the weight)."""
    return float(1.0 / np.square(np.asarray(weights, np.float64)).sum())


def rank_of_last(scores: np.ndarray) -> int:
    """1-based rank of ``scores[-1]`` among all (higher is better; ties count against it)."""
    return int((scores[:-1] >= scores[-1]).sum()) + 1


def cross_task_cosine(rows: Sequence[dict[str, Any]]) -> tuple[float | None, int]:
    """Mean cosine between the plan shifts (``row["shift"]``, ``None``: no shift) of instances
    of different tasks, and the number of such pairs (0: undefined, ``None``)."""
    cosines = []
    for i, a in enumerate(rows):
        for b in rows[i + 1 :]:
            if a["task"] == b["task"] or a["shift"] is None or b["shift"] is None:
                continue
            u, v = np.asarray(a["shift"]), np.asarray(b["shift"])
            cosines.append(float(u @ v / (np.linalg.norm(u) * np.linalg.norm(v))))
    return (float(np.mean(cosines)) if cosines else None), len(cosines)


# --------------------------------------------------------------------------- planning step


def scripted_plan(actions: np.ndarray, horizon: int, action_dim: int) -> torch.Tensor:
    """The first ``horizon`` scripted actions of an instance, zero-padded, clipped to [-1, 1]."""
    plan = np.zeros((horizon, action_dim))
    k = min(horizon, len(actions))
    plan[:k] = actions[:k]
    return torch.as_tensor(np.clip(plan, -1.0, 1.0), dtype=torch.float32)


def step_context(instance: TaskInstance, size: int, executed: int = 0) -> dict[str, Any]:
    """What a planning step of the trial on ``instance`` sees after the zero action (SPEC §4)
    and the first ``executed`` scripted actions (0: the trial's first planning step).

    Returns:
        ``goal`` (the goal image), ``frames`` (the last two frames, ``(2, size, size, 3)``
        uint8), ``state`` (the simulator state), ``last_action`` (the last executed action) and
        ``rest`` (the scripted actions still to come).
    """
    env = instance.make_env(observation_size=None)
    try:
        goal = goal_image_at(instance, env, size)
        env.reset_to(instance.init_state)
        env.set_goal(instance.goal_state)
        last = np.zeros(env.action_dim)
        frames = [env.render(size)]
        env.step(last)
        frames.append(env.render(size))
        for action in instance.actions[:executed]:
            last = np.asarray(action, dtype=np.float64)
            env.step(last)
            frames.append(env.render(size))
        state = env.get_state()
    finally:
        env.close()
    return {"goal": goal, "frames": np.stack(frames[-2:]), "state": state, "last_action": last,
            "rest": instance.actions[executed:]}  # fmt: skip


def reset_agent(
    model: Any,
    instance: TaskInstance,
    goal: np.ndarray,
    seed: int,
    num_samples: int,
    device: torch.device,
    cost_mode: str = "auto",
) -> PlanningAgent:
    """A planning agent of ``model`` reset as the trial ``(instance, seed)`` resets it."""
    agent = PlanningAgent(model, PlannerConfig(num_samples=num_samples), cost_mode, device=device)
    agent.reset(instance.task, goal, trial_seed(instance.task, instance.index, seed))
    return agent


def step_objective(agent: PlanningAgent, instance: TaskInstance, context: dict[str, Any]) -> Any:
    """The agent's objective (``candidates -> scores``) at the planning step ``context``
    (:func:`step_context`); a model that predicts from the simulator state is put in it."""
    if getattr(agent.model, "needs_simulator_state", False):
        agent.model.set_simulator_state(instance.env_meta, context["state"])
    frames = frames_to_tensor(context["frames"][-agent.num_context :], agent.device)
    last = torch.as_tensor(context["last_action"], dtype=torch.float32, device=agent.device)
    return agent.objective(frames, last)


def draw_batch(agent: PlanningAgent, rest: np.ndarray, num_samples: int) -> tuple[torch.Tensor, torch.Tensor]:
    """The ``num_samples`` candidates the agent's sampler draws at its current plan, and the
    batch they make with the scripted plan ``rest`` appended last, ``(N + 1, T, A)``."""
    optimizer = agent.optimizer
    std = broadcast_std(optimizer.sigma, agent.plan)
    candidates = optimizer.sampler.sample(agent.plan, std, num_samples, agent.generator)
    scripted = scripted_plan(rest, agent.horizon, agent.action_dim).to(candidates)
    return candidates, torch.cat([candidates, scripted[None]])


def oracle_cache_dir() -> Path:
    """``$VP2_CACHE_DIR/diagnose-oracle`` if set, else ``~/.cache/vp2/diagnose-oracle``: the
    simulator's scores of probed candidates, one ``.npy`` file per instance, seed and batch."""
    return cache_dir("diagnose-oracle")


def simulator_scores(
    simulator: Any,
    instance: TaskInstance,
    batch: torch.Tensor,
    context: dict[str, Any],
    seed: int,
    num_samples: int,
    device: torch.device,
    cache: Path | None = None,
) -> np.ndarray:
    """The task's cost of each candidate of ``batch`` under the simulator's futures (higher is
    better), at the planning step ``context`` (:func:`step_context`) of the trial
    ``(instance, seed)``.

    With ``cache`` (a folder), the scores are read from there when the same instance, seed,
    planner and cost (classifier file included), rendering, vp2 version and batch were scored
    before, else from :data:`SHIPPED_ORACLE_SCORES` (the default probes), else
    computed and written there; a cache that cannot be written is skipped (debug log).
    """
    from vp2.envs.render_specs import render_fingerprint

    agent = reset_agent(simulator, instance, context["goal"], seed, num_samples, device)
    path = None
    if cache is not None:
        key = {
            "instance": instance.fingerprint, "seed": seed, "agent": agent.describe(),
            "render": render_fingerprint(instance.task.split("/", 1)[0]), "vp2": vp2.__version__,
            "last_action": [float(v) for v in context["last_action"]],
        }  # fmt: skip
        digest = hashlib.sha256(json.dumps(key, sort_keys=True, default=str).encode())
        digest.update(batch.detach().cpu().numpy().astype(np.float32).tobytes())
        path = cache / f"{digest.hexdigest()[:40]}.npy"
        if path.is_file():
            return np.load(path)
        shipped = SHIPPED_ORACLE_SCORES / path.name
        if shipped.is_file():
            return np.load(shipped)
    objective = step_objective(agent, instance, context)
    with torch.no_grad():
        scores = objective(batch.to(agent.device)).double().cpu().numpy()
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            with atomic_path(path) as tmp, open(tmp, "wb") as f:
                np.save(f, scores)
        except OSError as exc:
            log.debug("simulator scores not cached at %s: %s", path, exc)
    return scores


def simulator_agreement(model_scores: np.ndarray, oracle_scores: np.ndarray) -> dict[str, Any]:
    """How the model's scores of the candidates agree with the simulator's: Spearman's ρ (0
    where the model scores every candidate the same: it orders nothing) and the model's rank
    of the simulator's best candidate (ties count against it: the number of candidates the
    model scores at least as high), and whether that rank is in the top
    :data:`AGREEMENT_TOP_FRACTION`."""
    top = max(1, int(AGREEMENT_TOP_FRACTION * len(model_scores)))
    best = int(np.argmax(oracle_scores))
    rank = int((model_scores >= model_scores[best]).sum())
    rho = spearman(model_scores, oracle_scores)
    if rho is None and np.ptp(model_scores) == 0:
        rho = 0.0
    return {"oracle_rho": rho, "oracle_best_rank": rank, "oracle_best_in_top": rank <= top}


def probe_instance(
    model: Any,
    instance: TaskInstance,
    num_samples: int,
    seed: int,
    device: torch.device,
    cost_mode: str = "auto",
    simulator: Any = None,
    cache: Path | None = None,
) -> dict[str, Any]:
    """The first planning step of the trial ``(instance, seed)``: its candidates and the
    scripted plan scored twice (see the module docstring); with ``simulator`` (the oracle
    model), scored by it too (``cache``: see :func:`simulator_scores`).

    Returns:
        One row: ``task``, ``instance``, ``cost``, ``scripted_actions`` (how many the instance
        stores), ``rank`` (of the scripted plan among the ``num_samples + 1``; ``None`` when the
        instance stores no scripted actions), ``of``, ``repeat_rho`` (``None``: the scores are
        constant), ``gamma``, ``score_spread``, ``gamma_spread``, ``ess``, ``shift`` (the net
        x/y/z motion by which MPPI's weights move the plan away from the samples' plain mean;
        ``None`` when the weights are equal), ``seconds``; and ``oracle_rho``,
        ``oracle_best_rank``, ``oracle_best_in_top`` (:func:`simulator_agreement`; ``None``
        without ``simulator``) and ``oracle_seconds``.
    """
    context = step_context(instance, int(model.image_size))
    agent = reset_agent(model, instance, context["goal"], seed, num_samples, device, cost_mode)
    objective = step_objective(agent, instance, context)
    candidates, batch = draw_batch(agent, context["rest"], num_samples)  # the scripted plan last
    optimizer = agent.optimizer
    start = time.perf_counter()
    with torch.no_grad():
        first = objective(batch).double().cpu().numpy()
        # The second scoring draws the model's noise from another seed; the candidates stay.
        agent.model_generator = torch.Generator().manual_seed(
            trial_seed(instance.task, instance.index, seed + 1_000_003)
        )
        second = objective(batch).double().cpu().numpy()
    seconds = time.perf_counter() - start
    gamma = float(getattr(optimizer, "gamma", spec.GAMMA))
    scores = first[:num_samples]
    weights = mppi_weights(torch.as_tensor(scores), gamma).numpy()
    motion = candidates[:, :, :DIRECTION_DIMS].sum(dim=1).double().cpu().numpy()  # (N, 3)
    shift = weights @ motion - motion.mean(axis=0)
    flat = np.ptp(scores) == 0 or float(np.linalg.norm(shift)) < 1e-9
    agreement: dict[str, Any] = dict.fromkeys(("oracle_rho", "oracle_best_rank", "oracle_best_in_top"))
    oracle_seconds = 0.0
    if simulator is not None:
        start = time.perf_counter()
        oracle = simulator_scores(simulator, instance, batch, context, seed, num_samples, device,
                                  cache)  # fmt: skip
        agreement = simulator_agreement(scores, oracle[:num_samples])
        oracle_seconds = time.perf_counter() - start
    return {
        "task": instance.task,
        "instance": instance.index,
        "cost": agent.cost_kind,
        "scripted_actions": len(instance.actions),
        "rank": rank_of_last(first) if len(instance.actions) else None,
        "of": len(first),
        "repeat_rho": spearman(scores, second[:num_samples]),
        "gamma": gamma,
        "score_spread": float(np.std(scores)),
        "gamma_spread": gamma * float(np.std(scores)),
        "ess": effective_sample_size(weights),
        "shift": None if flat else [float(v) for v in shift],
        "seconds": round(seconds, 3),
        **agreement,
        "oracle_seconds": round(oracle_seconds, 3),
    }
