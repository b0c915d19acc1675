"""The trajectory optimiser: one sample's optimal command sequence for the paper's trajectory cost.

For one sample (seed pose θ₀, reference x_d known over the whole horizon) :func:`solve_sample` solves

    min_U  V(U) = Σₖ (eₖᵀQeₖ + uₖᵀRuₖ + u̇ₖᵀRu̇ₖ) Δt,   k = 0..K−1,  Q = I₃, R = I₆
    s.t.   θₖ₊₁ = θₖ + uₖΔt,  |uₖⱼ| ≤ ūⱼ,  θ⁻ ≤ θₖ ≤ θ⁺ (k = 1..K),  u₋₁ = 0,  u̇ₖ = (uₖ − uₖ₋₁)/Δt,
           eₖ = f(θₖ) − x_d(tₖ)

(on a pose task, x = [p; log₃ R] and eₖ = [p − p_d; log₃(R R_dᵀ)] with Q = I₆, differentiated exactly:
:func:`snac_gym.tasks.pose.pose_errors_and_jacobians`), for a cost convention
(:class:`snac_gym.control.cost.CostConvention`). It is the core that the evaluator's ``optimal`` reference
(:mod:`snac_gym.evaluation.reference.optimum`, which adds the starts, the rollout and the report) and the
``mpc`` controller (:mod:`snac_gym.baselines.mpc`, which re-solves a short horizon each step) share.
(Not :mod:`snac_gym.control.optimality`: that is the frozen-Jacobian, infinite-horizon optimum the critics
are compared with; this is the whole trajectory's, over a finite horizon.)

**Method** (direct single shooting in U, Gauss-Newton steps in θ). θ is linear in U, so V and its
exact gradient cost one batched FK+Jacobian pass (:func:`trajectory_cost_and_gradient`; the cost and
its gradient are written in :func:`snac_gym.control.cost.cost_and_gradient`). The quadratic effort + smoothness
part has the
fixed Hessian ``H₀ = 2Δt I + (2w/Δt) DᵀD`` in u (:func:`_effort_hessian_band`). In the variables θ₁..θ_K the
error term depends on θₖ alone and u = Mθ + c (first differences), so the Gauss-Newton matrix
``MᵀH₀M ⊗ I + blockdiag(2Δt q JₖᵀJₖ)`` is block-banded (bandwidth 12 scalars, 6 without the u̇
term) and each step is one banded Cholesky solve (:func:`gauss_newton`), followed by a
backtracking line search on the exact V. **Limits** (:func:`interior_point`): where that optimum
breaks a joint position or velocity limit, a primal-dual interior point on the same banded system
solves the constrained problem.

**Tolerance**. Each Gauss-Newton step δ predicts the decrease −½ ∂V/∂uᵀδ, the model's
V − V* (of the local optimum). The solve stops after a step whose prediction was ≤
:data:`GAP_RTOL` · V (10⁻⁷), or when V decreases relatively by ≤ :data:`FTOL` (at
most :data:`MAX_ITERATIONS` iterations). The prediction follows the true V − V* to within a
factor of about 1.2 (``docs/optimal.md``), and the step removes most of it, so the cost is left
within far less than 10⁻⁷ V of its optimum. With ``H₀ = LLᵀ`` (:func:`_preconditioner`), the
effort + smoothness part is ‖z‖² in ``z = Lᵀu``.
"""

from __future__ import annotations

import contextlib
import functools
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cholesky_banded, solve_banded
from scipy.linalg.lapack import dpbtrf, dpbtrs
from threadpoolctl import threadpool_limits

from snac_gym.control.cost import CostConvention, cost_and_gradient
from snac_gym.model.kinematics import Kinematics, joint_path
from snac_gym.tasks.pose import pose_errors_and_jacobians

#: Stop Gauss-Newton once the step just taken was predicted to remove at most GAP_RTOL·V: V − V*
#: (of the local optimum, by the Gauss-Newton model) was then at most that, and is far less after the step.
GAP_RTOL = 1e-7
#: Converged also when max |∂V/∂z| ≤ GTOL (z = Lᵀu, the preconditioned variables; V has the units of
#: the cost).
GTOL = 1e-6
#: ...or when (V_k − V_{k+1}) / max(|V_k|, |V_{k+1}|, 1) ≤ FTOL.
FTOL = 1e-13
#: Iteration cap of each solve (Gauss-Newton, and the interior point).
MAX_ITERATIONS = 5000
#: Sufficient-decrease constant of the Gauss-Newton line search (Armijo).
ARMIJO = 1e-4
#: Smallest step fraction the Gauss-Newton line search tries before giving up.
MIN_STEP = 1e-10
#: The clearance, rad, kept from every joint position limit (:func:`position_bounds`): a rollout integrates
#: θₖ₊₁ = θₖ + uₖΔt step by step, the solver sums the commands in another order, and an active limit must
#: not be crossed by the rounding between the two (about 1e-13 rad over 2500 steps).
LIMIT_CLEARANCE = 1e-9
#: An interior-point start's commands are shrunk by this share into the open velocity box.
START_SHRINK = 1e-3


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


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Run the block with BLAS on one thread (``threadpoolctl``; restored after).

    L-BFGS-B's and the banded Cholesky's BLAS calls on ~10⁴ variables are far too small to gain
    from threads: with OpenBLAS's default thread count on a busy 2-core machine a solve ran 5-10x
    slower (measured, docs/optimal.md). Worker processes already run in parallel.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        yield


@functools.lru_cache(maxsize=8)
def _effort_hessian_band(steps: int, dt: float, weight: float = 1.0, udot_start: str = "rest") -> np.ndarray:
    """Lower band ``(2, K)`` of H₀ = 2Δt I + (2w/Δt) DᵀD, the fixed Hessian of V's effort + smoothness part in u.

    D: first differences, with the row u₀ − u₋₁ = u₀ for ``udot_start="rest"`` only; w: the u̇ weight.
    """
    diagonal = np.full(steps, 2.0 * dt + 4.0 * weight / dt)
    diagonal[-1] = 2.0 * dt + 2.0 * weight / dt
    if udot_start == "first":
        diagonal[0] -= 2.0 * weight / dt
    band = np.zeros((2, steps))
    band[0] = diagonal
    band[1, :-1] = -2.0 * weight / dt
    band.setflags(write=False)
    return band


@functools.lru_cache(maxsize=8)
def _preconditioner(steps: int, dt: float, weight: float = 1.0, udot_start: str = "rest") -> np.ndarray:
    """Banded lower Cholesky factor L of H₀ (:func:`_effort_hessian_band`; ``cholesky_banded`` lower form)."""
    return cholesky_banded(_effort_hessian_band(steps, dt, weight, udot_start), lower=True)


@functools.lru_cache(maxsize=8)
def _theta_effort_band(steps: int, dt: float, weight: float = 1.0, udot_start: str = "rest") -> np.ndarray:
    """Lower band of A = MᵀH₀M, the effort + smoothness Hessian in the variables θ₁..θ_K (one joint).

    u = Mθ + c with uₖ = (θₖ₊₁ − θₖ)/Δt (θ₀ fixed, in c), so A has bandwidth 2 (1 without the u̇ term:
    the rows beyond the last non-zero diagonal are dropped, which narrows the Gauss-Newton system).
    """
    h0 = _effort_hessian_band(steps, dt, weight, udot_start)
    hessian = sp.diags([h0[1, :-1], h0[0], h0[1, :-1]], [-1, 0, 1], shape=(steps, steps), format="csr")
    difference = sp.diags([np.full(steps, 1.0 / dt), np.full(steps - 1, -1.0 / dt)], [0, -1], shape=(steps, steps))
    product = (difference.T @ hessian @ difference).todia()
    band = np.zeros((3, steps))
    for offset in range(min(3, steps)):
        band[offset, : steps - offset] = product.diagonal(-offset)
    width = 1 + max((d for d in range(3) if np.any(band[d])), default=0)
    band = band[:width]
    band.setflags(write=False)
    return band


@dataclass
class OptimalSolution:
    """One sample's solution.

    Attributes:
        commands: ``(K, m)`` optimal commands.
        cost: V at the solution (the solver's own evaluation).
        iterations: Gauss-Newton iterations, plus the bounded polish's L-BFGS-B ones if it ran.
        evaluations: Cost+gradient evaluations.
        gradient: Final max |∂V/∂z| (unconstrained) or projected max |∂V/∂u| (bounded polish).
        gap_estimate: ½‖∂V/∂z‖₂² at the solution: the decrease left to a quadratic model whose
            Hessian in z is I (the effort + smoothness part; the Gauss-Newton error part only adds
            to it), an estimate of V − V* near a local optimum (NaN after the bounded polish).
        converged: The stopping test (GTOL or FTOL) was met, not the iteration cap.
        bounded: The bounded polish ran (the unconstrained optimum broke a velocity limit).
        seconds: Wall time of the solve.
    """

    commands: np.ndarray
    cost: float
    iterations: int
    evaluations: int
    gradient: float
    gap_estimate: float
    converged: bool
    bounded: bool
    seconds: float


def gauss_newton(
    q0: np.ndarray,
    x_d: np.ndarray,
    kinematics: Kinematics,
    dt: float,
    start: np.ndarray,
    gtol: float,
    ftol: float,
    max_iterations: int,
    convention: CostConvention,
    gap_rtol: float = GAP_RTOL,
    until: Callable[[np.ndarray], bool] | None = None,
    gradient: bool = True,
) -> tuple[np.ndarray, float, np.ndarray, int, int, bool]:
    """Unconstrained Gauss-Newton in θ₁..θ_K with a backtracking (Armijo) line search on the exact V.

    Each iteration solves the block-banded system (A ⊗ I_m + blockdiag(2Δt q JₖᵀJₖ)) δθ = −Mᵀ ∂V/∂u
    (:func:`gauss_newton_direction`) and steps u ← u + α M δθ (:func:`_line_search`). The matrix is
    positive definite (A is), so δθ is a descent direction. The Jacobians are those of the last
    accepted cost evaluation (:meth:`Kinematics.forward_and_jacobian_batch` remembers its last batch),
    so an iteration costs one FK+Jacobian pass when the full step is taken.

    ``until``: called with the commands after each accepted step; the solve stops (not converged)
    once it returns True (a multi-start's screen stops a start that has reached a known basin).
    ``gradient=False``: skip the final ∂V/∂z (returned empty) where only the commands and V are wanted.

    Returns:
        (commands, V, ∂V/∂z flattened, iterations, cost evaluations, converged) with the stopping
        test of the module docstring: a step predicted to gain ≤ ``gap_rtol``·V, or a relative
        decrease ≤ ``ftol``; converged also when max |∂V/∂z| ≤ ``gtol`` at the end.
    """
    steps, m = start.shape
    lower = _preconditioner(steps, dt, convention.smoothness_weight, convention.udot_start)
    base = theta_system_base(steps, m, dt, convention)

    def evaluate(commands: np.ndarray) -> tuple[float, np.ndarray]:
        return trajectory_cost_and_gradient(commands, q0, x_d, kinematics, dt, convention)

    commands = start.copy()
    value, grad = evaluate(commands)
    iterations, evaluations, converged = 0, 1, False
    while iterations < max_iterations:
        _, jacobians = errors_and_jacobians(kinematics, angles(commands, q0, dt), x_d)
        step = gauss_newton_direction(base, jacobians, grad, dt, convention.q_scale)
        predicted = -0.5 * float(np.vdot(grad, step))  # the model's V − V*: half the Gauss-Newton decrement
        if predicted <= 0.0:  # no descent left in the model: rounding dominates
            converged = True
            break
        alpha, trial_value, trial_grad, tries = _line_search(evaluate, commands, value, grad, step)
        evaluations += tries
        if alpha < MIN_STEP:  # no decrease along a descent direction: rounding dominates
            break
        iterations += 1
        decrease = (value - trial_value) / max(abs(value), abs(trial_value), 1.0)
        commands, value, grad = commands + alpha * step, trial_value, trial_grad
        if predicted <= gap_rtol * abs(value) or decrease <= ftol:
            converged = True
            break
        if until is not None and until(commands):
            break
    if not gradient:
        return commands, value, np.empty(0), iterations, evaluations, converged
    grad_z = solve_banded((1, 0), lower, grad).ravel()
    converged = converged or float(np.abs(grad_z).max()) <= gtol
    return commands, value, grad_z, iterations, evaluations, converged


def theta_system_base(steps: int, m: int, dt: float, convention: CostConvention) -> np.ndarray:
    """The fixed part A ⊗ I_m of the Gauss-Newton matrix, in LAPACK's lower band form over K·m unknowns.

    A ⊗ I_m couples each joint with itself only, so band row ``offset·m`` holds A's diagonal
    ``offset``, each entry repeated for the m joints (:func:`_theta_effort_band`).
    """
    effort = _theta_effort_band(steps, dt, convention.smoothness_weight, convention.udot_start)
    width = effort.shape[0]
    base = np.zeros((m * (width - 1) + 1, steps * m))
    for offset in range(width):
        base[offset * m] = np.repeat(effort[offset], m)
    return base


def gauss_newton_direction(
    base: np.ndarray, jacobians: np.ndarray, grad: np.ndarray, dt: float, q_scale: float
) -> np.ndarray:
    """The Gauss-Newton step in u: M δθ with (A ⊗ I_m + blockdiag(2Δt q JₖᵀJₖ)) δθ = −Mᵀ ∂V/∂u.

    The blocks JₖᵀJₖ (k = 1..K−1) are added to the band (:func:`~snac_gym.kernels.trajopt.add_jacobian_blocks`) and the
    system is solved by LAPACK's banded Cholesky, O(K·m·b²).

    Raises:
        numpy.linalg.LinAlgError: If the matrix is not positive definite (it is, in exact arithmetic).
    """
    steps, m = grad.shape
    from snac_gym.kernels.trajopt import add_jacobian_blocks  # numba: imported where first needed

    band = np.array(base, order="F")  # LAPACK's layout, so that dpbtrf factors it in place
    add_jacobian_blocks(band, np.ascontiguousarray(jacobians, dtype=float), 2.0 * dt * q_scale)
    factor, info = dpbtrf(band, lower=1, overwrite_ab=1)  # band is this call's own copy
    if info != 0:
        raise np.linalg.LinAlgError(f"Gauss-Newton matrix not positive definite (dpbtrf info {info})")
    grad_theta = np.empty_like(grad)  # Mᵀ ∂V/∂u
    grad_theta[:-1] = (grad[:-1] - grad[1:]) / dt
    grad_theta[-1] = grad[-1] / dt
    step_theta = dpbtrs(factor, -grad_theta.reshape(-1), lower=1)[0].reshape(steps, m)
    return np.diff(step_theta, axis=0, prepend=np.zeros((1, m))) / dt  # M δθ


def _line_search(
    evaluate: Callable[[np.ndarray], tuple[float, np.ndarray]],
    commands: np.ndarray,
    value: float,
    grad: np.ndarray,
    step: np.ndarray,
) -> tuple[float, float, np.ndarray, int]:
    """Backtracking from the full step until V decreases enough (Armijo), or the step is below :data:`MIN_STEP`.

    Returns:
        (step fraction α, V and ∂V/∂u at the last trial, cost evaluations).
    """
    slope, alpha, tries = float(np.vdot(grad, step)), 1.0, 0
    while True:
        trial_value, trial_grad = evaluate(commands + alpha * step)
        tries += 1
        if trial_value <= value + ARMIJO * alpha * slope:
            return alpha, trial_value, trial_grad, tries
        alpha *= 0.5
        if alpha < MIN_STEP:
            return alpha, trial_value, trial_grad, tries


def solve_sample(
    q0: np.ndarray,
    x_d: np.ndarray,
    kinematics: Kinematics,
    dt: float,
    velocity_limits: np.ndarray,
    initial: np.ndarray | None = None,
    gtol: float = GTOL,
    ftol: float = FTOL,
    max_iterations: int = MAX_ITERATIONS,
    convention: CostConvention | None = None,
    gap_rtol: float = GAP_RTOL,
    position_limits: tuple[np.ndarray, np.ndarray] | None = None,
    interior_start: np.ndarray | None = None,
) -> OptimalSolution:
    """The optimal command sequence of one sample from one start (see the module docstring).

    Gauss-Newton first, without constraints (the common case: its optimum keeps every limit, and is
    then the constrained problem's too). Where that optimum breaks a limit, the interior point
    (:func:`interior_point`) solves the constrained problem from ``initial`` (or from rest where
    ``initial`` does not keep the limits strictly).

    Args:
        q0: ``(m,)`` seed pose.
        x_d: ``(K, n)`` desired positions at the start of each step.
        kinematics: The shared kinematic model.
        dt: Control period, s.
        velocity_limits: ``(m,)`` limits ū.
        initial: ``(K, m)`` start (default zeros: at rest).
        gtol, ftol, max_iterations, gap_rtol: The stopping test (:data:`GTOL`, :data:`FTOL`,
            :data:`GAP_RTOL`) and the cap.
        convention: The cost solved for (default: Table I's, Q = I, u₋₁ = 0).
        position_limits: ``(θ⁻, θ⁺)``, the joint position limits kept at θ₁..θ_K (``None``: velocity
            limits only, the variant that ignores the joints' position limits). A limit that θ₀
            itself does not keep is moved out to θ₀: no sequence could keep it.
        interior_start: ``(K, m)`` start of the interior point, if not ``initial`` (e.g. the
            feedback rollout that ``initial`` was refined from, which keeps the limits).
    """
    started = time.perf_counter()
    convention = convention if convention is not None else CostConvention()
    steps, m = x_d.shape[0], kinematics.n_joints
    q0 = np.asarray(q0, dtype=float)
    limits = _limits(velocity_limits, position_limits, q0)
    start = np.zeros((steps, m)) if initial is None else np.asarray(initial, dtype=float)
    commands, value, grad_z, iterations, evaluations, converged = gauss_newton(
        q0, x_d, kinematics, float(dt), start, gtol, ftol, max_iterations, convention, gap_rtol
    )
    gradient = float(np.abs(grad_z).max())
    gap_estimate = 0.5 * float(grad_z @ grad_z)
    bounded = limits.violation(commands, q0, dt) > 0.0
    if bounded:
        inside = _strictly_inside(start if interior_start is None else np.asarray(interior_start, dtype=float),
                                  q0, dt, limits)  # fmt: skip
        solves = [interior_point(q0, x_d, kinematics, float(dt), inside, limits, convention, max_iterations,
                                  gap_rtol, barrier_start) for barrier_start in BARRIER_STARTS]  # fmt: skip
        commands, value, _, _, converged = min(solves, key=lambda solve: solve[1])
        iterations += sum(solve[2] for solve in solves)
        evaluations += sum(solve[3] for solve in solves)
        gradient, gap_estimate = float("nan"), float("nan")
    return OptimalSolution(
        commands,
        value,
        iterations,
        evaluations,
        gradient,
        gap_estimate,
        converged,
        bounded,
        time.perf_counter() - started,
    )


def _limits(
    velocity_limits: np.ndarray, position_limits: tuple[np.ndarray, np.ndarray] | None, q0: np.ndarray
) -> Limits:
    velocity = np.asarray(velocity_limits, dtype=float)
    if position_limits is None:
        return Limits(velocity)
    return Limits(velocity, *position_bounds(*position_limits, q0))


def position_bounds(lower: np.ndarray, upper: np.ndarray, q0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The position bounds the solvers keep: θ⁻ + c and θ⁺ − c (c = :data:`LIMIT_CLEARANCE`), each moved
    just past a θ₀ that does not keep it (θ₀ is given: no sequence could keep that bound)."""
    lower, upper = np.asarray(lower, dtype=float) + LIMIT_CLEARANCE, np.asarray(upper, dtype=float) - LIMIT_CLEARANCE
    return np.where(q0 > lower, lower, q0 - LIMIT_CLEARANCE), np.where(q0 < upper, upper, q0 + LIMIT_CLEARANCE)


def _strictly_inside(start: np.ndarray, q0: np.ndarray, dt: float, limits: Limits) -> np.ndarray:
    """``start`` shrunk into the open velocity box if that keeps every position limit strictly, else rest."""
    inside = np.clip(start, -(1.0 - START_SHRINK) * limits.velocity, (1.0 - START_SHRINK) * limits.velocity)
    if limits.violation(inside, q0, dt) < 0.0:
        return inside
    return np.zeros_like(start)


# -- the constrained problem: joint position and velocity limits as hard constraints ----------------
#: Fraction-to-the-boundary of every interior-point step: a slack or a multiplier may lose at most this
#: share of its value in one step (IPOPT's τ_min), so the iterates stay strictly inside the limits.
BOUNDARY_FRACTION = 0.995
#: Factor the barrier parameter μ is divided by once a barrier problem is solved (centred).
BARRIER_DECREASE = 10.0
#: The first μ of each interior-point solve: its barrier's gap μ·(number of constraints) is this multiple
#: of V at the start. Where a limit binds, the basin the solve ends in depends on it (from a barrier far
#: above V the path starts near the centre of the limits, from one far below it near the unconstrained
#: path): the constrained problem is solved from both, and the better kept. Measured against IPOPT on
#: workspace samples whose joint limits bind, each alone missed a better basin that the other found.
BARRIER_STARTS = (100.0, 1e-2)
#: A barrier problem counts as solved once the Newton step is predicted to gain at most this share of
#: its gap μ·n_c (the centring test; the last μ also needs the gain below GAP_RTOL·V).
CENTRING = 0.1
#: Safeguard of the multipliers: each zᵢ is kept within [μ/(κ sᵢ), κ μ/sᵢ] (IPOPT's κ_Σ).
MULTIPLIER_SAFEGUARD = 1e10


@dataclass(frozen=True)
class Limits:
    """The hard constraints of the reference: |uₖⱼ| ≤ ūⱼ, and θ⁻ ≤ θₖ ≤ θ⁺ for k = 1..K when ``lower``
    and ``upper`` are given (the limits the success rule counts, ``joint_limit_margin ≥ 0``)."""

    velocity: np.ndarray
    lower: np.ndarray | None = None
    upper: np.ndarray | None = None

    @property
    def has_positions(self) -> bool:
        return self.lower is not None and self.upper is not None

    def slacks(self, commands: np.ndarray, angles: np.ndarray) -> list[np.ndarray]:
        """Every constraint's slack (≥ 0 inside): ū + u, ū − u, then θ − θ⁻ and θ⁺ − θ over θ₁..θ_K."""
        slacks = [self.velocity + commands, self.velocity - commands]
        if self.has_positions:
            slacks += [angles - self.lower, self.upper - angles]
        return slacks

    def violation(self, commands: np.ndarray, q0: np.ndarray, dt: float) -> float:
        """The largest excess over any limit (≤ 0: the sequence keeps every limit)."""
        return -min(float(s.min()) for s in self.slacks(commands, next_angles(commands, q0, dt)))


def next_angles(commands: np.ndarray, q0: np.ndarray, dt: float) -> np.ndarray:
    """θ₁..θ_K of θₖ₊₁ = θₖ + uₖΔt: the variables of the Gauss-Newton and interior-point systems."""
    return joint_path(q0, commands, dt)


def _difference_transpose(values: np.ndarray, dt: float) -> np.ndarray:
    """Mᵀy for y in u-space, with u = Mθ + c, uₖ = (θₖ₊₁ − θₖ)/Δt over the variables θ₁..θ_K."""
    out = np.empty_like(values)
    out[:-1] = (values[:-1] - values[1:]) / dt
    out[-1] = values[-1] / dt
    return out


@dataclass
class Barrier:
    """The interior-point state of one solve: slacks s, multipliers z, and μ."""

    limits: Limits
    dt: float
    mu: float
    slacks: list[np.ndarray]
    multipliers: list[np.ndarray]

    @property
    def count(self) -> int:
        return sum(s.size for s in self.slacks)

    def barrier(self, slacks: list[np.ndarray]) -> float:
        return -self.mu * sum(float(np.log(s).sum()) for s in slacks)

    def gradient(self) -> np.ndarray:
        """∂(−μ Σ log s)/∂θ."""
        inverse = [self.mu / s for s in self.slacks]
        grad = _difference_transpose(inverse[1] - inverse[0], self.dt)
        if self.limits.has_positions:
            grad += inverse[3] - inverse[2]
        return grad

    def add_to_band(self, band: np.ndarray, m: int) -> None:
        """Add Σ = z/s of every constraint to the θ-system: diagonal for θ bounds, MᵀΣM for u bounds."""
        weights = [z / s for z, s in zip(self.multipliers, self.slacks, strict=True)]
        velocity = (weights[0] + weights[1]) / self.dt**2
        diagonal = velocity.copy()
        diagonal[:-1] += velocity[1:]
        if self.limits.has_positions:
            diagonal += weights[2] + weights[3]
        band[0] += diagonal.ravel()
        band[m, :-m] -= velocity[1:].ravel()

    def step_multipliers(self, slack_steps: list[np.ndarray]) -> list[np.ndarray]:
        """δz = μ/s − z − (z/s) δs of every constraint (the linearised complementarity)."""
        return [
            self.mu / s - z - (z / s) * ds for z, s, ds in zip(self.multipliers, self.slacks, slack_steps, strict=True)
        ]

    def safeguard(self) -> None:
        for z, s in zip(self.multipliers, self.slacks, strict=True):
            np.clip(z, self.mu / (MULTIPLIER_SAFEGUARD * s), MULTIPLIER_SAFEGUARD * self.mu / s, out=z)


def _boundary_step(values: list[np.ndarray], steps: list[np.ndarray]) -> float:
    """The largest α ≤ 1 with v + α δv ≥ (1 − τ) v for every entry (fraction to the boundary)."""
    alpha = 1.0
    for v, dv in zip(values, steps, strict=True):
        shrinking = dv < 0
        if shrinking.any():
            alpha = min(alpha, float((-BOUNDARY_FRACTION * v[shrinking] / dv[shrinking]).min()))
    return alpha


def interior_point(
    q0: np.ndarray,
    x_d: np.ndarray,
    kinematics: Any,
    dt: float,
    start: np.ndarray,
    limits: Limits,
    convention: CostConvention,
    max_iterations: int = MAX_ITERATIONS,
    gap_rtol: float = GAP_RTOL,
    barrier_start: float = BARRIER_STARTS[0],
) -> tuple[np.ndarray, float, int, int, bool]:
    """Primal-dual interior point in θ₁..θ_K with Gauss-Newton on V: the constrained optimum from ``start``.

    ``start`` must keep every limit strictly. Each iteration solves the same block-banded system as the
    unconstrained solve, with the barrier's Σ = z/s added (diagonal for the position bounds, MᵀΣM for the
    velocity bounds: it stays within the band), takes the largest step that keeps every slack and
    multiplier at least 1 − τ of its value, and backtracks on the barrier function V − μ Σ log s. μ is
    divided by :data:`BARRIER_DECREASE` each time its problem is centred, until its gap μ·n_c is at
    most ``gap_rtol``·V: the sequence then keeps every limit and is within that of a local optimum.

    Returns:
        (commands, V, iterations, cost evaluations, converged).
    """
    steps, m = start.shape
    base = theta_system_base(steps, m, dt, convention)
    if base.shape[0] <= m:  # without the u̇ term A is tridiagonal: room for MᵀΣM's off-diagonal
        base = np.vstack([base, np.zeros((m + 1 - base.shape[0], base.shape[1]))])

    def evaluate(commands: np.ndarray) -> tuple[float, np.ndarray, list[np.ndarray]]:
        value, grad = trajectory_cost_and_gradient(commands, q0, x_d, kinematics, dt, convention)
        return value, grad, limits.slacks(commands, next_angles(commands, q0, dt))

    commands = start.copy()
    value, grad, slacks = evaluate(commands)
    if min(float(s.min()) for s in slacks) <= 0.0:
        raise ValueError("the interior-point start must keep every limit strictly")
    count = sum(s.size for s in slacks)
    mu = max(barrier_start * value / count, 1e-300)
    state = Barrier(limits, dt, mu, slacks, [mu / s for s in slacks])
    iterations, evaluations = 0, 1
    while iterations < max_iterations:
        _, jacobians = errors_and_jacobians(kinematics, angles(commands, q0, dt), x_d)
        step_u, slack_steps, decrement = _interior_direction(base, jacobians, grad, state, dt, convention.q_scale)
        alpha, trial, tries = _barrier_line_search(evaluate, commands, value, step_u, slack_steps, decrement, state)
        evaluations += tries
        if alpha < MIN_STEP:  # no decrease along a descent direction: rounding dominates
            return commands, value, iterations, evaluations, False
        iterations += 1
        multiplier_steps = state.step_multipliers(slack_steps)
        alpha_z = _boundary_step(state.multipliers, multiplier_steps)
        commands = commands + alpha * step_u
        value, grad, state.slacks = trial
        state.multipliers = [z + alpha_z * dz for z, dz in zip(state.multipliers, multiplier_steps, strict=True)]
        state.safeguard()
        gap, gain = state.mu * count, 0.5 * decrement  # the barrier's own gap; the step's predicted gain
        if gain <= CENTRING * gap and gap > gap_rtol * abs(value):
            state.mu /= BARRIER_DECREASE
            state.safeguard()
        elif gap <= gap_rtol * abs(value) and gain <= gap_rtol * abs(value):
            return commands, value, iterations, evaluations, True
    return commands, value, iterations, evaluations, False


def _interior_direction(
    base: np.ndarray, jacobians: np.ndarray, grad: np.ndarray, state: Barrier, dt: float, q_scale: float
) -> tuple[np.ndarray, list[np.ndarray], float]:
    """The primal-dual Newton step: (A ⊗ I + blockdiag(2Δt q JₖᵀJₖ) + Σ) δθ = −∂(V − μ Σ log s)/∂θ.

    Returns:
        (δu = M δθ, the slacks' steps, the decrement −∂Φ/∂θᵀδθ, twice the model's decrease).
    """
    from snac_gym.kernels.trajopt import add_jacobian_blocks  # numba: imported where first needed

    steps, m = grad.shape
    band = np.array(base, order="F")
    add_jacobian_blocks(band, np.ascontiguousarray(jacobians, dtype=float), 2.0 * dt * q_scale)
    state.add_to_band(band, m)
    rhs = -(_difference_transpose(grad, dt) + state.gradient())
    factor, info = dpbtrf(band, lower=1, overwrite_ab=1)
    if info != 0:
        raise np.linalg.LinAlgError(f"interior-point matrix not positive definite (dpbtrf info {info})")
    step_theta = dpbtrs(factor, rhs.reshape(-1), lower=1)[0].reshape(steps, m)
    step_u = np.diff(step_theta, axis=0, prepend=np.zeros((1, m))) / dt
    slack_steps = [step_u, -step_u] + ([step_theta, -step_theta] if state.limits.has_positions else [])
    return step_u, slack_steps, float(np.vdot(rhs, step_theta))


def _barrier_line_search(
    evaluate: Callable[[np.ndarray], tuple[float, np.ndarray, list[np.ndarray]]],
    commands: np.ndarray,
    value: float,
    step: np.ndarray,
    slack_steps: list[np.ndarray],
    decrement: float,
    state: Barrier,
) -> tuple[float, tuple[float, np.ndarray, list[np.ndarray]], int]:
    """Backtracking from the largest step that keeps the slacks 1 − τ of their value, until the barrier
    function V − μ Σ log s decreases enough (Armijo) with every slack still positive.

    Returns:
        (α, (V, ∂V/∂u, slacks) at the last trial, cost evaluations).
    """
    merit = value + state.barrier(state.slacks)
    alpha, tries = _boundary_step(state.slacks, slack_steps), 0
    while True:
        trial = evaluate(commands + alpha * step)
        tries += 1
        inside = min(float(s.min()) for s in trial[2]) > 0.0
        if inside and trial[0] + state.barrier(trial[2]) <= merit - ARMIJO * alpha * decrement:
            return alpha, trial, tries
        alpha *= 0.5
        if alpha < MIN_STEP:
            return alpha, trial, tries
