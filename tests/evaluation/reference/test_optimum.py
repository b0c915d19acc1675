"""The ``optimal`` reference: exact gradient, convergence, a lower bound on every controller, reports."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.linalg import solve_banded
from scipy.optimize import minimize
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation.reference.multistart import BASIN_RADIUS, NEWTON, solve_from_rest
from snac_gym.evaluation.reference.optimum import OPTIMAL
from snac_gym.evaluation.samples import generate_samples

from snac_gym.control.cost import CostConvention, cost_and_gradient, trajectory_cost
from snac_gym.control.trajopt import (
    FTOL,
    GAP_RTOL,
    GTOL,
    MAX_ITERATIONS,
    _preconditioner,
    angles,
    solve_sample,
    trajectory_cost_and_gradient,
)
from snac_gym.model.kinematics import Kinematics
from snac_gym.rollout import log_array, read_log, reference_trajectories
from snac_gym.sampling import SampleSpace

DT = 1.0 / 125.0
MEMORY = 20


def _bounded_polish(
    commands: np.ndarray,
    q0: np.ndarray,
    x_d: np.ndarray,
    kinematics,
    dt: float,
    limits: np.ndarray,
    gtol: float,
    ftol: float,
    max_iterations: int,
    convention: CostConvention,
) -> tuple[np.ndarray, float, int, int, float, bool]:
    """Bounded L-BFGS-B in u from the clipped ``commands``: an independent solver of the velocity-bounded problem.

    Returns:
        (commands, V, iterations, cost evaluations, projected max |∂V/∂u|, converged).
    """
    steps, m = commands.shape

    def in_u(u: np.ndarray) -> tuple[float, np.ndarray]:
        value, grad = trajectory_cost_and_gradient(u.reshape(steps, m), q0, x_d, kinematics, dt, convention)
        return value, grad.ravel()

    bounds = np.repeat(np.stack([-limits, limits], axis=1)[None], steps, axis=0).reshape(-1, 2)
    clipped = np.clip(commands, -limits, limits)
    options = {"maxiter": max_iterations, "maxfun": 4 * max_iterations, "gtol": gtol, "ftol": ftol, "maxcor": MEMORY}
    polish = minimize(in_u, clipped.ravel(), jac=True, method="L-BFGS-B", bounds=bounds, options=options)
    projected = np.clip(polish.x - polish.jac, bounds[:, 0], bounds[:, 1]) - polish.x
    gradient = float(np.abs(projected).max())
    return (
        polish.x.reshape(steps, m),
        float(polish.fun),
        int(polish.nit),
        int(polish.nfev),
        gradient,
        polish.status == 0,
    )


@pytest.fixture(scope="module")
def ur10():
    return Kinematics("ur10")


@pytest.fixture(scope="module")
def track_sample(ur10):
    return generate_samples(ur10, SampleSpace.for_robot(ur10), 0, "track", [0])[0]


@pytest.mark.parametrize(
    "convention", [CostConvention(), CostConvention("table1", "first", 50.0), CostConvention("hjb", q_scale=1e4)]
)
def test_cost_and_gradient_match_the_shared_cost_and_finite_differences(ur10, track_sample, convention):
    steps = 20
    x_d = reference_trajectories([track_sample.reference], np.arange(steps) * DT)[0][0]
    commands = np.random.default_rng(0).normal(scale=0.3, size=(steps, ur10.n_joints))
    value, grad = trajectory_cost_and_gradient(commands, track_sample.q0, x_d, ur10, DT, convention)
    q = track_sample.q0 + DT * np.vstack([np.zeros(ur10.n_joints), np.cumsum(commands[:-1], axis=0)])
    errors = np.array([ur10.forward(qk) for qk in q]) - x_d
    initial = commands[0] if convention.udot_start == "first" else None
    terms = trajectory_cost(errors, commands, DT, Q=convention.error_weight(3), initial_command=initial)
    assert value == pytest.approx(float(convention.total(terms)), rel=1e-12)
    numeric = np.zeros_like(commands)
    for index in np.ndindex(commands.shape):
        step = np.zeros_like(commands)
        step[index] = 1e-6
        plus = trajectory_cost_and_gradient(commands + step, track_sample.q0, x_d, ur10, DT, convention)[0]
        minus = trajectory_cost_and_gradient(commands - step, track_sample.q0, x_d, ur10, DT, convention)[0]
        numeric[index] = (plus - minus) / 2e-6
    np.testing.assert_allclose(grad, numeric, rtol=0, atol=1e-6 * np.abs(grad).max())


@pytest.mark.parametrize(
    "convention", [CostConvention(), CostConvention("table1", "first", 3.0), CostConvention("hjb")]
)
def test_the_shared_cost_gradient_on_a_linear_model(convention):
    """snac_gym.control.cost.cost_and_gradient alone, on e = Aθ + b (constant Jacobian A): V and ∂V/∂U."""
    rng = np.random.default_rng(1)
    steps, m, n, dt = 7, 4, 3, 0.05
    matrix, offset, q0 = rng.normal(size=(n, m)), rng.normal(size=n), rng.normal(size=m)

    def errors_of(commands):
        q = q0 + dt * np.vstack([np.zeros(m), np.cumsum(commands[:-1], axis=0)])
        return q @ matrix.T + offset

    def cost(commands):
        errors = errors_of(commands)
        return cost_and_gradient(errors, np.broadcast_to(matrix, (steps, n, m)), commands, dt, convention)

    commands = rng.normal(size=(steps, m))
    value, grad = cost(commands)
    initial = commands[0] if convention.udot_start == "first" else None
    terms = trajectory_cost(errors_of(commands), commands, dt, Q=convention.error_weight(n), initial_command=initial)
    assert value == pytest.approx(float(convention.total(terms)), rel=1e-12)
    numeric = np.zeros_like(commands)
    for index in np.ndindex(commands.shape):
        step = np.zeros_like(commands)
        step[index] = 1e-6
        numeric[index] = (cost(commands + step)[0] - cost(commands - step)[0]) / 2e-6
    np.testing.assert_allclose(grad, numeric, rtol=0, atol=1e-6 * np.abs(grad).max())


def test_the_hjb_optimum_is_below_the_frozen_jacobian_lqr(ur10, track_sample):
    """Without the u̇ term the optimum is close to, and never above, the LQR law's open-loop cost."""
    from snac_gym.evaluation.execution.jobs import policy_context

    from snac_gym.metrics import rollout_metrics
    from snac_gym.policies import make_policy
    from snac_gym.rollout import simulate_kinematic

    convention = CostConvention("hjb")  # Q = I: far from the velocity limits
    sample = generate_samples(ur10, SampleSpace.for_robot(ur10), 0, "reach", [1])[0]
    steps = 1500  # the evaluator's 12 s: the finite horizon's end hardly matters (at 2 s lqr costs 5 % more)
    x_d = reference_trajectories([sample.reference], np.arange(steps) * DT)[0][0]
    solution = solve_sample(sample.q0, x_d, ur10, DT, ur10.velocity_limits, convention=convention)
    context = policy_context("ur10", DT, "reach")
    lqr = simulate_kinematic(context, lambda: make_policy("lqr", context, q_scale=1.0), [sample], steps, [0])
    lqr_cost = float(rollout_metrics(lqr, "reach", ur10.velocity_limits, convention)["cost"].iloc[0])
    assert solution.converged and not solution.bounded and solution.cost <= lqr_cost <= 1.05 * solution.cost


def test_solver_converges_to_the_same_optimum_with_a_tighter_tolerance(ur10, track_sample):
    steps = 150
    x_d = reference_trajectories([track_sample.reference], np.arange(steps) * DT)[0][0]
    default = solve_sample(track_sample.q0, x_d, ur10, DT, ur10.velocity_limits)
    tight = solve_sample(track_sample.q0, x_d, ur10, DT, ur10.velocity_limits, gtol=1e-11, ftol=1e-16, gap_rtol=0.0)
    assert default.converged and not default.bounded
    assert tight.iterations > default.iterations  # the tolerance stopped the default solve earlier
    assert 0.0 <= default.cost - tight.cost <= GAP_RTOL * tight.cost
    assert default.commands[0] @ default.commands[0] < 1e-2  # the optimum ramps up from rest (u₋₁ = 0)


def test_a_velocity_limit_below_the_unconstrained_optimum_is_respected(ur10, track_sample):
    steps = 100
    x_d = reference_trajectories([track_sample.reference], np.arange(steps) * DT)[0][0]
    free = solve_sample(track_sample.q0, x_d, ur10, DT, ur10.velocity_limits)
    limits = 0.5 * np.abs(free.commands).max(axis=0) + 1e-3
    bounded = solve_sample(track_sample.q0, x_d, ur10, DT, limits)
    assert bounded.bounded and bounded.converged
    assert (np.abs(bounded.commands) <= limits + 1e-12).all()
    assert bounded.cost >= free.cost


@pytest.mark.parametrize("task, region", [("reach", "cuboid"), ("track", "cuboid"), ("reach", "workspace"),
                                          ("track", "workspace")])  # fmt: skip
def test_the_solve_from_rest_through_the_coarse_grid_ends_at_the_direct_solves_optimum(ur10, task, region):
    space = SampleSpace.for_robot(ur10) if region == "cuboid" else SampleSpace.workspace(ur10)
    samples = generate_samples(ur10, space, 41, task, range(3))
    steps = 375  # 3 s: 38 points on the coarse grid
    x_d = reference_trajectories([s.reference for s in samples], np.arange(steps) * DT)[0]
    bounds = (ur10.lower_limits, ur10.upper_limits)
    for i, sample in enumerate(samples):
        # The direct solve with the reference's steps (Newton's where the Hessian allows): Gauss-Newton alone stopped
        # 2.4·10⁻⁷ above the optimum on track sample 0 of the workspace, where it converges linearly.
        direct = solve_sample(sample.q0, x_d[i], ur10, DT, ur10.velocity_limits, position_limits=bounds, newton=NEWTON)
        through = solve_from_rest(sample.q0, x_d[i], ur10, DT, ur10.velocity_limits, CostConvention(), bounds)
        assert through.converged and through.bounded == direct.bounded, (i, through.bounded, direct.bounded)
        # Each stops within GAP_RTOL·V of its local optimum: the same optimum, not bit for bit the same point.
        assert abs(through.cost - direct.cost) <= 2 * GAP_RTOL * direct.cost, (i, through.cost, direct.cost)
        # Along the valley's flat directions (six joints, a 3-D target) the two stop up to 3·10⁻³ rad apart; distinct
        # optima lie radians apart (BASIN_RADIUS, 0.1 rad, is the multi-start's own test of one basin).
        gap = np.abs(angles(through.commands, sample.q0, DT) - angles(direct.commands, sample.q0, DT)).max()
        assert gap < 0.1 * BASIN_RADIUS, (i, gap)


def test_where_a_limit_binds_the_solve_from_rest_through_the_coarse_grid_is_the_interior_point_from_rest(
    ur10, track_sample
):
    steps = 100
    x_d = reference_trajectories([track_sample.reference], np.arange(steps) * DT)[0][0]
    free = solve_sample(track_sample.q0, x_d, ur10, DT, ur10.velocity_limits)
    limits = 0.5 * np.abs(free.commands).max(axis=0) + 1e-3
    direct = solve_sample(track_sample.q0, x_d, ur10, DT, limits)
    through = solve_from_rest(track_sample.q0, x_d, ur10, DT, limits, CostConvention())
    assert direct.bounded and through.bounded
    np.testing.assert_array_equal(through.commands, direct.commands)
    assert through.iterations > direct.iterations  # the coarse grid's steps are counted too


@pytest.fixture(scope="module")
def optimal_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("optimal")
    config = EvaluationConfig(
        out=out,
        tasks=("reach", "track"),
        controllers=(OPTIMAL, "snac", "rnn", "svf", "dls"),
        samples=3,
        effort_samples=0,
        horizons={"reach": 1.5, "track": 1.0},
        chunk_size=2,
        save_trajectories=True,
        progress=False,
        plots=False,
    )
    return config, run_evaluation(config)


def test_no_controller_beats_the_optimum_on_any_sample(optimal_run):
    _, results = optimal_run
    assert set(results["controller"]) == {OPTIMAL, "snac", "rnn", "svf", "dls"}
    optimum = results[results["controller"] == OPTIMAL].set_index(["task", "sample"])["cost"]
    for row in results.itertuples():
        assert row.cost >= optimum[(row.task, row.sample)], (row.task, row.controller, row.sample)
        assert row.ratio_to_optimal == pytest.approx(row.cost / optimum[(row.task, row.sample)])
    assert not results["below_optimal"].any()
    rows = results[results["controller"] == OPTIMAL]
    assert rows["optimal_converged"].all() and (rows["ratio_to_optimal"] == 1.0).all()


def test_optimal_rows_are_measured_like_every_controller(optimal_run):
    config, results = optimal_run
    for row in results[results["controller"] == OPTIMAL].itertuples():
        log = read_log(config.out / "trajectories" / row.task / OPTIMAL / f"sample_{row.sample:05d}.parquet")
        terms = trajectory_cost(log_array(log, "e"), log_array(log, "u"), log.attrs["dt"])
        assert float(terms.total) == pytest.approx(row.cost, rel=1e-12)
        assert row.cost == pytest.approx(row.optimal_solver_cost, rel=1e-9)  # the solver's own V agrees


def test_summary_reports_the_optimal_row_and_mean_ratios(optimal_run):
    config, results = optimal_run
    summary = pd.read_csv(config.out / "summary.csv").set_index("controller")
    assert OPTIMAL in summary.index and "effort" not in str(summary.loc[OPTIMAL].get("reach_effort_role", ""))
    for task in config.tasks:
        part = results[results["task"] == task].groupby("controller")["ratio_to_optimal"].mean()
        np.testing.assert_allclose(summary[f"{task}_ratio_to_optimal_mean"], part[summary.index], rtol=1e-9)
        assert (summary[f"{task}_below_optimal"] == 0).all()
    text = (config.out / "summary.md").read_text()
    assert "## Optimality gap" in text and "open-loop reference" in text
    assert "No controller that keeps the limits has a cost below the optimum on any sample." in text


def test_a_controller_below_the_optimum_is_reported(optimal_run):
    from snac_gym.evaluation.reports.summary import summarise
    from snac_gym.evaluation.reports.writer import optimality_markdown

    config, results = optimal_run
    tampered = results.copy()
    index = tampered.index[(tampered["controller"] == "snac") & (tampered["task"] == "reach")][0]
    tampered.loc[index, "below_optimal"] = True
    summary = summarise(tampered, [], config.tasks, list(dict.fromkeys(tampered["controller"])))
    text = "\n".join(optimality_markdown(summary, tampered, config.tasks))
    assert "**Warning: the optimum is not a lower bound everywhere.**" in text and "snac on 1 reach" in text
    # The same rollout crossing a joint limit is counted apart, with no warning: the optimum keeps the limits.
    tampered.loc[index, "joint_limit_margin"] = -0.1
    summary = summarise(tampered, [], config.tasks, list(dict.fromkeys(tampered["controller"])))
    assert summary.set_index("controller").loc[
        "snac", ["reach_below_optimal", "reach_below_optimal_crossing"]
    ].tolist() == [0, 1]
    assert "**Warning" not in "\n".join(optimality_markdown(summary, tampered, config.tasks))


def test_optimal_alone_and_not_with_pybullet(tmp_path: Path):
    results = run_evaluation(
        EvaluationConfig(
            out=tmp_path / "alone",
            tasks=("reach",),
            controllers=(OPTIMAL,),
            samples=1,
            horizons={"reach": 0.2},
            progress=False,
            plots=False,
        )
    )
    assert list(results["controller"]) == [OPTIMAL]
    with pytest.raises(ValueError, match="kinematic"):
        EvaluationConfig(out=tmp_path / "pb", controllers=(OPTIMAL,), engine="pybullet").validate()


CONVENTIONS = [CostConvention(), CostConvention("table1", "first"), CostConvention("hjb", q_scale=4.0)]


def _lbfgs_optimum(q0, x_d, kinematics, limits, convention=None):
    """An independent solve to check the Gauss-Newton one against: L-BFGS in z = Lᵀu (H₀ = LLᵀ),
    then the bounded polish if it breaks a limit. Returns (commands, V, converged, bounded)."""
    convention = convention if convention is not None else CostConvention()
    steps, m = x_d.shape[0], kinematics.n_joints
    lower = _preconditioner(steps, DT, convention.smoothness_weight, convention.udot_start)
    upper = np.zeros_like(lower)  # Lᵀ in solve_banded((0, 1), ...) form
    upper[0, 1:], upper[1] = lower[1, :-1], lower[0]

    def in_z(z):
        u = solve_banded((0, 1), upper, z.reshape(steps, m))  # u = L⁻ᵀ z
        value, grad = trajectory_cost_and_gradient(u, q0, x_d, kinematics, DT, convention)
        return value, solve_banded((1, 0), lower, grad).ravel()  # ∂V/∂z = L⁻¹ ∂V/∂u

    options = {"maxiter": MAX_ITERATIONS, "maxfun": 4 * MAX_ITERATIONS, "gtol": GTOL, "ftol": FTOL, "maxcor": 20}
    result = minimize(in_z, np.zeros(steps * m), jac=True, method="L-BFGS-B", options=options)
    commands, value = solve_banded((0, 1), upper, result.x.reshape(steps, m)), float(result.fun)
    bounded = bool((np.abs(commands) > limits).any())
    converged = result.status == 0
    if bounded:
        commands, value, _, _, _, converged = _bounded_polish(
            commands, q0, x_d, kinematics, DT, limits, GTOL, FTOL, MAX_ITERATIONS, convention
        )
    return commands, value, converged, bounded


@pytest.mark.parametrize("convention", CONVENTIONS, ids=["table1-rest", "table1-first", "hjb-q4"])
@pytest.mark.parametrize(("task", "steps"), [("reach", 1500), ("track", 500)])
def test_gauss_newton_finds_the_lbfgs_optimum(ur10, convention, task, steps):
    """The Gauss-Newton solve and an independent L-BFGS solve in z agree: the evaluator's reach
    horizon, and 4 s of tracking (the full 20 s make L-BFGS take 80 s here)."""
    samples = generate_samples(ur10, SampleSpace.for_robot(ur10), 0, task, [0, 2])
    x_d = reference_trajectories([s.reference for s in samples], np.arange(steps) * DT)[0]
    for sample, target in zip(samples, x_d, strict=True):
        _, lbfgs_cost, lbfgs_converged, _ = _lbfgs_optimum(sample.q0, target, ur10, ur10.velocity_limits, convention)
        newton = solve_sample(sample.q0, target, ur10, DT, ur10.velocity_limits, convention=convention)
        assert lbfgs_converged and newton.converged and not newton.bounded
        assert newton.cost == pytest.approx(lbfgs_cost, rel=GAP_RTOL)
        value, _ = trajectory_cost_and_gradient(newton.commands, sample.q0, target, ur10, DT, convention)
        assert value == newton.cost  # the reported V is the exact cost of the returned commands


def test_the_interior_point_and_lbfgs_b_agree_when_a_velocity_limit_binds(ur10, track_sample):
    steps = 100
    x_d = reference_trajectories([track_sample.reference], np.arange(steps) * DT)[0][0]
    free = solve_sample(track_sample.q0, x_d, ur10, DT, ur10.velocity_limits)
    limits = 0.5 * np.abs(free.commands).max(axis=0) + 1e-3
    newton = solve_sample(track_sample.q0, x_d, ur10, DT, limits)
    _, lbfgs_cost, lbfgs_converged, lbfgs_bounded = _lbfgs_optimum(track_sample.q0, x_d, ur10, limits)
    assert newton.bounded and lbfgs_bounded and newton.converged and lbfgs_converged
    assert (np.abs(newton.commands) <= limits + 1e-12).all()
    assert newton.cost == pytest.approx(lbfgs_cost, rel=1e-8)
    assert np.isnan(newton.gap_estimate)  # the interior point has no z-gap


def test_the_gauss_newton_band_holds_the_blocks_jk_t_jk_on_its_diagonal(rng):
    """``add_jacobian_blocks`` against a dense assembly: block k−1 of θ₁..θ_K gets scale·JₖᵀJₖ (k = 1..K−1), the last
    none."""
    from snac_gym.kernels.trajopt import add_jacobian_blocks

    steps, n, m, scale = 7, 3, 6, 0.037
    jacobians = rng.normal(size=(steps, n, m))
    base = rng.normal(size=(2 * m + 1, steps * m))
    band = np.array(base, order="F")
    add_jacobian_blocks(band, jacobians, scale)

    def dense(lower_band):
        matrix = np.zeros((steps * m, steps * m))
        for offset, row in enumerate(lower_band):
            columns = np.arange(steps * m - offset)
            matrix[columns + offset, columns] = row[: steps * m - offset]
        return matrix

    blocks = np.zeros((steps * m, steps * m))
    for k in range(1, steps):
        blocks[(k - 1) * m : k * m, (k - 1) * m : k * m] = scale * jacobians[k].T @ jacobians[k]
    np.testing.assert_allclose(dense(band) - dense(base), np.tril(blocks), rtol=0, atol=1e-14)
