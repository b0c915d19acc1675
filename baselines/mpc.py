"""Model-predictive control: a receding-horizon Gauss-Newton solver on the evaluator's cost.

``optimal`` (evaluation/reference/optimum.py) is the open-loop optimum of a whole sample, solved
with the whole reference known; it cannot be run. This is the best feedback law one can run on the
same model and cost: at every re-solve, from the measured θ, it solves

    min_U  Σᵢ (eᵢᵀQeᵢ + uᵢᵀRuᵢ + w u̇ᵢᵀRu̇ᵢ) Δt_s + e_Nᵀ P̄ e_N,    i = 0..N−1,  Q = q·I, R = I
    s.t.   θᵢ₊₁ = θᵢ + uᵢΔt_s,  eᵢ = f(θᵢ) − x̂_d(t + iΔt_s),  u̇ᵢ = (uᵢ − uᵢ₋₁)/Δt,  u₋₁ = the last command

applies the first command (clipped into the velocity limits) and solves again ``period`` control
steps later. Details and measurements: docs/mpc.md.

* **Solver grid (move blocking).** Δt_s = ``block``·Δt: the command is held over ``block`` control
  periods, N = horizon/Δt_s solver steps. The effort and u̇ terms are exact for such piecewise-constant
  commands (w = ``block`` on the grid Δt_s; w = 0 for the HJB cost); the error term is sampled at the
  start of each block.
* **Solver.** The trajectory optimiser's :class:`~snac_gym.control.trajopt.GaussNewtonSolver`: its Gauss-Newton
  step (the block-banded system in θ₁..θ_N) with the terminal block 2J_NᵀP̄J_N added, and its Armijo
  backtracking on the exact cost, every sample of the batch at once; at most ``iterations`` steps per
  re-solve, warm-started from the previous plan shifted by ``period`` control periods.
* **Terminal cost.** e_NᵀP̄e_N + 2p̄ᵀe_N with P̄ = P*(J(θ_N)), the frozen-Jacobian LQR cost-to-go
  (:mod:`snac_gym.control.optimality`), and p̄ = −(JJᵀ)⁻¹ẋ_d(t_N), the price of making up a lag behind a moving
  reference (:meth:`MPCPolicy._terminal_cost`); both at the end of the warm start, held fixed during a
  re-solve so that the line search sees one function. Without it (``terminal=False``) a short horizon
  is myopic: for ė = σu the finite-horizon gain is tanh(σ√q T)·√q instead of √q. It leaves out the u̇
  term's cost-to-go, which is why ``table1`` needs a longer horizon (:data:`DEFAULT_GRID`).
* **Limits.** With ``constraints=True`` (default) the joint velocity limits and the URDF's joint
  position limits (the limits of the success rule and of the ``optimal`` reference) are constraints
  of every re-solve: a log barrier μ Σ log s over the plan (slacks ū ± uᵢ and θᵢ − θ⁻, θ⁺ − θᵢ on the
  solver grid, where θ is piecewise linear), added to the Gauss-Newton matrix as the reference's
  interior point adds it (:class:`~snac_gym.control.trajopt.Barrier`), with the fraction-to-the-
  boundary step; μ is fixed per re-solve at :data:`BARRIER_SHARE` of its V over the constraints. The
  warm start is shrunk into the open limits first, so every plan, and every applied command, keeps
  them strictly. ``constraints=False``: the first version, unconstrained, its command clipped into ±ū.
* **Reference ahead.** Not in the observation. Regulation: x_d is constant (exact). Tracking
  (position tasks): harmonic prediction x̂_d(t+τ) = x_c + r cos ωτ + (ẋ_d/ω) sin ωτ with r = x_d − x_c,
  exact for every ellipse of :class:`snac_gym.references.Ellipse` given ω; ω² is estimated from the
  last two observations (r̈ = −ω²r), |ẋ_d|/|r| (exact for a circle) at the first step.
  ``reference="hold"`` keeps x_d constant instead; pose tasks always hold.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from snac_gym.baselines._common import ObservationReader, clip_to_box, one_of, positive_int

from snac_gym.control.cost import COSTS, UDOT_STARTS, CostConvention, cost_and_gradient
from snac_gym.control.optimality import FrozenJacobianLQR
from snac_gym.control.trajopt import (
    BOUNDARY_FRACTION,
    START_SHRINK,
    Barrier,
    GaussNewtonSolver,
    Limits,
    errors_and_jacobians,
    next_angles,
    position_bounds,
)
from snac_gym.model.joint_limits import make_limit_box
from snac_gym.policies.base import BasePolicy, positive_float

#: (horizon s, block) when not given, per cost: measured in docs/mpc.md. The u̇ term of ``table1`` makes the
#: command itself a slow state (time scale ~1 s) that the terminal cost does not price, and a coarse grid
#: cannot follow its ramp from rest: it needs the longer horizon on the control grid.
DEFAULT_GRID = {"hjb": (0.4, 5), "table1": (1.0, 1)}
#: How the reference ahead is obtained (``reference=``).
REFERENCES = ("predict", "hold")
#: Trials of the Armijo backtracking before a sample keeps its plan for this iteration.
MAX_BACKTRACKS = 20
#: A sample stops iterating when the Gauss-Newton decrement −∇Vᵀδ is below this fraction of V.
DECREMENT_TOLERANCE = 1e-12
#: The log barrier of the limits in each re-solve: μ·(number of constraints) is this share of the warm
#: start's V, so the barrier shifts the plan by about that share of its cost (the reference drives its μ
#: to 1e-7·V; a re-solve of two steps cannot, so it keeps one small μ).
BARRIER_SHARE = 1e-3


def _identity_multiple(Q: Any, dim: int) -> float:
    """q of Q = q·I (the solver's cost has that form): ``None`` → 1.

    Raises:
        ValueError: If Q is not a positive multiple of the identity.
    """
    if Q is None:
        return 1.0
    matrix = FrozenJacobianLQR(Q, None, dim, 1).Q  # validates shape, symmetry, definiteness
    q = float(matrix[0, 0])
    if not np.allclose(matrix, q * np.eye(dim), rtol=1e-12, atol=0.0):
        raise ValueError(f"Q must be a positive multiple of the identity (the cost's Q = q·I), got {matrix.tolist()}")
    return q


@dataclass(frozen=True)
class _BlockedConvention(CostConvention):
    """The run's cost on the solver grid Δt_s = block·Δt: a command held over ``block`` control periods
    jumps once per block, so its u̇ term (1/Δt)|Δu|² is (block/Δt_s)|Δu|²: weight ``block``, not 1."""

    block: int = 1

    @property
    def smoothness_weight(self) -> float:
        return self.block * (1.0 if self.cost == "table1" else 0.0)


class MPCPolicy(BasePolicy):
    """Receding-horizon Gauss-Newton MPC of the kinematic model on the evaluator's cost (module docstring).

    Args:
        env: The env (or :class:`~snac_gym.policies.base.PolicyContext`) to drive.
        horizon: Prediction horizon, s (rounded to whole solver steps, at least one); ``None``:
            :data:`DEFAULT_GRID` of ``cost`` (0.4 s for ``hjb``, 1 s for ``table1``).
        block: Control periods per solver step (move blocking): the solver grid is block·Δt; ``None``:
            :data:`DEFAULT_GRID` of ``cost`` (5 for ``hjb``, 1 for ``table1``).
        iterations: Gauss-Newton steps per re-solve (a sample stops earlier when converged).
        period: Control periods between re-solves; in between the plan is played open loop.
        q_scale: The effort knob (:attr:`effort_parameter`), as for ``lqr``: the solver's error weight
            is q_scale·Q (R = I fixed), so larger is more aggressive. Default 1: the run's own cost.
        Q: The cost's error weight, a positive multiple of the identity (``None``: I); the evaluator
            passes ``--q-scale`` here.
        cost: ``"table1"`` (with the u̇ term, the evaluator's default) or ``"hjb"`` (without); the
            evaluator passes the run's ``--cost`` (and ``--udot-start``).
        udot_start: u₋₁ of the first solve: ``"rest"`` (0) or ``"first"`` (u₀); later solves use
            the last applied command.
        terminal: Add the frozen-Jacobian LQR cost-to-go e_NᵀP̄e_N at the end of the horizon.
        reference: ``"predict"`` (harmonic prediction of a tracking reference) or ``"hold"``.
        constraints: Keep the velocity and joint position limits as barrier constraints of each
            re-solve (module docstring); ``False``: unconstrained, the command clipped into ±ū.
        joint_limits: Clamp the command into the position-limit box Ω(θ) (:mod:`snac_gym.model.joint_limits`);
            ``None``: on for the 7-DOF arms only, as for the other baselines.

    Raises:
        ValueError: On a parameter outside its range, naming it.

    Attributes:
        effort_parameter: ``"q_scale"``.
        steps: N, solver steps per horizon.
        internals: After :meth:`act`: ``plan_cost`` (the solver's V of the plan) and ``solved``.
    """

    effort_parameter = "q_scale"

    def __init__(
        self,
        env: Any,
        horizon: float | None = None,
        block: int | None = None,
        iterations: int = 2,
        period: int = 1,
        q_scale: float = 1.0,
        Q: Any = None,
        cost: str = "table1",
        udot_start: str = "rest",
        terminal: bool = True,
        reference: str = "predict",
        joint_limits: bool | None = None,
        constraints: bool = True,
    ) -> None:
        super().__init__(env)
        self.cost = one_of("cost", cost, COSTS)
        self.horizon = positive_float("horizon", DEFAULT_GRID[self.cost][0] if horizon is None else horizon)
        self.block = positive_int("block", DEFAULT_GRID[self.cost][1] if block is None else block)
        self.iterations = positive_int("iterations", iterations)
        self.period = positive_int("period", period)
        self.q_scale = positive_float("q_scale", q_scale)
        self.udot_start = one_of("udot_start", udot_start, UDOT_STARTS)
        self.reference = one_of("reference", reference, REFERENCES)
        if not isinstance(terminal, (bool, np.bool_)):
            raise ValueError(f"terminal must be true or false, got {terminal!r}")
        self.terminal = bool(terminal)
        if not isinstance(constraints, (bool, np.bool_)):
            raise ValueError(f"constraints must be true or false, got {constraints!r}")
        self.constraints = bool(constraints)
        n, m = self.kinematics.task_dim, self.kinematics.n_joints
        self.weight = self.q_scale * _identity_multiple(Q, n)
        self.solver_dt = self.block * self.dt
        self.steps = int(round(self.horizon / self.solver_dt))
        if self.steps < 1:
            raise ValueError(
                f"horizon {self.horizon:g} s is shorter than one solver step (block·Δt = {self.solver_dt:g} s)"
            )
        if self.period > self.steps * self.block:
            raise ValueError(
                f"period ({self.period} control periods) must not exceed the horizon ({self.steps * self.block})"
            )
        self.limit_box = make_limit_box(self, joint_limits)
        self._reader = ObservationReader(self)
        self._lqr = FrozenJacobianLQR(self.weight * np.eye(n), None, n, m)
        self._conventions = {
            start: _BlockedConvention(self.cost, start, self.weight, self.block) for start in UDOT_STARTS
        }
        self._solvers = {
            start: GaussNewtonSolver(self.steps, m, self.solver_dt, c, barrier=self.constraints)
            for start, c in self._conventions.items()
        }
        self._predicts = self.reference == "predict" and self.tracking and n == 3
        self._start(1)

    # -- episode state ---------------------------------------------------------------------------
    def _start(self, count: int) -> None:
        m = self.kinematics.n_joints
        self._plan = np.zeros((count, self.steps, m))  # solver-grid commands of the last solve
        self._previous = np.zeros((count, m))  # the last applied command (u₋₁ of the next solve)
        self._count = 0  # control steps since the episode began
        self._since_solve = 0  # control steps played from the current plan
        self._last_reference: tuple[np.ndarray, np.ndarray] | None = None

    def reset(self, seed: int | None = None) -> None:
        """Start an episode (the plan starts at rest; ``seed`` is unused: the law is deterministic)."""
        self._start(1)
        self.internals = {}

    def reset_batch(self, seeds: Sequence[int]) -> None:
        """Start ``len(seeds)`` independent episodes."""
        self._start(len(seeds))
        self.internals = {}

    def _act(self, obs: np.ndarray) -> np.ndarray:
        """Joint-velocity command (rad/s) for ``obs``, inside the velocity limits."""
        obs = self._reader.read(obs)
        command, value = self._control(obs[None])
        self.internals = {"plan_cost": float(value[0]), "solved": self._since_solve == 1}
        return command[0]

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        """Commands ``(B, m)`` for observations ``(B, size)``: row i is :meth:`act` of episode i."""
        return self._control(self._reader.read_batch(obs_batch))[0]

    def _control(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if len(obs) != len(self._plan):
            raise ValueError(f"{len(obs)} observations for {len(self._plan)} episodes; call reset_batch first")
        q = obs[:, self._reader.q]
        references, end_velocity = self._references(obs)
        value = np.full(len(obs), np.nan)
        if self._since_solve % self.period == 0:
            first = self._count == 0
            start = self.udot_start if first else "rest"  # later: u₋₁ = the applied command
            self._plan, value = self._solve(q, references, end_velocity, self._shifted_plan(first), start)
            self._since_solve = 0
        command = clip_to_box(self._plan[:, self._since_solve // self.block], self.velocity_limits)
        if self.limit_box is not None:
            command = self.limit_box.clamp(q, command)
        self._previous = command
        self._count += 1
        self._since_solve += 1
        return command, value

    def _shifted_plan(self, first: bool) -> np.ndarray:
        """The warm start: the last plan advanced by ``period`` control periods, its last block repeated."""
        if first:
            return self._plan
        fine = np.repeat(self._plan, self.block, axis=1)  # (B, N·block, m) control-period commands
        fine = np.concatenate([fine[:, self.period :], np.repeat(fine[:, -1:], self.period, axis=1)], axis=1)
        shifted = fine.reshape(len(fine), self.steps, self.block, -1).mean(axis=2)
        return clip_to_box(shifted, self.velocity_limits)

    # -- the reference ahead -----------------------------------------------------------------------
    def _references(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """x̂_d at the solver times 0, Δt_s, ..., NΔt_s ahead ``(B, N+1, n)``, and ẋ̂_d at NΔt_s ``(B, n)``."""
        x_d = obs[:, self.layout.slices["x_d"]]
        velocity = obs[:, self.layout.slices["xdot_d"]]
        if not self._predicts:
            return np.repeat(x_d[:, None], self.steps + 1, axis=1), velocity
        radius = x_d - obs[:, self.layout.slices["x_c"]]  # r = x_d − x_c
        omega = self._angular_rate(radius, velocity)
        self._last_reference = (radius, velocity)
        tau = np.arange(self.steps + 1) * self.solver_dt
        phase = omega[:, None] * tau[None]  # (B, N+1)
        # Harmonic motion r̈ = −ω²r from (r, ṙ): exact for an ellipse; sin(ωτ)/ω = τ·sinc(ωτ/π) stays finite at ω = 0.
        ahead = (
            np.cos(phase)[..., None] * radius[:, None] + (tau * np.sinc(phase / np.pi))[..., None] * velocity[:, None]
        )
        end = phase[:, -1:]
        end_velocity = np.cos(end) * velocity - (omega[:, None] * np.sin(end)) * radius  # ṙ(τ) of the same motion
        return obs[:, None, self.layout.slices["x_c"]] + ahead, end_velocity

    def _angular_rate(self, radius: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        """ω per sample: from r̈ ≈ (ṙₖ − ṙₖ₋₁)/Δt = −ω² (rₖ + rₖ₋₁)/2 when the last step is known (exact
        to O(ω²Δt²)), else the circle's |ṙ|/|r|; 0 where neither is defined (the reference holds)."""
        norm = np.linalg.norm(radius, axis=1)
        circle = np.divide(np.linalg.norm(velocity, axis=1), norm, out=np.zeros_like(norm), where=norm > 1e-9)
        if self._last_reference is None or len(self._last_reference[0]) != len(radius):
            return circle
        last_radius, last_velocity = self._last_reference
        middle = 0.5 * (radius + last_radius)
        square = np.einsum("bi,bi->b", middle, middle)
        estimate = -np.einsum("bi,bi->b", velocity - last_velocity, middle) / np.where(square > 1e-18, square, 1.0)
        estimate /= self.dt
        return np.where((square > 1e-18) & (estimate > 0), np.sqrt(np.maximum(estimate, 0.0)), circle)

    # -- the solver --------------------------------------------------------------------------------
    def _solve(
        self, q0: np.ndarray, x_d: np.ndarray, end_velocity: np.ndarray, plan: np.ndarray, start: str
    ) -> tuple[np.ndarray, np.ndarray]:
        """At most ``iterations`` Gauss-Newton steps from ``plan`` for every sample; the plans and their V."""
        convention, solver = self._conventions[start], self._solvers[start]
        limits = self._limits(q0) if self.constraints else None
        plan = self._inside(q0, plan, limits) if limits is not None else plan.copy()
        everyone = np.arange(len(plan))
        terminal = self._terminal_cost(q0, plan, end_velocity)
        value, grad, jacobians = self._evaluate(everyone, q0, x_d, plan, terminal, convention)
        jacobians = jacobians.copy()  # the kinematics' cached batch is read-only; the line search updates rows
        if limits is not None:
            count = 4 * plan.shape[1] * plan.shape[2]
            self._mu = BARRIER_SHARE * np.maximum(value, 1e-12) / count
            barrier, barrier_grad, self._slacks = self._barrier(everyone, q0, plan, limits)
            value, grad = value + barrier, grad + barrier_grad
        active = np.ones(len(plan), dtype=bool)
        for _ in range(self.iterations):
            rows = np.flatnonzero(active)
            if not len(rows):
                break
            directions = [self._direction(solver, jacobians[i], grad[i], terminal, i, limits) for i in rows]
            steps = np.stack([step for step, _ in directions])
            slopes = np.einsum("bkj,bkj->b", grad[rows], steps)
            active[rows] = -slopes > DECREMENT_TOLERANCE * np.maximum(value[rows], 1.0)
            first = np.array([alpha for _, alpha in directions])
            self._line_search(solver, rows, q0, x_d, plan, steps, slopes, terminal, convention,
                              (value, grad, jacobians), first, limits)  # fmt: skip
        return plan, value

    # -- the limits as constraints of the re-solve ----------------------------------------------------
    def _limits(self, q0: np.ndarray) -> list[Limits]:
        """Each episode's limits: ū, and the reference's position bounds
        (:func:`~snac_gym.control.trajopt.position_bounds`:
        a clearance from θ⁻ and θ⁺ against rounding, each moved just past a measured θ on or beyond it, which
        could not be brought back inside a barrier's domain otherwise)."""
        lower = getattr(self.kinematics, "lower_limits", None)
        upper = getattr(self.kinematics, "upper_limits", None)
        if lower is None or upper is None:
            return [Limits(self.velocity_limits) for _ in q0]
        return [Limits(self.velocity_limits, *position_bounds(lower, upper, q)) for q in q0]

    def _inside(self, q0: np.ndarray, plan: np.ndarray, limits: list[Limits]) -> np.ndarray:
        """The warm start shrunk into the open limits: commands into (1 − ε)ū, then halved toward rest
        (θ stays nearer θ₀, which keeps the limits) until every θᵢ keeps them strictly."""
        plan = clip_to_box(plan, (1.0 - START_SHRINK) * self.velocity_limits)
        for i, limit in enumerate(limits):
            for _ in range(60):
                if limit.violation(plan[i], q0[i], self.solver_dt) < 0.0:
                    break
                plan[i] *= 0.5
            else:
                plan[i] = 0.0
        return plan

    def _barrier(
        self, rows: np.ndarray, q0: np.ndarray, plans: np.ndarray, limits: list[Limits]
    ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
        """−μ Σ log s of each plan (inf outside the limits), its gradient in u, and its slacks stacked."""
        values, grads, every = np.empty(len(rows)), np.empty_like(plans), []
        for b, i in enumerate(rows):
            mu, limit = self._mu[i], limits[i]
            slacks = np.stack(
                limit.slacks(plans[b], next_angles(plans[b], q0[i], self.solver_dt))
            )  # one array: fewer calls
            every.append(slacks)
            if slacks.min() <= 0.0:
                values[b], grads[b] = np.inf, 0.0
                continue
            values[b] = -mu * float(np.log(slacks).sum())
            inverse = mu / slacks
            grads[b] = inverse[1] - inverse[0]
            if limit.has_positions:
                # θᵢ₊₁.. depend on uᵢ through Δt_s: the position terms' gradient is a reverse cumulative sum.
                grads[b] += self.solver_dt * np.cumsum((inverse[3] - inverse[2])[::-1], axis=0)[::-1]
        return values, grads, every

    def _terminal_cost(
        self, q0: np.ndarray, plan: np.ndarray, end_velocity: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """(P̄ ``(B, n, n)``, p̄ ``(B, n)``) of the cost-to-go e_NᵀP̄e_N + 2p̄ᵀe_N, frozen at the warm start's θ_N.

        P̄ = P*(J): the frozen-Jacobian LQR's. p̄ = −(JJᵀ)⁻¹ẋ_d(t_N): after the horizon the motion costs
        uᵀu with u = J⁺ẋ_d + u_fb, whose cross term 2(J⁺ẋ_d)ᵀu_fb makes up a lag e_N (∫J u_fb dt = −e_N)
        at −2ẋ_dᵀ(JJᵀ)⁻¹e_N: first order in e_N, so without it the plan slows down and lags a moving
        reference. Directions where J lost rank are dropped from both.
        """
        if not self.terminal:
            return None
        end = q0 + self.solver_dt * plan.sum(axis=1)
        _, values, right, _ = self._lqr.factors(self.kinematics.jacobian_batch(end))
        weight = np.swapaxes(right, -1, -2) @ (values[..., :, None] ** -0.5 * right)  # P* = Cᵀ diag(λ^{-1/2}) C
        inverse = np.swapaxes(right, -1, -2) @ (values[..., :, None] ** -1.0 * right)  # (JJᵀ)⁻¹ = Cᵀ diag(λ⁻¹) C
        return weight, -(inverse @ end_velocity[..., None])[..., 0]

    def _evaluate(
        self,
        rows: np.ndarray,
        q0: np.ndarray,
        x_d: np.ndarray,
        plans: np.ndarray,
        terminal: tuple[np.ndarray, np.ndarray] | None,
        convention: CostConvention,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """V, ∂V/∂U and J(θ₀..θ_N) of ``plans`` (one per sample of ``rows``), one FK pass for all of them."""
        count, steps, m = plans.shape
        angles = np.empty((count, steps + 1, m))
        angles[:, 0] = q0[rows]
        np.cumsum(plans * self.solver_dt, axis=1, out=angles[:, 1:])
        angles[:, 1:] += q0[rows, None]
        n = x_d.shape[-1]
        errors, jacobians = errors_and_jacobians(self.kinematics, angles.reshape(-1, m), x_d[rows].reshape(-1, n))
        errors, jacobians = errors.reshape(count, steps + 1, n), jacobians.reshape(count, steps + 1, n, m)
        values, grads = np.empty(count), np.empty((count, steps, m))
        smoothness = convention.smoothness_weight / self.solver_dt
        for b, i in enumerate(rows):
            values[b], grads[b] = cost_and_gradient(
                errors[b, :steps], jacobians[b, :steps], plans[b], self.solver_dt, convention
            )
            if smoothness and convention.udot_start == "rest":
                # cost_and_gradient takes u₋₁ = 0; the jump is from the last command: (w/Δt_s)(|u₀ − u₋₁|² − |u₀|²).
                last = self._previous[i]
                values[b] += smoothness * (last @ last - 2.0 * plans[b, 0] @ last)
                grads[b, 0] -= 2.0 * smoothness * last
            if terminal is not None:
                # e_NᵀP̄e_N + 2p̄ᵀe_N, θ_N = θ₀ + Δt_s Σ uᵢ: the same gradient 2Δt_s J_Nᵀ(P̄e_N + p̄) for every uᵢ.
                error = errors[b, steps]
                weighted = terminal[0][i] @ error
                values[b] += error @ (weighted + 2.0 * terminal[1][i])
                grads[b] += 2.0 * self.solver_dt * (jacobians[b, steps].T @ (weighted + terminal[1][i]))
        return values, grads, jacobians

    def _direction(
        self,
        solver: GaussNewtonSolver,
        jacobians: np.ndarray,
        grad: np.ndarray,
        terminal: Any,
        i: int,
        limits: list[Limits] | None,
    ) -> tuple[np.ndarray, float]:
        """The solver's Gauss-Newton step, with the terminal Hessian 2J_NᵀP̄J_N in θ_N's block and, with the limits,
        the barrier's Σ = μ/s²; and the largest step fraction (≤ 1) that keeps every slack at least 1 − τ of its
        value."""
        steps = grad.shape[0]
        block = None if terminal is None else 2.0 * jacobians[steps].T @ terminal[0][i] @ jacobians[steps]
        if limits is None:
            return solver.direction(jacobians[:steps], grad, terminal=block), 1.0
        slacks = self._slacks[i]  # the plan's (stacked), kept from its last evaluation
        # primal barrier: z = μ/s, so Σ = z/s = μ/s²
        barrier = Barrier(limits[i], self.solver_dt, float(self._mu[i]), list(slacks), list(self._mu[i] / slacks))
        step = solver.direction(jacobians[:steps], grad, terminal=block, barrier=barrier)
        step_angles = self.solver_dt * np.cumsum(step, axis=0)
        slack_steps = np.stack([step, -step] + ([step_angles, -step_angles] if limits[i].has_positions else []))
        # Fraction to the boundary: the largest α ≤ 1 keeping every slack ≥ (1 − τ) of its value.
        shrinking = slack_steps < 0.0
        if not shrinking.any():
            return step, 1.0
        return step, min(1.0, float((-BOUNDARY_FRACTION * slacks[shrinking] / slack_steps[shrinking]).min()))

    def _line_search(
        self,
        solver: GaussNewtonSolver,
        rows: np.ndarray,
        q0: np.ndarray,
        x_d: np.ndarray,
        plan: np.ndarray,
        steps: np.ndarray,
        slopes: np.ndarray,
        terminal: tuple[np.ndarray, np.ndarray] | None,
        convention: CostConvention,
        state: tuple[np.ndarray, np.ndarray, np.ndarray],
        first: np.ndarray,
        limits: list[Limits] | None = None,
    ) -> None:
        """The solver's Armijo backtracking of the samples ``rows`` from step fractions ``first``, at most
        :data:`MAX_BACKTRACKS` halvings, every pending sample in one FK pass; updates ``plan`` and ``state`` =
        (V, ∂V/∂U, J) in place where a step is accepted. With the limits, V includes the barrier (inf outside them)."""
        value, grad, jacobians = state
        trials: dict[str, Any] = {}

        def merit(pending: np.ndarray, alpha: np.ndarray) -> np.ndarray:
            trial = plan[rows[pending]] + alpha[:, None, None] * steps[pending]
            trial_value, trial_grad, trial_jacobians = self._evaluate(
                rows[pending], q0, x_d, trial, terminal, convention
            )
            if limits is not None:
                barrier, barrier_grad, trials["slacks"] = self._barrier(rows[pending], q0, trial, limits)
                trial_value, trial_grad = trial_value + barrier, trial_grad + barrier_grad
            trials.update(plan=trial, value=trial_value, grad=trial_grad, jacobians=trial_jacobians)
            return trial_value

        def accept(pending: np.ndarray, accepted: np.ndarray) -> None:
            done = rows[pending[accepted]]
            plan[done], value[done] = trials["plan"][accepted], trials["value"][accepted]
            grad[done], jacobians[done] = trials["grad"][accepted], trials["jacobians"][accepted]
            if limits is not None:
                for b in np.flatnonzero(accepted):
                    self._slacks[rows[pending[b]]] = trials["slacks"][b]

        solver.line_search(merit, value[rows], slopes, first, accept, max_tries=MAX_BACKTRACKS, min_step=0.0)
