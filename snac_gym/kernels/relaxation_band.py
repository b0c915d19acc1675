"""The banded linear algebra of the lower bound's interior point (:mod:`snac_gym.kernels.relaxation`): the relaxed
cost's Hessian and the constraints' curvature as a band, its LDLᵀ factor and solve, and the products with the
Hessian and the constraints. Each is a leaf (it calls no other helper), compiled by
:func:`snac_gym.kernels.relaxation.relaxation_kernel` and bound in that module's namespace, where its callers look
it up.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

#: The kernels' float arrays (numba ignores the annotations: it types the arguments it is called with).
_Floats = npt.NDArray[np.float64]


def _relaxed_hessian_band(
    steps: int, dt: float, q: float, w: float, rest: bool, terminal: float, band: _Floats
) -> None:  # pragma: no cover - compiled
    """Lower band of H, the Hessian of the relaxed cost in the interleaved variables (rows: diagonal, first and
    second subdiagonal, at the row's index): 2qΔt on each r, 2Δt + (2w/Δt)·(jumps vₖ is in) on each v (and
    2·terminal on the last), −2w/Δt between consecutive v (two places apart)."""
    c = w / dt
    for row in range(band.shape[0]):
        for column in range(band.shape[1]):
            band[row, column] = 0.0
    for k in range(steps):
        jumps = (1.0 if k > 0 else (1.0 if rest else 0.0)) + (1.0 if k < steps - 1 else 0.0)
        band[0, 2 * k] = 2.0 * dt + 2.0 * c * jumps
        if k > 0:
            band[0, 2 * k - 1] = 2.0 * q * dt
            band[2, 2 * k] = -2.0 * c
    band[0, 2 * steps - 2] += 2.0 * terminal


def _add_constraint_curvature(
    steps: int, b: _Floats, weight: _Floats, capped: bool, band: _Floats
) -> None:  # pragma: no cover - compiled
    """band += Gᵀ diag(weight) G: constraint k, rₖ − bₖvₖ − rₖ₊₁ ≤ dₖ, couples rₖ, vₖ, rₖ₊₁ (places 2k−1, 2k, 2k+1)."""
    for k in range(steps - 1):
        wk, bk = weight[k], b[k]
        band[0, 2 * k] += wk * bk * bk
        band[0, 2 * k + 1] += wk
        band[1, 2 * k + 1] += wk * bk
        if k > 0:
            band[0, 2 * k - 1] += wk
            band[1, 2 * k] -= wk * bk
            band[2, 2 * k + 1] -= wk
    if capped:
        for k in range(steps):
            band[0, 2 * k] += weight[steps - 1 + k]


def _ldl_factor(band: _Floats, inverse_pivots: _Floats) -> None:  # pragma: no cover - compiled
    """In place: the band's subdiagonals become those of the unit lower L of LDLᵀ, ``inverse_pivots`` 1/D.

    Lᵢ,ᵢ₋₂ = Aᵢ,ᵢ₋₂/Dᵢ₋₂,  Lᵢ,ᵢ₋₁ = (Aᵢ,ᵢ₋₁ − Lᵢ,ᵢ₋₂Lᵢ₋₁,ᵢ₋₂Dᵢ₋₂)/Dᵢ₋₁,  Dᵢ = Aᵢᵢ − Lᵢ,ᵢ₋₁²Dᵢ₋₁ − Lᵢ,ᵢ₋₂²Dᵢ₋₂
    (the previous two pivots and L₍ᵢ₋₁,ᵢ₋₂₎ carried in scalars: this recursion is the solve's critical path).
    """
    pivot1, pivot2, inverse1, inverse2, previous_first = 1.0, 1.0, 0.0, 0.0, 0.0
    for i in range(band.shape[1]):
        second = band[2, i] * inverse2
        coupling = band[1, i] - second * previous_first * pivot2
        # Lᵢ,ᵢ₋₁²Dᵢ₋₁ as coupling²/Dᵢ₋₁: one multiply between the last division and the next
        pivot = (band[0, i] - second * second * pivot2) - coupling * coupling * inverse1
        first = coupling * inverse1
        band[1, i], band[2, i] = first, second
        inverse = 1.0 / pivot
        inverse_pivots[i] = inverse
        pivot2, inverse2, pivot1, inverse1, previous_first = pivot1, inverse1, pivot, inverse, first


def _ldl_solve(band: _Floats, inverse_pivots: _Floats, rhs: _Floats) -> _Floats:  # pragma: no cover - compiled
    """rhs ← (LDLᵀ)⁻¹ rhs with the factor of :func:`_ldl_factor` (the last two values carried in scalars)."""
    n = band.shape[1]
    previous2, previous1 = 0.0, 0.0
    for i in range(n):
        value = rhs[i] - band[2, i] * previous2 - band[1, i] * previous1
        rhs[i] = value
        previous2, previous1 = previous1, value
    next2, next1 = 0.0, 0.0
    for i in range(n - 1, -1, -1):
        first = band[1, i + 1] if i + 1 < n else 0.0
        second = band[2, i + 2] if i + 2 < n else 0.0
        value = rhs[i] * inverse_pivots[i] - first * next1 - second * next2
        rhs[i] = value
        next2, next1 = next1, value
    return rhs


def _apply_constraints(
    steps: int, b: _Floats, x: _Floats, capped: bool, out: _Floats
) -> None:  # pragma: no cover - compiled
    """out ← G x: rₖ − bₖvₖ − rₖ₊₁ (r₀ is data, in h), then vₖ for the velocity caps."""
    for k in range(steps - 1):
        out[k] = (x[2 * k - 1] if k > 0 else 0.0) - b[k] * x[2 * k] - x[2 * k + 1]
    if capped:
        for k in range(steps):
            out[steps - 1 + k] = x[2 * k]


def _apply_constraints_transposed(
    steps: int, b: _Floats, z: _Floats, capped: bool, out: _Floats
) -> None:  # pragma: no cover - compiled
    """out ← Gᵀ z."""
    for k in range(steps):
        out[2 * k] = (z[steps - 1 + k] if capped else 0.0) - (b[k] * z[k] if k < steps - 1 else 0.0)
        if k > 0:
            out[2 * k - 1] = (z[k] if k < steps - 1 else 0.0) - z[k - 1]


def _apply_hessian(
    steps: int, dt: float, q: float, w: float, rest: bool, terminal: float, x: _Floats, out: _Floats
) -> None:  # pragma: no cover - compiled
    """out ← H x (:func:`_relaxed_hessian_band`)."""
    c = w / dt
    for k in range(steps):
        v = x[2 * k]
        value = 2.0 * dt * v
        if k > 0:
            value += 2.0 * c * (v - x[2 * k - 2])
            out[2 * k - 1] = 2.0 * q * dt * x[2 * k - 1]
        elif rest:
            value += 2.0 * c * v
        if k < steps - 1:
            value += 2.0 * c * (v - x[2 * k + 2])
        else:
            value += 2.0 * terminal * v
        out[2 * k] = value
