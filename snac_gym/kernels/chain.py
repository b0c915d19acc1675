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
    return (np.zeros((2, 1)), np.array([-1], dtype=np.int64), np.eye(3)[None].copy(), np.zeros((1, 3)),
            np.array([[0.0, 0.0, 1.0]]), np.array([True]), np.array([0], dtype=np.int64), np.ones(3), 1)  # fmt: skip


def joint_frames(  # noqa: C901  # pragma: no cover - compiled; one loop nest, as the kernels that call it
    qs: np.ndarray,
    b: int,
    parent_slot: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    axes: np.ndarray,
    revolute: np.ndarray,
    columns: np.ndarray,
    ee_offset: np.ndarray,
    R: np.ndarray,
    p: np.ndarray,
    z: np.ndarray,
    F: np.ndarray,
    x: np.ndarray,
) -> None:
    """Every joint's frame ``R``, origin ``p`` and world axis ``z`` at configuration ``qs[b]``, and the end effector's
    position into ``x`` (the module docstring's arithmetic; ``F`` is scratch)."""
    chain = rotations.shape[0]
    for s in range(chain):
        parent = parent_slot[s]
        if parent < 0:
            for i in range(3):
                p[s, i] = translations[s, i]
                for j in range(3):
                    F[i, j] = rotations[s, i, j]
        else:
            for i in range(3):
                p[s, i] = p[parent, i] + (
                    R[parent, i, 0] * translations[s, 0]
                    + R[parent, i, 1] * translations[s, 1]
                    + R[parent, i, 2] * translations[s, 2]
                )
                for j in range(3):
                    F[i, j] = (
                        R[parent, i, 0] * rotations[s, 0, j]
                        + R[parent, i, 1] * rotations[s, 1, j]
                        + R[parent, i, 2] * rotations[s, 2, j]
                    )
        a0, a1, a2 = axes[s, 0], axes[s, 1], axes[s, 2]
        for i in range(3):
            z[s, i] = F[i, 0] * a0 + F[i, 1] * a1 + F[i, 2] * a2
        angle = qs[b, columns[s]]
        if not revolute[s]:
            for i in range(3):
                p[s, i] += z[s, i] * angle
                for j in range(3):
                    R[s, i, j] = F[i, j]
        else:
            c, sn = np.cos(angle), np.sin(angle)
            v = 1.0 - c
            for i in range(3):
                f0, f1, f2 = F[i, 0], F[i, 1], F[i, 2]
                along = z[s, i] * v  # (Fᵢ·a)(1 − cos θ): row i of F a aᵀ, scaled
                R[s, i, 0] = c * f0 + sn * (f1 * a2 - f2 * a1) + along * a0
                R[s, i, 1] = c * f1 + sn * (f2 * a0 - f0 * a2) + along * a1
                R[s, i, 2] = c * f2 + sn * (f0 * a1 - f1 * a0) + along * a2
    last = chain - 1
    for i in range(3):
        x[i] = p[last, i] + (R[last, i, 0] * ee_offset[0] + R[last, i, 1] * ee_offset[1] + R[last, i, 2] * ee_offset[2])


joint_frames = helper(joint_frames, inline=True)


@kernel(chain_example)
def chain_forward_and_jacobian(
    qs: np.ndarray,
    parent_slot: np.ndarray,
    rotations: np.ndarray,
    translations: np.ndarray,
    axes: np.ndarray,
    revolute: np.ndarray,
    columns: np.ndarray,
    ee_offset: np.ndarray,
    n_joints: int,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled; tested against Pinocchio
    """``(f(θ_b), J(θ_b))`` for the ``(B, m)`` configurations ``qs``: shapes ``(B, 3)`` and ``(B, 3, n_joints)``.

    The chain's S joints are given base first; the last one carries the end effector.

    Args:
        parent_slot: ``(S,)`` index of each joint's parent in the chain, −1 for a joint on the base.
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
    R = np.empty((chain, 3, 3))
    p = np.empty((chain, 3))
    z = np.empty((chain, 3))
    F = np.empty((3, 3))
    for b in range(count):
        joint_frames(qs, b, parent_slot, rotations, translations, axes, revolute, columns, ee_offset, R, p, z, F, x[b])
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
