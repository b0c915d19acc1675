"""Off-policy integral RL (snac_gym.control.irl, Jiang & Jiang 2012): the paper's example, a random system
against the ARE, the data matrices against their definitions, and the ``snac-irl`` arm controller."""

import importlib.util
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import solve_continuous_are

from snac_gym.control.irl import (
    IRLData,
    policy_iteration,
    quadratic_features,
    simulate_linear,
    windows_from_samples,
)
from snac_gym.control.optimality import matrix_to_quadratic_weights, quadratic_weights_to_matrix

EXAMPLE = Path(__file__).resolve().parents[2] / "docs" / "scripts" / "irl_example.py"


def _example():
    spec = importlib.util.spec_from_file_location("irl_example", EXAMPLE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_vech_is_the_papers_and_inverts(rng):
    P = rng.normal(size=(4, 4))
    P = P + P.T
    x = rng.normal(size=4)
    assert np.isclose(quadratic_features(x) @ matrix_to_quadratic_weights(P), x @ P @ x)  # xᵀPx = x̄ᵀP̂
    assert np.allclose(quadratic_weights_to_matrix(matrix_to_quadratic_weights(P), 4), P)


def test_the_papers_example_converges_to_the_are_solution():
    """Sec. 4 of the paper (data of the authors' MATLAB code, seed fixed): with the paper's ε = 0.03
    the iteration stops after 3 least-squares solves, the model-based Kleinman count (the data-driven
    iterates equal it, Lemma 6); the learned K agrees with the K the paper prints to its 4 decimals
    (≤ 1e-4 apart: the paper's own learned K differs from K* by 1e-4 in two entries)."""
    example = _example()
    result, P_star, K_star = example.run()
    assert result.converged and result.iterations == 3
    assert np.linalg.norm(result.P_final - P_star, 2) <= 1e-3 * np.linalg.norm(P_star, 2)  # 9.6e-5 of 130
    assert np.linalg.norm(result.K_final - K_star, 2) <= 1e-5  # 9.9e-7
    assert np.abs(result.K_final - example.PAPER_K).max() <= 1.5e-4  # the paper's printed K_15, rounded


def test_the_authors_code_stopping_rule_runs_to_its_cap_of_16():
    """The authors' code stops at ‖P_k − P_{k−1}‖ ≤ 1e-10 or 16 iterations; the differences of the
    data-driven iterates level off near 1e-7 (integration error of the data), so it runs all 16."""
    example = _example()
    result, P_star, _ = example.run(tolerance=example.CODE_TOLERANCE, max_iterations=example.CODE_MAX_ITERATIONS)
    assert not result.converged and result.iterations == 16
    assert max(result.differences[2:]) < 1e-5
    assert all(np.linalg.norm(P - P_star, 2) < 1e-3 for P in result.P[2:])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_random_unstable_system_learns_the_are_gain(seed):
    """A random (n=4, m=2) system, open-loop unstable, K₀ stabilising; the data come from u = −K₀x + e."""
    rng = np.random.default_rng(seed)
    n, m = 4, 2
    A = rng.normal(size=(n, n)) + 0.5 * np.eye(n)
    B = rng.normal(size=(n, m))
    Q, R = np.eye(n), np.diag([1.0, 2.0])
    assert np.linalg.eigvals(A).real.max() > 0
    P_init = solve_continuous_are(A, B, 10 * np.eye(n), np.eye(m))  # some stabilising gain, not the optimum
    K0 = B.T @ P_init
    assert np.linalg.eigvals(A - B @ K0).real.max() < 0
    frequencies = rng.uniform(-50, 50, size=(m, 30))
    signal = lambda t, x: -K0 @ x + np.sin(frequencies * t).sum(axis=1)  # noqa: E731
    data, _, _ = simulate_linear(A, B, rng.normal(size=n), signal, window=0.02, windows=60, substeps=20)
    result = policy_iteration(data, Q, R, K0, tolerance=1e-8)
    P_star = solve_continuous_are(A, B, Q, R)
    K_star = np.linalg.solve(R, B.T @ P_star)
    assert result.converged
    assert np.allclose(result.K_final, K_star, atol=1e-5 * np.abs(K_star).max())
    assert np.allclose(result.P_final, P_star, atol=1e-5 * np.abs(P_star).max())


def test_sampled_windows_with_a_drift_are_exact_for_a_held_input(rng):
    """ẋ = B u + w with u, w held over each period (the arm's ė = J u − ẋ_d): the data of
    windows_from_samples, drift included, give the ARE of (0, B) exactly."""
    n, m, dt = 3, 6, 0.008
    B = rng.normal(size=(n, m))
    R = np.eye(m)
    Q = 4 * np.eye(n)
    K0 = 2.0 * B.T
    x = [rng.normal(size=n)]
    us, ws = [], []
    for k in range(200):
        u = -K0 @ x[-1] + 0.3 * np.sin(np.arange(1, m + 1) * 1.7 * k * dt + np.arange(m))
        w = 0.2 * np.array([np.cos(k * dt), np.sin(2 * k * dt), 0.5])
        x.append(x[-1] + dt * (B @ u + w))
        us.append(u)
        ws.append(w)
    data = windows_from_samples(np.array(x), np.array(us), dt, steps_per_window=2, drifts=np.array(ws))
    assert data.windows == 100 and data.rank() == n * (n + 1) // 2 + m * n
    result = policy_iteration(data, Q, R, K0, tolerance=1e-10)
    P_star = solve_continuous_are(np.zeros((n, n)), B, Q, R)
    assert np.allclose(result.P_final, P_star, atol=1e-8)
    assert np.allclose(result.K_final, B.T @ P_star, atol=1e-8)
    without = policy_iteration(IRLData(data.delta_xx, data.I_xx, data.I_xu), Q, R, K0, tolerance=1e-10)
    assert not np.allclose(without.P_final, P_star, atol=1e-3)  # ignoring the drift biases P


def test_bad_arguments_are_refused(rng):
    data, _, _ = simulate_linear(
        -np.eye(2), np.eye(2), [1.0, -1.0], lambda t, x: np.sin([3 * t, 7 * t]), window=0.1, windows=12
    )
    with pytest.raises(ValueError, match="K0"):
        policy_iteration(data, np.eye(2), np.eye(2), np.zeros((3, 2)))
    with pytest.raises(ValueError, match="tolerance"):
        policy_iteration(data, np.eye(2), np.eye(2), np.zeros((2, 2)), tolerance=-1.0)
    with pytest.raises(ValueError, match="R must be"):
        policy_iteration(data, np.eye(2), -np.eye(2), np.zeros((2, 2)))
    with pytest.raises(ValueError, match="rank"):
        policy_iteration(
            IRLData(data.delta_xx[:3], data.I_xx[:3], data.I_xu[:3]), np.eye(2), np.eye(2), np.zeros((2, 2))
        )
    with pytest.raises(ValueError, match="window"):
        simulate_linear(-np.eye(2), np.eye(2), [1.0, 0.0], lambda t, x: x, window=0.0, windows=3)
    with pytest.raises(ValueError, match="steps_per_window"):
        windows_from_samples(np.zeros((5, 2)), np.zeros((4, 2)), 0.1, steps_per_window=0)


# -- the arm controller ---------------------------------------------------------------------------
DT = 1.0 / 125.0


def _arm_context(kinematics, task="reach"):
    from snac_gym.observation import ObservationLayout
    from snac_gym.policies.base import PolicyContext

    layout = ObservationLayout(kinematics.n_joints, kinematics.task_dim)
    return PolicyContext(kinematics, DT, np.full(kinematics.n_joints, 3.0), layout, task)


def test_registered():
    from snac_gym.policies import available_policies

    assert "snac-irl" in available_policies()


def test_on_a_frozen_jacobian_the_arm_learner_finds_the_are_gain_from_data(ur10):
    """ė = J₀u with J₀ frozen (the learner's assumption): the gain learned from the measured (e, u)
    is the ARE's R⁻¹J₀ᵀP*(J₀), although the policy never evaluates J after its K₀."""
    from snac_gym.control.optimality import FrozenJacobianLQR
    from snac_gym.policies import make_policy

    context = _arm_context(ur10)
    q = np.array([0.0, -1.2, 1.5, -1.8, -1.57, 0.0])
    J0, x_d = ur10.jacobian(q), ur10.forward(q) + np.array([0.3, -0.2, 0.1])
    policy = make_policy("snac-irl", context, Q=[4.0] * 3, initial_gain_scale=0.5)
    policy.reset(seed=3)
    e = ur10.forward(q) - x_d
    for _ in range(policy.learning_steps + 1):
        u = policy.act(context.layout.pack(q, np.zeros(6), x_d + e, x_d, np.zeros(3), x_d))
        e = e + DT * J0 @ u
    K_star = FrozenJacobianLQR([4.0] * 3, None, 3, 6).gain(J0)
    assert policy.internals["learned"]
    assert np.linalg.norm(policy._batch["gain"][0] - K_star) <= 1e-4 * np.linalg.norm(K_star)


def test_the_batch_rows_are_the_single_episodes(ur10):
    from snac_gym.policies import make_policy

    context = _arm_context(ur10)
    rng = np.random.default_rng(5)
    q = np.array([0.0, -1.2, 1.5, -1.8, -1.57, 0.0]) + rng.normal(scale=0.2, size=(3, 6))
    x_d = np.array([ur10.forward(row) for row in q]) + rng.uniform(-0.2, 0.2, size=(3, 3))
    batch = make_policy("snac-irl", context)
    batch.reset_batch([0, 1, 2])
    singles = [make_policy("snac-irl", context) for _ in range(3)]
    for seed, single in enumerate(singles):
        single.reset(seed=seed)
    for _ in range(batch.learning_steps + 3):
        obs = np.array(
            [context.layout.pack(q[i], np.zeros(6), ur10.forward(q[i]), x_d[i], np.zeros(3), x_d[i]) for i in range(3)]
        )
        commands = batch.act_batch(obs)
        for i, single in enumerate(singles):
            assert np.allclose(single.act(obs[i]), commands[i], atol=1e-12)
        q = q + DT * commands


def test_the_reach_env_error_decreases():
    import gymnasium as gym

    from snac_gym.policies import make_policy

    env = gym.make("snac_gym/UR10Reach-v0")
    policy = make_policy("snac-irl", env)
    obs, _ = env.reset(seed=0)
    policy.reset(seed=0)
    e_slice = policy.layout.slices["e"]
    start = np.linalg.norm(obs[e_slice])
    for _ in range(300):
        obs, *_ = env.step(policy.act(obs))
    assert np.linalg.norm(obs[e_slice]) < 0.5 * start  # 0.79 m -> 0.22 m after 2.4 s (seed 0)
    env.close()


def test_bad_arm_arguments_are_refused(ur10):
    from snac_gym.policies.snac_irl import SNACIRLPolicy

    context = _arm_context(ur10)
    with pytest.raises(ValueError, match="learning_time"):
        SNACIRLPolicy(context, learning_time=0.05)  # 6 windows, eq. 13 needs 24
    with pytest.raises(ValueError, match="exploration"):
        SNACIRLPolicy(context, exploration=-0.1)
    with pytest.raises(ValueError, match="frequency_range"):
        SNACIRLPolicy(context, frequency_range=(1.0, 1000.0))
    with pytest.raises(ValueError, match="relearn_every"):
        SNACIRLPolicy(context, relearn_every=-1)
    with pytest.raises(RuntimeError, match="reset"):
        SNACIRLPolicy(context).act(np.zeros(context.layout.size))
