"""Would a compiled banded Cholesky speed up the reference's Gauss-Newton steps? Timed against LAPACK's, one core.

    python docs/scripts/banded_cholesky.py

Each Gauss-Newton step of the ``optimal`` reference factors a symmetric positive definite band of bandwidth 12 (the
u̇ term couples θₖ with θₖ₊₁ and θₖ₊₂, six joints each) with LAPACK's ``dpbtrf``
(:func:`snac_gym.control.gauss_newton.gauss_newton_direction`): about 15 % of a cold reference job's CPU. At that
bandwidth ``dpbtrf`` runs its unblocked code, one rank-1 BLAS update per column, which looked like overhead a compiled
loop could save. This times the plain column Cholesky compiled by numba against ``dpbtrf`` on bands of the
reference's sizes (the coarse grid's 250 steps, a reach and a track horizon's 1500 and 2500 steps, six joints each),
best of 50 after a warm-up, and checks that both give the same factor.
"""

from __future__ import annotations

import time

import numpy as np
from numba import njit
from scipy.linalg.lapack import dpbtrf
from threadpoolctl import threadpool_limits

BANDWIDTH = 12
#: Unknowns: 6 joints × the coarse grid's, a reach horizon's and a track horizon's steps.
SIZES = (1500, 9000, 15000)
REPEATS = 50


@njit(cache=False, nogil=True)
def banded_cholesky(band: np.ndarray) -> int:
    """Lower Cholesky factor of a band in LAPACK's lower form (``band[d, j] = A[j + d, j]``), in place; 0, or the
    1-based column where A is not positive definite (``dpbtrf``'s ``info``)."""
    kd, n = band.shape[0] - 1, band.shape[1]
    for j in range(n):
        pivot = band[0, j]
        if pivot <= 0.0:
            return j + 1
        pivot = np.sqrt(pivot)
        band[0, j] = pivot
        below = min(kd, n - j - 1)
        for i in range(1, below + 1):
            band[i, j] /= pivot
        for c in range(1, below + 1):  # the trailing block's column j + c, rows j + c .. j + below
            value = band[c, j]
            for r in range(c, below + 1):
                band[r - c, j + c] -= band[r, j] * value
    return 0


def best_of(function, repeats: int = REPEATS) -> float:
    best = float("inf")
    for _ in range(repeats):
        start = time.perf_counter()
        function()
        best = min(best, time.perf_counter() - start)
    return best


def main() -> None:
    rng = np.random.default_rng(0)
    print(f"{'unknowns':>9s} {'dpbtrf':>10s} {'numba':>10s} {'factors differ by':>18s}")
    for n in SIZES:
        band = rng.normal(size=(BANDWIDTH + 1, n)) * 0.1
        band[0] = 10.0 + rng.random(n)  # diagonally dominant: positive definite
        fortran = np.asfortranarray(band)
        banded_cholesky(band.copy())  # compile
        lapack = best_of(lambda: dpbtrf(np.array(fortran, order="F"), lower=1, overwrite_ab=1))
        compiled = best_of(lambda: banded_cholesky(band.copy()))
        factor, info = dpbtrf(np.array(fortran, order="F"), lower=1)
        ours = band.copy()
        assert info == 0 and banded_cholesky(ours) == 0
        difference = float(np.abs(factor - ours).max() / np.abs(factor).max())
        print(f"{n:9d} {lapack * 1e3:8.3f}ms {compiled * 1e3:8.3f}ms {difference:18.1e}")


if __name__ == "__main__":
    with threadpool_limits(1):
        main()
