"""The residual law of SNAC-HJB, compiled: one damped Newton step of Ŵ per episode (:mod:`snac_gym.policies.snac_hjb`).

The law is the policy's (its docstring holds the maths); this evaluates it sample by sample in
one compiled loop instead of as NumPy stacks of tiny products, which cost 40 % of the policy's
step in the evaluator. Written out, for the directions d ∈ {d₁…d_N, e/‖e‖} and P̂ from Ŵ:

* J û(d) = −G P̂ d, ω(d) = ∇σ(d) J û(d), δ(d) = ωᵀŴ + dᵀQd + dᵀP̂GP̂d, ρ = 1 + ‖ω‖²;
* Γ = Σ ω ωᵀ/ρ + ε·tr(Σ ω ωᵀ/ρ)·I, the step −α Γ⁻¹ Σ ω δ/ρ (Γ by Cholesky: it is positive definite).
"""

from __future__ import annotations

import numpy as np

from snac_gym.kernels.compiled import Example, kernel


def _example() -> Example:
    """A 3-D critic, one episode: the argument types of every call."""
    first, second = np.triu_indices(3)
    return (np.ones((1, 6)), np.eye(3)[None].copy(), np.ones((1, 3)), 0.1, np.eye(3), first, second, np.eye(3), 1e-9)


@kernel(_example)
def residual_steps(  # noqa: C901 - one compiled loop nest, kept inline for speed
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
            for j in range(size):
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
                for m in range(size):
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
