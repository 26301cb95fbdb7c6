"""Planning with an ensemble: the agent's objective is SPEC §5's ensemble score, its member
draws come from the trial seed and are recorded, and the members must fit together."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from vp2 import spec
from vp2.models.baselines import RepeatLastFrame
from vp2.models.ensemble import EnsembleMismatch, EnsembleModel
from vp2.planning import LBFGS, ensemble_disagreement
from vp2.planning.agent import Observation, PlanningAgent
from vp2.planning.planner import PlannerConfig

TASK = "tabletop/push_sphere"  # cost: 1 x pixel SSE to the goal
PIXELS = 10 * 3 * 8 * 8  # values of one sample's predicted frames
WHITE = np.full((8, 8, 3), 255, np.uint8)


class LevelModel(RepeatLastFrame):
    """Deterministic and differentiable: uniform frames of brightness
    ``offset + (mean_t a_t[0] + 1) / 4``, so that members with different offsets differ by
    exactly the offsets' difference at every pixel."""

    def __init__(self, offset: float, action_dim: int = 4) -> None:
        super().__init__(action_dim, image_size=8)
        self.offset = offset

    def predict(self, context_frames, actions, *, generator=None, grad=None):
        level = self.offset + (actions[:, 1:, 0].mean(dim=1) + 1) / 4  # (B,) in [offset, +0.5]
        return level[:, None, None, None, None].expand(-1, 10, 3, 8, 8).float()


def _ensemble() -> EnsembleModel:
    return EnsembleModel([LevelModel(0.0), LevelModel(0.2)], labels=["dark", "bright"])


def _observation(step: int) -> Observation:
    frames = np.random.default_rng(step).integers(0, 256, (step + 1, 8, 8, 3), dtype=np.uint8)
    return Observation(step, frames, np.zeros(4), env_meta={}, state=np.zeros(3))


def _candidates(n: int = 32) -> torch.Tensor:
    return torch.rand(n, 10, 4, generator=torch.Generator().manual_seed(1)) * 2 - 1


def test_the_objective_is_the_drawn_members_score_minus_lambda_times_the_disagreement():
    agent = PlanningAgent(_ensemble(), PlannerConfig(num_samples=32))
    agent.reset(TASK, WHITE, seed=7)
    context = torch.full((2, 3, 8, 8), 0.5)
    candidates = _candidates()
    scores = agent.objective(context, torch.zeros(4))(candidates)  # (32,)
    members = agent.ensemble_cost.last_members  # the recorded draw of every candidate
    assert members is not None and set(members.tolist()) == {0, 1}  # both members drawn
    # Member k predicts offset_k + (mean a[0] + 1) / 4 at every pixel; they differ by 0.2, so
    # each deviates 0.1 from the mean at every pixel: disagreement 0.1 x 1920 values.
    disagreement = 0.1 * PIXELS
    level = (candidates[:, :, 0].mean(dim=1) + 1) / 4 + 0.2 * members  # the drawn member's
    member_cost = (1 - level) ** 2 * PIXELS  # SSE to the white goal
    expected = -member_cost - 0.01 * disagreement
    torch.testing.assert_close(scores, expected, rtol=1e-5, atol=1e-3)
    assert spec.ENSEMBLE_DISAGREEMENT_WEIGHT == 0.01
    predicted = agent.ensemble.predict_members(
        context.expand(32, -1, -1, -1, -1), torch.cat([torch.zeros(32, 1, 4), candidates], 1)
    )
    torch.testing.assert_close(
        ensemble_disagreement(predicted), torch.full((32,), disagreement), rtol=1e-5, atol=1e-3
    )
    # A single model's objective has no penalty: the bright member alone scores -SSE.
    single = PlanningAgent(LevelModel(0.2), PlannerConfig(num_samples=32))
    single.reset(TASK, WHITE, seed=7)
    bright = (1 - ((candidates[:, :, 0].mean(dim=1) + 1) / 4 + 0.2)) ** 2 * PIXELS
    torch.testing.assert_close(
        single.objective(context, torch.zeros(4))(candidates), -bright, rtol=1e-5, atol=1e-3
    )


def test_member_draws_come_from_the_trial_seed_not_global_state():
    def draws(seed: int, global_seed: int) -> list[int]:
        torch.manual_seed(global_seed)
        np.random.seed(global_seed)  # noqa: NPY002  (must not matter)
        agent = PlanningAgent(_ensemble(), PlannerConfig(num_samples=32))
        agent.reset(TASK, WHITE, seed=seed)
        agent.objective(torch.full((2, 3, 8, 8), 0.5), torch.zeros(4))(_candidates())
        return agent.ensemble_cost.last_members.tolist()

    assert draws(3, 0) == draws(3, 1234)
    assert draws(3, 0) != draws(4, 0)
    # The ensemble's stream is a fourth word of the trial seed's SeedSequence: the planner's
    # and the model's streams are those a single model gets.
    agent = PlanningAgent(_ensemble(), PlannerConfig(num_samples=32))
    agent.reset(TASK, WHITE, seed=3)
    words = np.random.SeedSequence(3).generate_state(4)
    for generator, word in [(agent.generator, words[0]), (agent.model_generator, words[1]),
                            (agent.ensemble_generator, words[3])]:
        torch.testing.assert_close(generator.get_state(),
                                   torch.Generator().manual_seed(int(word)).get_state())


def test_every_planning_step_records_its_draws_and_survives_a_resume():
    def agent() -> PlanningAgent:
        a = PlanningAgent(_ensemble(), PlannerConfig(num_samples=16))
        a.reset(TASK, WHITE, seed=5)
        return a

    whole = agent()
    actions = [whole.act(_observation(step))[0] for step in (1, 2)]
    described = whole.describe()["ensemble"]
    assert described["members"] == ["dark", "bright"] and described["lam"] == 0.01
    steps = described["steps"]
    assert len(steps) == 2 and all(sum(s["draws"]) == 16 for s in steps)  # one MPPI call each
    assert steps[-1]["draws"] == torch.bincount(whole.ensemble_cost.last_members, minlength=2
                                                ).tolist()
    assert all(s["best_member"] in (0, 1) for s in steps)
    # Stopped after one step and resumed from its trial state: the same draws and actions.
    first = agent()
    first.act(_observation(1))
    state = first.trial_state()
    resumed = agent()
    resumed.load_trial_state(state)
    np.testing.assert_array_equal(resumed.act(_observation(2))[0], actions[1])
    assert resumed.describe()["ensemble"]["steps"] == steps


def test_a_gradient_planner_differentiates_the_ensemble_score():
    # Two equal members: the score is smooth (a random member's jumps would be noise to
    # L-BFGS's line search), and its gradient reaches the actions through the ensemble.
    twins = EnsembleModel([LevelModel(0.1), LevelModel(0.1)], labels=["a", "b"])
    agent = PlanningAgent(twins, PlannerConfig("lbfgs", grad_steps=2))
    agent.reset(TASK, WHITE, seed=0)
    assert isinstance(agent.optimizer, LBFGS) and agent.optimizer.num_steps == 2
    action, info = agent.act(_observation(1))
    # Brighter is better: L-BFGS pushes the first action coordinate up.
    assert action[0] > 0.5 and info["num_evaluations"] > 1
    assert sum(sum(s["draws"]) for s in agent.describe()["ensemble"]["steps"]) == info[
        "num_evaluations"
    ]
    # A member without gradients is named.
    mixed = EnsembleModel([LevelModel(0.0), RepeatLastFrame(4, image_size=8)], ["lvl", "rlf"])
    assert mixed.gradient_problem() == (
        "(member 'rlf') returned predictions without a gradient (grad_fn is None)"
    )


def test_members_must_fit_together():
    with pytest.raises(EnsembleMismatch, match="at least 2 members"):
        EnsembleModel([LevelModel(0.0)])
    with pytest.raises(EnsembleMismatch, match=r"^ensemble member 'five' has action_dim 5, "
                       r"member 'four' has 4; members must agree on num_context, num_future, "
                       r"action_dim, image_size$"):
        EnsembleModel([LevelModel(0.0), LevelModel(0.0, action_dim=5)], ["four", "five"])

    class Oracle(LevelModel):
        needs_simulator_state = True

    with pytest.raises(EnsembleMismatch, match="member 'o' plans from the simulator state"):
        EnsembleModel([LevelModel(0.0), Oracle(0.0)], ["l", "o"])
    # As a plain model it predicts the members' mean.
    ensemble = _ensemble()
    frames, actions = torch.full((3, 2, 3, 8, 8), 0.5), torch.zeros(3, 11, 4)
    torch.testing.assert_close(ensemble.predict(frames, actions),
                               torch.full((3, 10, 3, 8, 8), 0.25 + 0.1))
