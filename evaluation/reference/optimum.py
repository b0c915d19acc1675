"""The ``optimal`` reference: each sample's numerical optimum of the evaluator's trajectory cost.

For one sample (seed pose θ₀, reference x_d known over the whole horizon) it solves

    min_U  V(U) = Σₖ (eₖᵀQeₖ + uₖᵀRuₖ + u̇ₖᵀRu̇ₖ) Δt,   k = 0..K−1,  Q = I₃, R = I₆
    s.t.   θₖ₊₁ = θₖ + uₖΔt,  |uₖⱼ| ≤ ūⱼ,  θ⁻ ≤ θₖ ≤ θ⁺ (k = 1..K),  u₋₁ = 0,  u̇ₖ = (uₖ − uₖ₋₁)/Δt,
           eₖ = f(θₖ) − x_d(tₖ)

(on a pose task, x = [p; log₃ R] and eₖ = [p − p_d; log₃(R R_dᵀ)] with Q = I₆, differentiated exactly:
:func:`snac_gym.tasks.pose.pose_errors_and_jacobians`) over the evaluator's horizon, Δt and
discretisation (docs/optimal.md), for the run's cost
convention (:class:`snac_gym.control.cost.CostConvention`: without the u̇ term for ``--cost hjb``, u₋₁ = u₀
for ``--udot-start first``, Q = q·I for ``--q-scale``). It is an *open-loop*
reference computed with knowledge of the whole reference, not a controller.
(Not :mod:`snac_gym.control.optimality`: that is the frozen-Jacobian, infinite-horizon optimum the critics
are compared with; this is the whole trajectory's, over the evaluator's finite horizon.)

**Method**: :func:`snac_gym.control.trajopt.solve_sample` (Gauss-Newton in θ, a primal-dual interior point where
the unconstrained optimum breaks a joint position or velocity limit: column ``optimal_bounded``; the
limits are those the success rule counts, ``--reference-limits velocity`` keeps the velocity limits
only). **Starts** (:func:`multi_start_solve`): U = 0 (the robot at rest, solved on a coarse time grid first:
:func:`solve_from_rest`), then the reference's own
feedback rollouts (:data:`OWN_STARTS`, fixed settings) and IK-branch and random starts
(:mod:`~snac_gym.evaluation.reference.branches`), each screened on a coarse time grid (Δt × :data:`COARSE_FACTOR`:
a few Gauss-Newton steps, stopped in a known basin, else solved there to the end); the cheapest few coarse optima
are polished on the full grid, and the best local optimum is kept (``optimal_starts``, ``optimal_winner``,
``optimal_local_spread``). The reference is thus a function of the sample alone, never of the
controllers it judges, and can be beaten: a controller that keeps the limits and costs less is a
failure of the reference, reported as such. ``optimal_gradient`` records the final max-norm gradient
in the preconditioned variables, ``optimal_gap_estimate`` the solver's estimate of V − V*
(:mod:`snac_gym.control.trajopt`: tolerance).

The reported cost of the solution is *not* the solver's value: the command sequence is rolled
out by :func:`snac_gym.rollout.simulate_kinematic` (an open-loop replay policy) and measured by
:func:`snac_gym.metrics.rollout_metrics`, the path every controller takes.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
from snac_gym.evaluation.execution.jobs import JobResult, kinematic_logs, policy_context
from snac_gym.evaluation.reference import cache as reference_cache
from snac_gym.evaluation.reference.branches import BRANCH_PREFIX, RANDOM_PREFIX, branch_candidates, needs_branches
from snac_gym.evaluation.reference.multistart import (
    BASIN_RADIUS,
    COARSE_FACTOR,
    COARSE_ITERATIONS,
    POLISHED,
    REST_START,
    SCREEN_ITERATIONS,
    SCREEN_MARGIN,
    MultiStart,
    coarse_commands,
    multi_start_solve,
    solve_from_rest,
)
from snac_gym.evaluation.samples import EvaluationSample

from snac_gym.control.cost import CostConvention
from snac_gym.control.lower_bounds import certified_cost_lower_bounds
from snac_gym.control.trajopt import (
    FTOL,
    GAP_RTOL,
    GTOL,
    LIMIT_CLEARANCE,
    Limits,
    OptimalSolution,
    angles,
    position_bounds,
    single_threaded_blas,
    solve_sample,
    trajectory_cost_and_gradient,
)
from snac_gym.metrics import check_metric_row, rollout_metrics
from snac_gym.policies.registry import make_policy, policy_factory
from snac_gym.rollout import reference_trajectories, simulate_kinematic

#: Name of the reference row in the results (selectable with ``--controllers optimal,...``).
OPTIMAL = "optimal"
#: Row label in the reports.
OPTIMAL_LABEL = "Optimal (open-loop reference, whole reference known)"
#: The reference's constraints (``--reference-limits``): the joint position and velocity limits (the
#: success rule's), or the velocity limits only.
REFERENCE_LIMITS = ("joints", "velocity")
#: Row label of the variant that keeps the velocity limits only.
OPTIMAL_VELOCITY_ONLY_LABEL = "Optimal, joint position limits ignored (open-loop reference, whole reference known)"
#: Extra columns of the optimal rows.
SOLVER_COLUMNS = (
    "optimal_iterations",
    "optimal_evaluations",
    "optimal_gradient",
    "optimal_gap_estimate",
    "optimal_converged",
    "optimal_bounded",
    "optimal_solver_cost",
    "optimal_solve_time",
    "optimal_starts",
    "optimal_same_basin",
    "optimal_winner",
    "optimal_local_spread",
    "optimal_lower_bound",
    "optimal_limits",
)


class ReplayPolicy:
    """An open-loop "policy" that replays precomputed command sequences (batch protocol).

    Used only to roll the optimal commands out through :func:`simulate_kinematic`, so that the
    optimum is measured exactly like every controller.
    """

    def __init__(self, commands: np.ndarray) -> None:
        self._commands = np.asarray(commands, dtype=float)  # (B, K, m)
        self._step = 0

    def reset_batch(self, seeds: Sequence[int]) -> None:
        self._step = 0

    def act_batch(self, obs_batch: np.ndarray) -> np.ndarray:
        commands = self._commands[:, self._step]
        self._step += 1
        return commands.copy()


#: The reference's own starts besides rest: feedback laws of this project at fixed settings, rolled out
#: on the true model (kept strictly inside the position limits by Ω(θ) where the reference keeps them:
#: :func:`own_start_commands`). They are the reference's, not the run's: a sample gets the same starts
#: whatever ``--controllers`` says. ``joint-goal`` goes straight in joint space to an in-limit IK solution
#: of another branch or winding where one is nearer: the basin the resolved-rate starts, stalled against
#: a limit, never reach (on the arm's whole reach, the solve from them could end 0.7 m off target).
#: ``dls`` (gain 2) was a start too, until an ablation on 1000 fresh samples found it ended nowhere the other starts
#: did not (docs/optimal.md, "Two feedback starts, not three"): 8 % of the reference's CPU on Table I's samples.
OWN_STARTS: tuple[tuple[str, dict[str, Any]], ...] = (("lqr", {"q_scale": 9.0}), ("joint-goal", {}))
#: The own starts whose path does not depend on the grid they are rolled out on, so that they are rolled out on the
#: coarse grid of the screen (:func:`own_start_commands`), a tenth of the steps: ``joint-goal`` goes straight in joint
#: space to its goal, the same segment at any Δt. The resolved-rate laws are rolled out on the full grid: which branch
#: they end on can depend on Δt (workspace reach sample 4 of seed 13, HJB cost, 5 s: lqr's full-grid rollout crosses to
#: the other elbow branch, where the optimum is 13 % below the solve from rest's, and its rollouts at Δt × 2 to × 10
#: do not).
GRID_FREE_STARTS = ("joint-goal",)
# Made by name, so outside the import graph the cache's key follows: their modules are given to it.
reference_cache.add_roots([policy_factory(name).__module__ for name, _ in OWN_STARTS])


@dataclass(frozen=True)
class OptimalJob:
    """The optimum of a chunk of samples of one task (picklable, like a :class:`RolloutJob`).

    It depends on the samples, the horizon, the cost and the arm only, never on the run's contestants.
    ``position_limits``: keep the joint position limits as hard constraints (the default reference);
    ``False`` gives the variant that keeps the velocity limits only. ``cache_dir``: reuse and store
    the rows there by sample content (:mod:`snac_gym.evaluation.reference.cache`); ``None``: solve every sample.
    """

    task: str
    samples: tuple[EvaluationSample, ...]
    seeds: tuple[int, ...]
    steps: int
    dt: float
    robot: str = "ur10"
    keep_logs: bool = False
    convention: CostConvention = field(default_factory=CostConvention)
    position_limits: bool = True
    screen_margin: float = SCREEN_MARGIN
    cache_dir: str | None = None


def own_start_commands(
    context: Any,
    samples: Sequence[Any],
    steps: int,
    seeds: Sequence[int],
    joint_limits: bool = True,
    factor: int = 1,
) -> list[dict[str, np.ndarray]]:
    """Per sample, the command sequence of each of :data:`OWN_STARTS`, rolled out on the true model.

    ``joint_limits``: keep them inside the position limits (Ω(θ)); ``False`` for the problem without
    position limits, whose better basins may lie beyond them. ``factor``: the commands on the coarse grid of the
    same horizon (Δt × ``factor``, ``⌈steps/factor⌉`` rows), where :func:`multi_start_solve` screens them: the
    laws of :data:`GRID_FREE_STARTS` rolled out there, the others on the full grid and block-averaged
    (:func:`coarse_commands`).
    """
    coarse_context = dataclasses.replace(context, dt=float(context.dt) * factor)
    starts: list[dict[str, np.ndarray]] = [{} for _ in samples]
    position_task = getattr(context.kinematics, "task_error", None) is None
    for name, kwargs in OWN_STARTS:
        if name == "joint-goal" and not position_task:
            continue  # its goal is a 3-D position; a pose task has the other starts
        # joint-goal keeps the limits by construction (a straight joint path between in-limit configurations).
        limit_kwargs = {} if name == "joint-goal" else {"joint_limits": joint_limits}
        on_coarse = factor > 1 and name in GRID_FREE_STARTS
        law_context, law_steps = (coarse_context, -(-steps // factor)) if on_coarse else (context, steps)
        make = functools.partial(make_policy, name, law_context, **{**kwargs, **limit_kwargs})
        rollouts = simulate_kinematic(law_context, make, samples, law_steps, seeds, True, name, keep_states=False)
        for i in range(len(samples)):
            commands = rollouts.commands[i]
            starts[i][name] = commands if on_coarse or factor == 1 else coarse_commands(commands, factor)
    return starts


def _lower_bounds(
    job: OptimalJob, kinematics: Any, x_d: np.ndarray, limits: np.ndarray, costs: np.ndarray
) -> np.ndarray:
    """:func:`snac_gym.control.lower_bounds.certified_cost_lower_bounds` per sample of a position task (reach or track,
    under the run's cost), else NaN: certified for every command sequence within the velocity limits. The
    optimum's cost is its V̄ (the reachable set's size, which tightens the Lipschitz constant): the bound
    holds for any V̄, so the reference does not certify itself."""
    if getattr(kinematics, "task_error", None) is not None:
        return np.full(len(job.samples), np.nan)
    q0s = np.array([s.q0 for s in job.samples], dtype=float)
    return certified_cost_lower_bounds(kinematics, q0s, x_d, job.dt, job.convention, limits, costs)


def run_optimal_job(job: OptimalJob) -> Any:
    """Solve every sample of ``job``, roll the solutions out and measure them like a controller's.

    With ``job.cache_dir`` (and no trajectories asked for), the samples whose rows are cached are not
    solved again, and the rows solved here are stored.

    Returns a :class:`snac_gym.evaluation.execution.jobs.JobResult` whose metrics carry :data:`SOLVER_COLUMNS` too.
    """
    if job.cache_dir is None or job.keep_logs:
        return _solve_job(job)
    folder = Path(job.cache_dir)
    keys = [reference_cache.sample_key(job, sample) for sample in job.samples]
    cached = reference_cache.read_rows(folder, keys, functools.partial(check_reference_row, task=job.task))
    missing = [i for i, row in enumerate(cached) if row is None]
    rows: list[dict[str, Any] | None] = [None if row is None else {"sample": s.index, **row}
                                         for row, s in zip(cached, job.samples, strict=True)]  # fmt: skip
    if missing:
        subset = dataclasses.replace(job, samples=tuple(job.samples[i] for i in missing),
                                     seeds=tuple(job.seeds[i] for i in missing))  # fmt: skip
        solved = _solve_job(subset).metrics
        for record in solved.drop(columns=["sample"]).to_dict("records"):
            check_reference_row(record, job.task)  # what a cached row must pass, a fresh one passes
        reference_cache.write_rows(folder, [keys[i] for i in missing], solved)
        for i, record in zip(missing, solved.to_dict("records"), strict=True):
            rows[i] = record
    return JobResult(pd.DataFrame(rows), None)


#: How far the reference's reported cost (the replayed rollout's) may be from the solver's own value: the same sums
#: in another order (measured: 3e-14 relative on Table I's 2000 samples).
SOLVER_AGREEMENT = 1e-9


def check_reference_row(row: Any, task: str) -> None:
    """Check one reference row as its computation fixes it (a row read back from the cache, and every fresh one):
    the metrics' own relations (:func:`snac_gym.metrics.check_metric_row`), the replayed cost equal to the solver's
    to :data:`SOLVER_AGREEMENT`, the certified lower bound not above it, the solver's counts whole and non-negative.

    Raises:
        ValueError: Naming the first column that does not hold.
    """
    check_metric_row(row, task)
    cost, solver = row["cost"], row["optimal_solver_cost"]
    if not (
        isinstance(solver, (float, np.floating))
        and math.isfinite(solver)
        and abs(solver - cost) <= SOLVER_AGREEMENT * max(cost, 1e-300)
    ):
        raise ValueError(f"cost {cost!r} is not the solver's value {solver!r}")
    bound = row["optimal_lower_bound"]
    if isinstance(bound, (float, np.floating)) and math.isfinite(bound) and bound > cost * (1.0 + SOLVER_AGREEMENT):
        raise ValueError(f"the lower bound {bound!r} is above the cost {cost!r}")
    for name in ("optimal_iterations", "optimal_evaluations", "optimal_starts", "optimal_same_basin"):
        value = row[name]
        if isinstance(value, bool) or not float(value).is_integer() or value < 0:
            raise ValueError(f"{name} = {value!r} is not a whole number ≥ 0")
    winner = row["optimal_winner"]
    if winner not in {REST_START, *(name for name, _ in OWN_STARTS)} and not (
        isinstance(winner, str)
        and any(winner.startswith(p) and winner[len(p) :].isdigit() for p in (BRANCH_PREFIX, RANDOM_PREFIX))
    ):
        raise ValueError(f"optimal_winner = {row['optimal_winner']!r} is not a start of the reference")
    if row["optimal_limits"] not in REFERENCE_LIMITS:
        raise ValueError(f"optimal_limits = {row['optimal_limits']!r}")


def solve_samples(
    context: Any,
    samples: Sequence[EvaluationSample],
    seeds: Sequence[int],
    x_d: np.ndarray,
    dt: float,
    convention: CostConvention,
    position_limits: bool = True,
    screen_margin: float = SCREEN_MARGIN,
) -> list[MultiStart]:
    """The reference of each sample (``x_d``: ``(B, K, n)``): the solve from rest, then every start of its own
    (:data:`OWN_STARTS`, the other IK branches) whose basin could win (:func:`multi_start_solve`)."""
    kinematics, limits = context.kinematics, np.asarray(context.velocity_limits, dtype=float)
    q0s = [np.asarray(s.q0, dtype=float) for s in samples]
    bounds = (kinematics.lower_limits, kinematics.upper_limits) if position_limits else None
    steps = x_d.shape[1]
    with single_threaded_blas():
        rest = [solve_from_rest(q0, x_d[i], kinematics, dt, limits, convention, bounds) for i, q0 in enumerate(q0s)]
        candidates = own_start_commands(context, samples, steps, seeds, position_limits, COARSE_FACTOR)
        branches: list[dict[str, np.ndarray]] = [{} for _ in q0s]
        if getattr(kinematics, "task_error", None) is None and context.layout.task_dim == 3:  # a 3-D target's branches
            paths = [angles(r.commands, q0, dt) for r, q0 in zip(rest, q0s, strict=True)]
            ends = [path[-1] for path in paths]
            searched = [i for i, r in enumerate(rest) if needs_branches(kinematics, r, paths[i], x_d[i])]
            if searched:
                found = branch_candidates(kinematics, [q0s[i] for i in searched], x_d[searched], dt, limits,
                                          [ends[i] for i in searched], [rest[i].cost for i in searched],
                                          COARSE_FACTOR)  # fmt: skip
                for i, starts in zip(searched, found, strict=True):
                    branches[i] = starts
        return [
            multi_start_solve(q0, x_d[i], kinematics, dt, limits, convention, {**candidates[i], **branches[i]},
                              screen_margin, rest[i], bounds)
            for i, q0 in enumerate(q0s)
        ]  # fmt: skip


def _solve_job(job: OptimalJob) -> Any:
    """:func:`run_optimal_job` without the cache."""
    context = policy_context(job.robot, job.dt, job.task)
    kinematics, limits = context.kinematics, np.asarray(context.velocity_limits, dtype=float)
    times = np.arange(job.steps) * job.dt
    x_d, _, _ = reference_trajectories([s.reference for s in job.samples], times, context.layout.task_dim)
    results = solve_samples(context, job.samples, job.seeds, x_d, job.dt, job.convention, job.position_limits,
                            job.screen_margin)  # fmt: skip
    solutions = [result.solution for result in results]
    commands = np.stack([s.commands for s in solutions])
    rollouts = simulate_kinematic(
        context, lambda: ReplayPolicy(commands), job.samples, job.steps, job.seeds, True, OPTIMAL
    )
    metrics = rollout_metrics(
        rollouts, job.task, limits, job.convention, (kinematics.lower_limits, kinematics.upper_limits)
    )
    metrics.insert(0, "sample", [s.index for s in job.samples])
    metrics["optimal_iterations"] = np.array([s.iterations for s in solutions], dtype=np.int64)
    metrics["optimal_evaluations"] = np.array([s.evaluations for s in solutions], dtype=np.int64)
    metrics["optimal_gradient"] = [s.gradient for s in solutions]
    metrics["optimal_gap_estimate"] = [s.gap_estimate for s in solutions]
    metrics["optimal_converged"] = [s.converged for s in solutions]
    metrics["optimal_bounded"] = [s.bounded for s in solutions]
    metrics["optimal_solver_cost"] = [s.cost for s in solutions]
    metrics["optimal_solve_time"] = [s.seconds for s in solutions]
    metrics["optimal_starts"] = np.array([r.starts for r in results], dtype=np.int64)
    metrics["optimal_same_basin"] = np.array([r.same_basin for r in results], dtype=np.int64)
    metrics["optimal_winner"] = [r.winner for r in results]
    metrics["optimal_local_spread"] = [r.spread for r in results]
    metrics["optimal_limits"] = REFERENCE_LIMITS[0] if job.position_limits else REFERENCE_LIMITS[1]
    metrics["optimal_lower_bound"] = _lower_bounds(job, kinematics, x_d, limits, np.array([s.cost for s in solutions]))
    attrs = {"task": job.task, "policy": OPTIMAL, "policy_kwargs": {}}
    logs = kinematic_logs(rollouts, job.samples, job.seeds, attrs, limits) if job.keep_logs else None
    return JobResult(metrics, logs)


def add_optimality(results: pd.DataFrame) -> pd.DataFrame:
    """Add ``ratio_to_optimal`` (cost / the optimal row's cost of the same task and sample) and
    ``below_optimal`` (the row's cost is below the optimum: the solver did not converge there)."""
    if OPTIMAL not in set(results["controller"]):
        return results
    optimum = results[results["controller"] == OPTIMAL].set_index(["task", "sample"])["cost"]
    keys = pd.MultiIndex.from_frame(results[["task", "sample"]])
    reference = optimum.reindex(keys).to_numpy()
    results = results.copy()
    results["ratio_to_optimal"] = results["cost"].to_numpy() / reference
    results["below_optimal"] = results["cost"].to_numpy() < reference
    return results


__all__ = [
    "FTOL",
    "GAP_RTOL",
    "GTOL",
    "OPTIMAL",
    "OPTIMAL_LABEL",
    "MultiStart",
    "OptimalJob",
    "OptimalSolution",
    "REST_START",
    "COARSE_FACTOR",
    "COARSE_ITERATIONS",
    "POLISHED",
    "SCREEN_ITERATIONS",
    "SCREEN_MARGIN",
    "BASIN_RADIUS",
    "GRID_FREE_STARTS",
    "OWN_STARTS",
    "REFERENCE_LIMITS",
    "Limits",
    "own_start_commands",
    "position_bounds",
    "LIMIT_CLEARANCE",
    "ReplayPolicy",
    "add_optimality",
    "check_reference_row",
    "run_optimal_job",
    "solve_samples",
    "multi_start_solve",
    "coarse_commands",
    "solve_sample",
    "trajectory_cost_and_gradient",
]
