"""The kinematic chain of a Pinocchio model evaluated over a batch of configurations at once: f and J
(:class:`BatchChain`, the compiled loop behind :meth:`~snac_gym.model.kinematics.Kinematics.forward_and_jacobian_batch`)
and f alone (:class:`PositionChain`, what the envs need each step)."""

from __future__ import annotations

from typing import Any, Protocol

import numpy as np
import pinocchio as pin

from snac_gym.model.model_error import joint_axis

__all__ = ["BatchChain", "PositionChain", "leaf_chain"]


class ChainSource(Protocol):
    """What the chains are read from: a model whose root joints are placed in the base frame, and the end-effector
    frame (a :class:`~snac_gym.model.kinematics.Kinematics`)."""

    model: pin.Model
    ee_frame: str


class BatchChain:
    """A Pinocchio model's kinematic tree evaluated over a batch of configurations at once.

    Pinocchio has no batched call from Python, and one ``computeFrameJacobian`` costs about
    1.6 µs of which most is the call itself, while the evaluator needs ``f`` and ``J`` for
    thousands of configurations per control step. This evaluates the same product of joint
    placements and joint motions, ``oMᵢ = oM_parent(i) · M_i · exp(S_i θᵢ)``, for the joints that
    carry the end effector, reading every placement and axis from the Pinocchio model (nothing
    about the UR arms is written here), in a compiled loop over the batch
    (:func:`~snac_gym.kernels.chain.chain_forward_and_jacobian`). The position Jacobian column of a
    revolute joint is ``zᵢ × (x − pᵢ)`` and of a prismatic joint ``zᵢ`` (eq. 2); joints that do not
    carry the end effector have zero columns. Results match Pinocchio to rounding
    (tests/model/test_kinematics.py, 1e-12).

    Build one with :meth:`from_model`, which returns ``None`` for a model with other joint types.
    """

    def __init__(
        self,
        parents: list[int],
        placements: list[tuple[np.ndarray, np.ndarray]],
        axes: list[np.ndarray],
        revolute: list[bool],
        q_index: list[int],
        ee_joint: int,
        ee_offset: np.ndarray,
        n_joints: int,
    ) -> None:
        support, joint = [], ee_joint
        while joint > 0:
            support.append(joint)
            joint = parents[joint - 1]
        self._support = sorted(support)
        # The chain base first, as arrays for the compiled kernel (snac_gym/kernels/chain.py): the path from the base
        # to the end effector's joint, each joint the parent of the next (Pinocchio numbers a parent before its child).
        chain = [joint - 1 for joint in self._support]
        self._kernel_arrays = (
            np.array([placements[i][0] for i in chain], dtype=float).reshape(-1, 3, 3),
            np.array([placements[i][1] for i in chain], dtype=float).reshape(-1, 3),
            np.array([axes[i] for i in chain], dtype=float).reshape(-1, 3),
            np.array([revolute[i] for i in chain], dtype=np.bool_),
            np.array([q_index[i] for i in chain], dtype=np.int64),
            np.asarray(ee_offset, dtype=float).reshape(3),
            int(n_joints),
        )

    @classmethod
    def from_model(cls, model: Any, ee_frame_id: int) -> BatchChain | None:
        """The chain of ``model`` up to frame ``ee_frame_id``, or ``None`` if a joint is not a 1-DoF
        revolute/prismatic."""
        parents, placements, axes, revolute, q_index = [], [], [], [], []
        for joint in range(1, model.njoints):
            joint_model = model.joints[joint]
            found = joint_axis(joint_model)
            if found is None:
                return None
            parents.append(int(model.parents[joint]))
            placement = model.jointPlacements[joint]
            placements.append((placement.rotation.copy(), placement.translation.copy()))
            axes.append(found[0])
            revolute.append(found[1])
            q_index.append(int(joint_model.idx_q))
        frame = model.frames[ee_frame_id]
        if frame.parentJoint == 0:
            return None
        offset = frame.placement.translation.copy()
        return cls(parents, placements, axes, revolute, q_index, int(frame.parentJoint), offset, int(model.nq))

    def forward_and_jacobian(self, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(f(θᵢ), J(θᵢ))``, shapes ``(B, 3)`` and ``(B, 3, m)``."""
        from snac_gym.kernels.chain import chain_forward_and_jacobian  # numba: imported where first needed

        return chain_forward_and_jacobian(np.ascontiguousarray(qs, dtype=float), *self._kernel_arrays)

    def error_curvature(self, qs: np.ndarray, errors: np.ndarray) -> np.ndarray:
        """``Σᵢ eᵢ ∂²fᵢ/∂θ²`` at each configuration for its error ``(B, 3)``: ``(B, m, m)``, the part of the Hessian of
        ½‖e‖² that J leaves out (:func:`~snac_gym.kernels.trajopt.chain_error_curvature`)."""
        from snac_gym.kernels.trajopt import chain_error_curvature  # numba: imported where first needed

        return chain_error_curvature(
            np.ascontiguousarray(qs, dtype=float), np.ascontiguousarray(errors, dtype=float), *self._kernel_arrays
        )


def leaf_chain(
    kinematics: ChainSource,
) -> tuple[list[tuple[np.ndarray, np.ndarray, np.ndarray, bool, int]], np.ndarray]:
    """The joints that carry the end effector, leaf first, as (rotation, translation, axis, revolute, q index) of
    each joint's placement and motion, and the end-effector frame's offset in its joint's frame.

    Read from ``kinematics.model``, whose root joints are already placed in the base frame, so the chain gives
    base-frame positions (:class:`PositionChain`, and the IPOPT cross-check's CasADi expression).

    Raises:
        ValueError: If a joint on the way is not a 1-DoF revolute or prismatic joint.
    """
    model = kinematics.model
    frame = model.frames[model.getFrameId(kinematics.ee_frame)]
    steps = []
    joint = int(frame.parentJoint)
    while joint > 0:
        found = joint_axis(model.joints[joint])
        if found is None:
            raise ValueError(f"joint {model.names[joint]!r} is not a 1-DoF revolute or prismatic joint")
        placement = model.jointPlacements[joint]
        steps.append(
            (
                placement.rotation.copy(),
                placement.translation.copy(),
                found[0],
                found[1],
                int(model.joints[joint].idx_q),
            )
        )
        joint = int(model.parents[joint])
    return steps, frame.placement.translation.copy()


class PositionChain:
    """Batched forward kinematics of the end-effector position only, f(θ) for B configurations.

    The env needs x = f(θ) each step but never J, and :class:`~snac_gym.model.kinematics.BatchChain`
    builds every joint frame (3×3 rotations) to get J. This evaluates the same chain of joint
    placements read from the Pinocchio model from the leaf inwards on one point,
    ``v ← tᵢ + Mᵢ · Rᵢ(θᵢ) · v`` (starting from the end-effector offset), with the batch as
    rows of length B (structure of arrays), about 4x fewer operations. Matches Pinocchio to
    1e-15 m (tests/envs/test_vector.py).

    Args:
        steps: Leaf-to-root joints, each ``(rotation M, translation t, axis, revolute, q column)``.
        offset: The end-effector frame's position in its parent joint's frame.
    """

    def __init__(self, steps: list[tuple[np.ndarray, np.ndarray, np.ndarray, bool, int]], offset: np.ndarray) -> None:
        self._steps = steps
        self._offset = offset
        self._aligned = [_aligned_axis(axis) for _, _, axis, _, _ in steps]
        self._identity = [bool(np.array_equal(rotation, np.eye(3))) for rotation, _, _, _, _ in steps]

    @classmethod
    def from_kinematics(cls, kinematics: ChainSource) -> PositionChain:
        """The chain from the model's root to ``kinematics.ee_frame`` (:func:`leaf_chain`).

        Raises:
            ValueError: If a joint on the way is not a 1-DoF revolute or prismatic joint.
        """
        return cls(*leaf_chain(kinematics))

    def forward(self, qs: np.ndarray) -> np.ndarray:
        """End-effector positions, ``(B, m) -> (B, 3)``, in the frame of :meth:`Kinematics.forward`."""
        qs = np.asarray(qs, dtype=float)
        count = len(qs)
        columns = qs.T  # joint-major: each joint's angles as one row
        cosines, sines = np.cos(columns), np.sin(columns)
        v = [np.full(count, value) for value in self._offset]
        for index, (rotation, translation, axis, revolute, column) in enumerate(self._steps):
            if revolute:
                v = self._rotate(v, index, cosines[column], sines[column])
            else:
                v = [v[i] + axis[i] * columns[column] for i in range(3)]
            if not self._identity[index]:
                v = [rotation[i, 0] * v[0] + rotation[i, 1] * v[1] + rotation[i, 2] * v[2] for i in range(3)]
            v = [v[i] + translation[i] for i in range(3)]
        return np.stack(v, axis=1)

    def _rotate(self, v: list[np.ndarray], index: int, cos: np.ndarray, sin: np.ndarray) -> list[np.ndarray]:
        """``R(axis, θ) · v`` for joint ``index``: two components turn about an aligned axis, else Rodrigues."""
        aligned = self._aligned[index]
        if aligned is not None:
            first, second = (aligned + 1) % 3, (aligned + 2) % 3
            turned = list(v)
            turned[first] = cos * v[first] - sin * v[second]
            turned[second] = sin * v[first] + cos * v[second]
            return turned
        a = self._steps[index][2]
        cross = [a[1] * v[2] - a[2] * v[1], a[2] * v[0] - a[0] * v[2], a[0] * v[1] - a[1] * v[0]]
        double = [
            a[1] * cross[2] - a[2] * cross[1],
            a[2] * cross[0] - a[0] * cross[2],
            a[0] * cross[1] - a[1] * cross[0],
        ]
        return [v[i] + sin * cross[i] + (1.0 - cos) * double[i] for i in range(3)]


def _aligned_axis(axis: np.ndarray) -> int | None:
    """Index of ``axis`` if it is a positive coordinate axis, else ``None``."""
    if np.count_nonzero(axis) == 1 and axis.max() == 1.0:
        return int(np.argmax(axis))
    return None
