"""Closed-loop inverse kinematics with the singular-value-filtered (SVF) inverse.

Reference:
    A. Colomé and C. Torras, "Redundant inverse kinematics: experimental comparative review
    and two enhancements", IEEE/RSJ IROS 2012, pp. 5333–5340.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from snac_gym.baselines._common import ResolvedRatePolicy, positive_float, transpose


def filtered_singular_values(singular_values: np.ndarray, nu: float, sigma0: float) -> np.ndarray:
    """Colomé and Torras' filter ``h(σ) = (σ³ + νσ² + 2σ + 2σ₀) / (σ² + νσ + 2)``.

    ``h(0) = σ₀``, ``h(σ) → σ`` as σ grows, and ``h(σ) ≥ σ₀`` for every σ ≥ 0 whenever
    ``σ₀ < ν`` and ``σ₀ν < 2`` (``h(σ) − σ₀`` has numerator ``σ³ + (ν − σ₀)σ² + (2 − σ₀ν)σ``),
    so ``1/h(σ) ≤ 1/σ₀``: the inverse gain stays bounded through singularities.
    """
    s = np.asarray(singular_values, dtype=float)
    s2 = s * s
    return (s2 * s + nu * s2 + 2.0 * s + 2.0 * sigma0) / (s2 + nu * s + 2.0)


class SVFPolicy(ResolvedRatePolicy):
    """Singular-value-filtering closed-loop IK (Colomé and Torras, IROS 2012).

    Implements, at every control step,

        v   = ẋ_d + K (x_d − x)                                 (reference velocity)
        J   = U diag(σᵢ) Vᵀ                                     (thin SVD of the 3×m position Jacobian)
        Ĵ⁺  = V diag(1/h(σᵢ)) Uᵀ,  h(σ) = (σ³ + νσ² + 2σ + 2σ₀)/(σ² + νσ + 2)
        u   = sat(Ĵ⁺ v)

    where ``sat`` scales ``u`` uniformly into the joint-velocity limits (keeping its direction;
    see :func:`snac_gym.baselines._common.scale_into_box`). Away from singularities ``h(σ) ≈ σ`` and
    ``Ĵ⁺ ≈ J⁺``; near them ``1/h(σ) ≤ 1/σ₀``, so ``‖Ĵ⁺‖ ≤ 1/σ₀`` always. Regulation is the case
    ``ẋ_d = 0``.

    Args:
        env: The env (or policy context) to drive.
        gain: Task-space feedback gain ``K``, 1/s; the effort knob (``effort_parameter``).
        nu: Filter shape ``ν`` (default 10, the paper's); larger ν makes ``h`` follow σ
            more closely down to smaller σ.
        sigma0: Minimum filtered singular value ``σ₀`` (default 0.005, the paper's), m/rad:
            the Jacobian's inverse gain never exceeds ``1/σ₀``.
        joint_limits: Clamp into the position-limit box Ω(θ) (:class:`~snac_gym.baselines._common.ResolvedRatePolicy`).

    Raises:
        ValueError: If a parameter is not positive, or ``σ₀ν ≥ 2`` or ``σ₀ ≥ ν`` (where the
            bound ``h(σ) ≥ σ₀`` would no longer hold).
    """

    def __init__(
        self, env: Any, gain: float = 2.0, nu: float = 10.0, sigma0: float = 0.005, joint_limits: bool | None = None
    ) -> None:
        super().__init__(env, gain, joint_limits)
        self.nu = positive_float("nu", nu)
        self.sigma0 = positive_float("sigma0", sigma0)
        if self.sigma0 * self.nu >= 2.0 or self.sigma0 >= self.nu:
            raise ValueError(f"need sigma0 < nu and sigma0 * nu < 2 for h(σ) ≥ σ₀, got sigma0={sigma0}, nu={nu}")

    def filtered_pseudoinverse(self, jacobian: np.ndarray) -> np.ndarray:
        """``Ĵ⁺ = V diag(1/h(σᵢ)) Uᵀ``, shape ``(m, n)``."""
        from snac_gym.kernels.small import svd  # compiled Jacobi SVD; numba imported where first needed

        u_mat, sigma, vt = svd(jacobian)
        return (vt.T / filtered_singular_values(sigma, self.nu, self.sigma0)) @ u_mat.T

    def resolve(self, jacobian: np.ndarray, task_velocity: np.ndarray) -> np.ndarray:
        """``Ĵ⁺ v`` for one ``(J, v)`` or stacks ``(B, n, m)``, ``(B, n, 1)``."""
        from snac_gym.kernels.small import svd  # numba imported where first needed, as above

        u_mat, sigma, vt = svd(jacobian)
        filtered = filtered_singular_values(sigma, self.nu, self.sigma0)
        if task_velocity.ndim > 1:
            filtered = filtered[..., None]  # a column per sample
        # Ĵ⁺ v without forming Ĵ⁺: V (Uᵀv / h(σ)).
        return transpose(vt) @ ((transpose(u_mat) @ task_velocity) / filtered)

    resolves_stacks = True
