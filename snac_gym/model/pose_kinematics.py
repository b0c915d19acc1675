"""Full end-effector pose kinematics for the pose tasks: 6-D task coordinates, the SO(3)-logarithm task error
and the 6-row Jacobian, around the position :class:`~snac_gym.model.kinematics.Kinematics`."""

from __future__ import annotations

from functools import lru_cache
from typing import Any

import numpy as np
import pinocchio as pin

from snac_gym.model.position_kinematics import Kinematics

__all__ = ["PoseKinematics", "shared_pose_kinematics"]


class PoseKinematics:
    """Full end-effector pose kinematics: 6-D task coordinates and the 6-row Jacobian (pose tasks).

    Task coordinates are ``x = [p; r]``: the position ``p`` (m) of the end-effector frame in the base
    frame and the rotation vector ``r = log₃(R)`` (rad) of its orientation ``R`` in the base frame.
    The task error is not ``x − x_d`` but, as in Pinocchio's CLIK example, taken from the SO(3)
    logarithm (:meth:`task_error`): ``e = [p − p_d; log₃(R R_dᵀ)]``, the orientation error expressed
    in the base frame. The Jacobian is the frame's ``LOCAL_WORLD_ALIGNED`` Jacobian, whose angular
    rows map θ̇ to the angular velocity ω in the base frame, the frame of that error:
    ``ė = J u − ẋ_d`` holds exactly for the position rows and to first order in the orientation
    error for the others (``d/dt log₃(R R_dᵀ) = J_log₃ (ω − ω_d)`` with ``J_log₃ → I`` as the
    error vanishes; the CLIK example multiplies by ``J_log`` instead, which needs the target in
    the Jacobian and is not the controllers' ``ẋ = J(θ) u`` form).

    Everything about the arm (joint names, limits, the URDF, ``inverse_position`` and
    ``singular_values`` of the position Jacobian, used by the samplers) is the position
    :class:`Kinematics`' (:attr:`position`), so the envs and the samplers run unchanged.

    Args:
        robot: Name of a registered robot.
    """

    task_dim: int = 6

    def __init__(self, robot: str = "ur10") -> None:
        self.position = Kinematics(robot)
        self._ee_id = self.position._ee_id
        self._frame = pin.LOCAL_WORLD_ALIGNED
        # Its own, not the position kinematics' (which __getattr__ would find): (qs, poses, jacobians).
        self._last_batch: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None

    def __getattr__(self, name: str) -> Any:
        if name == "position":  # not set yet (unpickling): no recursion
            raise AttributeError(name)
        return getattr(self.position, name)

    def __reduce__(self) -> tuple[Any, ...]:
        return (PoseKinematics, (self.position.robot,))

    def __repr__(self) -> str:
        return f"PoseKinematics(robot={self.position.robot!r}, n_joints={self.position.n_joints})"

    def placement(self, q: np.ndarray) -> pin.SE3:
        """The end-effector frame's pose in the base frame."""
        k = self.position
        pin.forwardKinematics(k.model, k.data, k._check_q(q))
        return pin.updateFramePlacement(k.model, k.data, self._ee_id).copy()

    def forward(self, q: np.ndarray) -> np.ndarray:
        """``x = [p; log₃(R)]``, m and rad."""
        placement = self.placement(q)
        return np.concatenate([placement.translation, pin.log3(placement.rotation)])

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """The 6-row ``LOCAL_WORLD_ALIGNED`` Jacobian ``[J_v; J_ω]``, shape ``(6, n_joints)``."""
        k = self.position
        jac: np.ndarray = pin.computeFrameJacobian(k.model, k.data, k._check_q(q), self._ee_id, self._frame).copy()
        return jac

    def forward_and_jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(x, J)`` from one kinematics pass."""
        jacobian = self.jacobian(q)
        placement = self.position.data.oMf[self._ee_id]
        return np.concatenate([placement.translation, pin.log3(placement.rotation)]), jacobian

    def forward_and_jacobian_batch(self, qs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(x, J)`` of each row of ``qs`` ``(B, m)``: shapes ``(B, 6)`` and ``(B, 6, m)`` (a loop over Pinocchio).

        The last batch is remembered, as :meth:`Kinematics.forward_and_jacobian_batch` does: each control step
        of the evaluator asks for ``x`` of every sample and the policies then for ``J`` of the same
        configurations, and the loop over Pinocchio is most of a pose rollout's time. The arrays returned are
        therefore read-only.
        """
        qs = self.position._check_batch(qs)
        last = self._last_batch
        if last is not None and last[0].shape == qs.shape and np.array_equal(last[0], qs):
            return last[1], last[2]
        # forward_and_jacobian's calls, written in place: the same numbers, in 0.6 of the time.
        k, frame, reference = self.position, self._ee_id, self._frame
        model, data, placements = k.model, k.data, k.data.oMf
        poses, jacobians = np.empty((len(qs), 6)), np.empty((len(qs), 6, k.n_joints))
        for row, q in enumerate(qs):
            jacobians[row] = pin.computeFrameJacobian(model, data, q, frame, reference)
            placement = placements[frame]
            poses[row, :3] = placement.translation
            poses[row, 3:] = pin.log3(placement.rotation)
        poses.setflags(write=False)
        jacobians.setflags(write=False)
        self._last_batch = (qs.copy(), poses, jacobians)
        return poses, jacobians

    def forward_batch(self, qs: np.ndarray) -> np.ndarray:
        """``x`` of each row of ``qs``."""
        return self.forward_and_jacobian_batch(qs)[0]

    def jacobian_batch(self, qs: np.ndarray) -> np.ndarray:
        """``J`` of each row of ``qs``."""
        return self.forward_and_jacobian_batch(qs)[1]

    @staticmethod
    def task_error(x: np.ndarray, x_d: np.ndarray) -> np.ndarray:
        """``e = [p − p_d; log₃(R R_dᵀ)]`` for ``x = [p; log₃ R]`` and ``x_d = [p_d; log₃ R_d]``, m and rad."""
        rotation, desired = pin.exp3(x[3:]), pin.exp3(x_d[3:])
        return np.concatenate([x[:3] - x_d[:3], pin.log3(rotation @ desired.T)])

    def inverse_pose(
        self, target: np.ndarray, q_init: np.ndarray, tol: float = 1e-6, max_iters: int = 500, damping: float = 1e-3
    ) -> tuple[np.ndarray, bool]:
        """Damped-least-squares pose IK on ``e`` (Pinocchio's CLIK iteration), inside the joint limits.

        Returns:
            ``(q, converged)``: the last iterate and whether ``‖e‖ ≤ tol`` (m and rad together).
        """
        k = self.position
        q = np.clip(k._check_q(q_init).copy(), k.lower_limits, k.upper_limits)
        eye = np.eye(6)
        for _ in range(max_iters):
            x, jac = self.forward_and_jacobian(q)
            err = self.task_error(x, target)
            if err @ err <= tol * tol:
                return q, True
            step = -jac.T @ np.linalg.solve(jac @ jac.T + damping**2 * eye, err)
            norm = np.linalg.norm(step)
            if norm > 0.5:  # a trust region, as in inverse_position
                step *= 0.5 / norm
            q = np.clip(q + step, k.lower_limits, k.upper_limits)
        err = self.task_error(self.forward(q), target)
        return q, bool(err @ err <= tol * tol)


@lru_cache(maxsize=8)
def shared_pose_kinematics(robot: str) -> PoseKinematics:
    """One :class:`PoseKinematics` per robot and process (see :func:`shared_kinematics`)."""
    return PoseKinematics(robot)
