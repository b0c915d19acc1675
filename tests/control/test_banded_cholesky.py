"""The reference's compiled banded Cholesky (:func:`snac_gym.kernels.trajopt.banded_cholesky_solve`) against LAPACK's
``dpbtrf``/``dpbtrs`` and a dense solve, on bands of the reference's θ-system."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse
from scipy.linalg.lapack import dpbtrf, dpbtrs
from scipy.sparse.linalg import norm as sparse_norm

from snac_gym.control.cost import CostConvention
from snac_gym.control.gauss_newton import theta_system_base
from snac_gym.kernels.compiled import read_only_view
from snac_gym.kernels.trajopt import add_jacobian_blocks, banded_cholesky_solve


def _band(steps: int, dt: float, convention: CostConvention, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    band = np.array(theta_system_base(steps, 6, dt, convention), order="F")
    jacobians = rng.normal(size=(steps, 3, 6)) * rng.uniform(0.01, 3.0)
    add_jacobian_blocks(band, read_only_view(jacobians), 2.0 * dt * rng.uniform(0.5, 50.0))
    return band, rng.normal(size=steps * 6) * 10.0 ** rng.uniform(-6.0, 3.0)


def _dense(band: np.ndarray) -> np.ndarray:
    rows, n = band.shape
    matrix = np.zeros((n, n))
    for offset in range(rows):
        index = np.arange(n - offset)
        matrix[index + offset, index] = matrix[index, index + offset] = band[offset, : n - offset]
    return matrix


def _sparse(band: np.ndarray, symmetric: bool) -> sparse.csr_array:
    """The matrix a lower band stands for: symmetric (``A``) or lower triangular (``L``), without making it dense
    (Table I's horizon is a 9000 × 9000 system)."""
    rows, n = band.shape
    offsets = range(rows)
    lower = sparse.diags_array([band[offset, : n - offset] for offset in offsets], offsets=[-o for o in offsets])
    if not symmetric:
        return lower.tocsr()
    return (lower + sparse.diags_array([band[o, : n - o] for o in offsets[1:]], offsets=list(offsets[1:]))).tocsr()


@pytest.mark.parametrize("cost", ["table1", "hjb"])
@pytest.mark.parametrize(("steps", "dt", "seed"), [(30, 0.08, 0), (150, 0.08, 1), (1500, 0.008, 2)])
def test_the_factor_and_the_solution_are_lapacks_and_solve_the_system(cost, steps, dt, seed):
    band, rhs = _band(steps, dt, CostConvention(cost), seed)
    factor, info = dpbtrf(band, lower=1)
    solution = dpbtrs(factor, rhs, lower=1)[0]
    ours = np.array(band, order="F")
    our_info, our_solution = banded_cholesky_solve(ours, rhs)
    assert info == our_info == 0
    # Backward stable as LAPACK is: L Lᵀ is A to rounding, and the residual of the solution is no larger than LAPACK's.
    # These hold on every machine; the factors themselves agree only to rounding times the system's condition, as the
    # multiply-adds of OpenBLAS's daxpy and ddot are fused or not by CPU (bit for bit on Intel's SkylakeX kernels, the
    # machine docs/scripts/banded_cholesky.py measured; Table I's horizon to 4e-11 on an AMD EPYC's).
    matrix = _sparse(band, symmetric=True)
    scale = sparse_norm(matrix)
    for name, lower in (("ours", ours), ("LAPACK's", factor)):
        triangle = _sparse(lower, symmetric=False)
        backward = sparse_norm(triangle @ triangle.T - matrix) / scale
        assert backward < 1e-15, (name, backward)
    residual = [np.linalg.norm(matrix @ x - rhs) / np.linalg.norm(rhs) for x in (our_solution, solution)]
    assert residual[0] <= 2.0 * residual[1] + 1e-15, residual
    np.testing.assert_allclose(ours, factor, rtol=1e-9, atol=1e-9 * np.abs(factor).max())
    if steps <= 150:  # against a dense solve, which shares nothing with either
        dense = np.linalg.solve(_dense(band), rhs)
        np.testing.assert_allclose(our_solution, dense, rtol=1e-8, atol=1e-8 * np.abs(dense).max())
        np.testing.assert_allclose(our_solution, solution, rtol=1e-11, atol=1e-11 * np.abs(solution).max())


@pytest.mark.parametrize("column", [0, 5, 400, 899])
@pytest.mark.parametrize("value", [-1.0, 0.0])
def test_a_matrix_not_positive_definite_is_reported_at_lapacks_column(column, value):
    band, rhs = _band(150, 0.08, CostConvention(), 3)
    band[0, column] = value
    _, info = dpbtrf(band, lower=1)
    our_info, _ = banded_cholesky_solve(np.array(band, order="F"), rhs)
    assert our_info == info == column + 1


@pytest.mark.parametrize("column", [0, 400, 899])
def test_a_nan_pivot_goes_through_as_in_lapack(column):
    """LAPACK's ``dpbtf2`` as SciPy ships it tests ``ajj <= 0`` only: a NaN is factored on, and the solution is NaN
    from there; the kernel does as it does, so that a caller meets the same outcome as before."""
    band, rhs = _band(150, 0.08, CostConvention(), 4)
    band[0, column] = np.nan
    factor, info = dpbtrf(band, lower=1)
    solution = dpbtrs(factor, rhs, lower=1)[0]
    our_info, our_solution = banded_cholesky_solve(np.array(band, order="F"), rhs)
    assert our_info == info
    np.testing.assert_array_equal(np.isnan(our_solution), np.isnan(solution))


def test_a_step_that_breaks_positive_definiteness_later_is_reported_too():
    """A pivot that turns non-positive only after the updates of the columns before it (a valid-looking diagonal)."""
    band = np.zeros((13, 24), order="F")
    band[0] = 1.0
    band[1, 0] = 2.0  # A = [[1, 2], [2, 1], …]: the second pivot is 1 − 4 < 0
    _, info = dpbtrf(band, lower=1)
    our_info, _ = banded_cholesky_solve(np.array(band, order="F"), np.ones(24))
    assert our_info == info == 2
