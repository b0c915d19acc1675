"""Compiled assembly of the optimum's Gauss-Newton matrix (:func:`snac_gym.control.trajopt.gauss_newton_direction`).

Each Gauss-Newton iteration adds the blocks 2Δt·q·JₖᵀJₖ (k = 1..K−1) to the fixed band A ⊗ I_m.
As NumPy array arithmetic (a stack of products, then a scattered ``+=``) that took about a fifth
of a 2500-step iteration; this is one pass over the Jacobians with the same sums in the same
order, so the band is the same bit for bit (tests/evaluation/reference/test_optimum.py).
"""

from __future__ import annotations

import numpy as np

from snac_gym.kernels.compiled import kernel, read_only


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
