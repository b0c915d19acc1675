"""``pink``: resolved-rate QP differential IK with pink (Pinocchio) and daqp (:mod:`snac_gym.baselines.qp_ik`).

Reference: S. Caron et al., "Pink: Python inverse kinematics based on Pinocchio", 2024,
https://github.com/stephane-caron/pink; the QP formulation of task-based differential IK:
https://scaron.info/robotics/differential-inverse-kinematics.html.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pinocchio as pin
from snac_gym.baselines.qp_ik import QPIKPolicy


def _task_class(pink: Any) -> type:
    """A pink ``Task`` with the project's task error (set before each solve) and the frame's Jacobian."""

    class ProjectTask(pink.tasks.Task):
        """``e`` given, ``J`` the frame's ``LOCAL_WORLD_ALIGNED`` Jacobian (its first ``dim`` rows), W = I."""

        def __init__(self, frame_id: int, dim: int, gain: float, lm_damping: float) -> None:
            super().__init__(cost=1.0, gain=gain, lm_damping=lm_damping)
            self.frame_id, self.dim = frame_id, dim
            self.error = np.zeros(dim)

        def compute_error(self, configuration: Any) -> np.ndarray:
            return self.error

        def compute_jacobian(self, configuration: Any) -> np.ndarray:
            jacobian = pin.getFrameJacobian(
                configuration.model, configuration.data, self.frame_id, pin.LOCAL_WORLD_ALIGNED
            )
            return jacobian[: self.dim]

        def compute_qp_objective(self, configuration: Any) -> tuple[np.ndarray, np.ndarray]:
            """pink's ``(H, c)`` of ``½‖J Δq + α e‖²`` with W = I, without building W: ``H = JᵀJ + μI``,
            ``c = α Jᵀe``, ``μ = lm_damping ‖α e‖²`` (``Task.compute_qp_objective`` with cost 1)."""
            jacobian = self.compute_jacobian(configuration)
            scaled_error = self.gain * self.error
            hessian = jacobian.T @ jacobian
            if self.lm_damping:
                hessian.flat[:: hessian.shape[0] + 1] += self.lm_damping * (scaled_error @ scaled_error)
            return hessian, scaled_error @ jacobian

        def __repr__(self) -> str:
            return f"ProjectTask(frame_id={self.frame_id}, dim={self.dim}, gain={self.gain})"

    return ProjectTask


class PinkPolicy(QPIKPolicy):
    """QP differential IK with pink: the project's task, pink's damping (``solve_ik(damping=λ²)``),
    ``ConfigurationLimit`` (gain 0.5, pink's default) and ``VelocityLimit`` (the env's velocity limits),
    ``pink.solve_ik`` with daqp.

    The Pinocchio model is a copy of the project's (:class:`~snac_gym.model.kinematics.Kinematics`: the same
    URDF, frames and base frame), so J is the project's Jacobian. Arguments:
    :class:`~snac_gym.baselines.qp_ik.QPIKPolicy`.
    """

    module = "pink"
    default_limit_gain = 0.5

    def _setup(self, pink: Any, kinematics: Any) -> None:
        model = pin.Model(kinematics.model)  # pink attaches its limits to the model: not on the shared one
        self._configuration = pink.Configuration(model, model.createData(), pin.neutral(model), copy_data=False)
        self._task = _task_class(pink)(kinematics._ee_id, self.task_dim, self.gain * self.dt, self.lm_damping)
        self._tasks = [self._task]
        self._limits = [
            pink.limits.ConfigurationLimit(model, config_limit_gain=self.limit_gain),
            pink.limits.VelocityLimit(model, velocity_limit=self.velocity_limits),
        ]
        self._solve_ik = pink.solve_ik
        self._model, self._data = model, self._configuration.data

    def task_jacobian(self, q: np.ndarray) -> np.ndarray:
        """``J`` at ``q``: Pinocchio's frame Jacobian in one call (what pink's ``Configuration.update`` and
        ``getFrameJacobian`` compute in two, with a read-only copy of ``q`` between)."""
        jacobian = pin.computeFrameJacobian(self._model, self._data, q, self._task.frame_id, pin.LOCAL_WORLD_ALIGNED)
        return jacobian[: self.task_dim]
