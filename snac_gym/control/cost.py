"""The paper's cost, in one place: the env reward, the evaluator and the plots all call it.

Instantaneous cost (integrand of eq. 6):            c(e, u) = eᵀQe + uᵀRu
Trajectory cost (Section V, "Quantitative Test"):   V = Σₖ (eₖᵀQeₖ + uₖᵀRuₖ + u̇ₖᵀRu̇ₖ) Δt

with eₖ the task-space error at the start of control step k, uₖ the joint-velocity
command held over step k, u̇ₖ = (uₖ − uₖ₋₁)/Δt and u₋₁ = 0 (the robot starts at rest).
Q = I₃ and R = I₆ in the paper.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import numpy as np
import numpy.typing as npt

from snac_gym.common.validation import real_array, real_number


def weight_matrix(matrix: np.ndarray | None, dim: int, name: str) -> np.ndarray | None:
    """Validate a weighting matrix (a ``(dim, dim)`` array or a length-``dim`` diagonal).

    ``None`` means identity and is returned as ``None``, so callers skip the matmul.

    A weight must be finite, symmetric and positive semidefinite: otherwise the cost is NaN or
    can be negative, and no controller can minimise it.

    Raises:
        ValueError: On a wrong shape, a non-finite entry, asymmetry or a negative eigenvalue,
            naming the matrix.
    """
    if matrix is None:
        return None
    try:
        if np.asarray(matrix).dtype.kind not in "iuf":  # a complex weight is refused, not cast to its real part
            raise TypeError(f"dtype {np.asarray(matrix).dtype}")
        matrix = np.asarray(matrix, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"{name} must be a ({dim}, {dim}) matrix or a length-{dim} diagonal of numbers: {exc}"
        ) from None
    if matrix.ndim == 1:
        matrix = np.diag(matrix)
    if matrix.shape != (dim, dim):
        raise ValueError(f"{name} must be ({dim}, {dim}) or a length-{dim} diagonal, got shape {matrix.shape}")
    if not np.all(np.isfinite(matrix)):
        raise ValueError(f"{name} must be finite, got {matrix.tolist()}")
    scale = float(np.abs(matrix).max())
    if not np.allclose(matrix, matrix.T, rtol=1e-12, atol=1e-12 * scale):
        raise ValueError(f"{name} must be symmetric, got {matrix.tolist()}")
    smallest = float(np.linalg.eigvalsh(0.5 * (matrix + matrix.T))[0])
    if smallest < -1e-12 * scale:
        raise ValueError(
            f"{name} must be positive definite or semidefinite (every eigenvalue >= 0); "
            f"its smallest eigenvalue is {smallest:.3g}"
        )
    return matrix


def quadratic_form(vectors: np.ndarray, matrix: np.ndarray | None) -> npt.NDArray[np.float64] | np.float64:
    """``vᵀMv`` over the last axis of ``vectors``; ``matrix=None`` is the identity. A vector ``(n,)`` gives a
    NumPy scalar, a stack ``(..., n)`` an array ``(...)``."""
    vectors = np.asarray(vectors, dtype=float)
    if vectors.ndim == 1:  # the per-step path of the env: plain dot products are ~5x faster than einsum
        scalar: np.float64 = vectors @ vectors if matrix is None else vectors @ matrix @ vectors  # stub: Any
        return scalar
    return _stacked_quadratic_form(vectors, matrix)


def _stacked_quadratic_form(vectors: np.ndarray, matrix: np.ndarray | None) -> npt.NDArray[np.float64]:
    """:func:`quadratic_form` of a float stack ``(..., n)`` with at least two axes: an array ``(...)``."""
    stacked: npt.NDArray[np.float64] = (  # np.einsum's stub: Any
        np.einsum("...i,...i->...", vectors, vectors)
        if matrix is None
        else np.einsum("...i,ij,...j->...", vectors, matrix, vectors)
    )
    return stacked


def instantaneous_cost(
    error: np.ndarray, command: np.ndarray, Q: np.ndarray | None = None, R: np.ndarray | None = None
) -> tuple[float, float]:
    """The two terms ``(eᵀQe, uᵀRu)`` of the integrand of eq. 6 (``None`` = identity)."""
    error = np.asarray(error, dtype=float)
    command = np.asarray(command, dtype=float)
    Qm = weight_matrix(Q, error.shape[-1], "Q")
    Rm = weight_matrix(R, command.shape[-1], "R")
    return float(quadratic_form(error, Qm)), float(quadratic_form(command, Rm))


def step_costs(
    error: np.ndarray,
    command: np.ndarray,
    previous_command: np.ndarray,
    dt: float,
    Q: np.ndarray | None = None,
    R: np.ndarray | None = None,
) -> tuple[float, float, float] | tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One control step's cost rates as the envs report them: ``(eₖᵀQeₖ, uₖᵀRuₖ, u̇ₖᵀRu̇ₖ)``.

    The first two are the integrand of eq. 6; the third is the smoothness term of the paper's
    Table I cost, with u̇ₖ = (uₖ − uₖ₋₁)/Δt. ``Q``/``R`` are matrices already checked by
    :func:`weight_matrix` (``None`` = identity): this runs every control step. One step gives
    floats; rows of a batch (``(B, n)``, ``(B, m)``, the vector env) give ``(B,)`` arrays.
    """
    if type(error) is np.ndarray and error.ndim == 1 and type(command) is np.ndarray and command.dtype == np.float64:
        # One step of an env (every control period): BLAS dots without quadratic_form's conversions and the
        # ufunc's dispatch; the same products in the same order, so the same floats.
        rate = command - previous_command
        rate /= dt
        return (
            float(error.dot(error) if Q is None else error @ Q @ error),
            float(command.dot(command) if R is None else command @ R @ command),
            float(rate.dot(rate) if R is None else rate @ R @ rate),
        )
    rates = (
        quadratic_form(error, Q),
        quadratic_form(command, R),
        quadratic_form((command - previous_command) / dt, R),
    )
    if np.ndim(rates[0]) == 0:
        return float(rates[0]), float(rates[1]), float(rates[2])
    return cast("tuple[np.ndarray, np.ndarray, np.ndarray]", rates)  # not scalars: arrays


@dataclass(frozen=True)
class CostTerms:
    """The trajectory cost split into its three terms (arrays broadcast over leading axes; NumPy scalars for one
    trajectory).

    Attributes:
        error: Σ eₖᵀQeₖ Δt.
        effort: Σ uₖᵀRuₖ Δt.
        smoothness: Σ u̇ₖᵀRu̇ₖ Δt.
    """

    error: npt.NDArray[np.float64]
    effort: npt.NDArray[np.float64]
    smoothness: npt.NDArray[np.float64]

    @property
    def total(self) -> npt.NDArray[np.float64]:
        """V, the sum of the three terms."""
        return self.error + self.effort + self.smoothness


def command_differences(commands: np.ndarray, initial_command: np.ndarray | None = None) -> np.ndarray:
    """``uₖ − uₖ₋₁`` for ``(..., K, m)`` commands, with ``u₋₁ = initial_command`` (default 0: at rest).

    (Slices rather than ``np.diff(prepend=...)``, which is 25x slower on the evaluator's (B, K, m) arrays.)
    """
    commands = np.asarray(commands, dtype=float)
    differences = np.empty_like(commands)
    np.subtract(commands[..., 1:, :], commands[..., :-1, :], out=differences[..., 1:, :])
    differences[..., 0, :] = commands[..., 0, :]
    if initial_command is not None:
        differences[..., 0, :] -= np.asarray(initial_command, dtype=float)
    return differences


def cost_rates(
    errors: np.ndarray,
    commands: np.ndarray,
    dt: float,
    Q: np.ndarray | None = None,
    R: np.ndarray | None = None,
    initial_command: np.ndarray | None = None,
) -> CostTerms:
    """Per-step integrands (eₖᵀQeₖ, uₖᵀRuₖ, u̇ₖᵀRu̇ₖ), each of shape ``(..., K)``.

    Args:
        errors: ``(..., K, n)`` errors at the start of each step.
        commands: ``(..., K, m)`` commands held over each step.
        dt: Control period Δt in seconds.
        Q, R: Weights (``None`` = identity, the paper's choice).
        initial_command: u₋₁ (default zero: the robot starts at rest).
    """
    for name, values in (("errors", errors), ("commands", commands)):
        kind = np.asarray(values).dtype.kind
        if kind not in "iuf":  # complex or not numbers: refused, not cast
            raise ValueError(f"{name} must be real numbers, got dtype {np.asarray(values).dtype}")
    errors = np.asarray(errors, dtype=float)
    commands = np.asarray(commands, dtype=float)
    for name, values in (("errors", errors), ("commands", commands)):
        if not np.isfinite(values).all():  # a NaN cost would rank as neither better nor worse
            raise ValueError(
                f"{name} must be finite, got NaN or inf at {np.argwhere(~np.isfinite(values))[0].tolist()}"
            )
    if errors.ndim < 2 or commands.ndim < 2 or errors.shape[:-1] != commands.shape[:-1]:
        raise ValueError(
            f"errors (..., K, n) and commands (..., K, m) must share leading axes, got {errors.shape} and "
            f"{commands.shape}"
        )
    if errors.shape[-2] == 0:
        raise ValueError(f"a trajectory cost needs at least one step, got K = 0 (errors {errors.shape})")
    real_number("dt", dt, 0.0, math.inf, low_open=True)
    Qm = weight_matrix(Q, errors.shape[-1], "Q")
    Rm = weight_matrix(R, commands.shape[-1], "R")
    if initial_command is not None:
        initial_command = _initial_command(initial_command, commands.shape)
    with np.errstate(over="ignore", invalid="ignore"):  # an overflow is refused below, by name
        command_rates = command_differences(commands, initial_command) / dt
        terms = CostTerms(
            error=_stacked_quadratic_form(errors, Qm),
            effort=_stacked_quadratic_form(commands, Rm),
            smoothness=_stacked_quadratic_form(command_rates, Rm),
        )
    _refuse_overflow(terms)
    return terms


def _initial_command(value: np.ndarray, commands: tuple[int, ...]) -> np.ndarray:
    """``initial_command`` u₋₁ checked: real, finite, ``(m,)`` or one per trajectory (``(..., m)`` of the commands'
    leading axes)."""
    initial = real_array("initial_command", value)
    first = commands[:-2] + commands[-1:]  # the shape of commands[..., 0, :]
    try:
        fits = (
            initial.ndim >= 1
            and initial.shape[-1] == commands[-1]
            and np.broadcast_shapes(initial.shape, first) == first
        )
    except ValueError:
        fits = False
    if not fits:
        shapes = f"({commands[-1]},)" + ("" if len(first) == 1 else f" or {first}")
        raise ValueError(
            f"initial_command must be u₋₁ of length {commands[-1]} (the commands' m), shape {shapes}, got "
            f"shape {initial.shape}"
        )
    return initial


def _refuse_overflow(terms: CostTerms) -> None:
    """Refuse a cost whose finite inputs overflow float64 (errors near 1e200 square to inf): it is not computed
    in another way, as no controller's rollout comes near (its errors are metres, its commands rad/s)."""
    for name in ("error", "effort", "smoothness"):
        values = getattr(terms, name)
        if not np.isfinite(values).all():
            raise ValueError(
                f"the {name} term of the trajectory cost overflows float64 (inf from finite errors and "
                "commands: a square above 1.8e308); refused, not computed another way: errors (m) and "
                "commands (rad/s) this large are no rollout's"
            )


def trajectory_cost(
    errors: np.ndarray,
    commands: np.ndarray,
    dt: float,
    Q: np.ndarray | None = None,
    R: np.ndarray | None = None,
    initial_command: np.ndarray | None = None,
) -> CostTerms:
    """The paper's trajectory cost ``V = Σₖ (eₖᵀQeₖ + uₖᵀRuₖ + u̇ₖᵀRu̇ₖ) Δt`` (Section V).

    Same arguments as :func:`cost_rates`; returns the three summed terms, shape ``(...)``.
    """
    rates = cost_rates(errors, commands, dt, Q, R, initial_command)
    with np.errstate(over="ignore"):  # a sum past float64's range is refused below, by name
        terms = CostTerms(
            error=rates.error.sum(axis=-1) * dt,
            effort=rates.effort.sum(axis=-1) * dt,
            smoothness=rates.smoothness.sum(axis=-1) * dt,
        )
    _refuse_overflow(terms)
    return terms


#: Trajectory costs a comparison can use (``snac-gym evaluate --cost``).
COSTS = ("table1", "hjb")
#: What u₋₁ is in the smoothness term (``--udot-start``): ``rest`` u₋₁ = 0, ``first`` u₋₁ = u₀.
UDOT_STARTS = ("rest", "first")


@dataclass(frozen=True)
class CostConvention:
    """Which trajectory cost a comparison is scored by.

    * ``cost="table1"``: the paper's Section V cost ``Σ (eᵀQe + uᵀRu + u̇ᵀRu̇) Δt``;
    * ``cost="hjb"``: the cost the controllers are derived for (eqs. 6, 32),
      ``Σ (eᵀQe + uᵀRu) Δt``, without the u̇ term;
    * ``udot_start``: ``"rest"`` (u₋₁ = 0: the jump from rest to the first command counts, the
      project's reading of Table I) or ``"first"`` (u₋₁ = u₀: it does not);
    * ``q_scale``: Q = q_scale·I, to price the error in other units (q_scale = 10⁶ prices it
      in mm²); R = I.

    Attributes:
        cost, udot_start, q_scale: As above.
    """

    cost: str = "table1"
    udot_start: str = "rest"
    q_scale: float = 1.0

    def __post_init__(self) -> None:
        if self.cost not in COSTS:
            raise ValueError(f"cost must be one of {COSTS}, got {self.cost!r}")
        if self.udot_start not in UDOT_STARTS:
            raise ValueError(f"udot_start must be one of {UDOT_STARTS}, got {self.udot_start!r}")
        if not (np.isfinite(self.q_scale) and self.q_scale > 0):
            raise ValueError(f"q_scale must be a positive finite number, got {self.q_scale!r}")

    @property
    def smoothness_weight(self) -> float:
        """1 when the u̇ term counts, 0 for the HJB cost."""
        return 1.0 if self.cost == "table1" else 0.0

    @property
    def first_jump_weight(self) -> float:
        """How much of the jump from rest ‖u₀‖²_R/Δt (the u̇ term of step 0 with u₋₁ = 0) is in V:
        1 for Table I's cost with u₋₁ = 0; 0 with u₋₁ = u₀ (no jump) or for the HJB cost (no u̇ term)."""
        return self.smoothness_weight if self.udot_start == "rest" else 0.0

    def error_weight(self, task_dim: int) -> np.ndarray | None:
        """Q (``None``: identity, the paper's)."""
        return None if self.q_scale == 1.0 else self.q_scale * np.eye(task_dim)

    def total(self, terms: CostTerms) -> np.ndarray:
        """V under this convention from its terms."""
        return terms.error + terms.effort + self.smoothness_weight * terms.smoothness

    def step_rate(
        self,
        error: np.ndarray | float,
        effort: np.ndarray | float,
        smoothness: np.ndarray | float,
        first_step: np.ndarray | bool,
    ) -> np.ndarray | float:
        """The integrand of V for one control step from its three terms (eₖᵀQeₖ, uₖᵀRuₖ, u̇ₖᵀRu̇ₖ with
        u₋₁ = 0): the u̇ term weighed in or out, and dropped on the first step when u₋₁ = u₀. Σₖ of it
        times Δt is :meth:`total` of the trajectory (the envs' ``reward_type="cost"`` is minus it times Δt)."""
        smoothness = np.where(first_step, 0.0, smoothness) if self.udot_start == "first" else smoothness
        return error + effort + self.smoothness_weight * smoothness

    def describe(self) -> str:
        """One line for reports, e.g. ``V = Σ (eᵀQe + uᵀRu + u̇ᵀRu̇) Δt with Q = I, R = I, u₋₁ = 0``."""
        integrand = "eᵀQe + uᵀRu" + (" + u̇ᵀRu̇" if self.cost == "table1" else "")
        weight = "I" if self.q_scale == 1.0 else f"{self.q_scale:g}·I"
        start = "" if self.cost == "hjb" else (", u₋₁ = 0" if self.udot_start == "rest" else ", u₋₁ = u₀")
        return f"V = Σ ({integrand}) Δt with Q = {weight}, R = I{start}"


def cost_and_gradient(
    errors: np.ndarray,
    jacobians: np.ndarray,
    commands: np.ndarray,
    dt: float,
    convention: CostConvention | None = None,
) -> tuple[float, np.ndarray]:
    """V of one kinematic rollout under ``convention`` and its exact gradient ∂V/∂U (the optimum's solver).

    The rollout is θₖ₊₁ = θₖ + uₖΔt with eₖ = f(θₖ) − x_d(tₖ), so eⱼ depends on uₖ for j > k
    through ∂eⱼ/∂uₖ = Δt Jⱼ. With Q = qI, R = I and the u̇ term weighted by w (1 for ``table1``,
    0 for ``hjb``)::

        V       = Δt (q Σ eₖᵀeₖ + Σ uₖᵀuₖ) + (w/Δt) Σ (uₖ − uₖ₋₁)ᵀ(uₖ − uₖ₋₁)
        ∂V/∂uₖ  = 2Δt uₖ + (2w/Δt)((uₖ − uₖ₋₁) − (uₖ₊₁ − uₖ)) + Δt Σ_{j>k} 2Δt q Jⱼᵀ eⱼ

    (u₋₁ = 0, or u₋₁ = u₀ for ``udot_start="first"``: the first difference is 0). V is the value
    of :func:`trajectory_cost` under ``convention`` (``convention.total``), summed in one
    contraction over the whole rollout instead of step by step: the solver's results (its line
    search, its stopping test and ``optimal_solver_cost``) are pinned to this summation order.

    Args:
        errors: ``(K, n)`` errors eₖ at the start of each step.
        jacobians: ``(K, n, m)`` task Jacobians Jₖ = ∂f/∂θ at θₖ.
        commands: ``(K, m)`` commands U.
        dt: Control period Δt, s.
        convention: The cost (default: Table I's, Q = I, R = I, u₋₁ = 0).
    """
    convention = convention if convention is not None else CostConvention()
    weight, q_scale = convention.smoothness_weight, convention.q_scale
    steps, m = commands.shape
    rates = command_differences(commands, commands[0] if convention.udot_start == "first" else None)  # uₖ − uₖ₋₁
    # Eq. 6's integrand eᵀQe + uᵀRu, plus Section V's u̇ᵀRu̇ (weighted by w), times Δt.
    value = dt * (q_scale * np.einsum("ij,ij->", errors, errors) + np.einsum("ij,ij->", commands, commands))
    value += weight * np.einsum("ij,ij->", rates, rates) / dt
    # Its gradient: the effort and smoothness terms directly, the error term through every later step.
    g = (2.0 * dt * q_scale) * np.einsum("kij,ki->kj", jacobians, errors)  # g_j = 2Δt q Jⱼᵀ eⱼ
    grad = 2.0 * dt * commands + (2.0 * weight / dt) * rates
    grad[:-1] -= (2.0 * weight / dt) * rates[1:]
    tail = np.zeros((steps, m))  # Σ_{j>k} g_j
    if steps > 1:
        tail[:-1] = np.cumsum(g[:0:-1], axis=0)[::-1]
    grad += dt * tail
    return float(value), grad
