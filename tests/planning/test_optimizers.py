"""The optimizers on known objectives: convergence, bounds, the update rules, determinism."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vp2.planning.optimizers import (
    CEM,
    CEMGD,
    LBFGS,
    MPPI,
    OPTIMIZERS,
    NotDifferentiableError,
    Optimizer,
    clamp_cem_variance,
    mppi_weights,
    shift_plan,
)

H, A = 10, 4
TABLETOP_SIGMA = (0.5, 0.5, 0.5, 0.0)


def _target() -> torch.Tensor:
    """A smooth action sequence inside the box, like a real plan: (H, A)."""
    t = torch.linspace(0, 1, H)
    return torch.stack([0.6 * torch.sin(3 * t), -0.5 + 0.8 * t, 0.3 * torch.ones(H), 0 * t], 1)


def quadratic(target: torch.Tensor):
    """score(a) = -||a - target||², maximised at the target."""
    return lambda actions: -((actions - target) ** 2).sum(dim=(1, 2))  # (N,)


class Recorder:
    """Wraps an objective and keeps every batch of actions and scores it saw."""

    def __init__(self, objective):
        self.objective = objective
        self.actions: list[torch.Tensor] = []
        self.scores: list[torch.Tensor] = []

    def __call__(self, actions):
        scores = self.objective(actions)
        self.actions.append(actions.detach().clone())
        self.scores.append(scores.detach().clone())
        return scores


def _rms(a: torch.Tensor, b: torch.Tensor) -> float:
    return float(((a - b) ** 2).mean().sqrt())


# ---- MPPI ------------------------------------------------------------------------------------


def test_mppi_weights_are_a_stable_softmax_of_gamma_times_score() -> None:
    scores = torch.tensor([0.0, -10.0, -20.0])
    expected = torch.softmax(0.1 * scores.double(), 0)  # the weights are float64
    torch.testing.assert_close(mppi_weights(scores, 0.1), expected, rtol=1e-15, atol=0)
    huge = torch.tensor([1e6, 1e6 - 1.0, -1e6])  # exp would overflow without the max shift
    weights = mppi_weights(huge, 1.0)
    assert torch.isfinite(weights).all()
    torch.testing.assert_close(weights.sum(), torch.tensor(1.0, dtype=torch.float64))
    assert weights[0] / weights[1] == pytest.approx(np.e, rel=1e-5)


def test_mppi_plan_is_the_plain_mean_when_gamma_is_zero() -> None:
    rec = Recorder(quadratic(_target()))
    plan, info = MPPI(TABLETOP_SIGMA, num_samples=50, gamma=0.0).optimize(
        rec, torch.zeros(H, A), torch.Generator().manual_seed(0)
    )
    torch.testing.assert_close(plan, rec.actions[0].mean(0))
    assert info.num_evaluations == 50 and info.num_objective_calls == 1
    assert info.best_score == pytest.approx(float(rec.scores[0].max()))


def test_mppi_plan_is_the_best_sample_when_gamma_is_large() -> None:
    rec = Recorder(lambda a: -1e3 * ((a - _target()) ** 2).sum(dim=(1, 2)))
    plan, _ = MPPI(TABLETOP_SIGMA, num_samples=50, gamma=1e3).optimize(
        rec, torch.zeros(H, A), torch.Generator().manual_seed(0)
    )
    torch.testing.assert_close(plan, rec.actions[0][rec.scores[0].argmax()])


def test_mppi_converges_on_a_quadratic() -> None:
    target = _target()
    mppi = MPPI((0.2, 0.2, 0.2, 0.0), num_samples=200, gamma=10.0, num_iterations=30)
    plan, info = mppi.optimize(
        quadratic(target), torch.zeros(H, A), torch.Generator().manual_seed(0)
    )
    assert _rms(plan, target) < 0.03  # start: 0.29
    assert (plan - target).abs().max() < 0.08
    assert info.num_evaluations == 30 * 200


def test_mppi_warm_started_calls_converge_like_iterations() -> None:
    target = _target()
    mppi = MPPI((0.2, 0.2, 0.2, 0.0), gamma=10.0)
    plan, g = torch.zeros(H, A), torch.Generator().manual_seed(1)
    for _ in range(30):
        plan, _ = mppi.optimize(quadratic(target), plan, g)
    assert _rms(plan, target) < 0.03


def test_mppi_plan_stays_in_bounds_when_the_optimum_is_outside() -> None:
    target = torch.full((H, A), 2.0)
    plan, _ = MPPI(TABLETOP_SIGMA, gamma=10.0, num_iterations=10).optimize(
        quadratic(target), torch.zeros(H, A), torch.Generator().manual_seed(0)
    )
    assert plan.max() <= 1.0 and plan[:, :3].mean() > 0.85


# ---- CEM -------------------------------------------------------------------------------------


def test_cem_variance_clamp() -> None:
    mean = torch.tensor([[0.0, 0.9, -0.5, 1.0]])
    var = torch.full((1, 4), 0.25)
    expected = torch.tensor([[0.25, 0.05**2, 0.25**2, 0.0]])
    torch.testing.assert_close(clamp_cem_variance(mean, var), expected)


def test_cem_samples_respect_the_variance_clamp() -> None:
    rec = Recorder(quadratic(_target()))
    CEM([0.5], num_samples=500, num_iterations=1).optimize(
        rec, torch.full((H, 1), 0.9), torch.Generator().manual_seed(0)
    )
    first_step = rec.actions[0][:, 0, 0]  # std of step 0 of correlated noise is the std given
    assert float(first_step.std()) == pytest.approx(0.05, rel=0.1)


def test_cem_returns_the_best_sample_of_its_last_iteration() -> None:
    rec = Recorder(quadratic(_target()))
    plan, info = CEM(TABLETOP_SIGMA).optimize(
        rec, torch.zeros(H, A), torch.Generator().manual_seed(0)
    )
    assert len(rec.actions) == 3 and rec.actions[0].shape == (200, H, A)
    torch.testing.assert_close(plan, rec.actions[-1][rec.scores[-1].argmax()])
    assert info.plan_score == pytest.approx(float(rec.scores[-1].max()))
    assert info.num_evaluations == 600


def test_cem_converges_on_a_quadratic_with_warm_starts() -> None:
    target = _target()
    cem, plan, g = CEM(TABLETOP_SIGMA), torch.zeros(H, A), torch.Generator().manual_seed(0)
    for _ in range(10):
        plan, _ = cem.optimize(quadratic(target), plan, g)
    assert _rms(plan, target) < 0.06  # start: 0.29
    assert (plan - target).abs().max() < 0.15


# ---- CEM-GD ----------------------------------------------------------------------------------


def test_cemgd_sample_counts_first_call_then_replan_and_reset() -> None:
    rec = Recorder(quadratic(_target()))
    cemgd, g = CEMGD(TABLETOP_SIGMA, num_samples_first=40, num_samples=12), torch.Generator()
    cemgd.optimize(rec, torch.zeros(H, A), g)
    assert [a.shape[0] for a in rec.actions[:3]] == [40, 40, 40]
    assert all(a.shape[0] == 1 for a in rec.actions[3:])  # refinement of the single best
    rec.actions.clear()
    cemgd.optimize(rec, torch.zeros(H, A), g)
    assert [a.shape[0] for a in rec.actions[:3]] == [12, 12, 12]
    rec.actions.clear()
    cemgd.reset()
    cemgd.optimize(rec, torch.zeros(H, A), g)
    assert rec.actions[0].shape[0] == 40


def test_cemgd_refinement_improves_on_cem() -> None:
    target = _target()
    cemgd = CEMGD(TABLETOP_SIGMA, num_samples_first=50, num_refined=3)
    plan, info = cemgd.optimize(
        quadratic(target), torch.zeros(H, A), torch.Generator().manual_seed(0)
    )
    cem_best = max(info.iteration_best_scores[:3])
    assert info.plan_score > cem_best + 0.1  # 15 Adam steps of 1e-2 per coordinate
    assert float(quadratic(target)(plan[None])[0]) == pytest.approx(info.plan_score)
    assert info.num_objective_calls == 3 + 1 + 15  # CEM, initial gradient, 15 accepted steps


def test_cemgd_backtracking_halves_the_step_and_stops_after_seven_failures() -> None:
    target = _target()

    def misleading(actions):
        # True score as value, but its gradient points the wrong way: every step fails.
        true = -((actions - target) ** 2).sum(dim=(1, 2))
        fake = ((actions - target) ** 2).sum(dim=(1, 2))
        return true.detach() + fake - fake.detach()

    rec = Recorder(misleading)
    plan, info = CEMGD(TABLETOP_SIGMA, num_samples_first=30).optimize(
        rec, torch.zeros(H, A), torch.Generator().manual_seed(0)
    )
    start, candidates = rec.actions[3][0], [a[0] for a in rec.actions[4:]]
    assert len(candidates) == 7
    torch.testing.assert_close(plan, start)  # nothing accepted
    steps = torch.stack([(c - start).abs().max() for c in candidates])
    torch.testing.assert_close(steps[1:] / steps[:-1], torch.full((6,), 0.5), rtol=1e-3, atol=0)
    assert float(steps[0]) == pytest.approx(1e-2, rel=1e-3)  # first Adam step: lr per coordinate
    assert info.plan_score == pytest.approx(float(rec.scores[3][0]))


def test_cemgd_projects_onto_the_action_box() -> None:
    target = torch.full((H, A), 1.5)
    plan, info = CEMGD(TABLETOP_SIGMA, num_samples_first=30).optimize(
        quadratic(target), torch.full((H, A), 0.95), torch.Generator().manual_seed(0)
    )
    assert plan.min() >= -1.0 and plan.max() <= 1.0
    assert info.plan_score >= max(info.iteration_best_scores[:3])


# ---- L-BFGS ----------------------------------------------------------------------------------


def test_lbfgs_reaches_the_optimum_of_a_convex_quadratic() -> None:
    target = _target()
    plan, info = LBFGS().optimize(quadratic(target), torch.zeros(H, A), torch.Generator())
    assert (plan - target).abs().max() < 1e-2
    assert info.plan_score == pytest.approx(float(quadratic(target)(plan[None])[0]))


def test_lbfgs_stays_in_bounds_and_approaches_a_bound_optimum() -> None:
    target = _target()
    target[:, 0] = 1.5
    plan, _ = LBFGS().optimize(quadratic(target), torch.zeros(H, A), torch.Generator())
    assert plan.min() >= -1.0 and plan.max() <= 1.0
    assert plan[:, 0].min() > 0.95


def _noisy_quadratic(seed: int):
    """A quadratic whose every call adds fresh noise, as a model that samples its latents anew
    on every call gives: the same actions, two scores. Also counts the non-finite actions it
    is asked to score."""
    g = torch.Generator().manual_seed(seed)
    target = torch.rand(H, A, generator=g) * 1.6 - 0.8
    seen = {"non_finite": 0}

    def objective(actions):
        if not torch.isfinite(actions).all():
            seen["non_finite"] += 1
        noise = torch.randn((), generator=g)
        return -10 * ((actions - target) ** 2).sum(dim=(1, 2)) + noise

    return objective, seen


def test_lbfgs_stops_with_its_best_plan_when_a_noisy_objective_sends_the_line_search_to_nan():
    # Seed 4 at step length 1e-3: torch's strong-Wolfe line search evaluates one step length
    # twice, gets two scores and interpolates 0/0 (measured with torch 2.13 on x86-64); before
    # the guard the NaN point reached the objective and the trial failed.
    objective, seen = _noisy_quadratic(4)
    plan, info = LBFGS(lr=1e-3, num_steps=20).optimize(
        objective, torch.zeros(H, A), torch.Generator()
    )
    assert seen["non_finite"] == 0
    assert torch.isfinite(plan).all() and plan.abs().max() < 1.0
    assert info.plan_score == max(info.iteration_best_scores) == info.best_score
    assert info.best_score > info.iteration_best_scores[0]


def test_lbfgs_never_evaluates_a_non_finite_point(monkeypatch) -> None:
    # Whatever torch's line search proposes: a point that is not finite is not scored, and the
    # plan is the best of those that were.
    real_step = torch.optim.LBFGS.step
    calls = {"n": 0}

    def step(self, closure):
        calls["n"] += 1
        if calls["n"] == 3:
            with torch.no_grad():
                self.param_groups[0]["params"][0].fill_(float("nan"))
            return closure()
        return real_step(self, closure)

    monkeypatch.setattr(torch.optim.LBFGS, "step", step)
    recorder = Recorder(quadratic(_target()))
    plan, info = LBFGS().optimize(recorder, torch.zeros(H, A), torch.Generator())
    assert calls["n"] == 3
    assert all(torch.isfinite(a).all() for a in recorder.actions)
    best = int(torch.cat(recorder.scores).argmax())
    assert torch.equal(plan, recorder.actions[best][0])
    assert info.num_objective_calls == len(recorder.actions)


def test_gradient_planners_improve_a_nonconvex_objective() -> None:
    target = _target()

    def wiggly(actions):  # smooth, non-convex
        quad = ((actions - target) ** 2).sum(dim=(1, 2))
        return -quad + 0.05 * torch.cos(8 * actions).sum(dim=(1, 2))

    start = torch.full((H, A), -0.3)
    start_score = float(wiggly(start[None])[0])
    for optimizer in (LBFGS(), CEMGD(TABLETOP_SIGMA, num_samples_first=50)):
        plan, info = optimizer.optimize(wiggly, start, torch.Generator().manual_seed(0))
        assert info.plan_score > start_score + 1.0
        assert float(wiggly(plan[None])[0]) == pytest.approx(info.plan_score, rel=1e-5)


@pytest.mark.parametrize("optimizer", [LBFGS(), CEMGD(TABLETOP_SIGMA, num_samples_first=20)])
@pytest.mark.parametrize("kind", ["no_grad", "numpy", "constant"])
def test_gradient_planners_reject_non_differentiable_objectives(optimizer, kind) -> None:
    target = _target()

    def objective(actions):
        if kind == "no_grad":
            with torch.no_grad():
                return quadratic(target)(actions)
        if kind == "numpy":
            return torch.from_numpy(-((actions.detach().numpy() - target.numpy()) ** 2).sum((1, 2)))
        w = torch.ones((), requires_grad=True)  # depends on parameters but not on the actions
        return w * torch.zeros(actions.shape[0])

    with pytest.raises(NotDifferentiableError, match="differentiable objective"):
        optimizer.optimize(objective, torch.zeros(H, A), torch.Generator().manual_seed(0))


# ---- shared contracts ------------------------------------------------------------------------


def _all_optimizers() -> list[Optimizer]:
    return [
        MPPI(TABLETOP_SIGMA, num_samples=30),
        CEM(TABLETOP_SIGMA, num_samples=30),
        CEMGD(TABLETOP_SIGMA, num_samples_first=30),
        LBFGS(num_steps=3),
    ]


@pytest.mark.parametrize("optimizer", _all_optimizers(), ids=lambda o: type(o).__name__)
def test_plans_are_deterministic_given_the_generator(optimizer: Optimizer) -> None:
    objective = quadratic(_target())
    plans = []
    for seed in (7, 7, 8):
        optimizer.reset()
        plan, _ = optimizer.optimize(
            objective, torch.zeros(H, A), torch.Generator().manual_seed(seed)
        )
        assert plan.shape == (H, A) and plan.min() >= -1.0 and plan.max() <= 1.0
        plans.append(plan)
    assert torch.equal(plans[0], plans[1])
    if not isinstance(optimizer, LBFGS):  # L-BFGS uses no randomness
        assert not torch.equal(plans[0], plans[2])


@pytest.mark.parametrize("optimizer", _all_optimizers(), ids=lambda o: type(o).__name__)
def test_objective_contract_is_checked(optimizer: Optimizer) -> None:
    g = torch.Generator().manual_seed(0)
    with pytest.raises(ValueError, match="shape"):
        optimizer.optimize(lambda a: a.sum(dim=2), torch.zeros(H, A), g)
    with pytest.raises(ValueError, match="non-finite"):
        optimizer.optimize(lambda a: a.sum(dim=(1, 2)) * float("nan"), torch.zeros(H, A), g)
    with pytest.raises(ValueError, match="initial_mean"):
        optimizer.optimize(quadratic(_target()), torch.zeros(H * A), g)


def test_shift_plan_drops_the_executed_action_and_pads() -> None:
    plan = torch.arange(8.0).view(4, 2)  # rows [0,1] [2,3] [4,5] [6,7]
    torch.testing.assert_close(shift_plan(plan), torch.tensor([[2.0, 3], [4, 5], [6, 7], [6, 7]]))
    torch.testing.assert_close(
        shift_plan(plan, pad="zero"), torch.tensor([[2.0, 3], [4, 5], [6, 7], [0, 0]])
    )
    torch.testing.assert_close(shift_plan(plan, steps=4), torch.zeros(4, 2))
    assert shift_plan(plan).data_ptr() != plan.data_ptr()
    with pytest.raises(ValueError):
        shift_plan(plan, steps=5)


def test_registry_names() -> None:
    assert OPTIMIZERS == {"mppi": MPPI, "cem": CEM, "cem_gd": CEMGD, "lbfgs": LBFGS}


@pytest.mark.gpu
@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_plans_match_cpu_plans_with_a_cpu_generator() -> None:
    target = _target()
    for make in (lambda: MPPI(TABLETOP_SIGMA), lambda: CEM(TABLETOP_SIGMA)):
        cpu, _ = make().optimize(
            quadratic(target), torch.zeros(H, A), torch.Generator().manual_seed(0)
        )
        gpu, _ = make().optimize(
            quadratic(target.cuda()),
            torch.zeros(H, A, device="cuda"),
            torch.Generator().manual_seed(0),
        )
        assert gpu.device.type == "cuda"
        torch.testing.assert_close(gpu.cpu(), cpu, atol=1e-5, rtol=0)
    plan, _ = CEMGD(TABLETOP_SIGMA, num_samples_first=30).optimize(
        quadratic(target.cuda()), torch.zeros(H, A, device="cuda"), torch.Generator().manual_seed(0)
    )
    assert plan.device.type == "cuda"
