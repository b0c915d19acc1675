"""The observation vector shared by the simulated env, the real-robot env and the evaluator.

One layout, built here, so a policy that parses observations with :meth:`ObservationLayout.unpack`
works unchanged in each of them.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np


class Observation(NamedTuple):
    """Named views into one observation vector (see :class:`ObservationLayout`)."""

    q: np.ndarray
    qdot: np.ndarray
    x: np.ndarray
    x_d: np.ndarray
    xdot_d: np.ndarray
    e: np.ndarray
    x_c: np.ndarray


class ObservationLayout:
    """Field order, sizes and units of the flat observation vector.

    =========  ========  =====  ========================================================
    field      size      unit   meaning
    =========  ========  =====  ========================================================
    q          m         rad    measured joint positions θ
    qdot       m         rad/s  measured joint velocities θ̇
    x          n         m      end-effector position f(θ) in the base frame
    x_d        n         m      desired position x_d(t)
    xdot_d     n         m/s    desired velocity ẋ_d(t)
    e          n         m      task error e = x − x_d (eq. 4)
    x_c        n         m      reference centre: the target (reach) or ellipse centre (track)
    =========  ========  =====  ========================================================

    ``m`` is the number of joints and ``n`` the task dimension: 3 for the position tasks; 6 for
    the pose tasks (:mod:`snac_gym.tasks.pose`), where x, x_d and x_c are ``[p; log₃ R]`` (m, rad),
    ẋ_d is ``[ṗ_d; ω_d]`` and e is ``[p − p_d; log₃(R R_dᵀ)]``, the orientation rows in radians.
    """

    FIELDS = ("q", "qdot", "x", "x_d", "xdot_d", "e", "x_c")

    def __init__(self, n_joints: int, task_dim: int = 3) -> None:
        if n_joints < 1 or task_dim < 1:
            raise ValueError(f"n_joints and task_dim must be positive, got {n_joints}, {task_dim}")
        self.n_joints = n_joints
        self.task_dim = task_dim
        sizes = [n_joints, n_joints] + [task_dim] * 5
        self.slices: dict[str, slice] = {}
        start = 0
        for name, size in zip(self.FIELDS, sizes):
            self.slices[name] = slice(start, start + size)
            start += size
        self.size = start
        # pack's slices, looked up once (pack runs every env step)
        self._pack_slices = tuple(self.slices[name] for name in self.FIELDS)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, ObservationLayout) and (other.n_joints, other.task_dim) == (
            self.n_joints,
            self.task_dim,
        )

    def __repr__(self) -> str:
        return f"ObservationLayout(n_joints={self.n_joints}, task_dim={self.task_dim})"

    def pack(
        self,
        q: np.ndarray,
        qdot: np.ndarray,
        x: np.ndarray,
        x_d: np.ndarray,
        xdot_d: np.ndarray,
        x_c: np.ndarray,
        error: np.ndarray | None = None,
    ) -> np.ndarray:
        """Build the observation; the error field is ``error``, by default ``x − x_d`` computed here
        (a pose task passes its logarithmic error, :meth:`~snac_gym.model.kinematics.PoseKinematics.task_error`)."""
        q_, qdot_, x_, x_d_, xdot_d_, e_, x_c_ = self._pack_slices
        obs = np.empty(self.size, dtype=np.float64)
        obs[q_] = q
        obs[qdot_] = qdot
        obs[x_] = x
        obs[x_d_] = x_d
        obs[xdot_d_] = xdot_d
        if error is None:
            np.subtract(obs[x_], obs[x_d_], out=obs[e_])
        else:
            obs[e_] = error
        obs[x_c_] = x_c
        return obs

    def unpack(self, obs: np.ndarray) -> Observation:
        """Named views (no copies) of the fields of ``obs``.

        Raises:
            ValueError: If ``obs`` does not have this layout's size.
        """
        obs = np.asarray(obs)
        if obs.shape != (self.size,):
            raise ValueError(f"observation must have shape ({self.size},) for {self!r}, got {obs.shape}")
        s = self.slices
        return Observation(
            obs[s["q"]], obs[s["qdot"]], obs[s["x"]], obs[s["x_d"]], obs[s["xdot_d"]], obs[s["e"]], obs[s["x_c"]]
        )
