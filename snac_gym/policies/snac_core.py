"""SNAC's critic and its law over one control period: :class:`SNACCore`, the base of
:class:`~snac_gym.policies.snac.SNACPolicy`.

The constructor's checks, the hot path's workspace, the learning-rate schedule and ``act``'s laws (eqs. 15, 19,
36, 38, each discretisation of the weight law) live here; :mod:`snac_gym.policies.snac` adds the batch protocol
(the same laws over B episodes' rows) and the optimality diagnostics, and documents the whole.
"""

from __future__ import annotations

import math
from typing import Any, cast

import numpy as np

from snac_gym.control.cost import weight_matrix
from snac_gym.model.joint_limits import make_limit_box
from snac_gym.policies.base import BasePolicy
from snac_gym.policies.critic import CriticEpisode, QuadraticBasis, matvec, transpose

__all__ = [
    "INITIAL_WEIGHTS",
    "INITIAL_WEIGHT_SCALES",
    "LEARNING_RATE_UNITS",
    "PAPER_SCHEDULES",
    "SCHEDULE_CLOCKS",
    "TRACKING_STATES",
    "WEIGHT_UPDATES",
    "SNACCore",
]

#: The paper's learning-rate schedules (Section V): task -> (α_initial, α_final, n).
PAPER_SCHEDULES: dict[str, tuple[float, float, float]] = {
    "reach": (100.0, 150.0, 50.0),
    "track": (20.0, 70.0, 10.0),
}
#: Discretisations of the weight law over one control period, see :class:`~snac_gym.policies.snac.SNACPolicy`.
WEIGHT_UPDATES = ("euler", "euler_updated", "zoh")
#: How the paper's α is read: a rate per second, or a gain per control step.
LEARNING_RATE_UNITS = ("per_step", "per_second")
#: What "k = time instance" of the schedule counts.
SCHEDULE_CLOCKS = ("steps", "seconds")
#: How the initial critic weights are drawn (the paper: "initialized randomly").
INITIAL_WEIGHTS = ("identity", "uniform")
#: The reference part of the tracking critic state ξ = [e; x_d − r]: ``"paper"`` r = 0 (eq. 31,
#: ξ = [e; x_d]) or ``"centred"`` r = x_c, the ellipse centre (so that φ(0) = 0, eq. 29).
TRACKING_STATES = ("paper", "centred")
#: Default c of ``initial_weights="identity"`` (Ŵ₀ = c on the squared terms), by task.
INITIAL_WEIGHT_SCALES: dict[str, float] = {"reach": 2.0, "track": 20.0}


class SNACCore(CriticEpisode, BasePolicy):
    """SNAC's critic, its settings and its one-step law; :class:`~snac_gym.policies.snac.SNACPolicy` documents the
    arguments and attributes."""

    def __init__(
        self,
        env: Any,
        *,
        Q: np.ndarray | None = None,
        R: np.ndarray | None = None,
        learning_rate_initial: float | None = None,
        learning_rate_final: float | None = None,
        schedule_shift: float | None = None,
        schedule_clock: str = "seconds",
        weight_update: str = "euler",
        learning_rate_unit: str = "per_second",
        freeze_when_saturated: bool = False,
        initial_weights: np.ndarray | str = "uniform",
        initial_weight_scale: float | None = None,
        initial_weight_range: tuple[float, float] = (0.0, 1.0),
        command_scale: float = 1.0,
        tracking_state: str = "paper",
        seed: int | None = None,
        joint_limits: bool | None = None,
    ) -> None:
        super().__init__(env)
        self.limit_box = make_limit_box(self, joint_limits)
        n, m = self.kinematics.task_dim, self.kinematics.n_joints
        self.task_dim, self.n_joints = n, m
        Q_matrix, R_matrix = weight_matrix(Q, n, "Q"), weight_matrix(R, m, "R")
        self.Q = np.eye(n) if Q_matrix is None else Q_matrix
        self.R = np.eye(m) if R_matrix is None else R_matrix
        if not np.allclose(self.R, self.R.T) or np.linalg.eigvalsh(self.R).min() <= 0:
            raise ValueError("R must be symmetric positive definite")
        self.R_inverse = np.linalg.inv(self.R)
        diagonal = np.allclose(self.R_inverse, np.diag(np.diag(self.R_inverse)))
        self._R_inverse_diagonal = np.diag(self.R_inverse).copy() if diagonal else None
        # evaluated only when diagonal: the diagonal is set
        self._R_is_identity = diagonal and np.array_equal(cast(np.ndarray, self._R_inverse_diagonal), np.ones(m))

        for name, value, allowed in (
            ("schedule_clock", schedule_clock, SCHEDULE_CLOCKS),
            ("weight_update", weight_update, WEIGHT_UPDATES),
            ("learning_rate_unit", learning_rate_unit, LEARNING_RATE_UNITS),
            ("tracking_state", tracking_state, TRACKING_STATES),
        ):
            if value not in allowed:
                raise ValueError(f"{name} must be one of {allowed}, got {value!r}")
        # The paper tuned one experiment per problem; another task takes the values of its kind.
        self.paper_task = self.task if self.task in PAPER_SCHEDULES else ("track" if self.tracking else "reach")
        alpha_i, alpha_f, shift = PAPER_SCHEDULES[self.paper_task]
        self.learning_rate_initial = float(alpha_i if learning_rate_initial is None else learning_rate_initial)
        self.learning_rate_final = float(alpha_f if learning_rate_final is None else learning_rate_final)
        self.schedule_shift = float(shift if schedule_shift is None else schedule_shift)
        self.schedule_clock = schedule_clock
        self.weight_update = weight_update
        self.learning_rate_unit = learning_rate_unit
        self.freeze_when_saturated = bool(freeze_when_saturated)
        self.command_scale = float(command_scale)
        self.tracking_state = tracking_state
        if not (math.isfinite(self.command_scale) and self.command_scale > 0):
            raise ValueError(f"command_scale must be positive, got {command_scale}")

        state_dim = 2 * n if self.tracking else n  # e (Section III) or ξ (eq. 31)
        self.basis = QuadraticBasis(state_dim)
        low, high = map(float, initial_weight_range)
        if not low <= high:
            raise ValueError(f"initial_weight_range must be (low, high) with low <= high, got {initial_weight_range}")
        self.initial_weight_range = (low, high)
        # Each knob belongs to one initialisation; given with another it would be ignored without a word.
        kind = (
            initial_weights if isinstance(initial_weights, str) else "uniform" if initial_weights is None else "array"
        )
        given = "an array" if kind == "array" else repr(kind)
        if initial_weight_scale is not None and kind != "identity":
            raise ValueError(
                f"initial_weight_scale is c of initial_weights='identity' and does nothing with initial_weights="
                f"{given}; pass initial_weights='identity' with it"
            )
        if (low, high) != (0.0, 1.0) and kind != "uniform":
            raise ValueError(
                f"initial_weight_range is the range of initial_weights='uniform' and does nothing with "
                f"initial_weights={given}; pass initial_weights='uniform' with it"
            )
        scale = INITIAL_WEIGHT_SCALES[self.paper_task] if initial_weight_scale is None else float(initial_weight_scale)
        if not math.isfinite(scale):
            raise ValueError(f"initial_weight_scale must be finite, got {initial_weight_scale}")
        self.initial_weight_scale = scale
        self._set_initial_weights("uniform" if initial_weights is None else initial_weights, scale)
        self._seed = seed
        self._rng = np.random.default_rng(seed)
        self.batch_critic_weights: np.ndarray | None = None
        self._batch_k = 0

        self._allocate_workspace(state_dim)

    def _allocate_workspace(self, state_dim: int) -> None:
        """The hot path's workspace: ``act`` allocates only its command and the new weights."""
        s = self.layout.slices
        self._q_slice, self._e_slice = s["q"], s["e"]
        self._xd_slice, self._xdotd_slice, self._xc_slice = s["x_d"], s["xdot_d"], s["x_c"]
        self._state = np.zeros(state_dim)
        self._gradient = np.zeros((self.basis.size, state_dim))  # ∇σ(s)
        self._make_views()
        self._pair = np.zeros((2, self.task_dim))  # rows: −½c ∇_e V̂ and h αₖ e, multiplied by J together
        self._upper = self.velocity_limits.copy()
        self._lower = -self.velocity_limits
        self._upper_list = self._upper.tolist()
        self._half_scale = -0.5 * self.command_scale
        self.critic_weights = np.zeros(self.basis.size)
        self._k = 0
        self._ready = False
        self._last: tuple[Any, ...] | None = None
        self._internals: dict[str, Any] = {}

    def _set_initial_weights(self, initial_weights: np.ndarray | str, scale: float) -> None:
        """Check and store Ŵ₀: a kind (``None`` means ``"uniform"``) or an array."""
        if isinstance(initial_weights, str):
            if initial_weights not in INITIAL_WEIGHTS:
                raise ValueError(
                    f"initial_weights must be one of {INITIAL_WEIGHTS} or an array, got {initial_weights!r}"
                )
            #: ``"identity"``, ``"uniform"`` or ``"given"`` (an array was passed).
            self.initial_weight_kind = initial_weights
            self.initial_weights = (
                np.where(self.basis.first == self.basis.second, scale, 0.0) if initial_weights == "identity" else None
            )
            return
        weights = np.array(initial_weights, dtype=float)
        if weights.shape != (self.basis.size,) or not np.isfinite(weights).all():
            raise ValueError(f"initial_weights must be {self.basis.size} finite numbers, got shape {weights.shape}")
        self.initial_weight_kind = "given"
        self.initial_weights = weights

    def _make_views(self) -> None:
        self._gradient_flat = self._gradient.reshape(-1)  # a view: vec(∇σ) = T s is written here
        self._gradient_e = self._gradient[:, : self.task_dim]  # G = [J; 0] keeps the error columns (eqs. 36, 38)

    # -- pickling: views into the workspace would come back as independent copies ----------------
    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        del state["_gradient_flat"], state["_gradient_e"]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._make_views()

    # -- internals, evaluated on access ---------------------------------------------------------
    @property
    def internals(self) -> dict[str, Any]:
        """See the class docstring; computed from the last ``act`` when first read."""
        if self._last is not None:
            weights_used, new_weights, alpha, saturated, k = self._last
            state = self._state
            self._internals = {
                "critic_weights": new_weights,
                "critic_value": 0.5 * float(state @ (weights_used @ self._gradient)),  # V̂ = Ŵᵀσ(s) = ½sᵀ∇σᵀŴ
                "lyapunov": 0.5 * float(state @ state),  # J_s(s) = ½sᵀs
                "learning_rate": alpha,
                "saturated": saturated,
                "step": k,
            }
            self._last = None
        return self._internals

    @internals.setter
    def internals(self, value: dict[str, Any]) -> None:
        self._internals = dict(value)
        self._last = None

    # -- episode ------------------------------------------------------------------------------
    def _initial_weights(self, rng: np.random.Generator) -> np.ndarray:
        """Ŵ₀ (a new array), drawn from ``rng`` for ``"uniform"``."""
        if self.initial_weights is not None:
            return self.initial_weights.copy()
        return rng.uniform(*self.initial_weight_range, size=self.basis.size)

    def learning_rate(self, k: int) -> float:
        """``α = α_i tanh(n − k) + α_f`` (Section V); k in steps or seconds per ``schedule_clock``."""
        clock = k if self.schedule_clock == "steps" else k * self.dt
        return self.learning_rate_initial * math.tanh(self.schedule_shift - clock) + self.learning_rate_final

    def _apply_r_inverse(self, rows: np.ndarray) -> np.ndarray:
        """``R⁻¹ r`` for each row r (the last axis); R⁻¹ symmetric, so ``r R⁻¹`` is the same."""
        if self._R_is_identity:
            return rows
        return rows * self._R_inverse_diagonal if self._R_inverse_diagonal is not None else rows @ self.R_inverse

    # -- the laws -----------------------------------------------------------------------------
    def _products(self, weights: np.ndarray, jacobian: np.ndarray) -> np.ndarray:
        """Rows ``c·û`` (eq. 15 / eq. 36, unclipped) and ``h αₖ R⁻¹ Jᵀ e`` from one product.

        ``self._pair`` row 1 must hold ``h αₖ e``; row 0 is set here to ``−½c ∇_eV̂``.
        """
        n = self.task_dim
        value_gradient = np.dot(weights, self._gradient)  # ∇σᵀŴ (np.dot: less overhead than @ on tiny arrays)
        np.multiply(value_gradient[:n], self._half_scale, out=self._pair[0])  # Gᵀ keeps the error part
        rows: np.ndarray = np.dot(self._pair, jacobian)  # (Jᵀ·)ᵀ for both rows
        if not self._R_is_identity:
            rows = self._apply_r_inverse(rows)
        return rows  # rows[0] = −½c R⁻¹Jᵀ∇σᵀŴ = c·û,  rows[1] = h αₖ R⁻¹Jᵀe

    def _euler_increment(self, jacobian: np.ndarray, scaled_r_inverse_jt_error: np.ndarray) -> np.ndarray:
        """One Euler step ``h αₖ ∇σ J R⁻¹ Jᵀ e`` of the weight law (eq. 19; eq. 38 with G = [J; 0], ∇J_s = s).

        ``scaled_r_inverse_jt_error`` is ``h αₖ R⁻¹Jᵀe`` (row 1 of :meth:`_products`).
        """
        step: np.ndarray = np.dot(self._gradient_e, np.dot(jacobian, scaled_r_inverse_jt_error))
        return step

    def _is_saturated(self, command: np.ndarray) -> bool:
        return any(abs(value) > limit for value, limit in zip(command.tolist(), self._upper_list))

    def _act(self, obs: np.ndarray) -> np.ndarray:
        """Joint-velocity command for ``obs`` (clipped to the limits); advances the critic one period.

        Raises:
            RuntimeError: If called before :meth:`reset`.
        """
        if not self._ready:
            raise RuntimeError("call reset() before act()")
        n = self.task_dim
        error = obs[self._e_slice]
        state = self._state
        state[:n] = error
        if self.tracking:  # ξ = [e; x_d] (eq. 31), or x_d about the centre so that φ(0) = 0 (eq. 29)
            if self.tracking_state == "paper":
                state[n:] = obs[self._xd_slice]
            else:
                np.subtract(obs[self._xd_slice], obs[self._xc_slice], out=state[n:])
        jacobian = self.kinematics.jacobian(obs[self._q_slice])  # x is not needed: the observation carries e
        np.dot(self.basis.selection, state, out=self._gradient_flat)  # ∇σ(s), as QuadraticBasis.gradient
        alpha = self.learning_rate(self._k)
        step_gain = alpha if self.learning_rate_unit == "per_step" else alpha * self.dt  # h·α
        np.multiply(error, step_gain, out=self._pair[1])  # ∇J_s(s) = s; G R⁻¹ Gᵀ keeps e
        weights = new_weights = self.critic_weights

        rows = self._products(weights, jacobian)
        command = rows[0]
        if self.weight_update == "euler_updated":  # command from Ŵₖ₊₁
            trial = weights + self._euler_increment(jacobian, rows[1])
            trial_command = self._products(trial, jacobian)[0]
            saturated = self._is_saturated(trial_command)
            if not (saturated and self.freeze_when_saturated):
                weights = new_weights = trial
                command = trial_command
            else:  # the trial is discarded: report the command actually sent
                saturated = self._is_saturated(command)
        else:
            saturated = self._is_saturated(command)
            if saturated and self.freeze_when_saturated:
                pass  # anti-windup: no learning on a clipped step
            elif self.weight_update == "euler":
                new_weights = weights + self._euler_increment(jacobian, rows[1])
            else:
                np.minimum(command, self._upper, out=command)
                np.maximum(command, self._lower, out=command)
                new_weights = weights + self._zoh_increment(obs, jacobian, command, step_gain, state, self._gradient_e)
        np.minimum(command, self._upper, out=command)
        np.maximum(command, self._lower, out=command)

        self._last = (weights, new_weights, alpha, saturated, self._k)
        self.critic_weights = new_weights
        self._k += 1
        return command if self.limit_box is None else self.limit_box.clamp(obs[self._q_slice], command)

    def _zoh_increment(
        self,
        obs: np.ndarray,
        jacobian: np.ndarray,
        command: np.ndarray,
        step_gain: float,
        state: np.ndarray,
        gradient_e: np.ndarray,
    ) -> np.ndarray:
        """``step_gain/Δt · ∫₀^Δt ∇σ(s(τ)) J R⁻¹ Jᵀ e(τ) dτ`` along ``s(τ) = s + τṡ`` (eq. 19 / eq. 38).

        The path is predicted with the held (clipped) command, J frozen and ẋ_d held
        (ė = J u − ẋ_d, eq. 30). ∇σ is linear in s and J R⁻¹ Jᵀ e linear in e, so the
        integrand ``(∇σ(s) + τ∇σ(ṡ)) (v + τ v̇)`` is quadratic in τ: closed form.

        One step: ``state`` s ``(d,)``, ``gradient_e`` the error columns of ∇σ(s) ``(size, n)``;
        or B rows at once: every argument with a leading batch axis.
        """
        n, dt = self.task_dim, self.dt
        xdot_d = obs[..., self._xdotd_slice]
        rate = np.zeros_like(state)
        rate[..., :n] = matvec(jacobian, command) - xdot_d  # ė = J u − ẋ_d (eq. 30; ẋ_d = 0 for reach)
        if self.tracking:
            rate[..., n:] = xdot_d
        gradient_rate_e = self.basis.gradient(rate)[..., :n]
        jr = jacobian @ self.R_inverse
        jacobian_t = transpose(jacobian)
        v = matvec(jr, matvec(jacobian_t, state[..., :n]))
        v_rate = matvec(jr, matvec(jacobian_t, rate[..., :n]))
        g0, g1 = gradient_e, gradient_rate_e
        integral: np.ndarray = (
            dt * matvec(g0, v) + 0.5 * dt**2 * (matvec(g0, v_rate) + matvec(g1, v)) + dt**3 / 3.0 * matvec(g1, v_rate)
        )
        return (step_gain / dt) * integral
