"""What every snac-gym env shares, whatever arm it drives: :class:`TaskEnvCore`.

The simulated env (:class:`snac_gym.envs.core.URTaskEnv`) and the real-arm env (:class:`snac_gym.real.RealUREnv`) add
the arm to it.
"""

from __future__ import annotations

import math
from typing import Any, cast

import gymnasium as gym
import numpy as np

from snac_gym.common.validation import real_number
from snac_gym.control.cost import step_costs, weight_matrix
from snac_gym.envs.arguments import MAX_SUCCESS_TOLERANCE, check_sample_space
from snac_gym.model.kinematics import Kinematics
from snac_gym.observation import ObservationLayout
from snac_gym.references import Reference
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import Task, get_task

__all__ = ["TaskEnvCore"]


class TaskEnvCore(gym.Env):
    """What every snac-gym env shares, whatever arm it drives (PyBullet, the kinematic model, a real UR).

    The task, the kinematics, the observation layout and its packing, the episode's start from
    ``reset`` options, the per-step cost terms (eq. 6 and the smoothness term, from
    :func:`snac_gym.control.cost.step_costs`), the info dicts and the success rule. Subclasses add the
    arm: :class:`~snac_gym.envs.core.URTaskEnv` (simulated) and :class:`snac_gym.real.RealUREnv` (a real arm behind
    the safety layer).
    """

    observation_space: gym.spaces.Box
    action_space: gym.spaces.Box

    def _init_task(
        self,
        task: Task[Any] | str,
        kinematics: Kinematics,
        dt: float,
        Q: Any,
        R: Any,
        success_tolerance: float | None,
        sample_space: SampleSpace | None,
    ) -> None:
        """Set the shared state; raises ``ValueError`` on a bad tolerance or weight matrix."""
        self.task: Task[Any] = get_task(task)
        self.task_name = self.task.name
        tolerance = self.task.success_tolerance if success_tolerance is None else success_tolerance
        #: Distance (m) under which the target counts as reached: in (0, :data:`MAX_SUCCESS_TOLERANCE`].
        self.success_tolerance = real_number(
            "success_tolerance (m)", tolerance, 0.0, MAX_SUCCESS_TOLERANCE, low_open=True
        )
        self.kinematics = kinematics
        # A pose task's error is a logarithm (PoseKinematics.task_error), not x − x_d (None).
        self._task_error = getattr(kinematics, "task_error", None)
        self.dt = float(dt)
        m, n = kinematics.n_joints, kinematics.task_dim
        self.Q = weight_matrix(Q, n, "Q")
        self.R = weight_matrix(R, m, "R")
        self.sample_space = check_sample_space(sample_space, kinematics)
        self.velocity_limits = kinematics.velocity_limits.copy()
        self.obs_layout = ObservationLayout(m, n)
        self._error_slice = self.obs_layout.slices["e"]
        self.reference: Reference = self.task.paper()
        self.steps = 0
        self._last_command = np.zeros(m)
        self._obs: np.ndarray | None = None

    @property
    def time(self) -> float:
        """Time since reset, s."""
        return self.steps * self.dt

    def _pack(self, q: np.ndarray, qdot: np.ndarray) -> np.ndarray:
        """The observation of the measured state, with the reference at the current time."""
        x_d, xdot_d = self.reference.position_and_velocity(self.time)
        x = self.kinematics.forward(q)
        error = None if self._task_error is None else self._task_error(x, x_d)
        return self.obs_layout.pack(q, qdot, x, x_d, xdot_d, self.reference.centre, error)

    def _is_success(self, error: np.ndarray, squared: float | None = None) -> bool:
        """‖e‖ within the tolerance (``squared``: ‖e‖², where the caller has it already)."""
        return bool((error.dot(error) if squared is None else squared) <= self.success_tolerance**2)

    def _step_costs(self, command: np.ndarray) -> tuple[float, float, float]:
        """``(eₖᵀQeₖ, uₖᵀRuₖ, u̇ₖᵀRu̇ₖ)`` of the step about to apply ``command`` (eₖ: the error now)."""
        assert self._obs is not None  # within an episode
        # one env's 1-D error and command: floats
        return cast(
            "tuple[float, float, float]",
            step_costs(self._obs[self._error_slice], command, self._last_command, self.dt, self.Q, self.R),
        )

    def _reset_info(self, q0: np.ndarray | None) -> dict[str, Any]:
        assert self._obs is not None  # reset() has observed
        error = self._obs[self._error_slice]
        info = {
            "error": error.copy(),
            "error_norm": float(np.linalg.norm(error)),
            "t": 0.0,
            "is_success": self._is_success(error),
            "reference": self.reference.to_dict(),
        }
        if q0 is not None:
            info["q0"] = np.array(q0, dtype=float)
        return info

    def _step_info(self, costs: tuple[float, float, float], command: np.ndarray) -> dict[str, Any]:
        assert self._obs is not None  # within an episode
        error = self._obs[self._error_slice]
        squared = error.dot(error)  # ‖e‖² once, for the norm and the success rule (:meth:`_is_success`)
        return {
            "error": error.copy(),
            "error_norm": math.sqrt(squared),
            "cost_error": costs[0],
            "cost_effort": costs[1],
            "cost_smoothness": costs[2],
            "command": command.copy(),
            "t": self.time,
            "is_success": self._is_success(error, squared),
        }
