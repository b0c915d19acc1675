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
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any, cast

import numpy as np

from snac_gym.control.cost import weight_matrix
from snac_gym.control.optimality import FrozenJacobianLQR, critic_error, hjb_residual, quadratic_weights_to_matrix
from snac_gym.model.joint_limits import make_limit_box
from snac_gym.policies.base import BasePolicy

#: The paper's learning-rate schedules (Section V): task -> (α_initial, α_final, n).
PAPER_SCHEDULES: dict[str, tuple[float, float, float]] = {
    "reach": (100.0, 150.0, 50.0),
    "track": (20.0, 70.0, 10.0),
}
#: Discretisations of the weight law over one control period, see :class:`SNACPolicy`.
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


def _matvec(matrices: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """``A @ x`` for one matrix and vector; row by row for stacks ``(B, r, c)``, ``(B, c)``."""
    return matrices @ vectors if vectors.ndim == 1 else (matrices @ vectors[..., None])[..., 0]


def _transpose(matrices: np.ndarray) -> np.ndarray:
    """``Aᵀ`` of one matrix, or of each matrix of a stack."""
    return matrices.T if matrices.ndim == 2 else np.swapaxes(matrices, -1, -2)


class QuadraticBasis:
    """All degree-2 monomials of a ``dim``-vector: ``σ(s) = [s_i s_j for i ≤ j]``.

    The order is the paper's: ``s₁², s₁s₂, …, s₁s_d, s₂², s₂s₃, …, s_d²`` (6 terms for
    ``d = 3``, 21 for ``d = 6``); ``size = d(d + 1)/2``. The gradient ``∇σ`` (``size × d``,
    row k = ∂σ_k/∂s) is linear in s with a fixed sparse structure, so it is computed as one
    product ``vec(∇σ(s)) = T s`` with the constant selection matrix ``T`` built here.

    Args:
        dim: Dimension of ``s``.
    """

    def __init__(self, dim: int) -> None:
        if dim < 1:
            raise ValueError(f"basis dimension must be positive, got {dim}")
        self.dim = int(dim)
        pairs = [(i, j) for i in range(dim) for j in range(i, dim)]
        self.size = len(pairs)
        #: ``first[k], second[k]``: the indices (i ≤ j) of term k.
        self.first = np.array([i for i, _ in pairs], dtype=np.intp)
        self.second = np.array([j for _, j in pairs], dtype=np.intp)
        # Term k = s_i s_j: ∂/∂s_i = s_j and ∂/∂s_j = s_i (i ≠ j), or ∂/∂s_i = 2 s_i (i = j).
        selection = np.zeros((self.size * dim, dim))
        for k, (i, j) in enumerate(pairs):
            selection[k * dim + i, j] += 1.0
            selection[k * dim + j, i] += 1.0
        #: The constant ``(size·dim, dim)`` matrix T with ``vec(∇σ(s)) = T s``.
        self.selection = selection

    def labels(self, names: list[str] | None = None) -> list[str]:
        """Readable names of the terms, e.g. ``["s0^2", "s0*s1", ...]``."""
        names = names or [f"s{i}" for i in range(self.dim)]
        return [f"{names[i]}^2" if i == j else f"{names[i]}*{names[j]}" for i, j in zip(self.first, self.second)]

    def __call__(self, s: np.ndarray) -> np.ndarray:
        """``σ(s)``, shape ``(size,)``."""
        s = np.asarray(s, dtype=float)
        return s[self.first] * s[self.second]

    def gradient(self, s: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """``∇σ(s) = ∂σ/∂s``, shape ``(size, dim)``; for a stack of points ``(B, dim)``, ``(B, size, dim)``.

        Every entry is one ``s_j`` or ``2 s_i``, so the result is exact whatever the shape.

        Args:
            s: The point, shape ``(dim,)`` (or ``(B, dim)``), float64.
            out: Optional C-contiguous float64 ``(size, dim)`` array to write into (one point only).
        """
        if s.ndim == 2:
            return (s @ self.selection.T).reshape(len(s), self.size, self.dim)
        if out is None:
            out = np.empty((self.size, self.dim))
        np.dot(self.selection, s, out=out.reshape(-1))
        return out


class CriticEpisode:
    """``reset`` of the critic-based policies: the step counter to 0 and the critic weights to Ŵ₀,
    drawn by the class's ``_initial_weights(rng)`` from ``seed`` (when given)."""

    _rng: np.random.Generator
    internals: dict[str, Any]

    def reset(self, seed: int | None = None) -> None:
        """Start an episode: step counter to 0, critic weights to Ŵ₀ (drawn from ``seed`` where random)."""
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        self.critic_weights = self._initial_weights(self._rng)
        self._k = 0
        self._ready = True
        self.internals = {"critic_weights": self.critic_weights}

    def _initial_weights(self, rng: np.random.Generator) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError


class SNACPolicy(CriticEpisode, BasePolicy):
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

    def reset_batch(self, seeds: Sequence[int | None]) -> None:
        """Start ``len(seeds)`` episodes for :meth:`act_batch`; episode i as ``reset(seed=seeds[i])``
        of a fresh policy (``None``: the constructor's ``seed``)."""
        rngs = [np.random.default_rng(self._seed if seed is None else seed) for seed in seeds]
        weights = [self._initial_weights(rng) for rng in rngs]
        self.batch_critic_weights = np.array(weights, dtype=float).reshape(len(weights), self.basis.size)
        self._batch_k = 0

    def learning_rate(self, k: int) -> float:
        """``α = α_i tanh(n − k) + α_f`` (Section V); k in steps or seconds per ``schedule_clock``."""
        clock = k if self.schedule_clock == "steps" else k * self.dt
        return self.learning_rate_initial * math.tanh(self.schedule_shift - clock) + self.learning_rate_final

    def _apply_r_inverse(self, rows: np.ndarray) -> np.ndarray:
        """``R⁻¹ r`` for each row r (the last axis); R⁻¹ symmetric, so ``r R⁻¹`` is the same."""
        if self._R_is_identity:
            return rows
        return rows * self._R_inverse_diagonal if self._R_inverse_diagonal is not None else rows @ self.R_inverse

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
            (‖P̂ − P*(J)‖_F / ‖P*‖_F) for regulation.
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
        command = -0.5 * self._apply_r_inverse(_matvec(_transpose(jacobians), gradient_e))  # eq. 15 / 36
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

    # -- the laws -----------------------------------------------------------------------------
    def _products(self, weights: np.ndarray, jacobian: np.ndarray) -> np.ndarray:
        """Rows ``c·û`` (eq. 15 / eq. 36, unclipped) and ``h αₖ R⁻¹ Jᵀ e`` from one product.

        ``self._pair`` row 1 must hold ``h αₖ e``; row 0 is set here to ``−½c ∇_eV̂``.
        """
        n = self.task_dim
        value_gradient = np.dot(weights, self._gradient)  # ∇σᵀŴ (np.dot: less overhead than @ on tiny arrays)
        np.multiply(value_gradient[:n], self._half_scale, out=self._pair[0])  # Gᵀ keeps the error part
        rows = np.dot(self._pair, jacobian)  # (Jᵀ·)ᵀ for both rows
        if not self._R_is_identity:
            rows = self._apply_r_inverse(rows)
        return rows  # rows[0] = −½c R⁻¹Jᵀ∇σᵀŴ = c·û,  rows[1] = h αₖ R⁻¹Jᵀe

    def _euler_increment(self, jacobian: np.ndarray, scaled_r_inverse_jt_error: np.ndarray) -> np.ndarray:
        """One Euler step ``h αₖ ∇σ J R⁻¹ Jᵀ e`` of the weight law (eq. 19; eq. 38 with G = [J; 0], ∇J_s = s).

        ``scaled_r_inverse_jt_error`` is ``h αₖ R⁻¹Jᵀe`` (row 1 of :meth:`_products`).
        """
        return np.dot(self._gradient_e, np.dot(jacobian, scaled_r_inverse_jt_error))

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
        rate[..., :n] = _matvec(jacobian, command) - xdot_d  # ė = J u − ẋ_d (eq. 30; ẋ_d = 0 for reach)
        if self.tracking:
            rate[..., n:] = xdot_d
        gradient_rate_e = self.basis.gradient(rate)[..., :n]
        jr = jacobian @ self.R_inverse
        jacobian_t = _transpose(jacobian)
        v = _matvec(jr, _matvec(jacobian_t, state[..., :n]))
        v_rate = _matvec(jr, _matvec(jacobian_t, rate[..., :n]))
        g0, g1 = gradient_e, gradient_rate_e
        integral = (
            dt * _matvec(g0, v)
            + 0.5 * dt**2 * (_matvec(g0, v_rate) + _matvec(g1, v))
            + dt**3 / 3.0 * _matvec(g1, v_rate)
        )
        return (step_gain / dt) * integral

    # -- the batch protocol: B episodes in lockstep, the same laws row by row ---------------------
    def _batch_command(self, weights: np.ndarray, gradient_e: np.ndarray, jacobians: np.ndarray) -> np.ndarray:
        """Rows ``c·û = −½c R⁻¹Jᵀ∇_eV̂`` (eq. 15 / eq. 36, unclipped) for weights ``(B, size)``."""
        value_gradient_e = np.einsum("bk,bkn->bn", weights, gradient_e)  # Gᵀ∇σᵀŴ: the error part
        return self._apply_r_inverse(_matvec(_transpose(jacobians), value_gradient_e * self._half_scale))

    def _batch_saturated(self, commands: np.ndarray) -> np.ndarray:
        """Which rows have a component beyond the velocity limits, ``(B,)`` bool."""
        return (np.abs(commands) > self._upper).any(axis=1)

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
        learning = self._apply_r_inverse(_matvec(_transpose(jacobians), error * step_gain))  # h αₖ R⁻¹Jᵀe
        command = self._batch_command(weights, gradient_e, jacobians)
        frozen = np.zeros(len(obs), dtype=bool)  # rows that keep their weights (anti-windup)
        if self.weight_update == "euler_updated":  # command from Ŵₖ₊₁ unless that one is clipped and frozen
            trial = weights + _matvec(gradient_e, _matvec(jacobians, learning))
            trial_command = self._batch_command(trial, gradient_e, jacobians)
            if self.freeze_when_saturated:
                frozen = self._batch_saturated(trial_command)
            command = np.where(frozen[:, None], command, trial_command)
            new_weights = trial
        else:
            if self.freeze_when_saturated:
                frozen = self._batch_saturated(command)
            if self.weight_update == "euler":
                new_weights = weights + _matvec(gradient_e, _matvec(jacobians, learning))
            else:
                command = np.maximum(np.minimum(command, self._upper), self._lower)
                new_weights = weights + self._zoh_increment(obs, jacobians, command, step_gain, state, gradient_e)
        self.batch_critic_weights = np.where(frozen[:, None], weights, new_weights)
        self._batch_k += 1
        command = np.maximum(np.minimum(command, self._upper), self._lower)
        return command if self.limit_box is None else self.limit_box.clamp(obs[:, self._q_slice], command)
