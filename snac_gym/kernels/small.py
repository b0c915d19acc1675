"""Compiled decompositions of stacks of small matrices: the symmetric eigenproblem and the SVD by Jacobi rotations.

The controllers decompose one 3×3 (or n×n, n ≤ 6) matrix per sample and step: the LQR gain
and the weighted pseudo-inverse (eigenvectors of Q^{1/2} J R⁻¹ Jᵀ Q^{1/2}), the singular-value
filtered inverse (the SVD of J). ``np.linalg.eigh`` and ``np.linalg.svd`` call LAPACK once per
matrix of a stack, about 1-4 µs each for 3×3 on this machine, most of it the call. Jacobi
rotations on a matrix this small take a few dozen rotations, and are as accurate: both
methods are backward stable (errors of order ε‖A‖), Jacobi's singular values even to high
relative accuracy (Demmel and Veselić, SIAM J. Matrix Anal. Appl. 13(4), 1992).

Figures: ``python docs/scripts/kernel_speed.py``.
"""

from __future__ import annotations

import functools

import numpy as np

from snac_gym.kernels.compiled import helper, kernel, read_only, read_only_view

#: Sweeps of the Jacobi methods before giving up (a 3×3 converges in 3-5).
MAX_SWEEPS = 60
_EPS = float(np.finfo(float).eps)


# The Jacobi methods' small steps are inlined: cheaper compiled into their callers than linked (the module's cold
# compile 1.8 → 1.5 s); jacobi_eigh itself is linked, as inlined into two kernels it compiled slower.
@functools.partial(helper, inline=True)
def _rotation(alpha: float, beta: float, gamma: float) -> tuple[float, float]:  # pragma: no cover - compiled
    """``(cos, sin)`` of the Jacobi rotation that zeroes ``gamma`` between diagonal entries ``alpha``, ``beta``."""
    zeta = (beta - alpha) / (2.0 * gamma)
    if abs(zeta) > 1e150:  # zeta² would overflow: t ≈ 1/(2ζ)
        t = 0.5 / zeta
    else:
        t = (1.0 if zeta >= 0.0 else -1.0) / (abs(zeta) + np.sqrt(1.0 + zeta * zeta))
    c = 1.0 / np.sqrt(1.0 + t * t)
    return c, c * t


@functools.partial(helper, inline=True)
def _sort_indices(keys: np.ndarray, order: np.ndarray, direction: float) -> None:  # pragma: no cover - compiled
    """``order`` ← the indices of ``keys`` ascending (``direction`` 1) or descending (−1); a stable insertion
    sort, n ≤ 6."""
    for i in range(len(keys)):
        order[i] = i
    for i in range(1, len(keys)):
        index = order[i]
        j = i - 1
        while j >= 0 and direction * keys[order[j]] > direction * keys[index]:
            order[j + 1] = order[j]
            j -= 1
        order[j + 1] = index


@functools.partial(helper, inline=True)
def _rotate_columns(matrix: np.ndarray, p: int, q: int, c: float, s: float) -> None:  # pragma: no cover - compiled
    """Columns p and q of ``matrix`` ← (c·x_p − s·x_q, s·x_p + c·x_q), in place: ``matrix`` times the rotation."""
    for k in range(matrix.shape[0]):
        first, second = matrix[k, p], matrix[k, q]
        matrix[k, p] = c * first - s * second
        matrix[k, q] = s * first + c * second


@helper
def jacobi_eigh(  # noqa: C901 - one compiled loop nest
    a: np.ndarray, v: np.ndarray, diagonal: np.ndarray, order: np.ndarray, values: np.ndarray, vectors: np.ndarray
) -> None:  # pragma: no cover - compiled
    """Eigenvalues (ascending) into ``values`` and eigenvectors (columns) into ``vectors`` of the
    symmetric ``a`` ``(n, n)``, which is overwritten; ``v`` ``(n, n)``, ``diagonal`` ``(n,)`` and
    ``order`` ``(n,)`` int64 are workspaces. Cyclic Jacobi with the relative stopping test
    ``|a_pq| ≤ ε·√(|a_pp a_qq|)``."""
    n = a.shape[0]
    for i in range(n):
        for j in range(n):
            v[i, j] = 1.0 if i == j else 0.0
    for _ in range(MAX_SWEEPS):
        rotated = False
        for p in range(n - 1):
            for q in range(p + 1, n):
                gamma = a[p, q]
                if gamma == 0.0 or abs(gamma) <= _EPS * np.sqrt(abs(a[p, p] * a[q, q])):
                    continue
                rotated = True
                c, s = _rotation(a[p, p], a[q, q], gamma)
                _rotate_columns(a, p, q, c, s)  # A ← Gᵀ A G: columns p, q, then rows p, q
                _rotate_columns(a.T, p, q, c, s)
                a[p, q] = 0.0
                a[q, p] = 0.0
                _rotate_columns(v, p, q, c, s)
        if not rotated:
            break
    for i in range(n):
        diagonal[i] = a[i, i]
    _sort_indices(diagonal, order, 1.0)
    for j in range(n):
        values[j] = diagonal[order[j]]
        for i in range(n):
            vectors[i, j] = v[i, order[j]]


# Nothing in a run calls it (lqr runs jacobi_eigh inside its own kernel): not warmed up, 0.8 s of a cold run's compiles.
@kernel(lambda: (read_only(np.eye(3)[None].copy()),), warm=False)
def symmetric_eigh(matrices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Eigenvalues (ascending) and eigenvectors (columns) of a stack ``(B, n, n)`` of symmetric matrices.

    ``np.linalg.eigh``'s contract (only the lower triangle is read), by :func:`jacobi_eigh`.
    Eigenvectors are unique up to sign (and, for a repeated eigenvalue, up to a rotation within
    its eigenspace), as LAPACK's are.
    """
    count, n = matrices.shape[0], matrices.shape[1]
    values = np.empty((count, n))
    vectors = np.empty((count, n, n))
    a = np.empty((n, n))
    v = np.empty((n, n))
    diagonal = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    for b in range(count):
        for i in range(n):
            for j in range(i + 1):
                a[i, j] = matrices[b, i, j]
                a[j, i] = matrices[b, i, j]
        jacobi_eigh(a, v, diagonal, order, values[b], vectors[b])
    return values, vectors


@kernel(lambda: (read_only(np.ones((1, 3, 6))),))
def thin_svd(matrices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # noqa: C901  # pragma: no cover - compiled
    """``(U, σ, Vᵀ)`` of a stack ``(B, n, m)``, n ≤ m: ``np.linalg.svd(..., full_matrices=False)``'s contract.

    One-sided Jacobi (Hestenes) on the columns of Aᵀ: rotations W orthogonalise them, so that
    AᵀW = V diag(σ) and U = W. σ descending. A zero singular value leaves its column of V zero
    (any unit vector would do; none is needed by a product V diag(f(σ)) Uᵀ with f(0) finite times 0).
    """
    count, n, m = matrices.shape[0], matrices.shape[1], matrices.shape[2]
    u = np.empty((count, n, n))
    sigma = np.empty((count, n))
    vt = np.zeros((count, n, m))
    g = np.empty((m, n))  # Aᵀ, rotated in place
    w = np.empty((n, n))
    norms = np.empty(n)
    order = np.empty(n, dtype=np.int64)
    for b in range(count):
        for i in range(n):
            for k in range(m):
                g[k, i] = matrices[b, i, k]
            for j in range(n):
                w[i, j] = 1.0 if i == j else 0.0
        for _ in range(MAX_SWEEPS):
            rotated = False
            for p in range(n - 1):
                for q in range(p + 1, n):
                    alpha, beta, gamma = 0.0, 0.0, 0.0
                    for k in range(m):
                        alpha += g[k, p] * g[k, p]
                        beta += g[k, q] * g[k, q]
                        gamma += g[k, p] * g[k, q]
                    if gamma == 0.0 or abs(gamma) <= _EPS * np.sqrt(alpha * beta):
                        continue
                    rotated = True
                    c, s = _rotation(alpha, beta, gamma)
                    _rotate_columns(g, p, q, c, s)
                    _rotate_columns(w, p, q, c, s)
            if not rotated:
                break
        for j in range(n):
            total = 0.0
            for k in range(m):
                total += g[k, j] * g[k, j]
            norms[j] = np.sqrt(total)
        _sort_indices(norms, order, -1.0)
        for j in range(n):
            column = order[j]
            value = norms[column]
            sigma[b, j] = value
            for i in range(n):
                u[b, i, j] = w[i, column]
            if value > 0.0:
                for k in range(m):
                    vt[b, j, k] = g[k, column] / value
    return u, sigma, vt


@kernel(lambda: (read_only(np.ones((1, 3, 6))), np.ones((1, 3)), 1e-4))
def damped_resolve(jacobians: np.ndarray, velocities: np.ndarray, damping: float) -> np.ndarray:  # noqa: C901  # pragma: no cover - compiled
    """``Jᵀ(JJᵀ + λ²I)⁻¹v`` for a stack ``(B, n, m)`` with ``(B, n)`` (``damping`` = λ²), by a Cholesky solve of
    each n×n system: the joint-goal IK's step, on thousands of candidates at once (NumPy's batched ``solve`` and
    ``matmul`` on 3×3 and 3×6 matrices spend most of their time per matrix, not in arithmetic)."""
    count, n, m = jacobians.shape[0], jacobians.shape[1], jacobians.shape[2]
    out = np.empty((count, m))
    a = np.empty((n, n))
    y = np.empty(n)
    for b in range(count):
        for i in range(n):
            for j in range(i + 1):
                total = 0.0
                for k in range(m):
                    total += jacobians[b, i, k] * jacobians[b, j, k]
                a[i, j] = total + (damping if i == j else 0.0)
        for j in range(n):  # a ← its lower Cholesky factor, in place
            pivot = a[j, j]
            for k in range(j):
                pivot -= a[j, k] * a[j, k]
            pivot = np.sqrt(pivot)
            a[j, j] = pivot
            for i in range(j + 1, n):
                total = a[i, j]
                for k in range(j):
                    total -= a[i, k] * a[j, k]
                a[i, j] = total / pivot
        for i in range(n):
            total = velocities[b, i]
            for k in range(i):
                total -= a[i, k] * y[k]
            y[i] = total / a[i, i]
        for i in range(n - 1, -1, -1):
            total = y[i]
            for k in range(i + 1, n):
                total -= a[k, i] * y[k]
            y[i] = total / a[i, i]
        for k in range(m):
            total = 0.0
            for i in range(n):
                total += jacobians[b, i, k] * y[i]
            out[b, k] = total
    return out


@functools.partial(helper, inline=True)
def clip_into(value: float, limit: float) -> float:  # pragma: no cover - compiled
    """``np.minimum(np.maximum(value, −limit), limit)`` of one number: a NaN stays NaN, as there."""
    value = value if (value >= -limit or value != value) else -limit
    return value if (value <= limit or value != value) else limit


@kernel(lambda: (read_only(np.ones((1, 6))), read_only(np.ones(6))))
def scale_rows(commands: np.ndarray, limits: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Each row of ``commands`` ``(B, m)`` divided by its largest ``|uⱼ|/limitⱼ`` where that exceeds 1, then clipped
    to ``±limits`` ``(m,)``: :func:`~snac_gym.policies.base.scale_rows_into_limits`, bit for bit NumPy's
    ``np.max(np.abs(u) / limits, axis=-1)``, ``np.maximum``, ``/`` and the clip (a NaN in a row makes the row NaN, as
    there), with no temporary arrays: five NumPy calls on a 250 × 6 stack cost 22 µs a control step, this 4 µs."""
    count, m = commands.shape[0], commands.shape[1]
    out = np.empty((count, m))
    for b in range(count):
        scale = -np.inf
        for j in range(m):
            ratio = abs(commands[b, j]) / limits[j]
            if not ratio <= scale:  # a larger ratio, or a NaN, which stays (np.max propagates it)
                if scale != scale:
                    break
                scale = ratio
        divisor = scale if not scale <= 1.0 else 1.0  # np.maximum(scale, 1.0), NaN kept
        for j in range(m):
            out[b, j] = clip_into(commands[b, j] / divisor, limits[j])
    return out


def eigh(matrices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``np.linalg.eigh`` of one symmetric matrix or a stack of any shape ``(…, n, n)``, by :func:`symmetric_eigh`."""
    matrices = np.asarray(matrices, dtype=float)
    shape = matrices.shape
    values, vectors = symmetric_eigh(read_only_view(matrices.reshape((-1, *shape[-2:]))))
    return values.reshape(shape[:-1]), vectors.reshape(shape)


def svd(matrices: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``np.linalg.svd(A, full_matrices=False)`` of one ``(n, m)`` matrix, n ≤ m, or a stack ``(…, n, m)``, by
    :func:`thin_svd`."""
    matrices = np.asarray(matrices, dtype=float)
    shape = matrices.shape
    if shape[-2] > shape[-1]:
        raise ValueError(f"svd: needs at most as many rows as columns, got shape {shape}")
    u, sigma, vt = thin_svd(read_only_view(matrices.reshape((-1, *shape[-2:]))))
    rows = shape[-2]
    return u.reshape((*shape[:-2], rows, rows)), sigma.reshape(shape[:-1]), vt.reshape(shape)
