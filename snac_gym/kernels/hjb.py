"""SNAC-HJB's period, compiled: the command and one damped Newton step of Ŵ per episode.

The law is the policy's, :mod:`snac_gym.policies.snac_hjb` (its docstring holds the maths); this evaluates it
sample by sample in compiled loops instead of as NumPy stacks of tiny products, which cost most of the policy's step
in the evaluator. Written out, for the directions d ∈ {d₁…d_N, e/‖e‖} and P̂ from Ŵ:

* J û(d) = −G P̂ d, ω(d) = ∇σ(d) J û(d), δ(d) = ωᵀŴ + dᵀQd + dᵀP̂GP̂d, ρ = 1 + ‖ω‖²;
* Γ = Σ ω ωᵀ/ρ + ε·tr(Σ ω ωᵀ/ρ)·I, the step −α Γ⁻¹ Σ ω δ/ρ (Γ by Cholesky: it is positive definite).

One kernel, with nothing it calls: each compiled function, and each helper linked into one, is seconds of a cold
run's compiles; the LQR's factors (for the tracking feed-forward) come from the caller, already compiled.
"""

from __future__ import annotations

import numpy as np

from snac_gym.kernels.compiled import Example, kernel, read_only


def _example() -> Example:
    """A 3-D critic of a 6-joint arm, one episode, tracking: the argument types of every call (the Jacobians and
    the limits read-only, as the kinematics and the envs hold them)."""
    first, second = np.triu_indices(3)
    return (
        read_only(np.ones((1, 3, 6))), np.ones((1, 3)), np.ones((1, 3)), np.ones((1, 6)), np.eye(6),
        np.ones((1, 6, 3)), np.ones((1, 3)), np.ones((1, 3, 3)), read_only(np.ones(6)), True, 0.4, 0.8, np.eye(3),
        first, second, np.eye(3), 1e-9, 0.1, 1e-9,
    )  # fmt: skip


@kernel(_example)
def periods(  # noqa: C901, PLR0912, PLR0915 - one compiled pass over the episodes, kept inline for speed
    jacobians: np.ndarray,
    errors: np.ndarray,
    velocities: np.ndarray,
    weights: np.ndarray,
    r_inverse: np.ndarray,
    left: np.ndarray,
    values: np.ndarray,
    right: np.ndarray,
    velocity_limits: np.ndarray,
    tracking: bool,
    step: float,
    stabilising: float,
    directions: np.ndarray,
    first: np.ndarray,
    second: np.ndarray,
    Q: np.ndarray,
    regularisation: float,
    floor: float,
    margin: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """One period of each of B episodes (``SNACHJBPolicy._step``): the command, the residual law's step with eq. 19's
    term, and the updated Ŵ's certificate.

    With G = J R⁻¹ Jᵀ and P̂ from Ŵ: the command ``sat(−R⁻¹JᵀP̂e [+ J⁺_R ẋ_d])`` (eq. 15, scaled into the limits;
    ``J⁺_R = A diag(λ⁻¹) C`` from the LQR's factors ``left``, ``values``, ``right`` of each J, read where
    ``tracking``); the law's step ``−step·Γ⁻¹ Σ ω δ/ρ`` at the directions and e/‖e‖; ``stabilising·∇σ(e)ᵀ G e``
    added where ``eᵀ J u_fb > 0`` (the feedback does not decrease J_s = ½eᵀe; eq. 19).

    Args:
        jacobians: J, ``(B, n, m)``.
        errors, velocities: e and ẋ_d, ``(B, n)``.
        weights: Ŵ that gives the command, ``(B, size)``.
        r_inverse, Q: R⁻¹ and the error weight.
        step, stabilising: α·Δt and α_s·Δt.
        directions: The fixed excitation directions, ``(N, n)``.
        first, second: The index pair (i ≤ j) of each basis term σ_k = s_i s_j, ``(size,)``.
        regularisation: ε of Γ.
        floor, margin: The projection's λ_floor and the certificate's relative margin.

    Returns:
        The commands ``(B, m)``, the increments ``(B, size)``, δ at e/‖e‖ ``(B,)``, ‖e‖ ``(B,)``, Ŵ + increment
        ``(B, size)`` and whether each is certainly above the floor ``(B,)`` (else the caller projects it).
    """
    count, n, m = jacobians.shape
    size = weights.shape[1]
    fixed = directions.shape[0]
    commands = np.empty((count, m))
    increments = np.empty((count, size))
    residuals = np.empty(count)
    norms = np.empty(count)
    updated = np.empty((count, size))
    certain = np.empty(count, dtype=np.bool_)
    rjt = np.empty((m, n))
    G = np.empty((n, n))
    current = np.empty(n)
    pe = np.empty(n)
    feedback = np.empty(m)
    y = np.empty(n)
    P = np.zeros((n, n))
    GP = np.empty((n, n))
    d = np.empty(n)
    closed = np.empty(n)
    omega = np.empty(size)
    gram = np.empty((size, size))
    gradient = np.empty(size)
    factor = np.empty((size, size))
    for b in range(count):
        for i in range(m):
            for j in range(n):
                total = 0.0
                for k in range(m):
                    total += r_inverse[i, k] * jacobians[b, j, k]
                rjt[i, j] = total
        for i in range(n):
            for j in range(n):
                total = 0.0
                for k in range(m):
                    total += jacobians[b, i, k] * rjt[k, j]
                G[i, j] = total
        squares = 0.0
        for i in range(n):
            squares += errors[b, i] * errors[b, i]
        norm = np.sqrt(squares)
        norms[b] = norm
        for i in range(n):
            current[i] = errors[b, i] / norm if norm > 0.0 else 0.0
        for k in range(size):  # P̂ of Ŵ: a cross term s_i s_j is split over P_ij and P_ji
            i, j = first[k], second[k]
            value = weights[b, k] if i == j else 0.5 * weights[b, k]
            P[i, j] = value
            P[j, i] = value
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
            for i in range(n):
                total = 0.0
                for k in range(n):
                    total += right[b, i, k] * velocities[b, k]
                y[i] = total / values[b, i]  # 0 along a lost direction (λ = +inf)
            for i in range(m):
                total = 0.0
                for k in range(n):
                    total += left[b, i, k] * y[k]
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
                total += jacobians[b, i, k] * feedback[k]
            rate += errors[b, i] * total
        unstable = rate > 0.0
        for i in range(n):
            for j in range(n):
                total = 0.0
                for k in range(n):
                    total += G[i, k] * P[k, j]
                GP[i, j] = total
        for i in range(size):  # loops, not slice assignments: numba compiles those slowly (a cold run's seconds)
            gradient[i] = 0.0
            for j in range(i + 1):
                gram[i, j] = 0.0
        for index in range(fixed + 1):
            for i in range(n):
                d[i] = directions[index, i] if index < fixed else current[i]
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
                for c in range(k + 1):  # the lower triangle: all that the trace and the Cholesky factor read
                    gram[k, c] += omega[c] * scaled
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
        if unstable:  # eq. 19 while the feedback does not decrease J_s = ½eᵀe: ∇σ(e)ᵀ G e
            for i in range(n):
                total = 0.0
                for k in range(n):
                    total += G[i, k] * errors[b, k]
                closed[i] = total  # closed reused as G e
            for k in range(size):
                i, j = first[k], second[k]
                increments[b, k] += stabilising * (errors[b, j] * closed[i] + errors[b, i] * closed[j])
        for k in range(size):
            updated[b, k] = weights[b, k] + increments[b, k]
        # The certificate of the updated P̂: Cholesky (LDLᵀ pivots) of P̂ − t I, t = floor + margin·max|P̂|. All pivots
        # positive means P̂ − t I + E is positive definite for a backward error ‖E‖ ≲ n ε ‖P̂‖, so λ_min ≥ floor +
        # (margin − n ε)‖P̂‖, and eigh's computed λ_min (equally backward stable) is ≥ floor too; False is undecided.
        largest = 0.0
        for k in range(size):
            i, j = first[k], second[k]
            value = updated[b, k] if i == j else 0.5 * updated[b, k]
            P[i, j] = value
            P[j, i] = value
            largest = max(largest, abs(value))
        shift = floor + margin * largest
        for i in range(n):
            for j in range(n):
                GP[i, j] = P[i, j] - shift * (1.0 if i == j else 0.0)  # GP reused as the factor
        positive = True
        for k in range(n):
            pivot = GP[k, k]
            if not pivot > 0.0:
                positive = False
                break
            for i in range(k + 1, n):
                column = GP[i, k] / pivot
                for j in range(k + 1, n):
                    GP[i, j] -= column * GP[k, j]
        certain[b] = positive
    return commands, increments, residuals, norms, updated, certain
