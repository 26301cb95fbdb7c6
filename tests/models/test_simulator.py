"""The simulator oracle predicts exactly what the simulator does."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from tests.benchmark import make_instance
from vp2.models.contract import CheckedModel
from vp2.models.simulator import SimulatorModel


@pytest.fixture(scope="module")
def tabletop():
    inst = make_instance("tabletop/push_sphere", 1)
    env = inst.make_env(observation_size=None)
    yield inst, env
    env.close()


def _rollout(env, state: np.ndarray, actions: np.ndarray) -> np.ndarray:
    """Ground truth: step the env itself, ``(T, 64, 64, 3)`` uint8."""
    env.reset_to(state)
    frames = []
    for a in actions:
        env.step(a)
        frames.append(env.render(64))
    return np.stack(frames)


def test_simulator_model_predicts_the_simulator(tabletop):
    inst, env = tabletop
    model = CheckedModel(SimulatorModel(action_dim=4))
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (2, 11, 4))
    # Start from a state that is not the initial one.
    env.reset_to(inst.init_state)
    env.step(np.array([0.5, 0.0, 0.0, 0.0]))
    state = env.get_state()
    model.set_simulator_state(inst.env_meta, state)
    out = model.predict(torch.zeros(2, 2, 3, 64, 64), torch.from_numpy(actions).float())
    assert out.shape == (2, 10, 3, 64, 64)
    for i in range(2):
        # actions[:, 0] already happened; the oracle simulates actions[:, 1:] (as float32,
        # what the planner hands it).
        truth = _rollout(env, state, actions[i, 1:].astype(np.float32))
        pred = (out[i].permute(0, 2, 3, 1) * 255).round().to(torch.uint8).numpy()
        np.testing.assert_array_equal(pred, truth)
    # Different candidates, different futures.
    assert not torch.equal(out[0], out[1])


def test_simulator_model_needs_a_state_and_no_gradients(tabletop):
    inst, _ = tabletop
    model = SimulatorModel(action_dim=4)
    assert model.needs_simulator_state
    with pytest.raises(RuntimeError, match="before set_simulator_state"):
        model.predict(torch.zeros(1, 2, 3, 64, 64), torch.zeros(1, 11, 4))
    model.set_simulator_state(inst.env_meta, inst.init_state)
    with pytest.raises(RuntimeError, match="not differentiable"):
        model.predict(torch.zeros(1, 2, 3, 64, 64), torch.zeros(1, 11, 4), grad=True)
    with pytest.raises(ValueError):
        SimulatorModel(action_dim=4, num_workers=0)


@pytest.mark.slow  # spawns two workers that import torch and the simulators (~20 s)
def test_simulator_model_worker_pool_matches_one_process(tabletop):
    inst, _ = tabletop
    actions = torch.from_numpy(np.random.default_rng(1).uniform(-1, 1, (3, 11, 4))).float()
    context = torch.zeros(3, 2, 3, 64, 64)
    serial = SimulatorModel(action_dim=4)
    serial.set_simulator_state(inst.env_meta, inst.init_state)
    pooled = SimulatorModel(action_dim=4, num_workers=2)
    pooled.set_simulator_state(inst.env_meta, inst.init_state)
    try:
        torch.testing.assert_close(
            pooled.predict(context, actions), serial.predict(context, actions)
        )
        pooled.num_workers = 1  # stops the pool; predictions go on in this process
        assert pooled._pool is None
        torch.testing.assert_close(
            pooled.predict(context[:1], actions[:1]), serial.predict(context[:1], actions[:1])
        )
    finally:
        pooled.close()
