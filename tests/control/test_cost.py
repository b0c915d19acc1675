"""The paper's cost against an explicit loop."""

import numpy as np
import pytest

from snac_gym.control.cost import cost_rates, instantaneous_cost, trajectory_cost


def _loop_cost(errors, commands, dt, Q, R):
    error = effort = smooth = 0.0
    previous = np.zeros(commands.shape[1])
    for e, u in zip(errors, commands):
        rate = (u - previous) / dt
        error += float(e @ Q @ e) * dt
        effort += float(u @ R @ u) * dt
        smooth += float(rate @ R @ rate) * dt
        previous = u
    return error, effort, smooth


@pytest.mark.parametrize("weighted", [False, True])
def test_trajectory_cost_matches_a_loop(rng, weighted):
    errors = rng.normal(size=(50, 3))
    commands = rng.normal(size=(50, 6))
    Q = np.diag(rng.uniform(0.5, 2, 3)) if weighted else np.eye(3)
    R = np.diag(rng.uniform(0.5, 2, 6)) if weighted else np.eye(6)
    terms = trajectory_cost(errors, commands, 0.008, Q if weighted else None, R if weighted else None)
    expected = _loop_cost(errors, commands, 0.008, Q, R)
    np.testing.assert_allclose([terms.error, terms.effort, terms.smoothness], expected, rtol=1e-12)
    assert terms.total == pytest.approx(sum(expected))


def test_batched_cost_equals_per_sample_cost(rng):
    errors = rng.normal(size=(4, 20, 3))
    commands = rng.normal(size=(4, 20, 6))
    batch = trajectory_cost(errors, commands, 0.01)
    for i in range(4):
        single = trajectory_cost(errors[i], commands[i], 0.01)
        assert batch.total[i] == pytest.approx(single.total)


def test_first_command_rate_starts_from_rest():
    commands = np.array([[1.0, 0, 0, 0, 0, 0], [1.0, 0, 0, 0, 0, 0]])
    rates = cost_rates(np.zeros((2, 3)), commands, dt=0.5)
    np.testing.assert_allclose(rates.smoothness, [4.0, 0.0])  # ((1 - 0)/0.5)² then no change


def test_instantaneous_cost_and_bad_shapes():
    assert instantaneous_cost(np.array([1.0, 2, 2]), np.ones(6)) == (9.0, 6.0)
    with pytest.raises(ValueError, match="Q must be"):
        instantaneous_cost(np.ones(3), np.ones(6), Q=np.eye(2))
    with pytest.raises(ValueError, match="share leading axes"):
        trajectory_cost(np.ones((5, 3)), np.ones((4, 6)), 0.1)
    with pytest.raises(ValueError, match=r"dt must be a finite number in \(0, inf\]"):
        trajectory_cost(np.ones((5, 3)), np.ones((5, 6)), 0.0)
