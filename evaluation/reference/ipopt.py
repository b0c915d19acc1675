"""An independent solve of the evaluator's per-sample optimal-control problem with IPOPT (through CasADi).

This is a cross-check, not the evaluator's path: the ``optimal`` reference is computed by the project's
own Gauss-Newton / interior-point solver (:mod:`snac_gym.evaluation.reference.optimum`). Here the same problem is
handed to an established NLP solver, so that the tests can check that solver's optima against it:

    min  V = Σₖ (q‖eₖ‖² + ‖uₖ‖² + w‖uₖ − uₖ₋₁‖²/Δt²) Δt,   k = 0..K−1
    s.t. θₖ₊₁ = θₖ + uₖΔt,  eₖ = f(θₖ) − x_d[k],  |uₖⱼ| ≤ ūⱼ,  θ⁻ ≤ θₖ ≤ θ⁺ (k = 1..K, optional)

with the cost convention of :class:`snac_gym.control.cost.CostConvention` (q = ``q_scale``, w = ``smoothness_weight``,
u₋₁ = 0 for ``udot_start="rest"``, no k = 0 smoothness term for ``"first"``), as
:func:`snac_gym.control.cost.cost_and_gradient` writes it.

**Formulation.** The decision variables are the angles θ₁..θ_K *and* the commands u₀..u_{K−1}, tied by the
linear equalities θₖ₊₁ − θₖ − uₖΔt = 0 (θ₀ is given). Each eₖ depends on θₖ alone and the effort and
smoothness terms on neighbouring uₖ only, so the Lagrangian's Hessian is banded (block diagonal in θ,
tridiagonal in u), which IPOPT's sparse factorisation (MUMPS) handles fast; both kinds of limit are simple
variable bounds. (u alone would make the Hessian dense: eₖ depends on every earlier command. θ alone, with
uₖ = (θₖ₊₁ − θₖ)/Δt, is also banded, but its gradient carries the u̇ term's 1/Δt³ and rounding then
floors IPOPT's dual infeasibility at about 10⁻⁸ at Δt = 8 ms, above the default ``tol`` of 10⁻¹⁰: IPOPT stops
with ``Search_Direction_Becomes_Too_Small`` instead of converging.)

The forward kinematics is written in CasADi from the Pinocchio model of the
:class:`~snac_gym.model.kinematics.Kinematics` (:func:`casadi_forward_kinematics`): one function of one
configuration, mapped over the horizon, so the expression graph stays small.

CasADi is an optional dependency (the ``check`` extra), imported only when called.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np

from snac_gym.common.extras import missing_extra, require
from snac_gym.control.cost import CostConvention
from snac_gym.control.trajopt import next_angles, trajectory_cost_and_gradient
from snac_gym.model.kinematics import Kinematics, leaf_chain

#: What a missing CasADi says (:func:`~snac_gym.common.extras.require`'s line).
_NEEDS_CASADI = "the IPOPT cross-check (CasADi)"
MISSING_CASADI = missing_extra(_NEEDS_CASADI, "check")


@dataclass
class IpoptSolution:
    """IPOPT's solution of one sample.

    Attributes:
        commands: ``(K, m)`` commands u₀..u_{K−1} of the solution.
        cost: V of ``commands`` by the project's own evaluation
            (:func:`snac_gym.evaluation.reference.optimum.trajectory_cost_and_gradient`), not IPOPT's number.
        ipopt_cost: The objective IPOPT reports at its solution.
        status: IPOPT's return status (e.g. ``"Solve_Succeeded"``).
        success: CasADi's reading of that status.
        iterations: IPOPT iterations.
        seconds: Wall time of the whole call (building the NLP included).
    """

    commands: np.ndarray
    cost: float
    ipopt_cost: float
    status: str
    success: bool
    iterations: int
    seconds: float


def _casadi() -> Any:
    return require("casadi", "check", _NEEDS_CASADI)


def casadi_forward_kinematics(kinematics: Kinematics) -> Any:
    """``fk(θ) → x``: the end-effector position in the base frame as a CasADi function of one ``(m,)`` configuration.

    The product of the joint placements and joint motions, applied to the end-effector offset from the leaf
    inwards: ``v ← Mᵢ (exp(Sᵢθᵢ) v) + tᵢ`` (Rodrigues' formula for a revolute joint, a shift along the axis for a
    prismatic one). Equals :meth:`Kinematics.forward` to rounding.
    """
    ca = _casadi()
    steps, offset = leaf_chain(kinematics)
    q = ca.SX.sym("q", kinematics.n_joints)
    v = ca.SX(ca.DM(offset))
    for rotation, translation, axis, revolute, index in steps:
        a = ca.DM(axis)
        if revolute:
            cos, sin = ca.cos(q[index]), ca.sin(q[index])
            v = v * cos + ca.cross(a, v) * sin + a * ca.dot(a, v) * (1.0 - cos)
        else:
            v = v + a * q[index]
        v = ca.mtimes(ca.DM(rotation), v) + ca.DM(translation)
    return ca.Function("fk", [q], [v], ["q"], ["x"])


def _check(q0: np.ndarray, x_d: np.ndarray, kinematics: Kinematics, dt: float) -> tuple[np.ndarray, np.ndarray]:
    if getattr(kinematics, "task_error", None) is not None or getattr(kinematics, "task_dim", 3) != 3:
        raise ValueError("the IPOPT cross-check solves the position tasks only (reach, track: x_d of shape (K, 3))")
    q0, x_d = np.asarray(q0, dtype=float), np.asarray(x_d, dtype=float)
    if x_d.ndim != 2 or x_d.shape[1] != 3 or len(x_d) < 1:
        raise ValueError(f"x_d must be (K, 3) desired positions (a position task), got shape {x_d.shape}")
    if q0.shape != (kinematics.n_joints,):
        raise ValueError(f"q0 must have shape ({kinematics.n_joints},), got {q0.shape}")
    if not (np.isfinite(dt) and dt > 0):
        raise ValueError(f"dt must be positive and finite, got {dt}")
    return q0, x_d


def _objective(angles: Any, commands: Any, q0: np.ndarray, x_d: np.ndarray, kinematics: Kinematics, dt: float,
               convention: CostConvention) -> Any:  # fmt: skip
    """V as a CasADi expression of θ₁..θ_K (``angles``) and u₀..u_{K−1} (``commands``), both ``(m, K)``."""
    ca = _casadi()
    steps = x_d.shape[0]
    previous = ca.horzcat(ca.DM(q0), angles[:, : steps - 1])  # θ₀..θ_{K−1}: where each step starts
    errors = casadi_forward_kinematics(kinematics).map(steps)(previous) - ca.DM(x_d.T)
    value = dt * (convention.q_scale * ca.sumsqr(errors) + ca.sumsqr(commands))
    if convention.smoothness_weight != 0.0:
        differences = commands[:, 1:] - commands[:, : steps - 1]  # uₖ − uₖ₋₁, k = 1..K−1
        value += convention.smoothness_weight * ca.sumsqr(differences) / dt
        if convention.udot_start == "rest":  # k = 0: u₀ − u₋₁ = u₀
            value += convention.smoothness_weight * ca.sumsqr(commands[:, 0]) / dt
    return value


def _dynamics(angles: Any, commands: Any, q0: np.ndarray, dt: float) -> Any:
    """θₖ₊₁ − θₖ − uₖΔt, k = 0..K−1 (``(m, K)``; zero on a rollout)."""
    ca = _casadi()
    previous = ca.horzcat(ca.DM(q0), angles[:, : angles.shape[1] - 1])
    return angles - previous - dt * commands


def ipopt_objective(
    commands: np.ndarray,
    q0: np.ndarray,
    x_d: np.ndarray,
    kinematics: Kinematics,
    dt: float,
    convention: CostConvention | None = None,
) -> float:
    """The NLP's objective (the CasADi expression IPOPT minimises) at ``commands`` (``(K, m)``) and their angles.

    For checking the NLP against :func:`snac_gym.evaluation.reference.optimum.trajectory_cost_and_gradient`.
    """
    ca = _casadi()
    q0, x_d = _check(q0, x_d, kinematics, dt)
    convention = convention if convention is not None else CostConvention()
    commands = np.asarray(commands, dtype=float)
    angles = ca.MX.sym("theta", kinematics.n_joints, x_d.shape[0])
    rates = ca.MX.sym("u", kinematics.n_joints, x_d.shape[0])
    value = _objective(angles, rates, q0, x_d, kinematics, float(dt), convention)
    objective = ca.Function("V", [angles, rates], [value])
    return float(objective(next_angles(commands, q0, float(dt)).T, commands.T))


def _bounds(q0: np.ndarray, steps: int, velocity_limits: np.ndarray,
            position_limits: tuple[np.ndarray, np.ndarray] | None) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
    """(lbx, ubx) of [vec θ; vec u] (each ``vec`` of an ``(m, K)`` matrix: joint fastest).

    A position limit that θ₀ does not keep is moved out past θ₀ as the project's solver does
    (:func:`snac_gym.evaluation.reference.optimum.solve_sample`), so that both solve the same problem.
    """
    m = len(q0)
    velocity = np.broadcast_to(np.asarray(velocity_limits, dtype=float), (m,))
    if position_limits is None:
        lower, upper = np.full(m, -np.inf), np.full(m, np.inf)
    else:
        lower, upper = (np.asarray(bound, dtype=float) for bound in position_limits)
        # The URDF's limits exactly (the project's solver keeps a 1e-9 rad clearance inside them); a bound
        # θ₀ itself breaks cannot be kept by any sequence, so it moves just past θ₀.
        lower, upper = np.where(q0 > lower, lower, q0 - 1e-9), np.where(q0 < upper, upper, q0 + 1e-9)
    return (
        np.concatenate([np.tile(lower, steps), np.tile(-velocity, steps)]),
        np.concatenate([np.tile(upper, steps), np.tile(velocity, steps)]),
    )


def _options(tol: float, max_iter: int, print_level: int) -> dict[str, Any]:
    """CasADi's and IPOPT's options: the constraints are linear, and the bounds are not relaxed (IPOPT's
    default relaxes them by 10⁻⁸ relative, so a binding limit could be broken by that much)."""
    ipopt = {
        "tol": tol,
        "max_iter": max_iter,
        "print_level": print_level,
        "sb": "yes",
        "jac_c_constant": "yes",
        "jac_d_constant": "yes",
        "bound_relax_factor": 0.0,
    }
    return {"print_time": False, "ipopt": ipopt}


def solve_with_ipopt(
    q0: np.ndarray,
    x_d: np.ndarray,
    kinematics: Kinematics,
    dt: float,
    velocity_limits: np.ndarray,
    position_limits: tuple[np.ndarray, np.ndarray] | None = None,
    convention: CostConvention | None = None,
    initial: np.ndarray | None = None,
    tol: float = 1e-10,
    max_iter: int = 3000,
    print_level: int = 0,
) -> IpoptSolution:
    """The optimal commands of one sample by IPOPT (exact Hessian, MUMPS), for cross-checking.

    Args:
        q0: ``(m,)`` seed pose θ₀.
        x_d: ``(K, 3)`` desired positions at the start of each step (reach, track).
        kinematics: The arm (:func:`snac_gym.model.kinematics.shared_kinematics`).
        dt: Control period Δt, s.
        velocity_limits: ``(m,)`` limits ū (``np.inf`` entries: none).
        position_limits: ``(θ⁻, θ⁺)`` kept at θ₁..θ_K, or ``None`` for no position limits.
        convention: The cost (default: Table I's, Q = I, u₋₁ = 0).
        initial: ``(K, m)`` start commands (default zeros: at rest).
        tol: IPOPT's ``tol``.
        max_iter: IPOPT's ``max_iter``.
        print_level: IPOPT's ``print_level`` (0: silent).

    Raises:
        ImportError: If CasADi is not installed.
        ValueError: For anything but a position task.
    """
    started = time.perf_counter()
    ca = _casadi()
    q0, x_d = _check(q0, x_d, kinematics, dt)
    dt = float(dt)
    convention = convention if convention is not None else CostConvention()
    steps, m = x_d.shape[0], kinematics.n_joints
    angles, commands = ca.MX.sym("theta", m, steps), ca.MX.sym("u", m, steps)
    nlp = {
        "x": ca.vertcat(ca.vec(angles), ca.vec(commands)),
        "f": _objective(angles, commands, q0, x_d, kinematics, dt, convention),
        "g": ca.vec(_dynamics(angles, commands, q0, dt)),
    }
    solver = ca.nlpsol("ipopt_reference", "ipopt", nlp, _options(tol, max_iter, print_level))
    start = np.zeros((steps, m)) if initial is None else np.asarray(initial, dtype=float)
    lbx, ubx = _bounds(q0, steps, velocity_limits, position_limits)
    x0 = np.concatenate([next_angles(start, q0, dt).ravel(), start.ravel()])
    result = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=0.0, ubg=0.0)
    stats = solver.stats()
    solution = np.asarray(result["x"]).ravel()[steps * m :].reshape(steps, m)  # u: the limits hold on it exactly
    cost = trajectory_cost_and_gradient(solution, q0, x_d, kinematics, dt, convention)[0]
    return IpoptSolution(
        commands=solution,
        cost=float(cost),
        ipopt_cost=float(result["f"]),
        status=str(stats["return_status"]),
        success=bool(stats["success"]),
        iterations=int(stats["iter_count"]),
        seconds=time.perf_counter() - started,
    )


__all__ = ["IpoptSolution", "casadi_forward_kinematics", "ipopt_objective", "solve_with_ipopt"]
