"""Compiled assembly of the optimum's Gauss-Newton matrix (:func:`snac_gym.control.trajopt.gauss_newton_direction`),
its banded Cholesky factor and solve (:func:`banded_cholesky_solve`), and the joint path of a plan
(:func:`joint_path`).

Each Gauss-Newton iteration adds the blocks 2Δt·q·JₖᵀJₖ (k = 1..K−1) to the fixed band A ⊗ I_m.
As NumPy array arithmetic (a stack of products, then a scattered ``+=``) that took about a fifth
of a 2500-step iteration; this is one pass over the Jacobians with the same sums in the same
order, so the band is the same bit for bit (tests/evaluation/reference/test_optimum.py). Newton's step adds the
error term's second-order blocks too (:func:`chain_error_curvature`, :func:`add_symmetric_blocks`); they are compiled
with the reference's kernels, not the kinematics' (the controllers' rollouts never need them).
"""

from __future__ import annotations

import numpy as np

from snac_gym.kernels.chain import chain_example, joint_frames
from snac_gym.kernels.compiled import Example, kernel, read_only


@kernel(lambda: (read_only(np.zeros(6)), read_only(np.ones((3, 6))), 0.008))
def joint_path(q0: np.ndarray, commands: np.ndarray, dt: float) -> np.ndarray:  # pragma: no cover - compiled
    """θ₁..θ_K = θ₀ + Δt Σᵢ≤ₖ uᵢ of :func:`snac_gym.model.kinematics.joint_path`: NumPy's ``q0 + cumsum(commands,
    axis=0) * dt`` bit for bit (its cumulative sum adds each column in order; then the product, then the sum), at a
    quarter of the three array operations' time on a 2500-step plan, which each cost evaluation of the optimum's
    solves makes.

    Args:
        q0: ``(m,)`` θ₀.
        commands: ``(K, m)`` commands u₀..u_{K−1}.
        dt: Δt.
    """
    steps, m = commands.shape
    path = np.empty((steps, m))
    total = np.zeros(m)
    for k in range(steps):
        for j in range(m):
            # the first row itself, as NumPy's cumsum starts, not 0.0 + it (which would turn a −0.0 into +0.0)
            total[j] = total[j] + commands[k, j] if k else commands[k, j]
            path[k, j] = q0[j] + total[j] * dt
    return path


@kernel(lambda: (np.zeros((13, 12), order="F"), read_only(np.ones((3, 3, 6))), 1.0))
def add_jacobian_blocks(band: np.ndarray, jacobians: np.ndarray, scale: float) -> None:  # pragma: no cover - compiled
    """``band[a − b, (k−1)·m + b] += scale · (JₖᵀJₖ)ₐᵦ`` for a ≥ b and k = 1..K−1, in place.

    Args:
        band: ``(rows, (K−1)·m)`` or wider lower band (LAPACK ``dpbtrf`` lower form) of the θ-system.
        jacobians: ``(K, n, m)``: Jₖ along the trajectory (J₀ is not used: θ₀ is fixed).
        scale: 2Δt·q.
    """
    steps, n, m = jacobians.shape
    for k in range(1, steps):
        column = (k - 1) * m
        for a in range(m):
            for b in range(a + 1):
                total = 0.0
                for i in range(n):
                    total += jacobians[k, i, a] * jacobians[k, i, b]
                band[a - b, column + b] += scale * total


@kernel(lambda: (np.zeros((13, 12), order="F"), np.ones((3, 6, 6)), 1.0))
def add_symmetric_blocks(band: np.ndarray, blocks: np.ndarray, scale: float) -> None:  # pragma: no cover - compiled
    """``band[a − b, (k−1)·m + b] += scale · Sₖ[a, b]`` for a ≥ b and k = 1..K−1, in place: symmetric ``(K, m, m)``
    blocks on the band's diagonal, as :func:`add_jacobian_blocks` adds JₖᵀJₖ (S₀ is not used: θ₀ is fixed)."""
    steps, m = blocks.shape[0], blocks.shape[1]
    for k in range(1, steps):
        column = (k - 1) * m
        for a in range(m):
            for b in range(a + 1):
                band[a - b, column + b] += scale * blocks[k, a, b]


def _curvature_example() -> Example:
    """:func:`chain_error_curvature`'s argument types: the chain kernel's example, with the errors."""
    example = chain_example()
    return (example[0], np.zeros((2, 3)), *example[1:])


@kernel(_curvature_example)
def chain_error_curvature(
    qs: np.ndarray,
    errors: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    axes: np.ndarray,
    revolute: np.ndarray,
    columns: np.ndarray,
    ee_offset: np.ndarray,
    n_joints: int,
) -> np.ndarray:  # pragma: no cover - compiled; tested against finite differences of J
    """``Σᵢ eᵢ ∂²fᵢ/∂θ∂θ`` at each configuration of ``qs`` ``(B, m)`` for the errors ``(B, 3)``: ``(B, m, m)``,
    symmetric. With JᵀJ it is the Hessian of ½‖f(θ) − x_d‖², whose second-order part Gauss-Newton leaves out.

    Joint s base-side of joint t (or s = t) moves everything beyond it: a revolute s turns z_t, x and p_t about z_s
    and a prismatic s translates them, so ∂²x/∂θₛ∂θₜ = zₛ × (zₜ × (x − pₜ)) for both revolute, zₛ × zₜ for a
    revolute s and a prismatic t, and 0 for a prismatic s. Arguments: :func:`chain_forward_and_jacobian`'s.
    """
    count, chain = qs.shape[0], rotations.shape[0]
    curvature = np.zeros((count, n_joints, n_joints))
    p = np.empty((chain, 3))
    z = np.empty((chain, 3))
    x = np.empty(3)
    for b in range(count):
        joint_frames(qs, b, rotations, translations, axes, revolute, columns, ee_offset, p, z, x)
        e0, e1, e2 = errors[b, 0], errors[b, 1], errors[b, 2]
        for t in range(chain):
            if revolute[t]:  # w = zₜ × (x − pₜ), the joint's Jacobian column
                l0, l1, l2 = x[0] - p[t, 0], x[1] - p[t, 1], x[2] - p[t, 2]
                w0, w1, w2 = z[t, 1] * l2 - z[t, 2] * l1, z[t, 2] * l0 - z[t, 0] * l2, z[t, 0] * l1 - z[t, 1] * l0
            else:  # w = zₜ
                w0, w1, w2 = z[t, 0], z[t, 1], z[t, 2]
            for s in range(t + 1):
                if not revolute[s]:
                    continue
                # eᵀ(zₛ × w) = w · (e × zₛ)
                c0 = e1 * z[s, 2] - e2 * z[s, 1]
                c1 = e2 * z[s, 0] - e0 * z[s, 2]
                c2 = e0 * z[s, 1] - e1 * z[s, 0]
                value = w0 * c0 + w1 * c1 + w2 * c2
                curvature[b, columns[s], columns[t]] += value
                if s != t:
                    curvature[b, columns[t], columns[s]] += value
    return curvature


@kernel(lambda: (np.eye(13, 12, order="F") * 4.0, np.ones(12)), fastmath={"contract"})
def banded_cholesky_solve(band: np.ndarray, rhs: np.ndarray) -> tuple[int, np.ndarray]:  # noqa: C901  # pragma: no cover - compiled
    """Factor the lower band (LAPACK's lower form, Fortran order) in place, L Lᵀ, and solve L Lᵀ x = ``rhs``.

    LAPACK's ``dpbtrf`` (its unblocked ``dpbtf2``, which it runs below bandwidth 32) then ``dpbtrs``, the same
    operations in the same order: a column scaled by the pivot's reciprocal, a rank-1 update of the trailing block
    column by column, two triangular solves. At the θ-system's bandwidth of 12 each of those is a BLAS call of a dozen
    numbers, whose call costs more than its arithmetic: as library calls they took about a tenth of the reference's time
    more (docs/benchmarks-log.md). ``contract`` lets LLVM fuse ``a + b·c`` as OpenBLAS's daxpy and ddot kernels do, so
    the factor and the solution are LAPACK's bit for bit where those fuse (checked on 120 of the reference's bands on an
    AVX-512 Intel machine, ``python docs/scripts/banded_cholesky.py``; elsewhere they agree to rounding).

    Returns (info, x): info > 0 is the 1-based column at which the matrix is not positive definite (x is then unset),
    as ``dpbtrf``'s; a NaN pivot is not refused there either."""
    rows, n = band.shape
    kd = rows - 1
    x = np.empty(n)
    for j in range(n):
        ajj = band[0, j]
        if ajj <= 0.0:  # a NaN pivot goes on, as in the dpbtf2 SciPy's OpenBLAS ships (no DISNAN test)
            return j + 1, x
        ajj = np.sqrt(ajj)
        band[0, j] = ajj
        kn = min(kd, n - 1 - j)
        if kn > 0:
            scale = 1.0 / ajj
            for i in range(1, kn + 1):
                band[i, j] = scale * band[i, j]
            for ii in range(kn):  # dsyr: the trailing block −= x xᵀ, column by column
                xi = band[1 + ii, j]
                if xi != 0.0:
                    step = -xi
                    column = j + 1 + ii
                    for offset in range(kn - ii):
                        band[offset, column] = band[offset, column] + step * band[1 + ii + offset, j]
    for i in range(n):
        x[i] = rhs[i]
    for i in range(n):  # L y = rhs (dtbsv, lower, no transpose)
        x[i] = x[i] / band[0, i]
        step = -x[i]
        for offset in range(min(n - 1 - i, kd)):
            x[i + 1 + offset] = x[i + 1 + offset] + step * band[1 + offset, i]
    for i in range(n - 1, -1, -1):  # Lᵀ x = y (dtbsv, lower, transposed)
        total = 0.0
        for offset in range(min(n - 1 - i, kd)):
            total = total + x[i + 1 + offset] * band[1 + offset, i]
        x[i] = (x[i] - total) / band[0, i]
    return 0, x
