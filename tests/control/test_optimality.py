"""snac_gym.control.optimality: the frozen-Jacobian optimum against SciPy's Riccati solver and hand
expansions, the HJB residual, stacks against single calls, and the map between SNAC's quadratic
basis weights and P̂ against the basis evaluated numerically."""

import numpy as np
import pytest
from scipy.linalg import fractional_matrix_power, solve_continuous_are, sqrtm

from snac_gym.control.optimality import (
    SINGULAR_TOLERANCE,
    FrozenJacobianLQR,
    critic_error,
    hjb_residual,
    lqr_gain,
    matrix_to_quadratic_weights,
    positive_definite_weight,
    quadratic_weights_to_matrix,
    relative_hjb_residual,
    riccati_solution,
)
from snac_gym.policies.snac import QuadraticBasis

#: Outstretched-upwards UR10: the position Jacobian loses rank (as in tests/baselines/test_rnn_svf_dls.py).
UPRIGHT = np.array([0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0])


def _spd(rng, size):
    a = rng.normal(size=(size, size))
    return a @ a.T + 0.3 * np.eye(size)


@pytest.fixture
def jacobians(ur10, rng):
    """UR10 Jacobians at random θ, away from singularities (σ_min ≥ 0.05)."""
    stack = []
    while len(stack) < 8:
        jac = ur10.jacobian(rng.uniform(-np.pi, np.pi, 6))
        if np.linalg.svd(jac, compute_uv=False)[-1] >= 0.05:
            stack.append(jac)
    return np.array(stack)


def test_riccati_solution_matches_scipy_care(jacobians, rng):
    for jac in jacobians:
        Q, R = _spd(rng, 3), _spd(rng, 6)
        expected = solve_continuous_are(np.zeros((3, 3)), jac, Q, R)
        P = riccati_solution(jac, Q, R)
        np.testing.assert_allclose(P, expected, rtol=1e-8, atol=1e-10 * np.abs(expected).max())
        np.testing.assert_allclose(P, P.T, rtol=0, atol=1e-12 * np.abs(P).max())
        assert np.linalg.eigvalsh(P).min() > 0
        # The brief's form G^{-1/2} (G^{1/2} Q G^{1/2})^{1/2} G^{-1/2}, G = J R⁻¹ Jᵀ, with SciPy's matrix roots.
        G = jac @ np.linalg.inv(R) @ jac.T
        G_half, G_inv_half = sqrtm(G).real, fractional_matrix_power(G, -0.5).real
        np.testing.assert_allclose(P, G_inv_half @ sqrtm(G_half @ Q @ G_half).real @ G_inv_half, rtol=1e-7)


def test_diagonal_weights_are_the_diagonal_matrices(jacobians):
    q, r = np.array([1.0, 2.0, 0.5]), np.array([1.0, 3.0, 0.2, 1.0, 2.0, 0.7])
    expected = solve_continuous_are(np.zeros((3, 3)), jacobians[0], np.diag(q), np.diag(r))
    np.testing.assert_allclose(riccati_solution(jacobians[0], q, r), expected, rtol=1e-8)


def test_identity_weights_give_the_inverse_square_root_of_jjt(jacobians):
    for jac in jacobians:
        np.testing.assert_allclose(riccati_solution(jac), fractional_matrix_power(jac @ jac.T, -0.5).real, rtol=1e-9)


def test_gain_is_r_inverse_jt_p_and_stabilises(jacobians, rng):
    for jac in jacobians:
        Q, R = _spd(rng, 3), _spd(rng, 6)
        P = solve_continuous_are(np.zeros((3, 3)), jac, Q, R)
        K = lqr_gain(jac, Q, R)
        np.testing.assert_allclose(K, np.linalg.solve(R, jac.T @ P), rtol=1e-7, atol=1e-9 * np.abs(K).max())
        assert np.linalg.eigvals(-jac @ K).real.max() < 0  # ė = −J K* e is stable


def test_weighted_pseudoinverse_is_the_least_effort_solution(jacobians, rng):
    for jac in jacobians[:4]:
        R = _spd(rng, 6)
        v = rng.normal(size=3)
        # KKT of min uᵀRu s.t. J u = v, solved as one (m + n) system, independent of the eigen form.
        kkt = np.block([[2 * R, jac.T], [jac, np.zeros((3, 3))]])
        least_effort = np.linalg.solve(kkt, np.concatenate([np.zeros(6), v]))[:6]
        pseudoinverse = FrozenJacobianLQR(None, R, 3, 6).weighted_pseudoinverse(jac)
        np.testing.assert_allclose(pseudoinverse @ v, least_effort, rtol=1e-8, atol=1e-12)
        unweighted = FrozenJacobianLQR(None, None, 3, 6).weighted_pseudoinverse(jac)
        np.testing.assert_allclose(unweighted, np.linalg.pinv(jac), rtol=1e-8, atol=1e-12)


def test_hjb_residual_vanishes_at_the_optimum_and_expands_by_hand(jacobians, rng):
    for jac in jacobians:
        Q, R = _spd(rng, 3), _spd(rng, 6)
        P = solve_continuous_are(np.zeros((3, 3)), jac, Q, R)
        K = np.linalg.solve(R, jac.T @ P)
        for _ in range(3):
            e = rng.normal(size=3)
            at_optimum = hjb_residual(2 * P @ e, jac, -K @ e, e, Q, R)
            assert abs(at_optimum) <= 1e-9 * (e @ Q @ e)
            grad, u = rng.normal(size=3), rng.normal(size=6)
            by_hand = sum(grad[i] * jac[i, j] * u[j] for i in range(3) for j in range(6))
            by_hand += sum(e[i] * Q[i, k] * e[k] for i in range(3) for k in range(3))
            by_hand += sum(u[j] * R[j, k] * u[k] for j in range(6) for k in range(6))
            assert hjb_residual(grad, jac, u, e, Q, R) == pytest.approx(by_hand, rel=1e-12)
            assert relative_hjb_residual(grad, jac, u, e, Q, R) == pytest.approx(by_hand / (e @ Q @ e), rel=1e-12)
        # A critic off the optimum along e leaves a residual of eᵀ(Q − P̂GP̂)e at its own greedy command.
        P_hat = 1.5 * P
        e = rng.normal(size=3)
        u_hat = -np.linalg.solve(R, jac.T @ P_hat @ e)
        G = jac @ np.linalg.solve(R, jac.T)
        assert hjb_residual(2 * P_hat @ e, jac, u_hat, e, Q, R) == pytest.approx(e @ (Q - P_hat @ G @ P_hat) @ e)


def test_compiled_factors_match_lapack_and_numpy_products(jacobians, rng):
    """The one-pass factors against the products and LAPACK's eigh they replaced, with general Q and R,
    for a stack, one J, a stack of stacks and a J that lost rank (a zero row)."""
    Q, R = _spd(rng, 3), _spd(rng, 6)
    lqr = FrozenJacobianLQR(Q, R, 3, 6)
    lost = jacobians[0].copy()
    lost[2] = 0.0
    stack = np.concatenate([jacobians, lost[None]])
    weighted = lqr.Q_half @ stack
    values, vectors = np.linalg.eigh(weighted @ lqr.R_inverse @ np.swapaxes(weighted, -1, -2))
    singular = values <= SINGULAR_TOLERANCE * values[..., -1:]
    left, got_values, right, got_singular = lqr.factors(stack)
    np.testing.assert_array_equal(got_singular, singular)
    assert got_singular[-1].tolist() == [True, False, False] and not got_singular[:-1].any()
    np.testing.assert_allclose(got_values[~singular], values[~singular], rtol=1e-12)
    assert np.isinf(got_values[singular]).all()
    expected_left = lqr.R_inverse @ np.swapaxes(weighted, -1, -2) @ vectors
    expected_right = np.swapaxes(vectors, -1, -2) @ lqr.Q_half
    for i in range(3):  # each eigenpair's A column ⊗ C row: free of the eigenvector's sign
        got = left[..., :, i, None] * right[..., None, i, :]
        expected = expected_left[..., :, i, None] * expected_right[..., None, i, :]
        np.testing.assert_allclose(got, expected, rtol=1e-10, atol=1e-12)
    one = lqr.factors(stack[3])
    nested = lqr.factors(stack[:8].reshape(2, 4, 3, 6))
    for got, whole in zip(one, (left, got_values, right, got_singular), strict=True):
        np.testing.assert_array_equal(got, whole[3])
    for got, whole in zip(nested, (left, got_values, right, got_singular), strict=True):
        np.testing.assert_array_equal(got.reshape(whole[:8].shape), whole[:8])


def test_stacks_equal_single_calls_row_for_row(jacobians, rng):
    Q, R = _spd(rng, 3), _spd(rng, 6)
    B = len(jacobians)
    errors, commands, grads = rng.normal(size=(B, 3)), rng.normal(size=(B, 6)), rng.normal(size=(B, 3))
    P_stack, K_stack = riccati_solution(jacobians, Q, R), lqr_gain(jacobians, Q, R)
    residuals = hjb_residual(grads, jacobians, commands, errors, Q, R)
    relative = relative_hjb_residual(grads, jacobians, commands, errors, Q, R)
    P_hat = P_stack + 0.1 * rng.normal(size=P_stack.shape)
    distances = critic_error(P_hat, P_stack)
    weights = matrix_to_quadratic_weights(P_hat)
    assert P_stack.shape == (B, 3, 3) and K_stack.shape == (B, 6, 3) and residuals.shape == (B,)
    for i in range(B):
        np.testing.assert_array_equal(P_stack[i], riccati_solution(jacobians[i], Q, R))
        np.testing.assert_array_equal(K_stack[i], lqr_gain(jacobians[i], Q, R))
        assert residuals[i] == hjb_residual(grads[i], jacobians[i], commands[i], errors[i], Q, R)
        assert relative[i] == relative_hjb_residual(grads[i], jacobians[i], commands[i], errors[i], Q, R)
        assert distances[i] == critic_error(P_hat[i], P_stack[i])
        np.testing.assert_array_equal(weights[i], matrix_to_quadratic_weights(P_hat[i]))
    np.testing.assert_array_equal(
        quadratic_weights_to_matrix(weights, 3)[2], quadratic_weights_to_matrix(weights[2], 3)
    )


def test_critic_error_is_the_relative_frobenius_distance():
    P = np.diag([1.0, 2.0, 2.0])
    assert critic_error(P, P) == 0.0
    assert critic_error(2 * P, P) == pytest.approx(1.0)
    P_hat = P + np.array([[0.0, 0.3, 0.0], [0.3, 0.0, 0.0], [0.0, 0.0, -0.4]])
    assert critic_error(P_hat, P) == pytest.approx(np.sqrt(0.3**2 * 2 + 0.4**2) / 3.0)


@pytest.mark.parametrize("dim", [3, 6])  # SNAC's regulation state e and tracking state ξ = [e; x_d − x_c]
def test_weight_map_matches_snac_basis(dim, rng):
    basis = QuadraticBasis(dim)
    for _ in range(5):
        weights = rng.normal(size=basis.size)
        P_hat = quadratic_weights_to_matrix(weights, dim)
        np.testing.assert_array_equal(P_hat, P_hat.T)
        for _ in range(4):
            s = rng.normal(size=dim)
            assert s @ P_hat @ s == pytest.approx(weights @ basis(s), rel=1e-12, abs=1e-12)
            # ∇V̂ = ∇σᵀŴ (what SNAC's command uses) is 2P̂s.
            np.testing.assert_allclose(basis.gradient(s).T @ weights, 2 * P_hat @ s, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(matrix_to_quadratic_weights(P_hat), weights, rtol=1e-15, atol=1e-15)
    # Any square P: the weights reproduce eᵀPe (only its symmetric part counts).
    P = rng.normal(size=(dim, dim))
    s = rng.normal(size=dim)
    assert matrix_to_quadratic_weights(P) @ basis(s) == pytest.approx(s @ P @ s, rel=1e-12)
    # SNAC's default initial critic, c on the squares, is c·I.
    identity_weights = np.where(basis.first == basis.second, 2.0, 0.0)
    np.testing.assert_array_equal(quadratic_weights_to_matrix(identity_weights, dim), 2.0 * np.eye(dim))
    with pytest.raises(ValueError, match="weights"):
        quadratic_weights_to_matrix(np.zeros(basis.size + 1), dim)


def test_singular_jacobian_no_solution_but_bounded_gain(ur10):
    jac = ur10.jacobian(UPRIGHT)
    assert np.linalg.svd(jac, compute_uv=False)[-1] < 1e-9
    with pytest.raises(ValueError, match="singular"):
        riccati_solution(jac)
    K = lqr_gain(jac, 4.0 * np.eye(3), np.eye(6))
    assert np.all(np.isfinite(K))
    assert np.linalg.norm(K, 2) <= 2.0 * (1 + 1e-9)  # ‖K*‖ = √(q/r) for scalar weights
    # Near the singularity the gain is bounded too, and tends to √(q/r) in every direction.
    near = UPRIGHT + np.array([0, 0, 1e-4, 0, 0, 0])
    singular_values = np.linalg.svd(lqr_gain(ur10.jacobian(near), 4.0 * np.eye(3)), compute_uv=False)
    np.testing.assert_allclose(singular_values, 2.0, rtol=1e-6)


@pytest.mark.parametrize(
    "matrix, message",
    [
        (np.ones((2, 2)), "matrix or a length-3 diagonal"),
        (np.array([[1.0, 0.5, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]), "symmetric"),
        (np.diag([1.0, -1.0, 1.0]), "positive definite"),
        (np.diag([1.0, 0.0, 1.0]), "positive definite"),
        (np.diag([1.0, np.nan, 1.0]), "finite"),
        ("abc", "matrix or a length-3 diagonal"),
    ],
)
def test_bad_weights_raise_clear_errors(matrix, message):
    with pytest.raises(ValueError, match=message):
        positive_definite_weight(matrix, 3, "Q")
    with pytest.raises(ValueError, match="Q"):
        riccati_solution(np.eye(3, 6), matrix)
