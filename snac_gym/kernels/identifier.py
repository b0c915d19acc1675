"""Compiled model of ``snac-adaptive``'s identifier: x̂, Ĵ and H = ∂x̂/∂c of a revolute chain with a rigid
correction at the base and after every joint, one row (an episode's θ and ĉ) per loop pass.

:class:`~snac_gym.policies.snac_adaptive.GeometricIdentifier` reads the chain from the Pinocchio model and
hands it here as arrays; this module knows nothing about any arm. Per row and frame k (0: the base, j: after
joint j's motion) the correction is E_k = (Exp(ρ_k), τ_k), and the arithmetic is the module docstring of
:mod:`snac_gym.policies.snac_adaptive`:

* R, p ← Exp(ρ₀), τ₀; for each joint j (base first): F = R Mⱼ, oⱼ = p + R tⱼ, zⱼ = F aⱼ, R⁻ = F Rot(aⱼ, θⱼ),
  then p⁺ = oⱼ + R⁻ τⱼ, R⁺ = R⁻ Exp(ρⱼ) (R, p ← R⁺, p⁺);
* x̂ = p + R p_tool; Ĵ's column j: zⱼ × (x̂ − oⱼ) (eq. 2 on the corrected chain);
* H_k = [R_k⁻, −[x̂ − p_k⁺]ₓ R_k⁺ J_r(ρ_k)], J_r SO(3)'s right Jacobian.

Written as NumPy array arithmetic over the batch, the model is some 300 small array operations, called four times
a control step (three Gauss–Newton passes and Ĵ after them): milliseconds for one episode, most of a 500 Hz period.
Compiled, one ``act`` of ``snac-adaptive`` takes a fraction of a millisecond (docs/model-error.md, "Speed").
"""

from __future__ import annotations

import numpy as np

from snac_gym.kernels.compiled import Example, kernel


def _example() -> Example:
    """A one-joint chain, two rows: the argument types of every call."""
    return (np.zeros((2, 1)), np.zeros((2, 12)), np.eye(3)[None].copy(), np.zeros((1, 3)),
            np.array([[0.0, 0.0, 1.0]]), np.array([0], dtype=np.int64), np.ones(3))  # fmt: skip


@kernel(_example)
def corrected_chain(  # noqa: C901 - one compiled loop nest, kept inline for speed
    qs: np.ndarray,
    params: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    axes: np.ndarray,
    columns: np.ndarray,
    tool: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:  # pragma: no cover - compiled; tested against finite differences
    """``(x̂, Ĵ, H)`` of shapes ``(B, 3)``, ``(B, 3, m)`` and ``(B, 3, 6(S + 1))`` for the ``(B, m)`` configurations.

    Args:
        qs: ``(B, m)`` joint angles.
        params: ``(B, 6(S + 1))`` corrections (τ₀, ρ₀, τ₁, ρ₁, …), frame 0 the base.
        rotations, translations: ``(S, 3, 3)`` and ``(S, 3)`` joint placements of the S joints, base first.
        axes: ``(S, 3)`` unit joint axes in the joint's frame (revolute joints).
        columns: ``(S,)`` each joint's column in ``qs`` and in Ĵ.
        tool: ``(3,)`` the tool point in the last joint's frame.
    """
    count, m = qs.shape
    chain = rotations.shape[0]
    frames = chain + 1
    x = np.empty((count, 3))
    jacobians = np.zeros((count, 3, m))
    regressors = np.empty((count, 3, 6 * frames))
    before = np.empty((frames, 3, 3))
    after = np.empty((frames, 3, 3))
    origin_after = np.empty((frames, 3))
    right = np.empty((frames, 3, 3))
    z = np.empty((chain, 3))
    o = np.empty((chain, 3))
    E = np.empty((3, 3))
    F = np.empty((3, 3))
    R = np.empty((3, 3))
    T = np.empty((3, 3))
    K = np.empty((3, 3))
    for b in range(count):
        for k in range(frames):
            r0, r1, r2 = params[b, 6 * k + 3], params[b, 6 * k + 4], params[b, 6 * k + 5]
            angle2 = r0 * r0 + r1 * r1 + r2 * r2
            angle = np.sqrt(angle2)
            if angle < 1e-6:  # Taylor series, where the closed forms lose their digits
                sa, sb, sc = 1.0 - angle2 / 6.0, 0.5 - angle2 / 24.0, 1.0 / 6.0 - angle2 / 120.0
            else:
                sa = np.sin(angle) / angle
                sb = (1.0 - np.cos(angle)) / angle2
                sc = (angle - np.sin(angle)) / (angle2 * angle)
            K[0, 0], K[0, 1], K[0, 2] = 0.0, -r2, r1
            K[1, 0], K[1, 1], K[1, 2] = r2, 0.0, -r0
            K[2, 0], K[2, 1], K[2, 2] = -r1, r0, 0.0
            for i in range(3):
                for j in range(3):
                    k2 = K[i, 0] * K[0, j] + K[i, 1] * K[1, j] + K[i, 2] * K[2, j]
                    eye = 1.0 if i == j else 0.0
                    after[k, i, j] = eye + sa * K[i, j] + sb * k2  # Exp(ρ), kept here until used
                    right[k, i, j] = eye - sb * K[i, j] + sc * k2
        # the base: R = Exp(ρ₀), p = τ₀
        for i in range(3):
            for j in range(3):
                E[i, j] = after[0, i, j]
                R[i, j] = E[i, j]
                before[0, i, j] = 1.0 if i == j else 0.0
            origin_after[0, i] = params[b, i]
        for s in range(chain):
            for i in range(3):
                o[s, i] = (
                    origin_after[s, i]
                    + R[i, 0] * translations[s, 0]
                    + R[i, 1] * translations[s, 1]
                    + R[i, 2] * translations[s, 2]
                )
                for j in range(3):
                    F[i, j] = R[i, 0] * rotations[s, 0, j] + R[i, 1] * rotations[s, 1, j] + R[i, 2] * rotations[s, 2, j]
            a0, a1, a2 = axes[s, 0], axes[s, 1], axes[s, 2]
            for i in range(3):
                z[s, i] = F[i, 0] * a0 + F[i, 1] * a1 + F[i, 2] * a2
            c, sn = np.cos(qs[b, columns[s]]), np.sin(qs[b, columns[s]])
            v = 1.0 - c
            for i in range(3):  # R⁻ = F Rot(a, θ)
                f0, f1, f2 = F[i, 0], F[i, 1], F[i, 2]
                along = z[s, i] * v
                T[i, 0] = c * f0 + sn * (f1 * a2 - f2 * a1) + along * a0
                T[i, 1] = c * f1 + sn * (f2 * a0 - f0 * a2) + along * a1
                T[i, 2] = c * f2 + sn * (f0 * a1 - f1 * a0) + along * a2
            frame = s + 1
            t0, t1, t2 = params[b, 6 * frame], params[b, 6 * frame + 1], params[b, 6 * frame + 2]
            for i in range(3):
                origin_after[frame, i] = o[s, i] + T[i, 0] * t0 + T[i, 1] * t1 + T[i, 2] * t2
                for j in range(3):
                    before[frame, i, j] = T[i, j]
                    E[i, j] = after[frame, i, j]
            for i in range(3):  # R⁺ = R⁻ Exp(ρ)
                for j in range(3):
                    R[i, j] = T[i, 0] * E[0, j] + T[i, 1] * E[1, j] + T[i, 2] * E[2, j]
            for i in range(3):
                for j in range(3):
                    after[frame, i, j] = R[i, j]
        last = frames - 1
        for i in range(3):
            x[b, i] = origin_after[last, i] + R[i, 0] * tool[0] + R[i, 1] * tool[1] + R[i, 2] * tool[2]
        for s in range(chain):
            column = columns[s]
            l0, l1, l2 = x[b, 0] - o[s, 0], x[b, 1] - o[s, 1], x[b, 2] - o[s, 2]
            jacobians[b, 0, column] += z[s, 1] * l2 - z[s, 2] * l1
            jacobians[b, 1, column] += z[s, 2] * l0 - z[s, 0] * l2
            jacobians[b, 2, column] += z[s, 0] * l1 - z[s, 1] * l0
        for k in range(frames):
            d0, d1, d2 = x[b, 0] - origin_after[k, 0], x[b, 1] - origin_after[k, 1], x[b, 2] - origin_after[k, 2]
            for j in range(3):  # Rj = R_k⁺ J_r(ρ_k), column j
                q0 = after[k, 0, 0] * right[k, 0, j] + after[k, 0, 1] * right[k, 1, j] + after[k, 0, 2] * right[k, 2, j]
                q1 = after[k, 1, 0] * right[k, 0, j] + after[k, 1, 1] * right[k, 1, j] + after[k, 1, 2] * right[k, 2, j]
                q2 = after[k, 2, 0] * right[k, 0, j] + after[k, 2, 1] * right[k, 1, j] + after[k, 2, 2] * right[k, 2, j]
                for i in range(3):
                    regressors[b, i, 6 * k + j] = before[k, i, j]
                # −[d]ₓ q = q × d
                regressors[b, 0, 6 * k + 3 + j] = q1 * d2 - q2 * d1
                regressors[b, 1, 6 * k + 3 + j] = q2 * d0 - q0 * d2
                regressors[b, 2, 6 * k + 3 + j] = q0 * d1 - q1 * d0
    return x, jacobians, regressors
