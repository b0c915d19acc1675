"""The single network adaptive critic (SNAC) kinematic controller of the paper (Sections III and IV).

One critic ``V̂(s) = Ŵᵀσ(s)`` over a quadratic basis of the critic state ``s`` gives the
command and is tuned online by a Lyapunov-based law; there is no actor network.

Regulation (``task="reach"``, Section III), critic state ``s = e = x − x_d``::

    û  = −½ R⁻¹ Jᵀ ∇σᵀ Ŵ                     (eq. 15)
    Ŵ̇ = α ∇σ J R⁻¹ Jᵀ ∇J_s(e),  J_s = ½eᵀe   (eq. 19)

Tracking (``task="track"``, Section IV), critic state ``s = ξ = [e; x_d]`` (eq. 31), with
``G(ξ) = [J; 0]``::

    û  = −½ R⁻¹ Gᵀ ∇φᵀ Ŵ                     (eq. 36)
    Ŵ̇ = α ∇φ G R⁻¹ Gᵀ ∇J_s(ξ),  J_s = ½ξᵀξ   (eq. 38)

Learning rate (Section V): ``α = α_i tanh(n − k) + α_f``; regulation ``n = 50, α_i = 100,
α_f = 150``, tracking ``n = 10, α_i = 20, α_f = 70``.

The defaults follow the paper where it speaks: the critic is "initialized
randomly", Ŵ₀ ~ U(0, 1) drawn from the reset seed (and logged as the first row of the ``w_*``
columns); the tracking state is the paper's ξ = [e; x_d]; α is the rate of the continuous law
(one Euler step of Δt·α per period) with k the time in seconds; no anti-windup. Where the paper
leaves a choice open, the other readings are constructor arguments: ``initial_weights="identity"``
(Ŵ₀ = c on the squared terms), ``tracking_state="centred"`` (ξ = [e; x_d − x_c]),
``learning_rate_unit="per_step"``, ``schedule_clock="steps"``, ``freeze_when_saturated``
(anti-windup) and ``weight_update``. docs/snac.md measures each against the headline figures.

The weight law contains neither Q nor any HJB residual: the trajectory does not depend on Q at
all (tested). :meth:`SNACPolicy.critic_diagnostics` measures how far the critic is from the HJB
equation and, for regulation, from the frozen-Jacobian optimum P*(J)
(:mod:`snac_gym.control.optimality`).

The parts: :mod:`~snac_gym.policies.critic` (the quadratic basis, the critic's episode reset) and
:mod:`~snac_gym.policies.snac_core` (the settings and the one-step law, :class:`SNACPolicy`'s base); their public
names are importable from here.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from snac_gym.control.optimality import FrozenJacobianLQR, critic_error, hjb_residual, quadratic_weights_to_matrix
from snac_gym.policies.critic import CriticEpisode, QuadraticBasis, matvec, transpose
from snac_gym.policies.snac_core import (
    INITIAL_WEIGHT_SCALES,
    INITIAL_WEIGHTS,
    LEARNING_RATE_UNITS,
    PAPER_SCHEDULES,
    SCHEDULE_CLOCKS,
    TRACKING_STATES,
    WEIGHT_UPDATES,
    SNACCore,
)

__all__ = [
    "INITIAL_WEIGHTS",
    "INITIAL_WEIGHT_SCALES",
    "LEARNING_RATE_UNITS",
    "PAPER_SCHEDULES",
    "SCHEDULE_CLOCKS",
    "TRACKING_STATES",
    "WEIGHT_UPDATES",
    "CriticEpisode",
    "QuadraticBasis",
    "SNACCore",
    "SNACPolicy",
]


class SNACPolicy(SNACCore):
    """SNAC kinematic control: regulation (eqs. 15, 19) or tracking (eqs. 36, 38) by the env's task.

    The critic state is ``e`` for ``reach`` and ``ξ = [e; x_d]`` (eq. 31) for ``track``
    (``tracking_state="centred"``: ``ξ = [e; x_d − x_c]``, x_d relative to the ellipse centre,
    the observation's ``x_c`` field, so that φ(0) = 0 as eq. 29 assumes).

    Args:
        env: The env to drive (or a :class:`~snac_gym.policies.base.PolicyContext`).
        Q: Error weight of the cost, ``(n, n)`` or its diagonal (default identity, the
            paper's). The paper's laws (eqs. 15, 19, 36, 38) do not use it (the weight law
            descends J_s, not the cost); it is kept as :attr:`Q`, the error weight of the
            cost the critic approximates, for callers that evaluate that cost.
        R: Effort weight ``(m, m)`` or its diagonal, symmetric positive definite (default
            identity, the paper's). Enters the command and the weight law as R⁻¹.
        learning_rate_initial: α_i of the schedule (default: the paper's for the task).
        learning_rate_final: α_f of the schedule (default: the paper's for the task).
        schedule_shift: n of the schedule (default: the paper's for the task).
        schedule_clock: What k counts in ``tanh(n − k)``: ``"seconds"`` (default: ``k·Δt``,
            the time of the continuous law) or ``"steps"`` (control steps since reset).
        weight_update: Discretisation of the weight law over one control period:

            * ``"euler"`` (default): ``uₖ`` from ``Ŵₖ``, then one explicit Euler step
              ``Ŵₖ₊₁ = Ŵₖ + h αₖ ∇σ(sₖ) Jₖ R⁻¹ Jₖᵀ eₖ`` (h per ``learning_rate_unit``); the
              command only uses weights learnt up to step k−1.
            * ``"euler_updated"``: the same step first, ``uₖ`` from ``Ŵₖ₊₁``.
            * ``"zoh"``: ``uₖ`` from ``Ŵₖ``, then the weight law integrated exactly over the
              period along ``s(τ) = sₖ + τṡ`` predicted with the held (clipped) command,
              J frozen at Jₖ and ẋ_d held (ė = Jₖuₖ − ẋ_d, eq. 30).
        learning_rate_unit: ``"per_second"`` (default): α is the rate of the continuous law,
            h = Δt; ``"per_step"``: α is the gain of one update,
            ``Ŵₖ₊₁ = Ŵₖ + αₖ ∇σ J R⁻¹ Jᵀ eₖ`` (h = 1, i.e. 1/Δt times the continuous rate).
        freeze_when_saturated: Anti-windup, not in the paper (default ``False``): skip the
            weight update on a step whose command had to be clipped to the velocity limits.
            Needed by ``"per_step"`` (without it that reading winds up and ends in a limit
            cycle on the reach demo).
        initial_weights: Initial critic weights Ŵ₀: ``"uniform"`` (default, the paper's
            "initialized randomly"): every weight drawn from U(``initial_weight_range``) with the
            reset seed (MATLAB's ``rand``; ``None`` means the same); ``"identity"``: c =
            ``initial_weight_scale`` on the squared terms s_i², 0 on the cross terms, so
            V̂₀ = c‖s‖² (the reset seed is not used); or an array of length ``basis.size``.
        initial_weight_scale: c of ``"identity"`` (default :data:`INITIAL_WEIGHT_SCALES`:
            2 for reach, 20 for tracking).
        initial_weight_range: ``(low, high)`` of ``"uniform"`` (default ``(0, 1)``).
        command_scale: The effort knob (:attr:`effort_parameter`): a positive scalar c
            multiplying the command of eq. 15/36 before clipping, ``u = clip(c·û)``.
            Default 1, the paper's law. The weight law is unchanged; peak ‖u‖ and effort
            were non-decreasing in c on every demo and random episode measured
            (docs/snac.md), flat only where all joints saturate.
        tracking_state: The reference part of the tracking critic state (:data:`TRACKING_STATES`):
            ``"paper"`` (default) ξ = [e; x_d], ``"centred"`` ξ = [e; x_d − x_c].
        seed: Seed of the initial-weight generator used by ``reset(seed=None)``.
        joint_limits: Clamp the command into the position-limit box Ω(θ) after the velocity
            clipping (:mod:`snac_gym.model.joint_limits`; the paper's law has no position limits);
            ``None`` (default): on for the 7-DOF arms only. The critic learns from its own
            command (eqs. 19, 38), as without the box.

    Commands are clipped element-wise to ``±velocity_limits`` (the env's action bounds).

    Attributes:
        basis: The :class:`QuadraticBasis` of the critic state (dimension n for reach, 2n
            for track).
        critic_weights: The current weights (replaced by a new array at each update, so a
            reference taken earlier keeps its values).
        internals: Evaluated on access, describing the last ``act`` (valid until the next):
            ``critic_weights`` (Ŵ after this step's update; after ``reset``, Ŵ₀),
            ``critic_value`` (V̂ = Ŵᵀσ(sₖ) with the weights that gave the command),
            ``lyapunov`` (J_s(sₖ) = ½sₖᵀsₖ), ``learning_rate`` (the schedule's αₖ),
            ``saturated`` (whether the command was clipped) and ``step`` (k).
        batch_critic_weights: ``(B, size)``, row i the weights of episode i of the batch
            protocol (``reset_batch`` / ``act_batch``, see ``snac_gym/policies/base.py``): B
            episodes stepped in lockstep with the same laws and options as ``act``, vectorised
            over the rows; ``None`` before ``reset_batch``. ``internals`` describe ``act`` only.
    """

    #: The constructor argument that scales the control effort monotonically (evaluator's
    #: equal-effort matching).
    effort_parameter = "command_scale"

    # -- episodes of the batch protocol -----------------------------------------------------------
    def reset_batch(self, seeds: Sequence[int | None]) -> None:
        """Start ``len(seeds)`` episodes for :meth:`act_batch`; episode i as ``reset(seed=seeds[i])``
        of a fresh policy (``None``: the constructor's ``seed``)."""
        rngs = [np.random.default_rng(self._seed if seed is None else seed) for seed in seeds]
        weights = [self._initial_weights(rng) for rng in rngs]
        self.batch_critic_weights = np.array(weights, dtype=float).reshape(len(weights), self.basis.size)
        self._batch_k = 0

    # -- optimality diagnostics ------------------------------------------------------------------
    def critic_diagnostics(
        self, q: np.ndarray, e: np.ndarray, x_d: np.ndarray, xdot_d: np.ndarray, x_c: np.ndarray, weights: np.ndarray
    ) -> dict[str, np.ndarray]:
        """How far the critic is from optimal at K logged states (rows), from the weights that gave each command.

        With ``û = −½R⁻¹Gᵀ∇V̂`` the critic's own command (eq. 15 / 36, before clipping and
        ``command_scale``) and ξ̇ = F + Gû (regulation: ė = Jû; tracking: ė = Jû − ẋ_d and
        the reference part moves at ẋ_d), the HJB residual (eq. 9)

            r = ∇V̂ᵀ ξ̇ + eᵀQe + ûᵀRû

        is 0 for the optimal value function; ``r / eᵀQe`` makes it comparable across error
        sizes. For regulation V̂ = eᵀP̂e (:func:`~snac_gym.control.optimality.quadratic_weights_to_matrix`)
        is also compared with the frozen-Jacobian optimum P*(J) at each θ.

        Args:
            q, e, x_d, xdot_d: ``(K, m)``, ``(K, n)``, ``(K, n)``, ``(K, n)``: the logged state.
            x_c: The reference centre ``(n,)`` (the target, or the ellipse centre).
            weights: ``(K, size)``, the critic weights used at each row.

        Returns:
            ``hjb_residual`` and ``hjb_ratio`` ``(K,)``, plus ``critic_error`` ``(K,)``
            (``‖P̂ − P*(J)‖_F / ‖P*‖_F``) for regulation.
        """
        n = self.task_dim
        e, xdot_d = np.asarray(e, dtype=float), np.asarray(xdot_d, dtype=float)
        state = e
        if self.tracking:
            reference = np.asarray(x_d, dtype=float) - (
                np.asarray(x_c, dtype=float) if self.tracking_state == "centred" else 0.0
            )
            state = np.concatenate((e, reference), axis=1)
        value_gradient = np.einsum("kc,kcd->kd", np.asarray(weights, dtype=float), self.basis.gradient(state))
        jacobians = self.kinematics.jacobian_batch(np.asarray(q, dtype=float))
        gradient_e = value_gradient[:, :n]
        command = -0.5 * self._apply_r_inverse(matvec(transpose(jacobians), gradient_e))  # eq. 15 / 36
        residual = hjb_residual(gradient_e, jacobians, command, e, self.Q, self.R)  # the ė = Jû part
        if self.tracking:  # −∇_eV̂ᵀẋ_d in ė, and the reference part of ξ moves at ẋ_d
            residual = residual - np.einsum("kd,kd->k", gradient_e, xdot_d)
            residual = residual + np.einsum("kd,kd->k", value_gradient[:, n:], xdot_d)
        error_cost = np.einsum("kd,de,ke->k", e, self.Q, e)
        with np.errstate(divide="ignore", invalid="ignore"):
            out = {"hjb_residual": residual, "hjb_ratio": residual / error_cost}
        if not self.tracking:
            optimum = FrozenJacobianLQR(self.Q, self.R, n, self.n_joints).solution(jacobians, at_singular="nan")
            out["critic_error"] = critic_error(quadratic_weights_to_matrix(weights, n), optimum)
        return out

    # -- the batch protocol: B episodes in lockstep, the same laws row by row ---------------------
    def _batch_command(self, weights: np.ndarray, gradient_e: np.ndarray, jacobians: np.ndarray) -> np.ndarray:
        """Rows ``c·û = −½c R⁻¹Jᵀ∇_eV̂`` (eq. 15 / eq. 36, unclipped) for weights ``(B, size)``."""
        value_gradient_e = np.einsum("bk,bkn->bn", weights, gradient_e)  # Gᵀ∇σᵀŴ: the error part
        return self._apply_r_inverse(matvec(transpose(jacobians), value_gradient_e * self._half_scale))

    def _batch_saturated(self, commands: np.ndarray) -> np.ndarray:
        """Which rows have a component beyond the velocity limits, ``(B,)`` bool."""
        saturated: np.ndarray = (np.abs(commands) > self._upper).any(axis=1)
        return saturated

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        """Commands ``(B, m)`` for observations ``(B, size)``, row i as :meth:`act` of episode i.

        Every option (weight update, learning-rate unit, anti-windup, R) is applied row by row
        as in :meth:`act`; the critic weights of the B episodes are :attr:`batch_critic_weights`.

        Raises:
            RuntimeError: If called before :meth:`reset_batch`.
        """
        weights = self.batch_critic_weights
        if weights is None:
            raise RuntimeError("call reset_batch() before act_batch()")
        obs = np.asarray(obs_batch, dtype=float)
        n = self.task_dim
        error = obs[:, self._e_slice]
        state = error
        if self.tracking:  # ξ = [e; x_d] (eq. 31) or [e; x_d − x_c], as in act
            reference = obs[:, self._xd_slice]
            if self.tracking_state == "centred":
                reference = reference - obs[:, self._xc_slice]
            state = np.concatenate((error, reference), axis=1)
        jacobians = self.kinematics.jacobian_batch(obs[:, self._q_slice])
        gradient_e = self.basis.gradient(state)[:, :, :n]
        alpha = self.learning_rate(self._batch_k)
        step_gain = alpha if self.learning_rate_unit == "per_step" else alpha * self.dt  # h·α, as in act
        learning = self._apply_r_inverse(matvec(transpose(jacobians), error * step_gain))  # h αₖ R⁻¹Jᵀe
        command = self._batch_command(weights, gradient_e, jacobians)
        frozen = np.zeros(len(obs), dtype=bool)  # rows that keep their weights (anti-windup)
        if self.weight_update == "euler_updated":  # command from Ŵₖ₊₁ unless that one is clipped and frozen
            trial = weights + matvec(gradient_e, matvec(jacobians, learning))
            trial_command = self._batch_command(trial, gradient_e, jacobians)
            if self.freeze_when_saturated:
                frozen = self._batch_saturated(trial_command)
            command = np.where(frozen[:, None], command, trial_command)
            new_weights = trial
        else:
            if self.freeze_when_saturated:
                frozen = self._batch_saturated(command)
            if self.weight_update == "euler":
                new_weights = weights + matvec(gradient_e, matvec(jacobians, learning))
            else:
                command = np.maximum(np.minimum(command, self._upper), self._lower)
                new_weights = weights + self._zoh_increment(obs, jacobians, command, step_gain, state, gradient_e)
        self.batch_critic_weights = np.where(frozen[:, None], weights, new_weights)
        self._batch_k += 1
        command = np.maximum(np.minimum(command, self._upper), self._lower)
        return command if self.limit_box is None else self.limit_box.clamp(obs[:, self._q_slice], command)
