"""The direct single-shooting objective of the trajectory optimiser: θ rolled out from the commands U, the
errors and Jacobians along it, and V(U) with its exact gradient (:mod:`snac_gym.control.trajopt`).

θ is linear in U, so V and its gradient cost one batched FK+Jacobian pass.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from snac_gym.control.cost import CostConvention, cost_and_gradient
from snac_gym.model.kinematics import Kinematics, joint_path
from snac_gym.tasks.pose import pose_errors_and_jacobians

__all__ = ["angles", "errors_and_jacobians", "next_angles", "trajectory_cost_and_gradient"]


def angles(commands: np.ndarray, q0: np.ndarray, dt: float) -> np.ndarray:
    """θ₀..θ_{K−1} of θₖ₊₁ = θₖ + uₖΔt (one place, so that repeated calls give bit-identical angles)."""
    q = np.empty(commands.shape)
    q[0] = q0
    if len(commands) > 1:
        q[1:] = joint_path(q0, commands[:-1], dt)
    return q


def trajectory_cost_and_gradient(
    commands: np.ndarray,
    q0: np.ndarray,
    x_d: np.ndarray,
    kinematics: Kinematics,
    dt: float,
    convention: CostConvention | None = None,
) -> tuple[float, np.ndarray]:
    """V(U) and its exact gradient ∂V/∂U under ``convention`` (default: Q = I, R = I, u₋₁ = 0).

    Rolls U out from θ₀ (one batched FK+Jacobian pass) and scores it with
    :func:`snac_gym.control.cost.cost_and_gradient`, where the cost and its gradient are written.

    Args:
        commands: ``(K, m)`` commands U.
        q0: ``(m,)`` seed pose θ₀.
        x_d: ``(K, n)`` desired positions x_d(tₖ), k = 0..K−1.
        kinematics: The shared kinematic model.
        dt: Control period Δt, s.
        convention: The cost (:class:`snac_gym.control.cost.CostConvention`).
    """
    errors, jacobians = errors_and_jacobians(kinematics, angles(commands, q0, dt), x_d)
    return cost_and_gradient(errors, jacobians, commands, dt, convention)


def errors_and_jacobians(kinematics: Any, angles: np.ndarray, x_d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """eₖ and ∂eₖ/∂θₖ along ``angles``: ``f(θ) − x_d`` and J for the position tasks (the arithmetic
    the solver always had, so its position results stay bit for bit), the log₃ error and its exact
    Jacobian for a pose task (:func:`snac_gym.tasks.pose.pose_errors_and_jacobians`)."""
    if getattr(kinematics, "task_error", None) is not None:
        return pose_errors_and_jacobians(kinematics, angles, x_d)
    positions, jacobians = kinematics.forward_and_jacobian_batch(angles)
    return positions - x_d, jacobians


def next_angles(commands: np.ndarray, q0: np.ndarray, dt: float) -> np.ndarray:
    """θ₁..θ_K of θₖ₊₁ = θₖ + uₖΔt: the variables of the Gauss-Newton and interior-point systems."""
    return joint_path(q0, commands, dt)
