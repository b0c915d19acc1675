"""Compiled forward kinematics and position Jacobian of a serial chain, one configuration per loop pass.

:class:`~snac_gym.model.kinematics.BatchChain` reads the chain from the Pinocchio model (placements,
axes, joint types) and hands it here as arrays; this module knows nothing about any arm. Every
lockstep step of the evaluator and every cost evaluation of the optimal-control solver needs
``f(θ)`` and ``J(θ)`` of hundreds to thousands of configurations; as NumPy array arithmetic over
the batch that took about 1.2-1.5 µs per configuration (some 60 array operations per joint on
rows of B), compiled it takes a fraction of that (``python docs/scripts/kernel_speed.py``).

The arithmetic, per configuration and joint i of the chain (base first):

* frame Fᵢ = R_parent · Mᵢ and origin pᵢ = p_parent + R_parent · tᵢ (Mᵢ, tᵢ: the joint's placement);
* world axis zᵢ = Fᵢ aᵢ;
* revolute: Rᵢ = Fᵢ · Rot(aᵢ, θᵢ) with Rot(a, θ) = cos θ I + sin θ [a]× + (1 − cos θ) a aᵀ;
  prismatic: Rᵢ = Fᵢ and pᵢ += zᵢ θᵢ;
* x = p_ee + R_ee · offset; J's column of joint i: zᵢ × (x − pᵢ) (revolute) or zᵢ (prismatic), eq. 2.
"""

from __future__ import annotations

import numpy as np

from snac_gym.kernels.compiled import Example, helper, kernel


def chain_example() -> Example:
    """A one-joint revolute chain and two configurations: the argument types of every call."""
    return (np.zeros((2, 1)), np.eye(3)[None].copy(), np.zeros((1, 3)), np.array([[0.0, 0.0, 1.0]]), np.array([True]),
            np.array([0], dtype=np.int64), np.ones(3), 1)  # fmt: skip


def joint_frames(  # noqa: PLR0915  # pragma: no cover - compiled; one loop nest, as the kernels that call it
    qs: np.ndarray,
    b: int,
    rotations: np.ndarray,
    translations: np.ndarray,
    axes: np.ndarray,
    revolute: np.ndarray,
    columns: np.ndarray,
    ee_offset: np.ndarray,
    p: np.ndarray,
    z: np.ndarray,
    x: np.ndarray,
) -> None:
    """Every joint's origin ``p`` and world axis ``z`` at configuration ``qs[b]``, and the end effector's position
    into ``x`` (the module docstring's arithmetic, in its order: the same bits as a loop over the rows).

    The chain is serial, base first (each joint's parent is the joint before it), so the parent's frame is carried
    from one joint to the next in scalars, written out row by row: kept in arrays, as it was, each joint's frame went
    through memory, and f(θ) and J(θ) took about a sixth longer (``python docs/scripts/kernel_speed.py``).
    """
    r00 = r01 = r02 = r10 = r11 = r12 = r20 = r21 = r22 = 0.0  # the parent's rotation
    o0 = o1 = o2 = 0.0  # the parent's origin
    for s in range(rotations.shape[0]):
        t0, t1, t2 = translations[s, 0], translations[s, 1], translations[s, 2]
        m00, m01, m02 = rotations[s, 0, 0], rotations[s, 0, 1], rotations[s, 0, 2]
        m10, m11, m12 = rotations[s, 1, 0], rotations[s, 1, 1], rotations[s, 1, 2]
        m20, m21, m22 = rotations[s, 2, 0], rotations[s, 2, 1], rotations[s, 2, 2]
        if s == 0:  # placed on the base
            o0, o1, o2 = t0, t1, t2
            f00, f01, f02, f10, f11, f12, f20, f21, f22 = m00, m01, m02, m10, m11, m12, m20, m21, m22
        else:
            o0 = o0 + (r00 * t0 + r01 * t1 + r02 * t2)
            o1 = o1 + (r10 * t0 + r11 * t1 + r12 * t2)
            o2 = o2 + (r20 * t0 + r21 * t1 + r22 * t2)
            f00 = r00 * m00 + r01 * m10 + r02 * m20
            f01 = r00 * m01 + r01 * m11 + r02 * m21
            f02 = r00 * m02 + r01 * m12 + r02 * m22
            f10 = r10 * m00 + r11 * m10 + r12 * m20
            f11 = r10 * m01 + r11 * m11 + r12 * m21
            f12 = r10 * m02 + r11 * m12 + r12 * m22
            f20 = r20 * m00 + r21 * m10 + r22 * m20
            f21 = r20 * m01 + r21 * m11 + r22 * m21
            f22 = r20 * m02 + r21 * m12 + r22 * m22
        a0, a1, a2 = axes[s, 0], axes[s, 1], axes[s, 2]
        z0 = f00 * a0 + f01 * a1 + f02 * a2
        z1 = f10 * a0 + f11 * a1 + f12 * a2
        z2 = f20 * a0 + f21 * a1 + f22 * a2
        z[s, 0], z[s, 1], z[s, 2] = z0, z1, z2
        angle = qs[b, columns[s]]
        if not revolute[s]:
            o0 += z0 * angle
            o1 += z1 * angle
            o2 += z2 * angle
            r00, r01, r02, r10, r11, r12, r20, r21, r22 = f00, f01, f02, f10, f11, f12, f20, f21, f22
        else:
            c, sn = np.cos(angle), np.sin(angle)
            v = 1.0 - c
            along = z0 * v  # (Fᵢ·a)(1 − cos θ): row i of F a aᵀ, scaled
            r00 = c * f00 + sn * (f01 * a2 - f02 * a1) + along * a0
            r01 = c * f01 + sn * (f02 * a0 - f00 * a2) + along * a1
            r02 = c * f02 + sn * (f00 * a1 - f01 * a0) + along * a2
            along = z1 * v
            r10 = c * f10 + sn * (f11 * a2 - f12 * a1) + along * a0
            r11 = c * f11 + sn * (f12 * a0 - f10 * a2) + along * a1
            r12 = c * f12 + sn * (f10 * a1 - f11 * a0) + along * a2
            along = z2 * v
            r20 = c * f20 + sn * (f21 * a2 - f22 * a1) + along * a0
            r21 = c * f21 + sn * (f22 * a0 - f20 * a2) + along * a1
            r22 = c * f22 + sn * (f20 * a1 - f21 * a0) + along * a2
        p[s, 0], p[s, 1], p[s, 2] = o0, o1, o2
    e0, e1, e2 = ee_offset[0], ee_offset[1], ee_offset[2]
    x[0] = o0 + (r00 * e0 + r01 * e1 + r02 * e2)
    x[1] = o1 + (r10 * e0 + r11 * e1 + r12 * e2)
    x[2] = o2 + (r20 * e0 + r21 * e1 + r22 * e2)


joint_frames = helper(joint_frames, inline=True)


@kernel(chain_example)
def chain_forward_and_jacobian(
    qs: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    axes: np.ndarray,
    revolute: np.ndarray,
    columns: np.ndarray,
    ee_offset: np.ndarray,
    n_joints: int,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled; tested against Pinocchio
    """``(f(θ_b), J(θ_b))`` for the ``(B, m)`` configurations ``qs``: shapes ``(B, 3)`` and ``(B, 3, n_joints)``.

    The chain's S joints are given base first, each the parent of the next (a serial chain: the path from the base to
    the end effector's joint); the last one carries the end effector.

    Args:
        rotations, translations: ``(S, 3, 3)`` and ``(S, 3)`` joint placements in the parent's frame.
        axes: ``(S, 3)`` unit joint axes in the joint's frame.
        revolute: ``(S,)`` ``True`` for a revolute joint, ``False`` for a prismatic one.
        columns: ``(S,)`` the joint's column in ``qs`` and in J.
        ee_offset: ``(3,)`` the end-effector frame's position in the last joint's frame.
        n_joints: m, the width of J.
    """
    count, chain = qs.shape[0], rotations.shape[0]
    x = np.empty((count, 3))
    jacobians = np.zeros((count, 3, n_joints))
    p = np.empty((chain, 3))
    z = np.empty((chain, 3))
    for b in range(count):
        joint_frames(qs, b, rotations, translations, axes, revolute, columns, ee_offset, p, z, x[b])
        for s in range(chain):
            column = columns[s]
            if not revolute[s]:
                for i in range(3):
                    jacobians[b, i, column] = z[s, i]
            else:
                l0, l1, l2 = x[b, 0] - p[s, 0], x[b, 1] - p[s, 1], x[b, 2] - p[s, 2]
                jacobians[b, 0, column] = z[s, 1] * l2 - z[s, 2] * l1
                jacobians[b, 1, column] = z[s, 2] * l0 - z[s, 0] * l2
                jacobians[b, 2, column] = z[s, 0] * l1 - z[s, 1] * l0
    return x, jacobians
