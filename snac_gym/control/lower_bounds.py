"""Certified lower bounds on the trajectory cost: numbers no command sequence can go below, whatever a solver did.

For a sample (θ₀, x_d) under any cost convention, with the velocity limits: the scalar relaxation of the error's
norm (:func:`solve_cost_relaxation`, a convex QP solved by a compiled primal-dual kernel), the relaxation that
follows the reference in 3-D (:func:`following_cost_lower_bounds`), the per-sample Lipschitz bounds of the joint ball
a trajectory of bounded cost can reach (:func:`reachable_lipschitz_bounds`), and the evaluator's entry point
(:func:`certified_cost_lower_bounds`). docs/lower-bounds.md derives each one.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from snac_gym.control.cost import CostConvention
from snac_gym.control.jacobian_bound import jacobian_norm_bound, joint_variation_bounds
from snac_gym.kernels.relaxation import relaxation_kernel


def regulation_cost_lower_bound(
    initial_error: float | np.ndarray, steps: int, dt: float, lipschitz: float, q_scale: float = 1.0
) -> np.ndarray:
    """A certified lower bound on the regulation cost Σₖ₌₀^{K−1} (q‖eₖ‖² + ‖uₖ‖²) Δt of *any* command sequence.

    With L a Lipschitz constant of f (:meth:`snac_gym.model.kinematics.Kinematics.position_lipschitz_bound`),
    a fixed target and θₖ₊₁ = θₖ + uₖΔt, the error norm rₖ = ‖eₖ‖ can fall by at most LΔt‖uₖ‖ per
    step: rₖ₊₁ ≥ rₖ − LΔt vₖ with vₖ = ‖uₖ‖. Relaxing the arm to this scalar system (any direction
    at the best gain L) leaves a scalar finite-horizon LQR, 1 = a, b = LΔt, whose value is P₀r₀²:

        P_K = 0,   Pₖ = qΔt + Pₖ₊₁ − (b Pₖ₊₁)² / (Δt + b² Pₖ₊₁)                   (Riccati, backwards)

    Its optimal rₖ stays ≥ 0 and vₖ ≥ 0, so it is also the optimum with those constraints, and every
    real trajectory is feasible for the relaxation: the bound holds for every controller and for the
    optimum. It ignores the velocity limits and the u̇ term (both only add cost), so it bounds the
    Table I cost as well as the HJB cost.

    Args:
        initial_error: ‖e₀‖ (m), a scalar or an array.
        steps: K.
        dt: Δt, s.
        lipschitz: L, m/rad.
        q_scale: Q = q·I (R = I).
    """
    if not (steps >= 1 and dt > 0 and lipschitz > 0 and q_scale > 0):
        raise ValueError(
            f"need steps ≥ 1, dt > 0, lipschitz > 0, q_scale > 0; got {steps}, {dt}, {lipschitz}, {q_scale}"
        )
    b, value = lipschitz * dt, 0.0
    for _ in range(int(steps)):
        value = q_scale * dt + value - (b * value) ** 2 / (dt + b * b * value)
    return value * np.square(np.asarray(initial_error, dtype=float))


# -- A certified lower bound on the trajectory cost, for reach and track, under every cost convention ----------------
#
# The derivation, what is relaxed and why each step is valid, is in solve_cost_relaxation's docstring and in
# docs/lower-bounds.md. The relaxed problem is solved by a primal-dual interior point method whose Newton systems are
# banded (the variables interleaved as v₀, r₁, v₁, r₂, …, r_{K−1}, v_{K−1}: every coupling is within two places); the
# kernels are plain functions compiled by numba on first use (snac_gym/kernels/relaxation.py), so that importing
# this module does not import numba.

#: Relative width of the interval [bound, relaxed optimum + neglected tail] at which the solve stops.
RELAXATION_RTOL = 1e-10
#: Interior-point iterations per horizon tried (it takes 10-20; the cap only stops a pathological solve, whose
#: last dual value is still a certified bound).
RELAXATION_MAX_ITERATIONS = 100
#: First horizon solved (steps), or 0: the relaxed regulation problem's decay time (_first_horizon). It grows
#: until the part left out is provably within RELAXATION_RTOL (see solve_cost_relaxation).
RELAXATION_FIRST_STEPS = 0


def reference_steps(x_d: np.ndarray) -> np.ndarray:
    """dₖ = ‖x_d(tₖ₊₁) − x_d(tₖ)‖, k = 0..K−2, of desired positions ``(…, K, n)``: ``(…, K−1)`` (zeros for a fixed
    target)."""
    x_d = np.asarray(x_d, dtype=float)
    return np.linalg.norm(np.diff(x_d, axis=-2), axis=-1)


@dataclass(frozen=True)
class CostRelaxation:
    """The relaxed problem of :func:`solve_cost_relaxation` for B samples, each field ``(B,)``.

    Attributes:
        bound: The certified lower bound on every trajectory's cost (a dual value of the relaxation).
        relaxed_upper: An upper bound on the relaxation's optimum (a feasible point's relaxed cost, plus the
            cost of continuing it with v = 0 over the steps not solved): the optimum lies in [bound, relaxed_upper].
        iterations: Interior-point iterations, over all horizons tried.
        steps: The horizon K' ≤ K solved (the relaxation over the first K' steps bounds the K-step cost too).
    """

    bound: np.ndarray
    relaxed_upper: np.ndarray
    iterations: np.ndarray
    steps: np.ndarray


def solve_cost_relaxation(
    initial_errors: float | np.ndarray,
    reference_steps: np.ndarray,
    dt: float,
    lipschitz: float | np.ndarray,
    convention: CostConvention | None = None,
    velocity_norm_limit: float | None = None,
    rtol: float = RELAXATION_RTOL,
) -> CostRelaxation:
    """A certified lower bound on the trajectory cost of *any* command sequence, per sample, with diagnostics.

    **Problem bounded.** θₖ₊₁ = θₖ + uₖΔt, eₖ = f(θₖ) − x_d(tₖ) and (:class:`snac_gym.control.cost.CostConvention`;
    Q = qI, R = I, w = 1 for ``table1``, 0 for ``hjb``)

        V = Σₖ₌₀^{K−1} (q‖eₖ‖² + ‖uₖ‖² + w‖uₖ − uₖ₋₁‖²/Δt²) Δt,    u₋₁ = 0 (``rest``) or u₀ (``first``),

    with |uₖⱼ| ≤ ūⱼ. **Relaxation** to the norms rₖ = ‖eₖ‖, vₖ = ‖uₖ‖:

    1. For k = 0..K−2, eₖ₊₁ = eₖ + (f(θₖ₊₁) − f(θₖ)) − (x_d(tₖ₊₁) − x_d(tₖ)), so by the triangle inequality
       rₖ₊₁ ≥ rₖ − ‖f(θₖ₊₁) − f(θₖ)‖ − dₖ ≥ rₖ − LₖΔt vₖ − dₖ, with dₖ = ‖x_d(tₖ₊₁) − x_d(tₖ)‖ and Lₖ ≥ ‖J‖₂
       on the segment [θₖ, θₖ₊₁] (f(θ + δ) − f(θ) = ∫₀¹ J(θ + sδ)δ ds). r₀ = ‖e₀‖ is data; u_{K−1} moves θ_K,
       which the cost does not score, so it enters through its effort and jump terms only.
    2. ‖uₖ − uₖ₋₁‖ ≥ |vₖ − vₖ₋₁| for k ≥ 1 (reverse triangle inequality); under ``rest`` ‖u₀ − u₋₁‖ = v₀.
    3. vₖ ≤ ‖ū‖₂ (the box |uₖⱼ| ≤ ūⱼ lies in that ball).
    4. rₖ ≥ 0 and vₖ ≥ 0 hold but are left out: they do not change the relaxed optimum (from any feasible point,
       v ← max(v, 0) and then r ← the least r the constraints allow, ≥ 0, is feasible and costs no more:
       max(·, 0) is 1-Lipschitz, so no jump grows, and b, d ≥ 0).

    A real trajectory gives a point (rₖ, vₖ) = (‖eₖ‖, ‖uₖ‖) feasible for 1-3 whose relaxed cost

        Σₖ (q rₖ² + vₖ² + w(vₖ − vₖ₋₁)²/Δt²) Δt      (v₋₁ = 0 under ``rest``; no k = 0 jump under ``first``)

    is at most V, term by term. So the relaxed optimum is at most every trajectory's cost: the optimum's and every
    controller's, on every sample. It is a convex QP in 2K − 1 variables with banded structure.

    **Certified whatever the solver's accuracy.** The value reported is the Lagrangian dual function of the relaxed
    QP, g(z) = min_x [F(x) + zᵀ(Gx − h)] = qΔt r₀² − ½(Gᵀz)ᵀH⁻¹(Gᵀz) − zᵀh (F = ½xᵀHx + qΔt r₀², H positive
    definite), at the interior-point multipliers z > 0, the best over the iterates: by weak duality every
    g(z) with z ≥ 0 is ≤ the relaxed optimum, converged or not (up to floating-point rounding, ~1e-12 relative).
    The solve stops once a feasible point's relaxed cost is within ``rtol`` of it.

    **Horizon.** All terms of V are ≥ 0, so the relaxation over the first K' ≤ K steps, plus a lower bound on the
    rest, bounds V too: the remaining K − K' steps cost at least P_{K−K'} v²_{K'−1} (their error terms dropped, the
    least effort and jump cost of bringing the last command down: a scalar Riccati recursion, 0 without the u̇
    term). K' starts at the relaxed regulation problem's decay time (or :data:`RELAXATION_FIRST_STEPS`) and grows
    until the rest is provably within ``rtol``: the truncated solution continued by those least-cost commands
    (along which r never rises) is feasible for the whole horizon, so the relaxed optimum lies in
    [bound, value + q r²_{K'−1}(K − K')Δt].

    Args:
        initial_errors: r₀ = ‖e₀‖ (m), ``()`` or ``(B,)``.
        reference_steps: dₖ, ``(K−1,)`` or ``(B, K−1)`` (:func:`reference_steps` of x_d; zeros for a fixed target).
        dt: Δt, s.
        lipschitz: Lₖ, m/rad: a scalar (e.g. :meth:`snac_gym.model.kinematics.Kinematics.position_lipschitz_bound`),
            or per step ``(K−1,)`` or ``(B, K−1)`` (each a bound on ‖J‖₂ along that step's segment).
        convention: The cost (default: Table I's, q = 1, u₋₁ = 0).
        velocity_norm_limit: ‖ū‖₂ (rad/s), or ``None`` for no limit.
        rtol: Stop once the relaxed optimum is pinned to this relative width.

    Raises:
        ValueError: On negative or non-finite errors or steps, a non-positive Lipschitz constant, Δt or limit.
    """
    convention = convention if convention is not None else CostConvention()
    errors, steps, slopes, limit = _relaxation_inputs(
        initial_errors, reference_steps, dt, lipschitz, velocity_norm_limit
    )
    out = np.empty((4, len(errors)))
    relaxation_kernel()(
        errors, steps, slopes, float(dt), float(convention.q_scale), float(convention.smoothness_weight),
        convention.udot_start == "rest", limit, float(rtol), RELAXATION_MAX_ITERATIONS, RELAXATION_FIRST_STEPS, out,
    )  # fmt: skip
    return CostRelaxation(out[0], out[1], out[2].astype(np.int64), out[3].astype(np.int64))


def _relaxation_inputs(
    initial_errors: Any, steps: Any, dt: float, lipschitz: Any, limit: float | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """(r₀ ``(B,)``, d ``(B, K−1)``, LₖΔt ``(B, K−1)``, ‖ū‖ or inf), checked and C-contiguous for the kernel."""
    errors = np.array(np.atleast_1d(np.asarray(initial_errors, dtype=float)), order="C")
    steps = np.asarray(steps, dtype=float)
    if errors.ndim != 1 or steps.ndim not in (1, 2):
        raise ValueError(
            f"initial_errors must be () or (B,), reference_steps (K−1,) or (B, K−1); got {errors.shape}, {steps.shape}"
        )
    # Writable C copies: numba compiles a read-only array (a broadcast view) as a type of its own
    steps = np.array(np.broadcast_to(steps, (len(errors), steps.shape[-1])), order="C")
    if not (np.all(np.isfinite(errors)) and np.all(errors >= 0) and np.all(np.isfinite(steps)) and np.all(steps >= 0)):
        raise ValueError("initial errors and reference steps must be finite and non-negative")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be positive and finite, got {dt}")
    slopes = np.asarray(lipschitz, dtype=float)
    if not (np.all(np.isfinite(slopes)) and np.all(slopes > 0)):
        raise ValueError(f"lipschitz must be positive and finite, got {lipschitz}")
    slopes = np.array(np.broadcast_to(slopes * dt, steps.shape), order="C")
    if limit is not None and not (np.isfinite(limit) and limit > 0):
        raise ValueError(f"velocity_norm_limit must be positive and finite (or None), got {limit}")
    return errors, steps, slopes, float(np.inf if limit is None else limit)


def trajectory_cost_lower_bounds(
    initial_errors: float | np.ndarray,
    reference_steps: np.ndarray,
    dt: float,
    lipschitz: float | np.ndarray,
    convention: CostConvention | None = None,
    velocity_norm_limit: float | None = None,
) -> np.ndarray:
    """The certified lower bounds of :func:`solve_cost_relaxation` (same arguments), ``(B,)``."""
    return solve_cost_relaxation(initial_errors, reference_steps, dt, lipschitz, convention, velocity_norm_limit).bound


def following_cost_lower_bounds(
    start_points: np.ndarray, x_d: np.ndarray, dt: float, lipschitz: float | np.ndarray, q_scale: float = 1.0
) -> np.ndarray:
    """A certified lower bound that sees where the reference goes: the end effector must *follow* it, per sample.

    The scalar relaxation (:func:`solve_cost_relaxation`) keeps only ‖eₖ‖, and a moving reference can carry itself
    towards the arm there for free. Here the end-effector positions pₖ = f(θₖ) stay 3-D vectors: with
    ‖pₖ₊₁ − pₖ‖ ≤ LₖΔt‖uₖ‖ (Lₖ ≥ ‖J‖₂ along the step), every trajectory has

        V ≥ Σ_{k<K} q‖pₖ − x_d(tₖ)‖²Δt + Σ_{k<K−1} ‖pₖ₊₁ − pₖ‖² / (Lₖ²Δt),   p₀ = f(θ₀),

    (the error terms equal, the effort terms by the Lipschitz bound, the jump terms and the velocity limits dropped:
    both only raise V), so the minimum over all point paths p is a lower bound. It is a linear-quadratic tracking
    problem, decoupled per axis: one tridiagonal positive definite system per sample, the three axes its right-hand
    sides (scipy's ``solveh_banded``).

    Args:
        start_points: f(θ₀), ``(B, n)``.
        x_d: ``(B, K, n)`` desired positions.
        dt: Δt, s.
        lipschitz: L (scalar), or Lₖ ``(K−1,)`` or ``(B, K−1)``.
        q_scale: Q = q·I.

    Returns:
        ``(B,)`` bounds.
    """
    x_d = np.asarray(x_d, dtype=float)
    count, steps, _ = x_d.shape
    if steps < 2:
        return q_scale * dt * np.sum((np.asarray(start_points, dtype=float) - x_d[:, 0]) ** 2, axis=-1)
    weights = 1.0 / (np.broadcast_to(np.asarray(lipschitz, dtype=float), (count, steps - 1)) ** 2 * dt)  # cₖ
    a = q_scale * dt
    # unknowns p₁..p_{K−1}: (a + c_{j−1} + c_j) p_j − c_{j−1} p_{j−1} − c_j p_{j+1} = a x_j (c_{K−1} = 0)
    diagonal = a + weights + np.concatenate([weights[:, 1:], np.zeros((count, 1))], axis=1)  # (B, K−1)
    upper = -weights[:, 1:]  # couples p_j and p_{j+1}
    rhs = a * x_d[:, 1:].copy()  # (B, K−1, n)
    rhs[:, 0] += weights[:, :1] * np.asarray(start_points, dtype=float)
    from scipy.linalg import solveh_banded  # start-up time: only where a bound is computed

    points = np.empty_like(rhs)
    for i in range(count):  # LAPACK's banded Cholesky, the three axes as right-hand sides
        band = np.stack([np.concatenate([[0.0], upper[i]]), diagonal[i]])
        points[i] = solveh_banded(band, rhs[i])
    path = np.concatenate([np.asarray(start_points, dtype=float)[:, None], points], axis=1)  # (B, K, n)
    error = a * np.sum((path - x_d) ** 2, axis=(1, 2))
    effort = np.sum(weights * np.sum(np.diff(path, axis=1) ** 2, axis=2), axis=1)
    return error + effort


def trajectory_cost_lower_bound(
    initial_error: float,
    reference_steps: np.ndarray,
    dt: float,
    lipschitz: float | np.ndarray,
    convention: CostConvention | None = None,
    velocity_norm_limit: float | None = None,
) -> float:
    """A certified lower bound on one sample's trajectory cost under ``convention``, for every command sequence.

    ``reference_steps`` is ``(K−1,)``; see :func:`solve_cost_relaxation` for the argument and the other arguments.
    """
    if np.ndim(initial_error) != 0 or np.ndim(reference_steps) != 1:
        raise ValueError("one sample: initial_error is a scalar and reference_steps a (K−1,) array")
    return float(
        trajectory_cost_lower_bounds(initial_error, reference_steps, dt, lipschitz, convention, velocity_norm_limit)[0]
    )


# -- A smaller Lipschitz constant per sample: where can a trajectory of bounded cost take the arm? -------------------


def jacobian_variation_bound(kinematics: Any) -> float | None:
    """M with σ_max(J(θ')) ≤ σ_max(J(θ)) + M‖θ' − θ‖ for every θ, θ', for a chain of revolute joints (else ``None``).

    With Mₐ ≥ sup ‖∂J/∂θₐ‖_F (:func:`~snac_gym.control.jacobian_bound.joint_variation_bounds`), along the segment
    ‖J(θ') − J(θ)‖₂ ≤ ‖J(θ') − J(θ)‖_F ≤ Σ_a |δ_a| M_a ≤ ‖δ‖ (Σ_a M_a²)^½ (Weyl: σ_max moves by at most ‖ΔJ‖₂). The
    first joint of the chain turns the whole arm about an axis fixed in the base, J(θ) = R(θ₁) J(0, θ₂, …): σ_max
    does not depend on θ₁, so its M₁ is left out of the sum.
    """
    terms = joint_variation_bounds(kinematics)
    return None if terms is None else float(np.sqrt(np.sum(terms[1:] ** 2)))


def reachable_lipschitz_bounds(
    kinematics: Any,
    q0: np.ndarray,
    steps: int,
    dt: float,
    cost_limits: float | np.ndarray,
    velocity_limits: np.ndarray | None = None,
) -> np.ndarray:
    """Lₖ ≥ ‖J‖₂ on every step θₖ → θₖ₊₁ (k = 0..K−2) of every trajectory from θ₀ whose cost is at most V̄.

    The cost contains Σ ‖uⱼ‖²Δt (R = I, every convention), so such a trajectory has, by Cauchy-Schwarz,
    ‖θₖ₊₁ − θ₀‖ ≤ Σ_{j≤k} ‖uⱼ‖Δt ≤ (tₖ₊₁ V̄)^½, and ≤ tₖ₊₁‖ū‖₂ within the velocity limits: the segment lies in that
    ball around θ₀, where σ_max(J) ≤ σ_max(J(θ₀)) + M·radius (:func:`jacobian_variation_bound`). Capped by the
    global L of :func:`~snac_gym.control.jacobian_bound.jacobian_norm_bound`; that L alone where M is not available.

    Args:
        kinematics: The arm (a :class:`~snac_gym.model.kinematics.Kinematics`).
        q0: θ₀, ``(m,)`` or ``(B, m)``.
        steps: K.
        dt: Δt, s.
        cost_limits: V̄ ≥ 0, a scalar or ``(B,)``.
        velocity_limits: ū, ``(m,)``, or ``None``.

    Returns:
        ``(B, K−1)``.
    """
    q0 = np.atleast_2d(np.asarray(q0, dtype=float))
    limits = np.broadcast_to(np.asarray(cost_limits, dtype=float), (len(q0),))
    if not (np.all(np.isfinite(limits)) and np.all(limits >= 0)):
        raise ValueError(f"cost limits must be finite and non-negative, got {cost_limits}")
    glob = jacobian_norm_bound(kinematics)
    variation = jacobian_variation_bound(kinematics)
    if variation is None or steps < 2:
        return np.full((len(q0), max(steps - 1, 0)), glob)
    times = np.arange(1, steps) * dt  # tₖ₊₁: the far end of step k
    radius = np.sqrt(times * limits[:, None])
    if velocity_limits is not None:
        radius = np.minimum(radius, times * float(np.linalg.norm(velocity_limits)))
    # σ_max(J(θ₀)) as computed, raised by far more than its rounding (~1e-15 relative)
    start = np.linalg.norm(kinematics.jacobian_batch(q0), ord=2, axis=(-2, -1)) * (1.0 + 1e-12)
    return np.minimum(glob, start[:, None] + variation * radius)


def certified_cost_lower_bounds(
    kinematics: Any,
    q0: np.ndarray,
    x_d: np.ndarray,
    dt: float,
    convention: CostConvention | None = None,
    velocity_limits: np.ndarray | None = None,
    cost_limits: float | np.ndarray | None = None,
    refinements: int = 0,
) -> np.ndarray:
    """Certified lower bounds on the trajectory cost of every command sequence, per sample of a position task.

    The evaluator's entry point: r₀ = ‖f(θ₀) − x_d(t₀)‖ and dₖ from the samples, then
    :func:`trajectory_cost_lower_bounds` with

    * no ``cost_limits`` and no ``refinements``: the global Lipschitz bound
      (:func:`~snac_gym.control.jacobian_bound.jacobian_norm_bound`, one relaxation per sample);
    * ``cost_limits`` V̄ (e.g. each sample's numerical optimum, the cost of a real trajectory): the per-step
      bounds Lₖ(V̄) of :func:`reachable_lipschitz_bounds`, valid for every trajectory costing at most V̄. The bound
      reported is min(B(V̄), V̄), which holds for *every* trajectory: one costing more than V̄ is above it
      anyway. So V̄ need not bound anything: any V̄ ≥ 0 gives a certified value, and the best is where the
      non-increasing B(V̄) crosses V̄;
    * ``refinements`` > 0: that many bisection steps (in log V̄) towards that crossing, each one more relaxation
      per sample, keeping the best value met. The bracket starts from V̄ (where B(V̄) < V̄ brackets from above)
      or from the global bound B₀ (B(B₀) ≥ B₀, as Lₖ ≤ L).

    Args:
        kinematics: The arm (:class:`~snac_gym.model.kinematics.Kinematics`).
        q0: θ₀, ``(m,)`` or ``(B, m)``.
        x_d: Desired positions x_d(tₖ), ``(K, n)`` or ``(B, K, n)``.
        dt: Δt, s.
        convention: The cost (default: Table I's).
        velocity_limits: ū, ``(m,)``, or ``None`` (no limit).
        cost_limits: V̄, a scalar or ``(B,)``, or ``None``.
        refinements: Bisection steps towards the crossing B(V̄) = V̄.

    Returns:
        ``(B,)`` bounds.
    """
    q0 = np.atleast_2d(np.asarray(q0, dtype=float))
    x_d = np.asarray(x_d, dtype=float)
    x_d = np.broadcast_to(x_d, (len(q0), *x_d.shape[-2:]))
    starts = kinematics.forward_batch(q0)
    errors = np.linalg.norm(starts - x_d[:, 0], axis=-1)
    steps = reference_steps(x_d)
    limit = None if velocity_limits is None else float(np.linalg.norm(velocity_limits))
    q_scale = (convention or CostConvention()).q_scale

    def bound_at(lipschitz: Any) -> np.ndarray:  # both relaxations hold: the larger
        scalar = trajectory_cost_lower_bounds(errors, steps, dt, lipschitz, convention, limit)
        return np.maximum(scalar, following_cost_lower_bounds(starts, x_d, dt, lipschitz, q_scale))

    def reachable(limits: np.ndarray) -> np.ndarray:  # B(V̄)
        return bound_at(reachable_lipschitz_bounds(kinematics, q0, x_d.shape[1], dt, limits, velocity_limits))

    if cost_limits is None:
        low = bound_at(jacobian_norm_bound(kinematics))
        if refinements <= 0 or jacobian_variation_bound(kinematics) is None:
            return low
        best, high = low, reachable(low)  # B(B₀) ≥ B₀ (so min(B(B₀), B₀) = B₀), and B(B(B₀)) ≤ B(B₀)
    else:
        trial = np.broadcast_to(np.asarray(cost_limits, dtype=float), errors.shape).copy()
        value = reachable(trial)
        best = np.minimum(value, trial)
        low, high = best, np.maximum(value, trial)  # the crossing is in [B(V̄), V̄] or in [V̄, B(V̄)]
    for _ in range(refinements):
        middle = np.sqrt(low * high)
        value = reachable(middle)
        best = np.maximum(best, np.minimum(value, middle))
        above = value >= middle  # B(middle) ≥ middle: the crossing is higher
        low, high = np.where(above, middle, low), np.where(above, high, middle)
    return best
