"""The Gauss-Newton solver of the trajectory cost in the variables θ₁..θ_K (:mod:`snac_gym.control.trajopt`).

In θ₁..θ_K the error term depends on θₖ alone and u = Mθ + c (first differences), so the Gauss-Newton matrix
``MᵀH₀M ⊗ I + blockdiag(2Δt q JₖᵀJₖ)`` is block-banded (bandwidth 12 scalars, 6 without the u̇ term), H₀ =
2Δt I + (2w/Δt) DᵀD being the fixed Hessian of the effort + smoothness part in u (:func:`_effort_hessian_band`).
Each step is one banded Cholesky solve (:func:`gauss_newton_direction`), followed by an Armijo backtracking on the
exact V. :class:`GaussNewtonSolver` holds both for one grid, for one plan or a batch of plans: the unconstrained
solve (:func:`gauss_newton`), the interior point (:mod:`snac_gym.control.interior_point`) and the ``mpc``
controller's re-solves all step with it.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Protocol

import numpy as np
import scipy.sparse as sp
from scipy.linalg import cholesky_banded, solve_banded

from snac_gym.control.cost import CostConvention
from snac_gym.control.shooting import angles, errors_and_jacobians, trajectory_cost_and_gradient
from snac_gym.kernels.compiled import read_only_view
from snac_gym.model.kinematics import Kinematics

__all__ = [
    "ARMIJO",
    "FTOL",
    "GAP_RTOL",
    "GTOL",
    "MAX_ITERATIONS",
    "MIN_STEP",
    "GaussNewtonSolver",
    "gauss_newton",
    "gauss_newton_direction",
    "theta_system_base",
]

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
    base: np.ndarray,
    jacobians: np.ndarray,
    grad: np.ndarray,
    dt: float,
    q_scale: float,
    curvature: np.ndarray | None = None,
) -> np.ndarray:
    """The Gauss-Newton step in u: M δθ with (A ⊗ I_m + blockdiag(2Δt q JₖᵀJₖ)) δθ = −Mᵀ ∂V/∂u.

    The blocks JₖᵀJₖ (k = 1..K−1) are added to the band (:func:`~snac_gym.kernels.trajopt.add_jacobian_blocks`) and the
    system is solved by a banded Cholesky, O(K·m·b²) (:func:`~snac_gym.kernels.trajopt.banded_cholesky_solve`:
    LAPACK's ``dpbtrf`` and ``dpbtrs``, compiled). ``curvature``: the blocks Σᵢ eₖᵢ∇²fᵢ(θₖ) ``(K, m, m)``
    added too (:meth:`~snac_gym.model.kinematics.Kinematics.error_curvature_batch`): the exact Hessian of V in θ,
    Newton's step; the error term depends on θₖ alone, so they keep the band.

    Raises:
        numpy.linalg.LinAlgError: If the matrix is not positive definite (the Gauss-Newton one is, in exact
            arithmetic; the exact Hessian need not be away from a minimum).
    """
    steps, m = grad.shape
    from snac_gym.kernels.trajopt import (  # numba: where first needed
        add_jacobian_blocks,
        add_symmetric_blocks,
        banded_cholesky_solve,
    )

    band = np.array(base, order="F")  # LAPACK's layout: each column's band contiguous
    add_jacobian_blocks(band, read_only_view(jacobians), 2.0 * dt * q_scale)
    if curvature is not None:
        add_symmetric_blocks(band, curvature, 2.0 * dt * q_scale)
    grad_theta = np.empty_like(grad)  # Mᵀ ∂V/∂u
    grad_theta[:-1] = (grad[:-1] - grad[1:]) / dt
    grad_theta[-1] = grad[-1] / dt
    info, solution = banded_cholesky_solve(band, -grad_theta.reshape(-1))  # band is this call's own copy
    if info != 0:
        raise np.linalg.LinAlgError(f"Gauss-Newton matrix not positive definite (Cholesky pivot {info})")
    step_theta = solution.reshape(steps, m)
    return np.diff(step_theta, axis=0, prepend=np.zeros((1, m))) / dt  # M δθ


class BandTerm(Protocol):
    """A term of the Gauss-Newton matrix beyond the cost's own (a log barrier's Σ): it adds itself to the band."""

    def add_to_band(self, band: np.ndarray, m: int) -> None: ...


class GaussNewtonSolver:
    """Gauss-Newton steps of the trajectory cost on one grid: K steps of Δt, m joints, one cost convention.

    The fixed part of the θ-system, A ⊗ I_m (:func:`theta_system_base`), is built once per grid; each
    :meth:`direction` adds one plan's Jacobian blocks to it and solves. :meth:`line_search` is the Armijo
    backtracking on the exact cost, for one plan or for a batch of plans at once (one FK pass per trial for all
    of them).

    Args:
        steps: K, the commands of a plan.
        joints: m.
        dt: The grid's step Δt, s.
        convention: The cost solved for (its u̇ weight and u₋₁ shape A; its q_scale the error blocks).
        barrier: Leave room in the band for a barrier's MᵀΣM (one off-diagonal block), which the u̇-free A lacks.

    Attributes:
        base: The band A ⊗ I_m in LAPACK's lower form (read-only use: :meth:`direction` copies it).
    """

    def __init__(self, steps: int, joints: int, dt: float, convention: CostConvention, barrier: bool = False) -> None:
        self.steps, self.joints, self.dt, self.convention = steps, joints, dt, convention
        base = theta_system_base(steps, joints, dt, convention)
        if barrier and base.shape[0] <= joints:  # without the u̇ term A is tridiagonal: room for MᵀΣM's off-diagonal
            base = np.vstack([base, np.zeros((joints + 1 - base.shape[0], base.shape[1]))])
        self.base = base

    def direction(
        self,
        jacobians: np.ndarray,
        grad: np.ndarray,
        terminal: np.ndarray | None = None,
        barrier: BandTerm | None = None,
        curvature: np.ndarray | None = None,
    ) -> np.ndarray:
        """The Gauss-Newton step in u of one plan (:func:`gauss_newton_direction`) from the Jacobians at θ₀..θ_{K−1}
        and ∂V/∂u; ``terminal``: an ``(m, m)`` Hessian added in θ_K's block (a terminal cost on θ_K), ``barrier``: a
        barrier's Σ added to the band, ``curvature``: the error term's second-order blocks (Newton's step)."""
        band = self.base
        if terminal is not None or barrier is not None:
            band = band.copy()
        if terminal is not None:
            m = self.joints
            rows, cols = np.tril_indices(m)
            # lower band: [a − b, k·m + b] ← H_ab
            band[rows - cols, (self.steps - 1) * m + cols] += terminal[rows, cols]
        if barrier is not None:
            barrier.add_to_band(band, self.joints)
        return gauss_newton_direction(band, jacobians, grad, self.dt, self.convention.q_scale, curvature)

    @staticmethod
    def line_search(
        merit: Callable[[np.ndarray, np.ndarray], np.ndarray],
        values: np.ndarray,
        slopes: np.ndarray,
        first: np.ndarray | float = 1.0,
        accept: Callable[[np.ndarray, np.ndarray], None] | None = None,
        max_tries: int | None = None,
        min_step: float = MIN_STEP,
    ) -> tuple[np.ndarray, np.ndarray, int]:
        """Armijo backtracking of a batch of plans: plan i tries the step fractions αᵢ = ``first``ᵢ, αᵢ/2, ... until
        its merit falls to ``values``ᵢ + :data:`ARMIJO`·αᵢ·``slopes``ᵢ, every pending plan in one call of ``merit``.

        Args:
            merit: ``merit(rows, alphas)``: the merit (the cost, plus a barrier; inf outside its domain) of the
                plans ``rows`` (indices into the batch) stepped by the fractions ``alphas``.
            values: The plans' merits at α = 0.
            slopes: Their slopes along the steps (∂V/∂uᵀδ, negative for a descent direction).
            first: The first fraction tried, per plan or for all.
            accept: ``accept(rows, taken)`` after each call of ``merit``: ``taken`` marks the plans of ``rows``
                whose trial was accepted (the caller keeps what ``merit`` computed for them).
            max_tries: Give up on a plan after this many trials (``None``: no cap).
            min_step: Give up on a plan once its next fraction would be below this.

        Returns:
            (the fractions αᵢ, accepted per plan, calls of ``merit``). A plan that gave up keeps its α unused.
        """
        values, slopes = np.atleast_1d(values), np.atleast_1d(slopes)
        alpha = np.array(np.broadcast_to(np.asarray(first, dtype=float), values.shape))
        accepted = np.zeros(len(values), dtype=bool)
        pending, tries = np.arange(len(values)), 0
        while len(pending):
            trial = merit(pending, alpha[pending])
            tries += 1
            taken = trial <= values[pending] + ARMIJO * alpha[pending] * slopes[pending]
            if accept is not None:
                accept(pending, taken)
            accepted[pending[taken]] = True
            pending = pending[~taken]
            if max_tries is not None and tries >= max_tries:
                break
            alpha[pending] *= 0.5
            pending = pending[alpha[pending] >= min_step]
        return alpha, accepted, tries


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
    newton: bool = False,
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
    ``newton``: take Newton's step, with the exact Hessian's blocks
    (:meth:`~snac_gym.model.kinematics.Kinematics.error_curvature_batch`), wherever that Hessian is positive
    definite, and the Gauss-Newton step elsewhere (position tasks only). Where the errors stay large along the
    path, Gauss-Newton leaves out a second-order part that is not small and converges linearly (the steps shrinking
    by 0.88 each on the reference's coarse solves, docs/benchmarks-log.md); Newton's converges quadratically near the
    optimum, and reaches the same local optimum.

    Returns:
        (commands, V, ∂V/∂z flattened, iterations, cost evaluations, converged) with the stopping
        test of the module docstring: a step predicted to gain ≤ ``gap_rtol``·V, or a relative
        decrease ≤ ``ftol``; converged also when max |∂V/∂z| ≤ ``gtol`` at the end.
    """
    steps, m = start.shape
    lower = _preconditioner(steps, dt, convention.smoothness_weight, convention.udot_start)
    solver = GaussNewtonSolver(steps, m, dt, convention)

    def evaluate(commands: np.ndarray) -> tuple[float, np.ndarray]:
        return trajectory_cost_and_gradient(commands, q0, x_d, kinematics, dt, convention)

    commands = start.copy()
    value, grad = evaluate(commands)
    iterations, evaluations, converged = 0, 1, False
    curvature = getattr(kinematics, "error_curvature_batch", None) if newton else None
    if getattr(kinematics, "task_error", None) is not None:
        curvature = None  # a pose task's error is a logarithm, not f(θ) − x_d
    while iterations < max_iterations:
        path = angles(commands, q0, dt)
        errors, jacobians = errors_and_jacobians(kinematics, path, x_d)
        step = _newton_direction(solver, curvature, path, errors, jacobians, grad)
        if step is None:
            step = solver.direction(jacobians, grad)
        predicted = -0.5 * float(np.vdot(grad, step))  # the model's V − V*: half the (Gauss-)Newton decrement
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


def _newton_direction(
    solver: GaussNewtonSolver,
    curvature: Callable[[np.ndarray, np.ndarray], np.ndarray | None] | None,
    path: np.ndarray,
    errors: np.ndarray,
    jacobians: np.ndarray,
    grad: np.ndarray,
) -> np.ndarray | None:
    """Newton's step with the exact Hessian's blocks, or None where they are unavailable or the Hessian is not
    positive definite (the caller takes the Gauss-Newton step)."""
    blocks = curvature(path, errors) if curvature is not None else None
    if blocks is None:
        return None
    try:
        return solver.direction(jacobians, grad, curvature=blocks)
    except np.linalg.LinAlgError:
        return None


def _line_search(
    evaluate: Callable[[np.ndarray], tuple[float, np.ndarray]],
    commands: np.ndarray,
    value: float,
    grad: np.ndarray,
    step: np.ndarray,
) -> tuple[float, float, np.ndarray, int]:
    """:meth:`GaussNewtonSolver.line_search` of one plan from the full step.

    Returns:
        (step fraction α, V and ∂V/∂u at the last trial, cost evaluations); α < :data:`MIN_STEP` where no
        fraction down to it decreased V enough.
    """
    last: list[tuple[float, np.ndarray]] = []

    def merit(rows: np.ndarray, alphas: np.ndarray) -> np.ndarray:
        last[:] = [evaluate(commands + alphas[0] * step)]
        return np.array([last[0][0]])

    slope = float(np.vdot(grad, step))
    alphas, accepted, tries = GaussNewtonSolver.line_search(merit, np.array([value]), np.array([slope]))
    trial_value, trial_grad = last[0]
    return (float(alphas[0]) if accepted[0] else 0.0), trial_value, trial_grad, tries
