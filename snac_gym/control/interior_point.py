"""The trajectory optimiser's constrained problem: the joint position and velocity limits as hard constraints,
solved by a primal-dual interior point on the Gauss-Newton system (:mod:`snac_gym.control.trajopt`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from snac_gym.control.cost import CostConvention
from snac_gym.control.gauss_newton import GAP_RTOL, MAX_ITERATIONS, MIN_STEP, GaussNewtonSolver
from snac_gym.control.shooting import angles, errors_and_jacobians, next_angles, trajectory_cost_and_gradient
from snac_gym.kernels.compiled import read_only_view

__all__ = [
    "BARRIER_DECREASE",
    "BARRIER_STARTS",
    "BOUNDARY_FRACTION",
    "CENTRING",
    "LIMIT_CLEARANCE",
    "MULTIPLIER_SAFEGUARD",
    "START_SHRINK",
    "Barrier",
    "Limits",
    "interior_point",
    "position_bounds",
]

#: The clearance, rad, kept from every joint position limit (:func:`position_bounds`): a rollout integrates
#: θₖ₊₁ = θₖ + uₖΔt step by step, the solver sums the commands in another order, and an active limit must
#: not be crossed by the rounding between the two (about 1e-13 rad over 2500 steps).
LIMIT_CLEARANCE = 1e-9
#: An interior-point start's commands are shrunk by this share into the open velocity box.
START_SHRINK = 1e-3
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
    until: Callable[[np.ndarray], bool] | None = None,
) -> tuple[np.ndarray, float, int, int, bool]:
    """Primal-dual interior point in θ₁..θ_K with Gauss-Newton on V: the constrained optimum from ``start``.

    ``start`` must keep every limit strictly. Each iteration solves the same block-banded system as the
    unconstrained solve, with the barrier's Σ = z/s added (diagonal for the position bounds, MᵀΣM for the
    velocity bounds: it stays within the band), takes the largest step that keeps every slack and
    multiplier at least 1 − τ of its value, and backtracks on the barrier function V − μ Σ log s. μ is
    divided by :data:`BARRIER_DECREASE` each time its problem is centred, until its gap μ·n_c is at
    most ``gap_rtol``·V: the sequence then keeps every limit and is within that of a local optimum.
    ``until``: called with the commands after each step; the solve stops there (not converged) once it returns True.

    Returns:
        (commands, V, iterations, cost evaluations, converged).
    """
    steps, m = start.shape
    base = GaussNewtonSolver(steps, m, dt, convention, barrier=True).base

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
        if until is not None and until(commands):
            break
    return commands, value, iterations, evaluations, False


def _interior_direction(
    base: np.ndarray, jacobians: np.ndarray, grad: np.ndarray, state: Barrier, dt: float, q_scale: float
) -> tuple[np.ndarray, list[np.ndarray], float]:
    """The primal-dual Newton step: (A ⊗ I + blockdiag(2Δt q JₖᵀJₖ) + Σ) δθ = −∂(V − μ Σ log s)/∂θ.

    Returns:
        (δu = M δθ, the slacks' steps, the decrement −∂Φ/∂θᵀδθ, twice the model's decrease).
    """
    from snac_gym.kernels.trajopt import add_jacobian_blocks, banded_cholesky_solve  # numba: where first needed

    steps, m = grad.shape
    band = np.array(base, order="F")
    add_jacobian_blocks(band, read_only_view(jacobians), 2.0 * dt * q_scale)
    state.add_to_band(band, m)
    rhs = -(_difference_transpose(grad, dt) + state.gradient())
    info, solution = banded_cholesky_solve(band, rhs.reshape(-1))
    if info != 0:
        raise np.linalg.LinAlgError(f"interior-point matrix not positive definite (Cholesky pivot {info})")
    step_theta = solution.reshape(steps, m)
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
    """:meth:`~snac_gym.control.gauss_newton.GaussNewtonSolver.line_search` on the barrier function V − μ Σ log s
    (inf where a slack is not positive), from the largest step that keeps the slacks 1 − τ of their value.

    Returns:
        (α, (V, ∂V/∂u, slacks) at the last trial, cost evaluations); α < :data:`MIN_STEP` where no step was
        accepted.
    """
    last: list[tuple[float, np.ndarray, list[np.ndarray]]] = []

    def merit(rows: np.ndarray, alphas: np.ndarray) -> np.ndarray:
        trial = evaluate(commands + alphas[0] * step)
        last[:] = [trial]
        inside = min(float(s.min()) for s in trial[2]) > 0.0
        return np.array([trial[0] + state.barrier(trial[2]) if inside else np.inf])

    start = np.array([value + state.barrier(state.slacks)])
    first = _boundary_step(state.slacks, slack_steps)
    alphas, accepted, tries = GaussNewtonSolver.line_search(merit, start, np.array([-decrement]), first)
    return (float(alphas[0]) if accepted[0] else 0.0), last[0], tries


def position_bounds(lower: np.ndarray, upper: np.ndarray, q0: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The position bounds the solvers keep: θ⁻ + c and θ⁺ − c (c = :data:`LIMIT_CLEARANCE`), each moved
    just past a θ₀ that does not keep it (θ₀ is given: no sequence could keep that bound)."""
    lower, upper = np.asarray(lower, dtype=float) + LIMIT_CLEARANCE, np.asarray(upper, dtype=float) - LIMIT_CLEARANCE
    return np.where(q0 > lower, lower, q0 - LIMIT_CLEARANCE), np.where(q0 < upper, upper, q0 + LIMIT_CLEARANCE)
