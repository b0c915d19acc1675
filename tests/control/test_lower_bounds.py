"""snac_gym.control.lower_bounds.trajectory_cost_lower_bound: the scalar relaxation of the trajectory cost against the
Riccati value, an established QP solver and exact linear optima, its validity on the UR10, certified when the
solve is cut short, and how much tighter it is than regulation_cost_lower_bound (docs/lower-bounds.md)."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from snac_gym.evaluation.samples import generate_samples

from snac_gym.control import lower_bounds
from snac_gym.control.cost import CostConvention
from snac_gym.control.jacobian_bound import jacobian_norm_bound
from snac_gym.control.lower_bounds import (
    certified_cost_lower_bounds,
    following_cost_lower_bounds,
    jacobian_variation_bound,
    reachable_lipschitz_bounds,
    reference_steps,
    regulation_cost_lower_bound,
    solve_cost_relaxation,
    trajectory_cost_lower_bound,
    trajectory_cost_lower_bounds,
)
from snac_gym.control.trajopt import solve_sample, trajectory_cost_and_gradient
from snac_gym.model.kinematics import shared_kinematics
from snac_gym.rollout import reference_trajectories
from snac_gym.sampling import SampleSpace

DT = 1.0 / 125.0
CONVENTIONS = (
    CostConvention(),
    CostConvention("table1", "first"),
    CostConvention("hjb"),
    CostConvention("table1", "rest", 50.0),
    CostConvention("hjb", q_scale=1e4),
)


@pytest.fixture(scope="module")
def ur10():
    return shared_kinematics("ur10")


def relaxed_qp_optimum(r0, steps, dt, lipschitz, convention, limit):
    """The relaxed QP solved by IPOPT (casadi), exact bounds (``bound_relax_factor`` 0), tolerance 1e-12."""
    casadi = pytest.importorskip("casadi")
    K, w, q = len(steps) + 1, convention.smoothness_weight, convention.q_scale
    opti = casadi.Opti()
    v, r = opti.variable(K), opti.variable(K - 1)
    errors = casadi.vertcat(r0, r)
    cost = dt * q * casadi.sumsqr(errors) + dt * casadi.sumsqr(v) + w / dt * casadi.sumsqr(v[1:] - v[:-1])
    if convention.udot_start == "rest":
        cost += w / dt * v[0] ** 2
    opti.minimize(cost)
    opti.subject_to(r >= errors[:-1] - lipschitz * dt * v[:-1] - steps)
    if limit is not None:
        opti.subject_to(v <= limit)
    opti.solver(
        "ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes", "tol": 1e-12, "bound_relax_factor": 0.0}
    )
    return float(opti.solve().value(cost))


@pytest.mark.parametrize("steps", [1, 2, 50, 1500, 2500])
@pytest.mark.parametrize(("lipschitz", "q_scale", "dt"), [(2.52, 1.0, DT), (1.3, 4.0, 0.01), (0.7, 1e4, 0.002)])
def test_without_the_udot_term_limits_and_motion_it_is_the_riccati_bound(steps, lipschitz, q_scale, dt):
    errors = np.array([0.0, 1e-3, 0.3, 1.7])
    bounds = trajectory_cost_lower_bounds(
        errors, np.zeros(steps - 1), dt, lipschitz, CostConvention("hjb", q_scale=q_scale)
    )
    riccati = regulation_cost_lower_bound(errors, steps, dt, lipschitz, q_scale)
    assert bounds[0] == 0.0
    np.testing.assert_allclose(bounds[1:], riccati[1:], rtol=1e-8, atol=0)


@pytest.mark.parametrize("trial", range(20))
def test_it_is_the_optimum_of_the_relaxed_qp_as_ipopt_finds_it(trial):
    rng = np.random.default_rng(trial)
    K = int(rng.integers(20, 51))
    r0, lipschitz = rng.uniform(0.01, 1.0), rng.uniform(0.5, 3.0)
    steps = rng.uniform(0.0, 0.02, K - 1) if trial % 2 else np.zeros(K - 1)  # a moving reference on odd trials
    convention = CONVENTIONS[trial % len(CONVENTIONS)]
    # On a third of the trials the velocity limit binds: far below the unlimited solution's speeds.
    limit = (None, rng.uniform(0.5, 3.0), 0.05 + 0.1 * r0)[trial % 3]
    bound = trajectory_cost_lower_bound(r0, steps, DT, lipschitz, convention, limit)
    assert bound == pytest.approx(relaxed_qp_optimum(r0, steps, DT, lipschitz, convention, limit), rel=1e-6)


def test_the_velocity_limit_raises_the_bound_when_it_binds():
    free = trajectory_cost_lower_bound(0.5, np.zeros(99), DT, 2.0, CostConvention("hjb"))
    limited = trajectory_cost_lower_bound(0.5, np.zeros(99), DT, 2.0, CostConvention("hjb"), velocity_norm_limit=0.2)
    loose = trajectory_cost_lower_bound(0.5, np.zeros(99), DT, 2.0, CostConvention("hjb"), velocity_norm_limit=50.0)
    assert limited > 1.05 * free and loose == pytest.approx(free, rel=1e-9)


@pytest.mark.parametrize("iterations", [0, 1, 2, 4, 7])
@pytest.mark.parametrize("convention", CONVENTIONS[:3])
def test_a_solve_cut_short_still_reports_a_certified_bound(monkeypatch, iterations, convention):
    """The value reported is a dual value: below the relaxed optimum after any number of iterations, and the
    relaxed_upper diagnostic above it; both close in on it as the solve runs."""
    steps, limit = np.full(39, 0.004), 1.5
    exact = relaxed_qp_optimum(0.4, steps, DT, 2.0, convention, limit)
    monkeypatch.setattr(lower_bounds, "RELAXATION_MAX_ITERATIONS", iterations)
    cut = solve_cost_relaxation(0.4, steps, DT, 2.0, convention, limit)
    assert 0.0 < cut.bound[0] <= exact * (1 + 1e-9) and cut.relaxed_upper[0] >= exact * (1 - 1e-9)
    assert cut.iterations[0] <= 2 * iterations  # once without the limit, once with it


def linear_optimum(matrix, e0, steps, dt, convention):
    """The exact optimum of the trajectory cost for the linear kinematics f(θ) = Aθ (a fixed target), by least
    squares: eₖ = e₀ + ΔtA Σ_{j<k} uⱼ is linear in the commands, so V is ‖MU − y‖²."""
    n, m = matrix.shape
    w, q = convention.smoothness_weight, convention.q_scale
    rows, targets = [], []
    for k in range(steps):  # √(qΔt) e_k
        row = np.zeros((n, steps * m))
        for j in range(k):
            row[:, j * m : (j + 1) * m] = dt * matrix
        rows.append(np.sqrt(q * dt) * row)
        targets.append(-np.sqrt(q * dt) * e0)
    for k in range(steps):  # √Δt u_k and √(w/Δt)(u_k − u_{k−1})
        row = np.zeros((m, steps * m))
        row[:, k * m : (k + 1) * m] = np.sqrt(dt) * np.eye(m)
        rows.append(row)
        targets.append(np.zeros(m))
        if w and (k > 0 or convention.udot_start == "rest"):
            jump = np.zeros((m, steps * m))
            jump[:, k * m : (k + 1) * m] = np.sqrt(w / dt) * np.eye(m)
            if k > 0:
                jump[:, (k - 1) * m : k * m] = -np.sqrt(w / dt) * np.eye(m)
            rows.append(jump)
            targets.append(np.zeros(m))
    M, y = np.vstack(rows), np.concatenate(targets)
    solution = np.linalg.solve(M.T @ M, M.T @ y)  # V is stationary there: its value is exact to second order
    return float(np.sum((M @ solution - y) ** 2))


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_on_a_linear_arm_it_is_the_exact_optimum_when_nothing_is_relaxed(convention):
    """f(θ) = Aθ with e₀ along A's top left singular vector: the best commands are along the top right one, where
    ‖Ju‖ = σ_max‖u‖, ‖uₖ − uₖ₋₁‖ = |vₖ − vₖ₋₁| and every relaxation step is an equality as long as the error has
    not reached 0 (40 steps: it has not), so the bound is the optimum. An index slip (e vs θ, the first jump, the
    last command) would show here."""
    rng = np.random.default_rng(4)
    matrix = rng.normal(size=(3, 5))
    left, singular, _ = np.linalg.svd(matrix)
    steps = 40
    optimum = linear_optimum(matrix, 0.3 * left[:, 0], steps, DT, convention)
    bound = trajectory_cost_lower_bound(0.3, np.zeros(steps - 1), DT, singular[0], convention)
    assert bound == pytest.approx(optimum, rel=1e-8)
    # Any other direction of e₀ is slower to remove: the bound (which only knows σ_max) stays below.
    assert bound < linear_optimum(matrix, 0.3 * left[:, 2], steps, DT, convention)


@pytest.mark.parametrize("convention", CONVENTIONS[:2])
def test_on_a_linear_arm_the_udot_term_makes_it_a_strict_bound_once_the_error_is_gone(convention):
    """Over 2 s the relaxed error reaches 0 while the command still ramps down (the relaxation may stop the error
    there, r ≥ 0 by the max); the arm overshoots instead, so its optimum is above the bound."""
    rng = np.random.default_rng(4)
    matrix = rng.normal(size=(3, 4))
    left, singular, _ = np.linalg.svd(matrix)
    optimum = linear_optimum(matrix, 0.3 * left[:, 0], 250, DT, convention)
    bound = trajectory_cost_lower_bound(0.3, np.zeros(249), DT, singular[0], convention)
    assert 0.95 * optimum < bound < (1 - 1e-3) * optimum


def sample_problem(ur10, task, index, steps):
    sample = generate_samples(ur10, SampleSpace.for_robot(ur10), 0, task, [index])[0]
    x_d = reference_trajectories([sample.reference], np.arange(steps) * DT)[0][0]
    return np.asarray(sample.q0, dtype=float), x_d


def certified_bound(ur10, q0, x_d, convention, limited=True):
    r0 = float(np.linalg.norm(ur10.forward(q0) - x_d[0]))
    limit = float(np.linalg.norm(ur10.velocity_limits)) if limited else None
    return trajectory_cost_lower_bound(r0, reference_steps(x_d), DT, jacobian_norm_bound(ur10), convention, limit)


def random_commands(rng, steps, limits, kind):
    """Smooth random commands (a random walk in their own units), fast ones held near the limits, or bang-bang."""
    if kind == "smooth":
        return np.cumsum(rng.normal(scale=0.05, size=(steps, len(limits))), axis=0) * limits / 3.0
    if kind == "near-limits":
        return limits * np.clip(
            rng.choice([-1.0, 1.0], size=len(limits)) * rng.uniform(0.9, 1.0, (steps, len(limits))), -1, 1
        )
    return limits * rng.choice([-1.0, 1.0], size=(steps, len(limits)))


@pytest.mark.parametrize("task", ["reach", "track"])
@pytest.mark.parametrize("convention", CONVENTIONS)
def test_it_is_below_the_cost_of_random_commands_on_the_ur10(ur10, task, convention):
    """Also with the per-sample Lipschitz bounds, for any cost limit V̄ (min(B(V̄), V̄) holds for every trajectory),
    the commands' own cost among them, and with the bisection towards B(V̄) = V̄."""
    rng = np.random.default_rng(11)
    limits = ur10.velocity_limits
    for draw in range(12):
        steps = int(rng.integers(2, 200))
        q0, x_d = sample_problem(ur10, task, draw, steps)
        commands = random_commands(rng, steps, limits, ("smooth", "near-limits", "bang-bang")[draw % 3])
        commands *= rng.uniform(0.0, 1.0) if draw % 4 == 0 else 1.0  # also slow ones, whose cost is mostly error
        assert np.all(np.abs(commands) <= limits)
        cost = trajectory_cost_and_gradient(commands, q0, x_d, ur10, DT, convention)[0]
        assert certified_bound(ur10, q0, x_d, convention) <= cost
        limit = cost * np.array([0.01, 0.3, 1.0, 1.0 + 1e-9, 3.0, 1e3])
        tighter = certified_cost_lower_bounds(ur10, np.tile(q0, (6, 1)), x_d, DT, convention, limits, limit, draw % 3)
        assert np.all(tighter <= cost)
        assert certified_cost_lower_bounds(ur10, q0, x_d, DT, convention, limits, refinements=2)[0] <= cost


@pytest.mark.parametrize("task", ["reach", "track"])
@pytest.mark.parametrize("convention", CONVENTIONS[:3])
def test_it_is_below_the_numerical_optimum_on_ur10_samples(ur10, task, convention):
    """The tightest trajectories there are: the evaluator's optimum of each sample (shortened to 3 s). With the
    optimum's cost as V̄ the per-sample Lipschitz bounds raise the bound, and the bisection raises it further."""
    limits = ur10.velocity_limits
    for index in range(3):
        q0, x_d = sample_problem(ur10, task, index, 375)
        optimum = solve_sample(q0, x_d, ur10, DT, limits, convention=convention).cost
        bound = certified_bound(ur10, q0, x_d, convention)
        assert 0.1 * optimum < bound <= optimum
        following = following_cost_lower_bounds(
            ur10.forward(q0)[None], x_d[None], DT, jacobian_norm_bound(ur10), convention.q_scale
        )[0]
        assert following <= optimum  # each relaxation holds; the entry point takes the larger
        entry = certified_cost_lower_bounds(ur10, q0, x_d, DT, convention, limits)[0]
        assert entry == pytest.approx(max(bound, following), rel=1e-12)
        bound = entry
        reachable = certified_cost_lower_bounds(ur10, q0, x_d, DT, convention, limits, optimum)[0]
        refined = certified_cost_lower_bounds(ur10, q0, x_d, DT, convention, limits, optimum, refinements=3)[0]
        assert bound < reachable <= refined <= optimum


@pytest.mark.parametrize("robot", ["ur10", "ur5", "panda"])
def test_the_jacobian_moves_no_faster_than_its_variation_bound(robot):
    """σ_max(J) changes by at most M‖Δθ‖, and J itself too when the first joint stays (σ_max ignores it)."""
    kinematics = shared_kinematics(robot)
    bound = jacobian_variation_bound(kinematics)
    rng = np.random.default_rng(2)
    q = rng.uniform(-np.pi, np.pi, (4000, kinematics.n_joints))
    step = rng.normal(size=q.shape) * rng.uniform(1e-3, 2.0, (len(q), 1))
    turned = q + step
    rates = np.abs(
        np.linalg.norm(kinematics.jacobian_batch(turned), ord=2, axis=(1, 2))
        - np.linalg.norm(kinematics.jacobian_batch(q), ord=2, axis=(1, 2))
    ) / np.linalg.norm(step, axis=1)
    step[:, 0] = 0.0
    moved = np.linalg.norm(kinematics.jacobian_batch(q + step) - kinematics.jacobian_batch(q), ord=2, axis=(1, 2))
    rates = np.maximum(rates, moved / np.linalg.norm(step, axis=1))
    assert rates.max() <= bound < 3.0 * rates.max()  # certified, and not vacuous


def test_reachable_lipschitz_bounds_cover_the_jacobian_along_trajectories_of_bounded_cost(ur10):
    rng = np.random.default_rng(5)
    limits, convention = ur10.velocity_limits, CostConvention()
    for draw in range(12):
        steps = 300
        q0, x_d = sample_problem(ur10, "reach", draw, steps)
        commands = random_commands(rng, steps, limits, ("smooth", "near-limits", "bang-bang")[draw % 3])
        commands *= rng.uniform(0.05, 1.0)
        cost = trajectory_cost_and_gradient(commands, q0, x_d, ur10, DT, convention)[0]
        bounds = reachable_lipschitz_bounds(ur10, q0, steps, DT, cost, limits if draw % 2 else None)[0]
        angles = q0 + DT * np.vstack([np.zeros(6), np.cumsum(commands, axis=0)])  # θ₀..θ_K
        for fraction in (0.0, 0.5, 1.0):  # each step's segment: its ends and its middle
            points = angles[:-2] + fraction * (angles[1:-1] - angles[:-2])
            assert np.all(np.linalg.norm(ur10.jacobian_batch(points), ord=2, axis=(1, 2)) <= bounds)


@functools.lru_cache(maxsize=None)
def controller_rollouts(task, controller):
    from snac_gym.evaluation.execution.jobs import policy_context

    from snac_gym.policies.registry import make_policy
    from snac_gym.rollout import simulate_kinematic

    context = policy_context("ur10", DT, task)
    samples = generate_samples(context.kinematics, SampleSpace.for_robot(context.kinematics), 0, task, range(3))
    make = functools.partial(make_policy, controller, context)
    return samples, simulate_kinematic(context, make, samples, 500, [0, 1, 2], True, controller)


@pytest.mark.parametrize("task", ["reach", "track"])
@pytest.mark.parametrize("controller", ["lqr", "dls", "svf"])
def test_it_is_below_the_cost_of_the_project_controllers(ur10, task, controller):
    from snac_gym.metrics import rollout_metrics

    samples, rollouts = controller_rollouts(task, controller)
    assert np.all(np.abs(rollouts.commands) <= ur10.velocity_limits * (1 + 1e-12))
    x_d = reference_trajectories([s.reference for s in samples], np.arange(500) * DT)[0]
    for convention in CONVENTIONS[:3]:
        costs = rollout_metrics(rollouts, task, ur10.velocity_limits, convention)["cost"].to_numpy()
        limit = float(np.linalg.norm(ur10.velocity_limits))
        bounds = trajectory_cost_lower_bounds(np.linalg.norm(rollouts.errors[:, 0], axis=-1), reference_steps(x_d), DT,
                                              jacobian_norm_bound(ur10), convention, limit)  # fmt: skip
        assert np.all(bounds > 0) and np.all(bounds <= costs)


def test_the_reachable_lipschitz_bounds_tighten_the_table1_bound_on_a_reach_sample(ur10):
    """Reach sample 0, 12 s, Table I's cost: the optimum is 1.935x the bound with the shipped global L, 1.926x the
    bound with the optimum's cost as V̄, and 1.910x after four bisection steps (with the summed link lengths as the
    global L: 2.57x, 2.22x, 2.04x; docs/lower-bounds.md)."""
    q0, x_d = sample_problem(ur10, "reach", 0, 1500)
    limits = ur10.velocity_limits
    optimum = solve_sample(q0, x_d, ur10, DT, limits).cost
    bounds = [certified_cost_lower_bounds(ur10, q0, x_d, DT, CostConvention(), limits, limit, refinements)[0]
              for limit, refinements in ((None, 0), (optimum, 0), (optimum, 4))]  # fmt: skip
    assert bounds[0] < bounds[1] < bounds[2]
    np.testing.assert_allclose(optimum / np.array(bounds), [1.935, 1.926, 1.910], atol=0.002)


def test_under_table1_cost_it_is_far_above_the_regulation_bound(ur10):
    """Reach sample 0 over the evaluator's 12 s: the u̇ term (from rest) that regulation_cost_lower_bound
    leaves out doubles the bound (2.02x; docs/lower-bounds.md)."""
    q0, x_d = sample_problem(ur10, "reach", 0, 1500)
    r0 = float(np.linalg.norm(ur10.forward(q0) - x_d[0]))
    regulation = float(regulation_cost_lower_bound(r0, 1500, DT, jacobian_norm_bound(ur10)))
    bound = certified_bound(ur10, q0, x_d, CostConvention())
    assert bound / regulation == pytest.approx(2.02, abs=0.01)


def test_batches_are_the_single_calls_and_inputs_are_checked():
    rng = np.random.default_rng(3)
    errors, steps = rng.uniform(0, 1, 5), rng.uniform(0, 0.01, (5, 30))
    slopes = rng.uniform(1, 3, 30)
    batch = trajectory_cost_lower_bounds(errors, steps, DT, slopes, CostConvention(), 2.0)
    single = [
        trajectory_cost_lower_bound(e, s, DT, slopes, CostConvention(), 2.0) for e, s in zip(errors, steps, strict=True)
    ]
    np.testing.assert_array_equal(batch, single)
    # One step: the first error is all that is paid.
    assert trajectory_cost_lower_bound(0.5, np.zeros(0), 0.01, 3.0, CostConvention(q_scale=2.0)) == pytest.approx(
        2.0 * 0.01 * 0.25
    )
    assert trajectory_cost_lower_bound(0.0, np.full(9, 0.01), DT, 2.0) == 0.0  # on the reference, which comes by itself
    for bad in ({"initial_error": -1.0}, {"reference_steps": np.full(9, np.nan)}, {"lipschitz": 0.0}, {"dt": 0.0},
                {"velocity_norm_limit": 0.0}):  # fmt: skip
        arguments = {"initial_error": 0.1, "reference_steps": np.zeros(9), "dt": DT, "lipschitz": 2.0} | bad
        with pytest.raises(ValueError):
            trajectory_cost_lower_bound(**arguments)


def test_the_following_bound_is_the_exact_optimum_of_an_isotropic_linear_arm():
    """f(θ) = L·Rθ (R a rotation: every direction moves at gain L, each relaxation step an equality), the HJB
    cost: the point-path problem is the arm's, so the bound is the optimum itself, solved here as one dense
    least-squares problem in the commands (an independent computation)."""
    rng = np.random.default_rng(4)
    gain, q, steps, dt = 0.8, 4.0, 40, 0.05
    rotation, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    theta0 = rng.normal(size=3)
    times = np.arange(steps) * dt
    x_d = np.stack([0.3 * np.cos(times), 0.3 * np.sin(times), 0.1 * times], axis=1) + 0.2
    # θₖ = θ₀ + Δt Σ_{j<k} uⱼ; cost Σ_k q‖L R θₖ − x_k‖²Δt + Σ_k ‖uₖ‖²Δt (k = 0..K−1; u_{K−1} is effort only)
    lower = np.tril(np.ones((steps, steps)), -1) * dt  # θₖ − θ₀ = Σ_j lower[k, j] uⱼ, per axis
    A = np.kron(lower, gain * rotation)  # (3K, 3K): the stacked errors' dependence on the stacked commands
    b = (x_d - gain * rotation @ theta0).ravel()
    system = np.vstack([np.sqrt(q * dt) * A, np.sqrt(dt) * np.eye(3 * steps)])
    target = np.concatenate([np.sqrt(q * dt) * b, np.zeros(3 * steps)])
    commands = np.linalg.lstsq(system, target, rcond=None)[0]
    optimum = float(np.sum((system @ commands - target) ** 2))
    bound = following_cost_lower_bounds((gain * rotation @ theta0)[None], x_d[None], dt, gain, q)[0]
    assert bound == pytest.approx(optimum, rel=1e-9)


def test_the_following_bound_sees_the_motion_the_scalar_one_gives_for_free(ur10):
    """A track sample whose ellipse starts at the tool: the scalar relaxation lets the reference carry itself
    along (its bound is near 0), the following one prices keeping up with it."""
    q0, x_d = sample_problem(ur10, "track", 0, 375)
    x_d = x_d - x_d[0] + ur10.forward(q0)  # the ellipse starts at the tool: e₀ = 0
    convention = CostConvention("hjb", "rest", 4.0)
    scalar = certified_bound(ur10, q0, x_d, convention)
    following = following_cost_lower_bounds(ur10.forward(q0)[None], x_d[None], DT, jacobian_norm_bound(ur10), 4.0)
    optimum = solve_sample(q0, x_d, ur10, DT, ur10.velocity_limits, convention=convention).cost
    assert scalar < 1e-3 * optimum < following[0] <= optimum
