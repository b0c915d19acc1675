"""Compiled factors of the frozen-Jacobian LQR for a stack of Jacobians
(:meth:`~snac_gym.control.optimality.FrozenJacobianLQR.factors`).

Per sample and control step the LQR controller, SNAC-HJB's weighted pseudo-inverse and the MPC's
terminal cost need ``S = Q^{1/2} J R⁻¹ Jᵀ Q^{1/2} = W diag(λ) Wᵀ`` and the products
``A = R⁻¹ Jᵀ Q^{1/2} W`` and ``C = Wᵀ Q^{1/2}``. As NumPy operations on the ``(B, n, m)`` stack
that was five stacked matrix products around the compiled eigendecomposition, more time than the
eigendecomposition itself; here it is one pass over the stack, each product summed in index order
(``python docs/scripts/kernel_speed.py``).
"""

from __future__ import annotations

import functools

import numpy as np

from snac_gym.kernels.compiled import Example, helper, kernel, read_only
from snac_gym.kernels.small import jacobi_eigh


def _examples() -> list[Example]:
    """A read-only stack: its callers pass one (:func:`~snac_gym.kernels.compiled.read_only_view`)."""
    return [(read_only(np.ones((1, 3, 6))), np.eye(3), np.eye(6), 1e-12)]


# Inlined: a few lines, cheaper compiled into the kernel than linked into it (the module's cold compile 2.1 → 1.7 s).
@functools.partial(helper, inline=True)
def _product(x: np.ndarray, y: np.ndarray, out: np.ndarray) -> None:  # pragma: no cover - compiled
    """``out ← x y``, each entry summed in index order."""
    for i in range(x.shape[0]):
        for j in range(y.shape[1]):
            total = 0.0
            for k in range(x.shape[1]):
                total += x[i, k] * y[k, j]
            out[i, j] = total


@kernel(_examples)
def frozen_lqr_factors(
    jacobians: np.ndarray, q_half: np.ndarray, r_inverse: np.ndarray, tolerance: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled; tested against NumPy
    """``(A, λ, C, singular)`` of each J of a stack ``(B, n, m)``: shapes ``(B, m, n)``, ``(B, n)``, ``(B, n, n)``,
    ``(B, n)``.

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
        _product(q_half, jacobians[b], g)
        _product(r_inverse, g.T, rg)
        _product(g, rg, a)
        for i in range(n):  # symmetric exactly: the lower triangle mirrored (R ≠ I rounds the two apart)
            for j in range(i):
                a[j, i] = a[i, j]
        jacobi_eigh(a, v, diagonal, order, values[b], w)
        largest = values[b, n - 1]
        for i in range(n):
            singular[b, i] = values[b, i] <= tolerance * largest
            if singular[b, i]:
                values[b, i] = np.inf
        _product(rg, w, left[b])
        _product(w.T, q_half, right[b])
    return left, values, right, singular
