"""Compiled factors of the frozen-Jacobian LQR for a stack of Jacobians (:meth:`~snac_gym.optimality.FrozenJacobianLQR.factors`).

Per sample and control step the LQR controller, SNAC-HJB's weighted pseudo-inverse and the MPC's
terminal cost need ``S = Q^{1/2} J R⁻¹ Jᵀ Q^{1/2} = W diag(λ) Wᵀ`` and the products
``A = R⁻¹ Jᵀ Q^{1/2} W`` and ``C = Wᵀ Q^{1/2}``. As NumPy operations on the ``(B, n, m)`` stack
that was five stacked matrix products around the compiled eigendecomposition, more time than the
eigendecomposition itself; here it is one pass over the stack, each product summed in index order
(``python docs/scripts/kernel_speed.py``).
"""

from __future__ import annotations

import numpy as np

from snac_gym.compiled import kernel
from snac_gym.small_kernels import jacobi_eigh


def _examples() -> list[tuple]:
    """A writable stack, and a read-only one (the kinematics' cached Jacobians are read-only)."""
    read_only = np.ones((1, 3, 6))
    read_only.setflags(write=False)
    return [(np.ones((1, 3, 6)), np.eye(3), np.eye(6), 1e-12), (read_only, np.eye(3), np.eye(6), 1e-12)]


@kernel(_examples)
def frozen_lqr_factors(  # noqa: C901 - one compiled loop nest
    jacobians: np.ndarray, q_half: np.ndarray, r_inverse: np.ndarray, tolerance: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled; tested against NumPy
    """``(A, λ, C, singular)`` of each J of a stack ``(B, n, m)``: shapes ``(B, m, n)``, ``(B, n)``, ``(B, n, n)``, ``(B, n)``.

    With ``G = Q^{1/2} J`` (``q_half`` = Q^{1/2}, ``r_inverse`` = R⁻¹): ``G R⁻¹ Gᵀ = W diag(λ) Wᵀ``
    (λ ascending), ``A = R⁻¹ Gᵀ W``, ``C = Wᵀ Q^{1/2}``; an eigenvalue ≤ ``tolerance``·λ_max is
    marked singular and set to +inf.
    """
    count, n, m = jacobians.shape
    left = np.empty((count, m, n))
    values = np.empty((count, n))
    right = np.empty((count, n, n))
    singular = np.empty((count, n), dtype=np.bool_)
    g = np.empty((n, m))  # Q^{1/2} J
    rg = np.empty((m, n))  # R⁻¹ Gᵀ
    a = np.empty((n, n))
    v = np.empty((n, n))
    w = np.empty((n, n))
    diagonal = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    for b in range(count):
        for i in range(n):
            for k in range(m):
                total = 0.0
                for j in range(n):
                    total += q_half[i, j] * jacobians[b, j, k]
                g[i, k] = total
        for k in range(m):
            for i in range(n):
                total = 0.0
                for j in range(m):
                    total += r_inverse[k, j] * g[i, j]
                rg[k, i] = total
        for i in range(n):
            for j in range(i + 1):
                total = 0.0
                for k in range(m):
                    total += g[i, k] * rg[k, j]
                a[i, j] = total
                a[j, i] = total
        jacobi_eigh(a, v, diagonal, order, values[b], w)
        largest = values[b, n - 1]
        for i in range(n):
            singular[b, i] = values[b, i] <= tolerance * largest
        for i in range(n):
            if singular[b, i]:
                values[b, i] = np.inf
        for k in range(m):
            for i in range(n):
                total = 0.0
                for j in range(n):
                    total += rg[k, j] * w[j, i]
                left[b, k, i] = total
        for i in range(n):
            for j in range(n):
                total = 0.0
                for k in range(n):
                    total += w[k, i] * q_half[k, j]
                right[b, i, j] = total
    return left, values, right, singular
