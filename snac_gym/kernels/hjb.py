"""The residual law of SNAC-HJB, compiled: one damped Newton step of Ŵ per episode (:mod:`snac_gym.policies.snac_hjb`).

The law is the policy's (its docstring holds the maths); this evaluates it sample by sample in
one compiled loop instead of as NumPy stacks of tiny products, which cost 40 % of the policy's
step in the evaluator. Written out, for the directions d ∈ {d₁…d_N, e/‖e‖} and P̂ from Ŵ:

* J û(d) = −G P̂ d, ω(d) = ∇σ(d) J û(d), δ(d) = ωᵀŴ + dᵀQd + dᵀP̂GP̂d, ρ = 1 + ‖ω‖²;
* Γ = Σ ω ωᵀ/ρ + ε·tr(Σ ω ωᵀ/ρ)·I, the step −α Γ⁻¹ Σ ω δ/ρ (Γ by Cholesky: it is positive definite).
"""

from __future__ import annotations

import numpy as np

from snac_gym.kernels.compiled import Example, helper, kernel, read_only
from snac_gym.kernels.lqr import factors_row


def _example() -> Example:
    """A 3-D critic, one episode: the argument types of every call."""
    first, second = np.triu_indices(3)
    return (np.ones((1, 6)), np.eye(3)[None].copy(), np.ones((1, 3)), 0.1, np.eye(3), first, second, np.eye(3), 1e-9)


@helper
def _residual_law(  # noqa: C901 - one compiled loop nest, kept inline for speed
    weights: np.ndarray,
    gram_matrices: np.ndarray,
    current: np.ndarray,
    step: float,
    directions: np.ndarray,
    first: np.ndarray,
    second: np.ndarray,
    Q: np.ndarray,
    regularisation: float,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled; tested against the NumPy law
    """Increments ``(B, size)`` of the residual law and δ at the current direction ``(B,)``.

    Args:
        weights: Ŵ, ``(B, size)``.
        gram_matrices: G = J R⁻¹ Jᵀ, ``(B, n, n)``.
        current: e/‖e‖ (0 at e = 0), ``(B, n)``.
        step: α·Δt.
        directions: The fixed excitation directions, ``(N, n)``.
        first, second: The index pair (i ≤ j) of each basis term σ_k = s_i s_j, ``(size,)``.
        Q: The error weight, ``(n, n)``.
        regularisation: ε.
    """
    count, size = weights.shape
    n = gram_matrices.shape[1]
    fixed = directions.shape[0]
    increments = np.empty((count, size))
    residuals = np.empty(count)
    P = np.empty((n, n))
    GP = np.empty((n, n))
    d = np.empty(n)
    closed = np.empty(n)
    omega = np.empty(size)
    gram = np.empty((size, size))
    gradient = np.empty(size)
    factor = np.empty((size, size))
    for b in range(count):
        for k in range(size):
            i, j = first[k], second[k]
            value = weights[b, k] if i == j else 0.5 * weights[b, k]
            P[i, j] = value
            P[j, i] = value
        for i in range(n):
            for j in range(n):
                total = 0.0
                for k in range(n):
                    total += gram_matrices[b, i, k] * P[k, j]
                GP[i, j] = total
        for i in range(size):  # loops, not slice assignments: numba compiles those slowly (a cold run's seconds)
            gradient[i] = 0.0
            for j in range(i + 1):
                gram[i, j] = 0.0
        for index in range(fixed + 1):
            for i in range(n):
                d[i] = directions[index, i] if index < fixed else current[b, i]
            for i in range(n):
                total = 0.0
                for k in range(n):
                    total += GP[i, k] * d[k]
                closed[i] = -total
            squares = 0.0
            fitted = 0.0
            for k in range(size):
                i, j = first[k], second[k]
                value = d[j] * closed[i] + d[i] * closed[j]  # ∇σ_k(d)·(J û): s_j ∂_i + s_i ∂_j (2 s_i ∂_i if i = j)
                omega[k] = value
                squares += value * value
                fitted += value * weights[b, k]
            effort = 0.0
            error_cost = 0.0
            for i in range(n):
                pd = 0.0
                qd = 0.0
                for k in range(n):
                    pd += d[k] * P[k, i]
                    qd += d[k] * Q[k, i]
                effort -= pd * closed[i]
                error_cost += qd * d[i]
            residual = fitted + error_cost + effort
            rho = 1.0 + squares
            for k in range(size):
                scaled = omega[k] / rho
                gradient[k] += omega[k] * (residual / rho)
                for m in range(k + 1):  # the lower triangle: all that the trace and the Cholesky factor read
                    gram[k, m] += omega[m] * scaled
            if index == fixed:
                residuals[b] = residual
        trace = 0.0
        for k in range(size):
            trace += gram[k, k]
        for k in range(size):
            gram[k, k] += regularisation * trace
        # Cholesky Γ = L Lᵀ, then L y = g, Lᵀ x = y.
        for j in range(size):
            total = gram[j, j]
            for k in range(j):
                total -= factor[j, k] * factor[j, k]
            diagonal = np.sqrt(total)
            factor[j, j] = diagonal
            for i in range(j + 1, size):
                total = gram[i, j]
                for k in range(j):
                    total -= factor[i, k] * factor[j, k]
                factor[i, j] = total / diagonal
        for i in range(size):
            total = gradient[i]
            for k in range(i):
                total -= factor[i, k] * omega[k]
            omega[i] = total / factor[i, i]  # omega reused as y
        for i in range(size - 1, -1, -1):
            total = omega[i]
            for k in range(i + 1, size):
                total -= factor[k, i] * increments[b, k]
            increments[b, i] = total / factor[i, i]
        for k in range(size):
            increments[b, k] = -step * increments[b, k]
    return increments, residuals


@kernel(_example)
def residual_steps(
    weights: np.ndarray,
    gram_matrices: np.ndarray,
    current: np.ndarray,
    step: float,
    directions: np.ndarray,
    first: np.ndarray,
    second: np.ndarray,
    Q: np.ndarray,
    regularisation: float,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled; tested against the NumPy law
    """Increments ``(B, size)`` of the residual law and δ at the current direction ``(B,)`` (:func:`_residual_law`)."""
    return _residual_law(weights, gram_matrices, current, step, directions, first, second, Q, regularisation)


@helper
def _certainly_above(matrix: np.ndarray, floor: float, margin: float, work: np.ndarray) -> bool:  # pragma: no cover
    """Whether the smallest eigenvalue of the symmetric ``matrix`` ``(n, n)`` is certainly ≥ ``floor``
    (:func:`snac_gym.policies.snac_hjb._certainly_above`, row by row, the same operations); ``work`` ``(n, n)``."""
    n = matrix.shape[0]
    largest = 0.0
    for i in range(n):
        for j in range(n):
            largest = max(largest, abs(matrix[i, j]))
    shift = floor + margin * largest
    for i in range(n):
        for j in range(n):
            work[i, j] = matrix[i, j] - shift * (1.0 if i == j else 0.0)
    for k in range(n):
        pivot = work[k, k]
        if not pivot > 0.0:
            return False
        for i in range(k + 1, n):
            column = work[i, k] / pivot
            for j in range(k + 1, n):
                work[i, j] -= column * work[k, j]
    return True


@helper
def _weights_to_matrix(
    weights: np.ndarray, first: np.ndarray, second: np.ndarray, out: np.ndarray
) -> None:  # pragma: no cover - compiled
    """``out`` ← P̂ of the quadratic weights ``(size,)`` (``quadratic_weights_to_matrix`` of
    :mod:`snac_gym.control.optimality`)."""
    for k in range(weights.shape[0]):
        i, j = first[k], second[k]
        value = weights[k] if i == j else 0.5 * weights[k]
        out[i, j] = value
        out[j, i] = value


@kernel(lambda: (np.ones((1, 6)), *np.triu_indices(3), 0.1, 1e-9))
def certainly_above(
    weights: np.ndarray, first: np.ndarray, second: np.ndarray, floor: float, margin: float
) -> np.ndarray:  # pragma: no cover - compiled; tested against the NumPy test
    """Rows of ``weights`` ``(B, size)`` whose P̂ certainly has no eigenvalue below ``floor`` ``(B,)``."""
    count = weights.shape[0]
    n = max(first.max(), second.max()) + 1 if first.shape[0] else 0
    matrix = np.zeros((n, n))
    work = np.empty((n, n))
    out = np.empty(count, dtype=np.bool_)
    for b in range(count):
        _weights_to_matrix(weights[b], first, second, matrix)
        out[b] = _certainly_above(matrix, floor, margin, work)
    return out


def _step_example() -> Example:
    """A 3-D critic of a 6-joint arm, one episode, tracking: the argument types of every call (the
    Jacobians and the limits read-only, as the kinematics and the envs hold them)."""
    first, second = np.triu_indices(3)
    return (
        read_only(np.ones((1, 3, 6))), np.ones((1, 3)), np.ones((1, 3)), np.ones((1, 6)), np.eye(6), np.eye(3),
        np.eye(3), first, second, 0.4, 1e-9, 0.8, read_only(np.ones(6)), True, np.eye(3), 1e-12, 0.1, 1e-9,
    )  # fmt: skip


@kernel(_step_example)
def policy_steps(  # noqa: C901, PLR0913 - one compiled pass over the episodes
    jacobians: np.ndarray,
    errors: np.ndarray,
    velocities: np.ndarray,
    weights: np.ndarray,
    r_inverse: np.ndarray,
    Q: np.ndarray,
    directions: np.ndarray,
    first: np.ndarray,
    second: np.ndarray,
    step: float,
    regularisation: float,
    stabilising: float,
    velocity_limits: np.ndarray,
    tracking: bool,
    q_half: np.ndarray,
    tolerance: float,
    floor: float,
    margin: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled; tested against NumPy
    """One control period of SNAC-HJB for each of B episodes (:meth:`snac_gym.policies.snac_hjb.SNACHJBPolicy._step`).

    With G = J R⁻¹ Jᵀ and P̂ from Ŵ: the command ``sat(−R⁻¹JᵀP̂e [+ J⁺_R ẋ_d])`` (eq. 15, scaled into the limits),
    the residual law's step at G and e/‖e‖ (``step`` = α·Δt) plus, where ``eᵀJ u_fb > 0``, the eq. 19 term
    ``stabilising·∇σ(e)ᵀ G e``, and whether each updated P̂ is certainly above ``floor`` (else the caller projects it).

    Args:
        jacobians: J, ``(B, n, m)``.
        errors, velocities: e and ẋ_d, ``(B, n)``.
        weights: Ŵ that gives the command, ``(B, size)``.
        r_inverse, Q, q_half: R⁻¹, Q and Q^{1/2} (the weighted pseudo-inverse's factors, as the LQR's).
        tracking: Whether to add the feed-forward J⁺_R ẋ_d.
        tolerance: The LQR's singular tolerance (J⁺_R drops a lost direction).

    Returns:
        The commands ``(B, m)``, the updated Ŵ ``(B, size)``, whether each is certainly above the floor ``(B,)``,
        and δ(e) at e ``(B,)``.
    """
    count, n, m = jacobians.shape
    size = weights.shape[1]
    commands = np.empty((count, m))
    gram_matrices = np.empty((count, n, n))
    current = np.empty((count, n))
    norms = np.empty(count)
    unstable = np.empty(count, dtype=np.bool_)
    rjt = np.empty((m, n))
    P = np.zeros((n, n))
    pe = np.empty(n)
    feedback = np.empty(m)
    y = np.empty(n)
    g, rg, a, v, w = np.empty((n, m)), np.empty((m, n)), np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    diagonal, order = np.empty(n), np.empty(n, dtype=np.int64)
    left, values, right = np.empty((m, n)), np.empty(n), np.empty((n, n))
    singular = np.empty(n, dtype=np.bool_)
    for b in range(count):
        jacobian = jacobians[b]
        for i in range(m):
            for j in range(n):
                total = 0.0
                for k in range(m):
                    total += r_inverse[i, k] * jacobian[j, k]
                rjt[i, j] = total
        for i in range(n):
            for j in range(n):
                total = 0.0
                for k in range(m):
                    total += jacobian[i, k] * rjt[k, j]
                gram_matrices[b, i, j] = total
        squares = 0.0
        for i in range(n):
            squares += errors[b, i] * errors[b, i]
        norm = np.sqrt(squares)
        norms[b] = norm
        for i in range(n):
            current[b, i] = errors[b, i] / norm if norm > 0.0 else 0.0
        _weights_to_matrix(weights[b], first, second, P)
        for i in range(n):
            total = 0.0
            for j in range(n):
                total += P[i, j] * errors[b, j]
            pe[i] = total
        for i in range(m):
            total = 0.0
            for j in range(n):
                total += rjt[i, j] * pe[j]
            feedback[i] = -total
            commands[b, i] = -total
        if tracking:  # J⁺_R ẋ_d = A diag(λ⁻¹) C ẋ_d: ė = J u_fb, the regulation problem
            factors_row(
                jacobian, q_half, r_inverse, tolerance, g, rg, a, v, w, diagonal, order, left, values, right, singular
            )
            for i in range(n):
                total = 0.0
                for k in range(n):
                    total += right[i, k] * velocities[b, k]
                y[i] = total / values[i]  # 0 along a lost direction (λ = +inf)
            for i in range(m):
                total = 0.0
                for k in range(n):
                    total += left[i, k] * y[k]
                commands[b, i] += total
        scale = 0.0  # into the limits, the direction kept (snac_gym.policies.base.scale_rows_into_limits)
        for i in range(m):
            scale = max(scale, abs(commands[b, i]) / velocity_limits[i])
        scale = max(scale, 1.0)
        for i in range(m):
            commands[b, i] = min(max(commands[b, i] / scale, -velocity_limits[i]), velocity_limits[i])
        rate = 0.0  # eᵀ J u_fb
        for i in range(n):
            total = 0.0
            for k in range(m):
                total += jacobian[i, k] * feedback[k]
            rate += errors[b, i] * total
        unstable[b] = rate > 0.0
    increments, residuals = _residual_law(
        weights, gram_matrices, current, step, directions, first, second, Q, regularisation
    )
    updated = np.empty((count, size))
    certain = np.empty(count, dtype=np.bool_)
    ge = np.empty(n)
    for b in range(count):
        if unstable[b]:  # eq. 19 while the feedback does not decrease J_s = ½eᵀe: ∇σ(e)ᵀ G e
            for i in range(n):
                total = 0.0
                for k in range(n):
                    total += gram_matrices[b, i, k] * errors[b, k]
                ge[i] = total
            for k in range(size):
                i, j = first[k], second[k]
                increments[b, k] += stabilising * (errors[b, j] * ge[i] + errors[b, i] * ge[j])
        for k in range(size):
            updated[b, k] = weights[b, k] + increments[b, k]
        _weights_to_matrix(updated[b], first, second, P)
        certain[b] = _certainly_above(P, floor, margin, a)
        residuals[b] *= norms[b] * norms[b]
    return commands, updated, certain, residuals
