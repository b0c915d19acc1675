"""snac-hjb: the critic law against an independent Kleinman step (scipy's Lyapunov
solver), convergence to the ARE's P*, the projection, and the reach demo's critic error."""

import numpy as np
import pytest
from scipy.linalg import solve_continuous_are, solve_continuous_lyapunov

from snac_gym.control.optimality import matrix_to_quadratic_weights, quadratic_weights_to_matrix
from snac_gym.observation import ObservationLayout
from snac_gym.policies import available_policies, make_policy
from snac_gym.policies.base import PolicyContext, scale_rows_into_limits
from snac_gym.policies.snac_hjb import SNACHJBPolicy, _certainly_above

DT = 1.0 / 125.0


def _context(kinematics, task="reach"):
    layout = ObservationLayout(kinematics.n_joints, kinematics.task_dim)
    return PolicyContext(kinematics, DT, np.full(kinematics.n_joints, 1e9), layout, task)


def _spd(rng, size):
    a = rng.normal(size=(size, size))
    return a @ a.T + size * np.eye(size)


def _obs(context, q, e, xdot_d=np.zeros(3)):
    x = context.kinematics.forward(q)
    return context.layout.pack(q, np.zeros(len(q)), x, x - e, xdot_d, x - e)


def test_registered_with_an_effort_knob():
    assert "snac-hjb" in available_policies()
    assert SNACHJBPolicy.effort_parameter == "q_scale"


@pytest.mark.parametrize("task", ["reach", "track"])
def test_command_is_eq_15_from_the_critic_plus_the_feed_forward(ur10, rng, task):
    context = _context(ur10, task)
    R = _spd(rng, 6)
    policy = SNACHJBPolicy(context, R=R, q_scale=2.0, warm_start_iterations=0)
    policy.reset(seed=4)
    q, e, xdot_d = rng.uniform(-2, 2, 6), rng.normal(scale=0.1, size=3), rng.normal(scale=0.05, size=3)
    P = quadratic_weights_to_matrix(policy.critic_weights, 3)
    jac = ur10.jacobian(q)
    r_inv = np.linalg.inv(R)
    expected = -r_inv @ jac.T @ P @ e  # −½R⁻¹Jᵀ∇V̂ with ∇V̂ = 2P̂e
    if task == "track":
        expected += r_inv @ jac.T @ np.linalg.solve(jac @ r_inv @ jac.T, xdot_d)  # J⁺_R ẋ_d
    np.testing.assert_allclose(policy.act(_obs(context, q, e, xdot_d)), expected, rtol=1e-9, atol=1e-12)


def test_one_full_step_is_kleinmans_newton_step(ur10, rng):
    """α·Δt = 1 at e = 0 (only the fixed directions): P̂⁺ solves P⁺A + AᵀP⁺ + Q + P̂GP̂ = 0, A = −GP̂."""
    context = _context(ur10)
    Q = _spd(rng, 3)
    policy = SNACHJBPolicy(context, Q=Q, learning_rate=1.0 / DT, regularisation=1e-14, warm_start_iterations=0)
    policy.reset(seed=1)
    P = quadratic_weights_to_matrix(policy.critic_weights, 3)
    q = rng.uniform(-2, 2, 6)
    jac = ur10.jacobian(q)
    G = jac @ jac.T
    A = -G @ P
    expected = solve_continuous_lyapunov(A.T, -(Q + P @ G @ P))
    policy.act(_obs(context, q, np.zeros(3)))
    np.testing.assert_allclose(quadratic_weights_to_matrix(policy.critic_weights, 3), expected, rtol=1e-6)


def test_the_critic_converges_to_the_are_solution_at_a_fixed_pose(ur10, rng):
    context = _context(ur10)
    Q, R = _spd(rng, 3), _spd(rng, 6)
    policy = SNACHJBPolicy(context, Q=Q, R=R, learning_rate=60.0, warm_start_iterations=0)
    policy.reset(seed=8)
    q = rng.uniform(-2, 2, 6)
    for _ in range(200):
        policy.act(_obs(context, q, np.zeros(3)))
    expected = solve_continuous_are(np.zeros((3, 3)), ur10.jacobian(q), Q, R)
    np.testing.assert_allclose(quadratic_weights_to_matrix(policy.critic_weights, 3), expected, rtol=1e-8)
    out = policy.critic_diagnostics(q[None], rng.normal(size=(1, 3)), None, None, None, policy.critic_weights[None])
    assert out["critic_error"][0] < 1e-8 and abs(out["hjb_ratio"][0]) < 1e-8


@pytest.mark.parametrize("task", ["reach", "track"])
def test_the_warm_start_converges_before_the_first_command(ur10, rng, task):
    """With warm_start_iterations, the first command is already the LQR's: u = J⁺_R ẋ_d − R⁻¹JᵀP*e."""
    context = _context(ur10, task)
    Q, R = _spd(rng, 3), _spd(rng, 6)
    policy = SNACHJBPolicy(context, Q=Q, R=R, q_scale=30.0)
    policy.reset(seed=2)
    q, e, xdot_d = rng.uniform(-2, 2, 6), rng.normal(scale=0.1, size=3), rng.normal(scale=0.05, size=3)
    jac = ur10.jacobian(q)
    P = solve_continuous_are(np.zeros((3, 3)), jac, 30.0 * Q, R)
    r_inv = np.linalg.inv(R)
    expected = -r_inv @ jac.T @ P @ e
    if task == "track":
        expected += r_inv @ jac.T @ np.linalg.solve(jac @ r_inv @ jac.T, xdot_d)
    np.testing.assert_allclose(policy.act(_obs(context, q, e, xdot_d)), expected, rtol=1e-8)
    # the same episode in the batch protocol
    policy.reset_batch([2])
    np.testing.assert_allclose(policy.act_batch(_obs(context, q, e, xdot_d)[None])[0], expected, rtol=1e-8)


def test_weights_are_projected_onto_positive_definite_critics(ur10):
    context = _context(ur10)
    policy = SNACHJBPolicy(context, initial_weight_range=(-1.0, 1.0), min_eigenvalue=0.2)
    for seed in range(20):
        policy.reset(seed=seed)
        assert np.linalg.eigvalsh(quadratic_weights_to_matrix(policy.critic_weights, 3)).min() >= 0.2 - 1e-12
    # a critic already above the floor is left exactly as it is
    weights = matrix_to_quadratic_weights(np.diag([1.0, 2.0, 3.0]))
    np.testing.assert_array_equal(policy._project(weights[None])[0], weights)


@pytest.mark.parametrize("weight_range", [(0.0, 1.0), (-1.0, 1.0)])
def test_a_batch_reset_gives_each_episode_the_weights_of_its_own_reset(ur10, weight_range):
    """reset_batch projects all draws at once; each row must be the single reset's, bit for bit,
    whether the row needed the projection or not (with (-1, 1) most draws are indefinite)."""

    def fresh() -> SNACHJBPolicy:
        return SNACHJBPolicy(_context(ur10), initial_weight_range=weight_range, min_eigenvalue=0.2)

    policy, seeds = fresh(), [*range(40), 7]
    policy.reset_batch(seeds)
    batch = policy.batch_critic_weights.copy()
    rows = []
    for seed in seeds:  # each as the reset of a fresh policy
        single = fresh()
        single.reset(seed=seed)
        rows.append(single.critic_weights)
    assert batch.tobytes() == np.array(rows).tobytes()
    draws = np.array([np.random.default_rng(seed).uniform(*weight_range, size=policy.basis.size) for seed in range(40)])
    projected = ~np.all(batch[:40] == draws, axis=1)
    assert projected.any() and (weight_range[0] < 0 or not projected.all())  # both kinds of row were checked


def test_reach_demo_critic_error_is_under_5_percent_at_the_end():
    from snac_gym.apps.demo import run_demo

    result = run_demo("reach", "snac-hjb", None, seed=0)
    assert result.metrics.critic_error_final <= 0.05  # 1.3e-6 measured
    assert result.metrics.final_error <= 1e-3
    assert result.metrics.descent_fraction_above_tolerance == 1.0


def test_bad_arguments_are_refused(ur10):
    context = _context(ur10)
    with pytest.raises(ValueError, match="learning_rate must be at most"):
        SNACHJBPolicy(context, learning_rate=1000.0)
    with pytest.raises(ValueError, match="q_scale"):
        SNACHJBPolicy(context, q_scale=-1.0)
    with pytest.raises(ValueError, match="warm_start_iterations"):
        SNACHJBPolicy(context, warm_start_iterations=-1)
    with pytest.raises(ValueError, match="initial_weight_range"):
        SNACHJBPolicy(context, initial_weight_range=(1.0, 0.0))
    with pytest.raises(RuntimeError, match="reset"):
        make_policy("snac-hjb", context).act(np.zeros(context.layout.size))


def test_diagnostics_residual_is_the_are_residual_of_the_critic(ur10, rng):
    """For V̂ = eᵀP̂e and its own command, eq. 9's residual is eᵀ(Q − P̂GP̂)e, G = JR⁻¹Jᵀ (by hand)."""
    context = _context(ur10)
    Q, R = _spd(rng, 3), _spd(rng, 6)
    policy = SNACHJBPolicy(context, Q=Q, R=R)
    q, e = rng.uniform(-2, 2, (4, 6)), rng.normal(scale=0.1, size=(4, 3))
    weights = rng.uniform(0.5, 2.0, (4, 6))
    out = policy.critic_diagnostics(q, e, None, None, None, weights)
    for k in range(4):
        P = quadratic_weights_to_matrix(weights[k], 3)
        jac = ur10.jacobian(q[k])
        G = jac @ np.linalg.inv(R) @ jac.T
        expected = e[k] @ (Q - P @ G @ P) @ e[k]
        assert out["hjb_residual"][k] == pytest.approx(expected, rel=1e-9)
        assert out["hjb_ratio"][k] == pytest.approx(expected / (e[k] @ Q @ e[k]), rel=1e-9)
        star = solve_continuous_are(np.zeros((3, 3)), jac, Q, R)
        assert out["critic_error"][k] == pytest.approx(np.linalg.norm(P - star) / np.linalg.norm(star), rel=1e-7)


@pytest.mark.parametrize("task", ["reach", "track"])
def test_a_command_beyond_the_limits_is_scaled_as_lqr_scales_it(ur10, rng, task):
    """The same saturation as lqr: the whole command divided by its largest |u_j|/ū_j, direction kept."""
    from snac_gym.policies.base import scale_rows_into_limits

    limits = np.array([2.16, 2.16, 3.15, 3.2, 3.2, 3.2])
    layout = ObservationLayout(ur10.n_joints, ur10.task_dim)
    free = PolicyContext(ur10, DT, np.full(6, 1e9), layout, task)
    bounded = PolicyContext(ur10, DT, limits, layout, task)
    q, e, xdot_d = rng.uniform(-2, 2, 6), np.array([0.5, -0.5, 0.3]), np.array([0.2, 0.1, -0.1])
    commands = []
    for context in (free, bounded):
        policy = SNACHJBPolicy(context, q_scale=400.0)
        policy.reset(seed=3)
        commands.append(policy.act(_obs(context, q, e, xdot_d)))
    unsaturated, saturated = commands
    scale = np.max(np.abs(unsaturated) / limits)
    assert scale > 1.5  # well beyond the limits: clipping each joint would turn it
    np.testing.assert_allclose(saturated, unsaturated / scale, rtol=1e-12)
    assert np.max(np.abs(saturated) / limits) == pytest.approx(1.0)
    np.testing.assert_array_equal(saturated, scale_rows_into_limits(unsaturated[None], limits)[0])


def _numpy_residual_step(policy, weights, gram_matrix, current, step):
    """The residual law as NumPy stacks (the policy's implementation before it was compiled)."""
    count = len(weights)
    P = quadratic_weights_to_matrix(weights, policy.task_dim)
    directions = np.concatenate(
        (np.broadcast_to(policy.directions, (count, *policy.directions.shape)), current[:, None]), axis=1
    )
    fixed_gradients = policy.basis.gradient(policy.directions)
    gradients = np.concatenate(
        (np.broadcast_to(fixed_gradients, (count, *fixed_gradients.shape)), policy.basis.gradient(current)[:, None]),
        axis=1,
    )
    closed_loop = -np.einsum("bij,bjk,bdk->bdi", gram_matrix, P, directions)
    omega = np.einsum("bdkn,bdn->bdk", gradients, closed_loop)
    effort = -np.einsum("bdi,bij,bdj->bd", directions, P, closed_loop)
    error_cost = np.einsum("bdi,ij,bdj->bd", directions, policy.Q, directions)
    residual = np.einsum("bdk,bk->bd", omega, weights) + error_cost + effort
    rho = 1.0 + np.sum(omega * omega, axis=-1)
    gram = np.einsum("bdk,bdl->bkl", omega, omega / rho[..., None])
    gram += (policy.regularisation * np.trace(gram, axis1=1, axis2=2))[:, None, None] * np.eye(policy.basis.size)
    gradient = np.einsum("bdk,bd->bk", omega, residual / rho)
    return -step * np.linalg.solve(gram, gradient[..., None])[..., 0], residual[:, -1]


def _policy_of_dim(kinematics, rng, task_dim):
    """A policy with a critic of ``task_dim`` (6: pose-sized; the law does not depend on the arm, only on n)."""
    policy = SNACHJBPolicy(_context(kinematics), q_scale=3.0, Q=np.diag(rng.uniform(0.5, 2.0, 3)))
    if task_dim == 6:
        from snac_gym.policies.snac import QuadraticBasis
        from snac_gym.policies.snac_hjb import _excitation_directions

        policy.task_dim, policy.basis, policy.directions = 6, QuadraticBasis(6), _excitation_directions(6)
        policy.Q = _spd(rng, 6)
    return policy


@pytest.mark.parametrize("task_dim", [3, 6])
def test_the_compiled_residual_law_is_the_numpy_one(ur10, rng, task_dim):
    policy = _policy_of_dim(ur10, rng, task_dim)
    n, size = policy.task_dim, policy.basis.size
    count = 40
    jacobians = rng.normal(size=(count, n, 6))
    gram_matrix = jacobians @ jacobians.transpose(0, 2, 1)  # R = I
    weights = matrix_to_quadratic_weights(np.array([_spd(rng, n) for _ in range(count)]))
    current = rng.normal(size=(count, n))
    current /= np.linalg.norm(current, axis=1, keepdims=True)
    current[0] = 0.0  # e = 0: the current direction is the zero vector
    _, increments, residual, *_ = policy._periods(jacobians, current, np.zeros_like(current), weights, None, 0.4, 0.0)
    expected_increments, expected_residual = _numpy_residual_step(policy, weights, gram_matrix, current, 0.4)
    assert increments.shape == (count, size)
    np.testing.assert_allclose(residual, expected_residual, rtol=1e-11, atol=1e-11)
    # Γ's condition number (up to ~1e8 for these random 21-term critics) sets how far two backward-stable
    # solves (Cholesky here, LU in NumPy) may differ: norm-wise, per row.
    difference = np.linalg.norm(increments - expected_increments, axis=1) / np.linalg.norm(expected_increments, axis=1)
    assert difference.max() < (1e-10 if task_dim == 3 else 1e-6)


@pytest.mark.parametrize("dim", [3, 6])
def test_the_compiled_certificate_is_the_numpy_one_and_never_clears_a_critic_below_the_floor(ur10, rng, dim):
    """The period's certificate of Ŵ + increment, with a zero step (the increment ±0: Ŵ itself), against the NumPy
    one a draw's projection uses, on critics a hair either side of the floor."""
    policy = _policy_of_dim(ur10, rng, dim)
    floor = policy.min_eigenvalue
    vectors = np.linalg.qr(rng.normal(size=(3000, dim, dim)))[0]
    # eigenvalues around the floor: far below, a hair either side (inside the margin), far above
    values = floor + rng.choice([-1.0, -1e-12, 0.0, 1e-12, 1e-6, 1.0], size=(3000, dim)) * rng.uniform(
        0.5, 2, (3000, 1)
    )
    matrices = (vectors * values[:, None, :]) @ np.swapaxes(vectors, 1, 2)
    weights = matrix_to_quadratic_weights(matrices)
    expected = _certainly_above(quadratic_weights_to_matrix(weights, dim), floor)
    errors = rng.normal(size=(3000, dim))
    *_, updated, found = policy._periods(rng.normal(size=(3000, dim, 6)), errors, errors, weights, None, 0.0, 0.0)
    np.testing.assert_array_equal(updated, weights)
    np.testing.assert_array_equal(found, expected)
    assert 0 < found.sum() < len(found)  # both answers were given
    assert np.linalg.eigvalsh(quadratic_weights_to_matrix(weights[found], dim)).min() >= floor


def _numpy_step(policy, obs, weights):
    """One period of the policy as NumPy stacks (before it was compiled): commands, updated weights, δ(e)·‖e‖²."""
    errors, velocities = obs[:, policy._e], obs[:, policy._xdot_d]
    jacobians = policy._jacobians(obs)
    r_inverse_jt = policy.R_inverse @ np.swapaxes(jacobians, -1, -2)
    gram_matrix = jacobians @ r_inverse_jt
    norms = np.linalg.norm(errors, axis=1, keepdims=True)
    current = np.divide(errors, norms, out=np.zeros_like(errors), where=norms > 0)
    P = quadratic_weights_to_matrix(weights, policy.task_dim)
    feedback = -(r_inverse_jt @ (P @ errors[..., None]))[..., 0]
    command = feedback
    if policy.tracking:
        command = feedback + (policy.lqr.weighted_pseudoinverse(jacobians) @ velocities[..., None])[..., 0]
    command = scale_rows_into_limits(command, policy.velocity_limits)
    increment, residual = _numpy_residual_step(policy, weights, gram_matrix, current, policy.learning_rate * policy.dt)
    error_rate = (jacobians @ feedback[..., None])[..., 0]
    unstable = np.einsum("bi,bi->b", errors, error_rate) > 0
    descent = np.einsum("bkn,bn->bk", policy.basis.gradient(errors), (gram_matrix @ errors[..., None])[..., 0])
    increment += (policy.stabilising_rate * policy.dt) * unstable[:, None] * descent
    return command, weights + increment, residual * norms[:, 0] ** 2, unstable


@pytest.mark.parametrize("task", ["reach", "track"])
def test_the_compiled_period_is_the_numpy_one(ur10, rng, task):
    """Command, update (the stabilising term where eᵀJu_fb > 0 included) and residual of the compiled period
    against the NumPy law, with R ≠ I, tight velocity limits (rows scaled into them), critics that destabilise
    (negative weights: eq. 19 active) and an e = 0 row."""
    context = _context(ur10, task)
    context = PolicyContext(ur10, DT, np.full(6, 0.3), context.layout, task)
    policy = SNACHJBPolicy(context, q_scale=3.0, R=np.diag(rng.uniform(0.5, 2.0, 6)), learning_rate=60.0)
    count = 200
    qs = rng.uniform(-2.5, 2.5, size=(count, 6))
    obs = np.array([_obs(context, q, rng.normal(scale=0.2, size=3), rng.normal(scale=0.3, size=3)) for q in qs])
    obs[0] = _obs(context, qs[0], np.zeros(3), np.zeros(3))
    weights = rng.uniform(-1.0, 2.0, size=(count, policy.basis.size))
    command, used, updated, residual = policy._step(obs, weights, first=False)
    expected_command, expected_updated, expected_residual, unstable = _numpy_step(policy, obs, weights)
    assert 0 < unstable.sum() < count  # both kinds of row
    peaks = np.max(np.abs(expected_command) / 0.3, axis=1)
    assert np.any(peaks == 1.0) and np.any((peaks > 0) & (peaks < 0.99))  # rows scaled into the limits, and not
    np.testing.assert_array_equal(used, weights)
    np.testing.assert_allclose(command, expected_command, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(residual, expected_residual, rtol=1e-9, atol=1e-12)
    expected = policy._project(expected_updated)
    # Γ's conditioning (these critics are far from converged) sets how far two backward-stable solves (Cholesky,
    # LU) may differ: norm-wise, per row (up to 7e-9 measured); a term left out or of the wrong sign moves rows by
    # far more (the stabilising term alone: 0.8·∇σ(e)ᵀGe)
    difference = np.linalg.norm(updated - expected, axis=1) / np.linalg.norm(expected, axis=1)
    assert difference.max() < 1e-7
