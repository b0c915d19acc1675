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
exact gradient cost one batched FK+Jacobian pass (:func:`trajectory_cost_and_gradient`,
:mod:`snac_gym.control.shooting`; the cost and its gradient are written in
:func:`snac_gym.control.cost.cost_and_gradient`). The quadratic effort + smoothness part has the fixed Hessian
``H₀ = 2Δt I + (2w/Δt) DᵀD`` in u. In the variables θ₁..θ_K the error term depends on θₖ alone and u = Mθ + c
(first differences), so the Gauss-Newton matrix ``MᵀH₀M ⊗ I + blockdiag(2Δt q JₖᵀJₖ)`` is block-banded
(bandwidth 12 scalars, 6 without the u̇ term) and each step is one banded Cholesky solve, followed by a
backtracking line search on the exact V: :class:`GaussNewtonSolver` (:mod:`snac_gym.control.gauss_newton`),
which the ``mpc`` controller steps with too. **Limits** (:func:`interior_point`,
:mod:`snac_gym.control.interior_point`): where that optimum breaks a joint position or velocity limit, a
primal-dual interior point on the same banded system solves the constrained problem.

**Tolerance**. Each Gauss-Newton step δ predicts the decrease −½ ∂V/∂uᵀδ, the model's
V − V* (of the local optimum). The solve stops after a step whose prediction was ≤
:data:`GAP_RTOL` · V (10⁻⁷), or when V decreases relatively by ≤ :data:`FTOL` (at
most :data:`MAX_ITERATIONS` iterations). The prediction follows the true V − V* to within a
factor of about 1.2 (``docs/optimal.md``), and the step removes most of it, so the cost is left
within far less than 10⁻⁷ V of its optimum. With ``H₀ = LLᵀ`` (``_preconditioner``), the
effort + smoothness part is ‖z‖² in ``z = Lᵀu``.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from snac_gym.control.cost import CostConvention
from snac_gym.control.gauss_newton import (
    ARMIJO,
    FTOL,
    GAP_RTOL,
    GTOL,
    MAX_ITERATIONS,
    MIN_STEP,
    GaussNewtonSolver,
    gauss_newton,
    gauss_newton_direction,
    theta_system_base,
)

# H₀'s factor L, which the module docstring's z = Lᵀu is written in
from snac_gym.control.gauss_newton import _preconditioner as _preconditioner
from snac_gym.control.interior_point import (
    BARRIER_DECREASE,
    BARRIER_STARTS,
    BOUNDARY_FRACTION,
    CENTRING,
    LIMIT_CLEARANCE,
    MULTIPLIER_SAFEGUARD,
    START_SHRINK,
    Barrier,
    Limits,
    interior_point,
    position_bounds,
)
from snac_gym.control.shooting import angles, errors_and_jacobians, next_angles, trajectory_cost_and_gradient
from snac_gym.model.kinematics import Kinematics

__all__ = [
    "ARMIJO",
    "BARRIER_DECREASE",
    "BARRIER_STARTS",
    "BOUNDARY_FRACTION",
    "CENTRING",
    "FTOL",
    "GAP_RTOL",
    "GTOL",
    "LIMIT_CLEARANCE",
    "MAX_ITERATIONS",
    "MIN_STEP",
    "MULTIPLIER_SAFEGUARD",
    "START_SHRINK",
    "Barrier",
    "GaussNewtonSolver",
    "Limits",
    "OptimalSolution",
    "angles",
    "errors_and_jacobians",
    "gauss_newton",
    "gauss_newton_direction",
    "interior_point",
    "next_angles",
    "position_bounds",
    "single_threaded_blas",
    "solve_sample",
    "theta_system_base",
    "trajectory_cost_and_gradient",
]


@contextlib.contextmanager
def single_threaded_blas() -> Iterator[None]:
    """Run the block with BLAS on one thread (``threadpoolctl``; restored after).

    L-BFGS-B's and the banded Cholesky's BLAS calls on ~10⁴ variables are far too small to gain
    from threads: with OpenBLAS's default thread count on a busy 2-core machine a solve ran 5-10x
    slower (measured, docs/optimal.md). Worker processes already run in parallel.
    """
    with threadpool_limits(limits=1, user_api="blas"):
        yield


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
    until: Callable[[np.ndarray], bool] | None = None,
    newton: bool = False,
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
        until: Called with the commands after each step; the solve stops there (not converged) once it returns True:
            a multi-start's start that has reached a known basin. Of the interior point's solves, one stopped so is
            kept only where every one was.
        newton: Newton's steps once Gauss-Newton converges slowly (:func:`gauss_newton`).
    """
    started = time.perf_counter()
    convention = convention if convention is not None else CostConvention()
    steps, m = x_d.shape[0], kinematics.n_joints
    q0 = np.asarray(q0, dtype=float)
    limits = _limits(velocity_limits, position_limits, q0)
    start = np.zeros((steps, m)) if initial is None else np.asarray(initial, dtype=float)
    commands, value, grad_z, iterations, evaluations, converged = gauss_newton(
        q0, x_d, kinematics, float(dt), start, gtol, ftol, max_iterations, convention, gap_rtol, until, newton=newton
    )
    gradient = float(np.abs(grad_z).max())
    gap_estimate = 0.5 * float(grad_z @ grad_z)
    stopped = until is not None and not converged and until(commands)
    bounded = not stopped and limits.violation(commands, q0, dt) > 0.0
    if bounded:
        inside = _strictly_inside(start if interior_start is None else np.asarray(interior_start, dtype=float),
                                  q0, dt, limits)  # fmt: skip
        solves = [interior_point(q0, x_d, kinematics, float(dt), inside, limits, convention, max_iterations,
                                  gap_rtol, barrier_start, until) for barrier_start in BARRIER_STARTS]  # fmt: skip
        # A solve that ``until`` stopped in a known basin is no answer where another went on to an optimum of its own.
        answers = [solve for solve in solves if until is None or solve[4] or not until(solve[0])] or solves
        commands, value, _, _, converged = min(answers, key=lambda solve: solve[1])
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


def _strictly_inside(start: np.ndarray, q0: np.ndarray, dt: float, limits: Limits) -> np.ndarray:
    """``start`` shrunk into the open velocity box if that keeps every position limit strictly, else rest."""
    inside = np.clip(start, -(1.0 - START_SHRINK) * limits.velocity, (1.0 - START_SHRINK) * limits.velocity)
    if limits.violation(inside, q0, dt) < 0.0:
        return inside
    return np.zeros_like(start)
