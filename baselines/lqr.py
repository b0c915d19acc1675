"""LQR at the frozen Jacobian: the optimum of the paper's cost as a state-feedback law.

At every control step the Jacobian is frozen at the current θ and the infinite-horizon LQR of
``ė = J u`` with the paper's cost ``∫ eᵀQe + uᵀRu dt`` is solved in closed form
(:mod:`snac_gym.control.optimality`); the command is its optimal feedback. This is what an ideal
critic converges to when J changes slowly, so it is the reference for SNAC's learnt critic.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from snac_gym.baselines._common import ObservationReader, scale_into_box

from snac_gym.control.optimality import FrozenJacobianLQR
from snac_gym.model.joint_limits import make_limit_box
from snac_gym.policies.base import BasePolicy, positive_float, scale_rows_into_limits


class LQRPolicy(BasePolicy):
    """Frozen-Jacobian LQR with a feed-forward for tracking.

    **Regulation.** With J frozen, ``ė = J u`` and ``V = ∫ eᵀQe + uᵀRu dt`` form an LQR with
    A = 0, B = J. Its value is ``V*(e) = eᵀP*e`` with P* the SPD solution of
    ``0 = Q − P* J R⁻¹ Jᵀ P*`` and the minimiser of the HJB Hamiltonian
    ``∇V*ᵀ J u + eᵀQe + uᵀRu`` is

        u = −½ R⁻¹ Jᵀ ∇V* = −R⁻¹ Jᵀ P* e = −K* e                 (the paper's eq. 15 at V̂ = V*)

    giving ``ė = −J R⁻¹ Jᵀ P* e``: for Q = qI, R = rI each singular direction of J decays at
    rate ``σᵢ √(q/r)`` with ``‖u‖ = √(q/r)‖e‖`` whatever σᵢ (``K* = √(q/r) V Uᵀ``): unlike a
    pseudo-inverse, the optimum does not buy speed in weak directions with large joint speeds.

    **Tracking.** With a moving reference ``ė = J u − ẋ_d``. Split ``u = u_ff + u_fb`` with
    ``J u_ff = ẋ_d``; the least-``uᵀRu`` such feed-forward is ``u_ff = J⁺_R ẋ_d``,
    ``J⁺_R = R⁻¹ Jᵀ (J R⁻¹ Jᵀ)⁻¹`` (the pseudo-inverse J⁺ for R = I), and then ``ė = J u_fb``
    is the regulation problem again:

        u = J⁺_R ẋ_d − K* e,        ė = −J K* e.

    The paper's *undiscounted* tracking cost ``∫₀^∞ eᵀQe + uᵀRu dt`` is infinite for every
    controller: following a moving reference needs ``u ≠ 0`` forever, so ``uᵀRu`` does not go to
    zero. Without the feed-forward it is worse: a pure feedback ``u = −K e`` needs a steady error
    ``e ≈ −(JK)⁻¹ ẋ_d`` to produce the motion, so ``eᵀQe`` does not vanish either. Only the error
    part of the problem is well posed, the cost of the error dynamics ``ė = −JK*e`` (finite,
    ``e₀ᵀP*e₀`` with J frozen) around the feed-forward motion; a discount factor is the other way
    to make the total finite. This controller optimises that error cost and spends the least
    ``uᵀRu`` on the motion itself.

    **Saturation.** The command is scaled uniformly into the joint-velocity limits
    (:func:`snac_gym.baselines._common.scale_into_box`), keeping its direction and that of ``ė = J u``:
    a saturated feedback still decreases ``½‖e‖²`` (``eᵀJu < 0`` survives a positive factor,
    not a per-joint clip). ``snac-hjb``, which learns this law's P*, saturates the same way, so
    that the two differ only in the critic.

    **Singularities.** ``K*`` stays bounded as J loses rank (``‖K*‖ = √(q/r)`` for
    ``q_scale·Q = qI``, ``R = rI``); at an exact loss of rank the lost direction gets gain 0
    (no command can move along it). The feed-forward ``J⁺_R ẋ_d`` grows like 1/σ_min as the pseudo-inverse does and
    is bounded by the saturation; the sample space keeps σ_min ≥ 0.05.

    Args:
        env: The env (or :class:`~snac_gym.policies.base.PolicyContext`) to drive.
        Q: Error weight, ``(n, n)`` symmetric positive definite or a length-n diagonal
            (default identity, the paper's).
        R: Effort weight, ``(m, m)`` symmetric positive definite or a length-m diagonal
            (default identity, the paper's).
        q_scale: The effort knob (:attr:`effort_parameter`): the law uses ``q_scale·Q``, which
            scales P* and K* by ``√q_scale`` (R fixed), so the feedback part of the command and
            its peak grow as ``√q_scale``. Default 9 (feedback ``‖u‖ = 3‖e‖`` for Q = R = I): with
            q_scale = 1, the paper's weights, the slowest direction at the paper's θ0 (σ_min = 0.40)
            decays at 0.4 1/s and the paper's reach first gets within 1 mm at 7.95 s of its 8 s; at 9
            all of 100 random reach episodes end within 1 mm (docs/baselines.md has the measurements).
        joint_limits: Clamp the command into the position-limit box Ω(θ) (:mod:`snac_gym.model.joint_limits`;
            the frozen-Jacobian LQR has no mechanism of its own); ``None``: on for the 7-DOF arms only.

    Raises:
        ValueError: If Q or R is not finite, symmetric and positive definite of the right
            shape, or ``q_scale`` is not a positive finite number.

    Attributes:
        effort_parameter: ``"q_scale"``, for the evaluator's effort matching.
        lqr: The :class:`~snac_gym.control.optimality.FrozenJacobianLQR` of ``(q_scale·Q, R)``.
        internals: After :meth:`act`: ``saturation_scale`` (the factor the command was divided
            by, 1 when inside the limits) and ``value`` (``eᵀP*e``, the frozen-Jacobian optimal
            cost-to-go of the error, with the weights the law uses).
    """

    effort_parameter = "q_scale"

    def __init__(
        self, env: Any, Q: Any = None, R: Any = None, q_scale: float = 9.0, joint_limits: bool | None = None
    ) -> None:
        super().__init__(env)
        self.limit_box = make_limit_box(self, joint_limits)
        self.q_scale = positive_float("q_scale", q_scale)
        n, m = self.kinematics.task_dim, self.kinematics.n_joints
        base = FrozenJacobianLQR(Q, R, n, m)  # validates Q and R as given, before scaling
        self.Q, self.R = base.Q, base.R
        self.lqr = FrozenJacobianLQR(self.q_scale * self.Q, self.R, n, m)
        self._reader = ObservationReader(self)

    def _commands(self, jacobians: np.ndarray, errors: np.ndarray, velocities: np.ndarray) -> tuple[np.ndarray, ...]:
        """Unsaturated ``J⁺_R ẋ_d − K* e`` and ``eᵀP*e`` for stacks ``(B, n, m)``, ``(B, n)``, ``(B, n)``.

        Both terms from one eigendecomposition (:meth:`FrozenJacobianLQR.factors`):
        ``K* e = A λ^{-1/2} C e`` and ``J⁺_R ẋ_d = A λ⁻¹ C ẋ_d``, so
        ``u = A (λ^{-1/2} ⊙ (λ^{-1/2} ⊙ C ẋ_d − C e))``. ``act`` calls this with a stack of one,
        so that its rows are bit-identical to ``act_batch``'s.
        """
        left, values, right, _ = self.lqr.factors(jacobians)
        inverse_root = values**-0.5
        projected_error = (right @ errors[..., None])[..., 0]  # C e
        projected_velocity = (right @ velocities[..., None])[..., 0]  # C ẋ_d
        coordinates = inverse_root * (inverse_root * projected_velocity - projected_error)
        value = np.einsum("...i,...i->...", inverse_root, projected_error**2)  # eᵀP*e = Σ λᵢ^{-1/2} (Ce)ᵢ²
        return (left @ coordinates[..., None])[..., 0], value

    def reset_batch(self, seeds: Sequence[int]) -> None:
        """Start ``len(seeds)`` episodes (nothing to set: the law has no state)."""
        self.internals = {}

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        """Commands ``(B, m)`` for observations ``(B, size)``: row i is :meth:`act` of row i."""
        obs_batch = self._reader.read_batch(obs_batch)
        jacobians = self.kinematics.jacobian_batch(obs_batch[:, self._reader.q])
        commands, _ = self._commands(jacobians, obs_batch[self._reader.e], obs_batch[self._reader.xdot_d])
        commands = scale_rows_into_limits(commands, self.velocity_limits)
        return commands if self.limit_box is None else self.limit_box.clamp(obs_batch[:, self._reader.q], commands)

    def _act(self, obs: np.ndarray) -> np.ndarray:
        """Joint-velocity command (rad/s) for ``obs``, inside the velocity limits."""
        obs = self._reader.read(obs)
        jacobian = self.kinematics.jacobian(obs[self._reader.q])
        commands, value = self._commands(
            jacobian[None], obs[None, self._reader.e[1]], obs[None, self._reader.xdot_d[1]]
        )
        command, scale = scale_into_box(commands[0], self.velocity_limits)
        self.internals = {"saturation_scale": scale, "value": float(value[0])}
        return command if self.limit_box is None else self.limit_box.clamp(obs[self._reader.q], command)
