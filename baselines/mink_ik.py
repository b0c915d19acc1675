"""``mink``: resolved-rate QP differential IK with mink (MuJoCo) and daqp (:mod:`snac_gym.baselines.qp_ik`).

Reference: K. Zakka et al., "mink: Python inverse kinematics based on MuJoCo", 2024,
https://github.com/kevinzakka/mink.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from snac_gym.baselines.qp_ik import QPIKPolicy

from snac_gym.common.extras import require
from snac_gym.physics.mujoco_model import EE_SITE, shared_mujoco_model


def _task_class(mink: Any, mujoco: Any) -> type:
    """A mink ``Task`` with the project's task error (set before each solve) and the site's Jacobian."""

    class ProjectTask(mink.Task):
        """``e`` given, ``J`` = [jacp; jacr] of the end-effector site (its first ``dim`` rows,
        world = base frame), W = I."""

        def __init__(self, site_id: int, nv: int, dim: int, gain: float, lm_damping: float) -> None:
            super().__init__(cost=np.ones(dim), gain=gain, lm_damping=lm_damping)
            self.site_id, self.dim = site_id, dim
            self.error = np.zeros(dim)
            self._jacobian = np.zeros((6, nv))

        def compute_error(self, configuration: Any) -> np.ndarray:
            return self.error

        def compute_jacobian(self, configuration: Any) -> np.ndarray:
            jacobian = self._jacobian
            mujoco.mj_jacSite(configuration.model, configuration.data, jacobian[:3], jacobian[3:], self.site_id)
            return jacobian[: self.dim]

        def __repr__(self) -> str:
            return f"ProjectTask(site_id={self.site_id}, dim={self.dim}, gain={self.gain})"

    return ProjectTask


class MinkPolicy(QPIKPolicy):
    """QP differential IK with mink: the project's task on a MuJoCo model of the same URDF
    (:mod:`snac_gym.physics.mujoco_model`: base frame as world, a site at the end-effector frame), mink's
    damping (``solve_ik(damping=λ²)``), ``ConfigurationLimit`` (gain 0.95, mink's default) and ``VelocityLimit`` (the
    env's velocity limits), ``mink.solve_ik`` with daqp. Arguments: :class:`~snac_gym.baselines.qp_ik.QPIKPolicy`.
    """

    module = "mink"
    default_limit_gain = 0.95

    def _setup(self, mink: Any, kinematics: Any) -> None:
        if getattr(kinematics, "model_error", None) is not None:
            # The MuJoCo model is built from the URDF: a wrong model would silently be the true one.
            raise ValueError("mink builds its MuJoCo model from the URDF and cannot take --model-error (pink can)")
        mujoco = require("mujoco", "ik", "mink")
        model = shared_mujoco_model(kinematics)
        self._configuration = mink.Configuration(model)
        self._task = _task_class(mink, mujoco)(
            model.site(EE_SITE).id, model.nv, self.task_dim, self.gain * self.dt, self.lm_damping
        )
        self._tasks = [self._task]
        velocities = dict(zip(kinematics.joint_names, self.velocity_limits, strict=True))
        self._limits = [
            mink.ConfigurationLimit(model, gain=self.limit_gain),
            mink.VelocityLimit(model, velocities),
        ]
        self._solve_ik = mink.solve_ik
