"""The compiled kernels of the certified lower bound (:func:`snac_gym.control.optimality.solve_cost_relaxation`): a
primal-dual
interior point on the relaxed problem, whose Newton systems are banded (docs/lower-bounds.md).

Arrays are filled by loops, not slice assignments or array expressions, the helpers carry no Python wrapper
(:func:`~snac_gym.kernels.compiled.helper`) and those called once are inlined (:data:`_INLINED`): each cut numba's
compile, seconds of a cold evaluation (7.5 → 4.6 s of one core in all, on an earlier day's machine). The loop over
samples and horizons, a few calls a sample, is Python (:func:`_relaxation_bounds`): compiled, it had the whole solve
built a second time with it (10.4-11.1 → 7.4-7.7 s of one core for this module, ``python
docs/scripts/compile_times.py``).

They are plain Python functions compiled by numba on first use (:func:`relaxation_kernel`), so that importing
:mod:`snac_gym.control.optimality` does not import numba.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
import numpy.typing as npt

from snac_gym.kernels.compiled import helper, stamp_with_dependencies
from snac_gym.kernels.relaxation_band import (  # the leaves, compiled by relaxation_kernel into this namespace
    _add_constraint_curvature,
    _apply_constraints,
    _apply_constraints_transposed,
    _apply_hessian,
    _ldl_factor,
    _ldl_solve,
    _relaxed_hessian_band,
)

if TYPE_CHECKING:
    from snac_gym.kernels.compiled import Example

#: The kernels' float arrays (numba ignores the annotations: it types the arguments it is called with).
_Floats = npt.NDArray[np.float64]


def _feasible_value(
    r0: float,
    d: _Floats,
    b: _Floats,
    dt: float,
    q: float,
    w: float,
    rest: bool,
    terminal: float,
    vmax: float,
    steps: int,
    x: _Floats,
) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    """The relaxed cost of a feasible point built from x: vₖ clipped to [0, v̄], each rₖ₊₁ the least the
    constraints allow, max(rₖ − bₖvₖ − dₖ, 0). Returns (value, r_{K−1}, v_{K−1}, max v)."""
    r, previous, value, v, peak = r0, 0.0, 0.0, 0.0, 0.0
    for k in range(steps):
        if k > 0:
            r = max(r - b[k - 1] * v - d[k - 1], 0.0)
        v = min(max(x[2 * k], 0.0), vmax)
        jump = v - previous if (k > 0 or rest) else 0.0
        value += dt * (q * r * r + v * v) + w / dt * jump * jump
        previous, peak = v, max(peak, v)
    return value + terminal * v * v, r, v, peak


def _dual_value(
    r0: float,
    q: float,
    dt: float,
    steps: int,
    b: _Floats,
    capped: bool,
    h: _Floats,
    hessian: _Floats,
    hessian_pivots: _Floats,
    z: _Floats,
    work: _Floats,
    image: _Floats,
) -> float:  # pragma: no cover - compiled
    """The Lagrangian dual function at z ≥ 0: g(z) = min_x F(x) + zᵀ(Gx − h) = qΔt r₀² − ½ yᵀH⁻¹y − zᵀh with
    y = Gᵀz (F = ½xᵀHx + qΔt r₀² has no linear term). A lower bound on the relaxed optimum for every z ≥ 0."""
    _apply_constraints_transposed(steps, b, z, capped, image)
    for i in range(image.shape[0]):
        work[i] = image[i]
    _ldl_solve(hessian, hessian_pivots, work)
    dual: float = q * dt * r0 * r0 - 0.5 * np.dot(image, work) - np.dot(z, h)  # np.dot's stub: Any
    return dual


def _max_step(value: _Floats, step: _Floats) -> float:  # pragma: no cover - compiled
    """The largest α ≤ 1 with value + α·step ≥ 0 (value > 0)."""
    alpha = 1.0
    for i in range(value.shape[0]):
        if step[i] * alpha < -value[i]:
            alpha = -value[i] / step[i]
    return alpha


def _newton_direction(
    steps: int,
    b: _Floats,
    capped: bool,
    band: _Floats,
    pivots: _Floats,
    s: _Floats,
    z: _Floats,
    dual_residual: _Floats,
    primal_residual: _Floats,
    complementarity: _Floats,
    rhs: _Floats,
    dx: _Floats,
    ds: _Floats,
    dz: _Floats,
    image: _Floats,
) -> None:  # pragma: no cover - compiled
    """The Newton direction of the perturbed KKT system  H x + Gᵀz = 0,  Gx + s = h,  s∘z = target, from its
    residuals (``complementarity`` = s∘z − target), through the normal equations (H + GᵀS⁻¹ZG)Δx = −r_d +
    GᵀS⁻¹(r_c − Z r_p) (factored in ``band``/``pivots``), then Δs = −r_p − GΔx and Δz = −S⁻¹(r_c + ZΔs)."""
    for i in range(s.shape[0]):
        ds[i] = (complementarity[i] - z[i] * primal_residual[i]) / s[i]
    _apply_constraints_transposed(steps, b, ds, capped, rhs)
    for i in range(rhs.shape[0]):
        dx[i] = rhs[i] - dual_residual[i]
    _ldl_solve(band, pivots, dx)
    _apply_constraints(steps, b, dx, capped, image)
    for i in range(s.shape[0]):
        ds[i] = -primal_residual[i] - image[i]
        dz[i] = -(complementarity[i] + z[i] * ds[i]) / s[i]


def _residuals(
    steps: int,
    dt: float,
    q: float,
    w: float,
    rest: bool,
    terminal: float,
    b: _Floats,
    capped: bool,
    h: _Floats,
    x: _Floats,
    s: _Floats,
    z: _Floats,
    dual_residual: _Floats,
    primal_residual: _Floats,
    work: _Floats,
) -> float:  # pragma: no cover - compiled
    """r_d = Hx + Gᵀz and r_p = Gx + s − h; returns the mean complementarity sᵀz/m."""
    _apply_hessian(steps, dt, q, w, rest, terminal, x, dual_residual)
    _apply_constraints_transposed(steps, b, z, capped, work)
    for i in range(dual_residual.shape[0]):
        dual_residual[i] += work[i]
    _apply_constraints(steps, b, x, capped, primal_residual)
    for i in range(primal_residual.shape[0]):
        primal_residual[i] += s[i] - h[i]
    mean: float = np.dot(s, z) / s.shape[0]  # np.dot's stub: Any
    return mean


def _predictor_corrector_step(
    steps: int,
    b: _Floats,
    capped: bool,
    band: _Floats,
    pivots: _Floats,
    s: _Floats,
    z: _Floats,
    x: _Floats,
    dual_residual: _Floats,
    primal_residual: _Floats,
    mu: float,
    work_n: _Floats,
    dx: _Floats,
    work_m: _Floats,
    ds: _Floats,
    dz: _Floats,
    image: _Floats,
) -> None:  # pragma: no cover - compiled
    """One Mehrotra predictor-corrector step (the factor of the normal matrix is in ``band``/``pivots``)."""
    complementarity, trial_s, trial_z = np.empty(s.shape[0]), np.empty(s.shape[0]), np.empty(s.shape[0])
    for i in range(s.shape[0]):
        complementarity[i] = s[i] * z[i]
    _newton_direction(
        steps, b, capped, band, pivots, s, z, dual_residual, primal_residual, complementarity, work_n, dx, ds, dz, image
    )
    alpha = min(_max_step(s, ds), _max_step(z, dz))
    for i in range(s.shape[0]):
        trial_s[i] = s[i] + alpha * ds[i]
        trial_z[i] = z[i] + alpha * dz[i]
    predicted = np.dot(trial_s, trial_z) / s.shape[0]
    centring = (predicted / mu) ** 3 * mu
    for i in range(s.shape[0]):
        complementarity[i] += ds[i] * dz[i] - centring
    _newton_direction(
        steps, b, capped, band, pivots, s, z, dual_residual, primal_residual, complementarity, work_n, dx, ds, dz, image
    )
    alpha = min(1.0, 0.99 * min(_max_step(s, ds), _max_step(z, dz)))
    for i in range(dx.shape[0]):
        x[i] += alpha * dx[i]
    for i in range(s.shape[0]):
        s[i] += alpha * ds[i]
        z[i] += alpha * dz[i]


def _constraint_bounds(
    r0: float, d: _Floats, vmax: float, steps: int, capped: bool
) -> _Floats:  # pragma: no cover - compiled
    """h of Gx ≤ h: dₖ (less r₀ for k = 0, where r₀ is data), then v̄ for the caps."""
    h = np.empty(steps - 1 + (steps if capped else 0))
    for k in range(h.shape[0]):
        h[k] = d[k] if k < steps - 1 else vmax
    if steps > 1:
        h[0] -= r0
    return h


def _relaxation_solve(
    r0: float,
    d: _Floats,
    b: _Floats,
    dt: float,
    q: float,
    w: float,
    rest: bool,
    terminal: float,
    vmax: float,
    steps: int,
    rtol: float,
    max_iterations: int,
    x: _Floats,
    z: _Floats,
) -> tuple[float, float, int, float, float, float]:  # pragma: no cover - compiled
    """The relaxed problem over the first ``steps`` steps (plus ``terminal``·v²_last, see _terminal_weight), from
    rest (v = 0, r = r₀: feasible) by the predictor-corrector interior point method. Fills x (primal) and z
    (multipliers of the constraints).

    Returns (bound, value, iterations, r_last, v_last, v_peak): the best dual value met (each one is a certified
    lower bound on the relaxed optimum, whatever the iterate), the least feasible value met (an upper bound on it),
    and the last r, last v and largest v of that feasible point. Stops once value − bound ≤ rtol·value."""
    capped = vmax < np.inf
    n = 2 * steps - 1
    h = _constraint_bounds(r0, d, vmax, steps, capped)
    m = h.shape[0]
    for i in range(n):
        x[i] = r0 if i % 2 == 1 else 0.0
    hessian, hessian_pivots = np.empty((3, n)), np.empty(n)
    _relaxed_hessian_band(steps, dt, q, w, rest, terminal, hessian)
    _ldl_factor(hessian, hessian_pivots)
    value, r_last, v_last, v_peak = _feasible_value(r0, d, b, dt, q, w, rest, terminal, vmax, steps, x)
    bound = q * dt * r0 * r0  # the first error is paid whatever the commands
    if m == 0:
        return bound, value, 0, r_last, v_last, v_peak
    work_n, dx, dual_residual, image_n = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    primal_residual, ds, dz, work_m = np.empty(m), np.empty(m), np.empty(m), np.empty(m)
    _apply_constraints(steps, b, x[:n], capped, work_m)
    s = np.empty(m)
    for i in range(m):  # strictly interior (lengths are in units of r₀ + Σd): r_p takes the rest
        s[i] = max(h[i] - work_m[i], 0.0) + 0.1
    for i in range(m):
        z[i] = 1.0
    band, pivots = np.empty((3, n)), np.empty(n)
    iterations = 0
    while True:
        mu = _residuals(
            steps, dt, q, w, rest, terminal, b, capped, h, x[:n], s, z[:m], dual_residual, primal_residual, image_n
        )
        # The certificates cost a solve and a pass: worth it once the complementarity gap m·μ is down to the tolerance.
        if m * mu <= rtol * value or iterations >= max_iterations:
            trial, r_end, v_end, peak = _feasible_value(r0, d, b, dt, q, w, rest, terminal, vmax, steps, x)
            if trial < value:
                value, r_last, v_last, v_peak = trial, r_end, v_end, peak
            candidate = _dual_value(r0, q, dt, steps, b, capped, h, hessian, hessian_pivots, z[:m], work_n, image_n)
            bound = max(bound, candidate)
            if value - bound <= rtol * value or iterations >= max_iterations:
                return bound, value, iterations, r_last, v_last, v_peak
        iterations += 1
        weight = np.empty(m)
        for i in range(m):
            weight[i] = z[i] / s[i]
        _relaxed_hessian_band(steps, dt, q, w, rest, terminal, band)
        _add_constraint_curvature(steps, b, weight, capped, band)
        _ldl_factor(band, pivots)
        _predictor_corrector_step(
            steps,
            b,
            capped,
            band,
            pivots,
            s,
            z[:m],
            x[:n],
            dual_residual,
            primal_residual,
            mu,
            work_n,
            dx,
            work_m,
            ds,
            dz,
            image_n,
        )


def _terminal_weight(w: float, dt: float, remaining: int) -> float:  # pragma: no cover - compiled
    """P_N with P_N v² the least Σ_{j<N} (Δt vⱼ² + (w/Δt)(vⱼ − vⱼ₋₁)²) over N = ``remaining`` steps from v₋₁ = v:
    the scalar Riccati recursion P₀ = 0, Pₙ = c(Δt + Pₙ₋₁)/(c + Δt + Pₙ₋₁), c = w/Δt (0 without the u̇ term).

    The steps after a truncated horizon cost at least that (their error terms are ≥ 0), so adding it to the last
    command of the truncated relaxation keeps it a relaxation, and spares solving the command's slow decay."""
    c, value = w / dt, 0.0
    if c == 0.0:
        return 0.0
    for _ in range(remaining):
        value = c * (dt + value) / (c + dt + value)
    return value


def _next_horizon(x: _Floats, steps: int, total: int, q: float, dt: float, tail: float, target: float) -> int:
    """The horizon to try after ``steps`` left a tail above ``target``: where the tail, decaying at the rate it
    did over the second half of this solve, would be below it (with a margin), at least double, at most K."""
    half = steps // 2
    r_half = max(float(x[2 * half - 1]), 0.0) if half > 0 else 0.0
    earlier = q * r_half * r_half * (total - half) * dt
    more = 2 * steps
    if 0.0 < tail < earlier and target > 0.0:
        # math.log, the C library's, as the compiled code calls it (NumPy's own may differ in the last bit)
        more = max(more, steps + int(1.25 * (steps - half) * math.log(tail / target) / math.log(earlier / tail)) + 1)
    return min(more, total)


def _capped_solve(
    solve: Any,  # the compiled _relaxation_solve
    r0: float,
    d: _Floats,
    b: _Floats,
    dt: float,
    q: float,
    w: float,
    rest: bool,
    terminal: float,
    vmax: float,
    steps: int,
    rtol: float,
    max_iterations: int,
    x: _Floats,
    z: _Floats,
) -> tuple[float, float, int, float, float]:
    """:func:`_relaxation_solve` without the velocity caps first (half the constraints), and with them only where
    its solution breaks one. Dropping constraints only lowers the dual values, so the bound stays certified; and a
    solution within the caps is feasible with them, so its value still bounds the capped optimum from above.
    Returns (bound, value, iterations, r_last, v_last)."""
    bound, value, used, r_last, v_last, v_peak = solve(
        r0, d, b, dt, q, w, rest, terminal, math.inf, steps, rtol, max_iterations, x, z
    )
    if v_peak <= vmax:
        return bound, value, used, r_last, v_last
    bound, value, more, r_last, v_last, v_peak = solve(
        r0, d, b, dt, q, w, rest, terminal, vmax, steps, rtol, max_iterations, x, z
    )
    return bound, value, used + more, r_last, v_last


def _first_horizon(q: float, dt: float, bs: _Floats, rtol: float, total: int) -> int:  # pragma: no cover - compiled
    """A horizon long enough for the relaxed regulation problem's error to fall below rtol: the steps it takes in
    the scalar Riccati closed loop rₖ₊₁ = ρ rₖ, ρ = Δt/(Δt + b²P) with b the largest of ``bs`` (1 on a horizon of
    one step; without the u̇ term; with it the error stops at 0 sooner), with a margin. A guess only: a horizon found
    short is extended, one found long is merely slower."""
    b = 1.0
    if total > 1:
        b = bs[0]
        for k in range(1, bs.shape[0]):
            b = max(b, bs[k])
    riccati = (q * dt * b * b + np.sqrt((q * dt * b * b) ** 2 + 4.0 * b * b * q * dt * dt)) / (2.0 * b * b)
    decay = dt / (dt + b * b * riccati)
    steps = np.log(rtol * riccati / (2.0 * q * total * dt)) / (2.0 * np.log(decay)) if decay > 0.0 else 1.0
    return min(total, max(int(1.25 * steps), 0) + 16)


class _Kernels(NamedTuple):
    """The compiled parts of the bound (numba dispatchers)."""

    solve: Any
    first_horizon: Any
    terminal_weight: Any


def _relaxation_bounds(
    kernels: _Kernels,
    r0s: _Floats,
    ds: _Floats,
    bs: _Floats,
    dt: float,
    q: float,
    w: float,
    rest: bool,
    vmax: float,
    rtol: float,
    max_iterations: int,
    first_steps: int,
    out: _Floats,
) -> None:
    """Per sample: the relaxed problem over a horizon that grows from ``first_steps`` until the part left out is
    provably within rtol, or the whole horizon. Rows of out: bound, upper bound on the relaxed optimum, iterations,
    horizon solved (steps).

    A few compiled calls a sample, so this loop is Python: compiled, it was a function that calls the solve, and
    numba has LLVM optimise and emit a caller's code together with all it calls, so the solve's code was built twice
    (2-3 s of a cold run's compile on 2-core machines, ``python docs/scripts/compile_times.py``). Its arithmetic is
    the compiled loop's, operation for operation, in float64 without fused multiply-adds, as that loop was compiled:
    on 1000 random problems (horizons of 2 to 2500 steps, with and without caps, u̇ term and rest start) every output
    was the compiled loop's, bit for bit."""
    total = ds.shape[1] + 1
    x, z, d = np.empty(2 * total - 1), np.empty(2 * total - 1), np.empty(total - 1)
    sums = np.empty(total - 1)
    for i in range(r0s.shape[0]):
        # In units of r₀ + Σd the solve starts from the same scale for every sample; V scales with its square. Σd in
        # order, one addition at a time (a running sum, not NumPy's pairwise one), as the compiled loop summed.
        total_d = float(np.cumsum(ds[i], out=sums)[-1]) if total > 1 else 0.0
        unit = float(r0s[i]) + total_d
        if unit == 0.0:  # nothing to move: the trajectory at rest costs 0
            out[:, i] = 0.0
            continue
        np.divide(ds[i], unit, out=d)
        r0 = float(r0s[i]) / unit
        steps = first_steps if first_steps > 0 else kernels.first_horizon(q, dt, bs[i], rtol, total)
        steps, iterations = min(steps, total), 0
        while True:
            terminal = kernels.terminal_weight(w, dt, total - steps)
            bound, value, used, r_last, v_last = _capped_solve(
                kernels.solve, r0, d, bs[i], dt, q, w, rest, terminal, vmax / unit, steps, rtol, max_iterations, x, z
            )
            iterations += used
            # Continued by the commands that cost terminal·v²_last (already in value), along which r never rises,
            # the truncated solution is feasible for the whole horizon: the relaxed optimum is in [bound, value + tail].
            tail = q * r_last * r_last * (total - steps) * dt
            if steps == total or value + tail - bound <= rtol * (value + tail):
                break
            steps = _next_horizon(x, steps, total, q, dt, tail, 0.5 * rtol * bound)
        out[0, i], out[1, i], out[2, i], out[3, i] = (
            bound * unit * unit,
            (value + tail) * unit * unit,
            iterations,
            steps,
        )


#: Helpers inlined into their one caller by numba rather than compiled on their own: each separate function costs its
#: own typing, lowering and linking (a cold run's compile of this module 5.9 → 5.4 s of one core, the mean of four in
#: fresh processes). Only those whose inlining cannot change a bit: called where the caller has the same fast-math
#: flags, or holding no product that feeds a sum (a fused multiply-add): ``_dual_value`` stays apart (inlined, it
#: moved the last bit of some bounds).
_INLINED = frozenset({"_constraint_bounds", "_add_constraint_curvature", "_residuals", "_predictor_corrector_step"})

#: The helpers the solve calls, compiled into this module's namespace (without Python wrappers).
_RELAXATION_HELPERS = (
    "_relaxed_hessian_band",
    "_add_constraint_curvature",
    "_ldl_factor",
    "_ldl_solve",
    "_apply_constraints",
    "_apply_constraints_transposed",
    "_apply_hessian",
    "_feasible_value",
    "_dual_value",
    "_max_step",
    "_newton_direction",
    "_residuals",
    "_predictor_corrector_step",
    "_constraint_bounds",
)


@functools.lru_cache(maxsize=1)
def _kernels() -> _Kernels:
    """The solve, the first horizon and the terminal weight compiled (numba, cached on disk), the solve's helpers
    compiled first and bound in place of their Python versions in this module's namespace, where the compiled
    callers look them up; numba imports here, not with the module."""
    from numba import njit  # numba (~0.2 s to import) only once a bound is asked for

    namespace = globals()
    for name in _RELAXATION_HELPERS:
        if not hasattr(namespace[name], "py_func"):
            namespace[name] = helper(namespace[name], fastmath={"contract"}, inline=name in _INLINED)
    kernels = _Kernels(
        solve=njit(cache=True, nogil=True, fastmath={"contract"})(_relaxation_solve),
        first_horizon=njit(cache=True, nogil=True, fastmath={"contract"})(_first_horizon),
        # without fast-math, as it was compiled inlined into the loop above (it holds no product that feeds a sum)
        terminal_weight=njit(cache=True, nogil=True)(_terminal_weight),
    )
    for dispatcher in kernels:
        stamp_with_dependencies(dispatcher)  # the solve's helpers' source is relaxation_band.py's
    return kernels


def relaxation_kernel() -> Callable[..., None]:
    """The bound over a batch of samples: ``kernel(r0s, ds, bs, dt, q, w, rest, vmax, rtol, max_iterations,
    first_steps, out)``, its compiled parts built on first use (a few seconds once, then a fraction of one)."""
    return functools.partial(_relaxation_bounds, _kernels())


def lazy_kernels() -> list[tuple[Any, list[Example]]]:  # Any: a numba dispatcher
    """The kernels built on first use, with arguments of the types the bound calls them with
    (:func:`snac_gym.kernels.compiled.warm_up` compiles or loads them with the other modules' kernels, so that an
    evaluator's workers share their compile instead of each making it at its first reference job)."""
    kernels = _kernels()
    work = np.empty(3)
    solve = (1.0, np.zeros(1), np.ones(1), 0.008, 1.0, 1.0, True, 0.0, math.inf, 2, 1e-3, 10, work, work.copy())
    return [
        (kernels.solve, [solve]),
        (kernels.first_horizon, [(1.0, 0.008, np.ones(2), 1e-3, 3)]),
        (kernels.terminal_weight, [(1.0, 0.008, 3)]),
    ]
