"""The optimality reference holds everywhere: the multi-start optimum, its certified lower bound, and
the ``workspace`` sample space that reaches outside Table I's cuboid (where a single start from rest
was beaten by feedback controllers)."""

from __future__ import annotations

import functools

import numpy as np
import pandas as pd
import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.reference import multistart, optimum
from snac_gym.evaluation.reference.branches import BRANCH_PREFIX, RANDOM_PREFIX
from snac_gym.evaluation.reference.multistart import COARSE_FACTOR, coarse_commands
from snac_gym.evaluation.reference.optimum import (
    OWN_STARTS,
    REST_START,
    multi_start_solve,
    own_start_commands,
    solve_samples,
)
from snac_gym.evaluation.samples import generate_samples

from snac_gym.control.cost import CostConvention
from snac_gym.control.lower_bounds import regulation_cost_lower_bound
from snac_gym.control.trajopt import solve_sample, trajectory_cost_and_gradient
from snac_gym.model.kinematics import Kinematics
from snac_gym.policies.registry import make_policy
from snac_gym.rollout import reference_trajectories, simulate_kinematic
from snac_gym.sampling import SampleSpace

DT = 1.0 / 125.0
HJB = CostConvention("hjb", "rest", 4.0)
TABLE1 = CostConvention()


@pytest.fixture(scope="module")
def ur10() -> Kinematics:
    return Kinematics("ur10")


def test_the_multi_start_optimum_is_below_the_single_start_on_a_workspace_sample(ur10):
    # Workspace reach sample 4 of seed 7 over 5 s under the HJB cost (q = 4): Gauss-Newton from rest
    # ends in a local optimum 62 % above the one it reaches from lqr's trajectory.
    steps, context = 625, policy_context("ur10", DT, "reach")
    sample = generate_samples(ur10, SampleSpace.workspace(ur10), 7, "reach", [4])[0]
    make = functools.partial(make_policy, "lqr", context, q_scale=1.0)
    lqr = simulate_kinematic(context, make, [sample], steps, [0], True, "lqr").commands[0]
    x_d = reference_trajectories([sample.reference], np.arange(steps) * DT, 3)[0][0]
    q0, limits = np.asarray(sample.q0), ur10.velocity_limits
    single = solve_sample(q0, x_d, ur10, DT, limits, convention=HJB)
    multi = multi_start_solve(q0, x_d, ur10, DT, limits, HJB, {"lqr": coarse_commands(lqr, COARSE_FACTOR)})
    assert single.converged  # a local optimum, not a failed solve
    assert multi.winner == "lqr" and multi.starts == 2
    assert multi.solution.cost < 0.7 * single.cost
    assert multi.spread == pytest.approx(single.cost / multi.solution.cost - 1.0)
    lqr_cost = trajectory_cost_and_gradient(lqr, q0, x_d, ur10, DT, HJB)[0]
    assert multi.solution.cost <= lqr_cost  # a descent from lqr's trajectory ends at most at its cost
    # No start is solved when no controller comes near the optimum from rest.
    far = multi_start_solve(
        q0, x_d, ur10, DT, limits, HJB, {"idle": np.zeros_like(coarse_commands(lqr, COARSE_FACTOR))}
    )
    assert far.winner == REST_START and far.starts == 1 and far.spread == 0.0


def test_a_start_off_the_coarse_grid_is_refused_naming_it(ur10):
    sample = generate_samples(ur10, SampleSpace.workspace(ur10), 7, "reach", [0])[0]
    steps = 250
    x_d = reference_trajectories([sample.reference], np.arange(steps) * DT, 3)[0][0]
    q0, limits = np.asarray(sample.q0), ur10.velocity_limits
    with pytest.raises(
        ValueError, match=r"start 'full': commands of shape \(250, 6\), expected the coarse grid's \(25, 6\)"
    ):
        multi_start_solve(q0, x_d, ur10, DT, limits, HJB, {"full": np.zeros((steps, 6))})


@pytest.mark.parametrize(("seed", "index"), [(13, 4), (7, 0), (7, 3)])
def test_the_starts_on_the_coarse_grid_find_the_optimum_the_full_grid_rollouts_find(ur10, seed, index):
    # Workspace reach samples, HJB cost, 5 s, where an own start beats the solve from rest (lqr on (13, 4), joint-goal
    # and, when it was a start, dls on (7, 0) and (7, 3) with every start on the full grid). Before, every own start was
    # rolled out on the full grid and block-averaged; now joint-goal (GRID_FREE_STARTS) is rolled out on the coarse
    # grid. On (13, 4) lqr's full-grid rollout crosses to the other elbow branch, 13 % below rest, and its coarse
    # rollouts do not: were lqr rolled out coarse, that optimum would be lost and this test would fail.
    steps, context = 625, policy_context("ur10", DT, "reach")
    sample = generate_samples(ur10, SampleSpace.workspace(ur10), seed, "reach", [index])
    x_d = reference_trajectories([sample[0].reference], np.arange(steps) * DT, 3)[0][0]
    q0, limits, box = np.asarray(sample[0].q0), ur10.velocity_limits, (ur10.lower_limits, ur10.upper_limits)
    full = own_start_commands(context, sample, steps, [0])[0]
    averaged = {name: coarse_commands(u, COARSE_FACTOR) for name, u in full.items()}
    before = multi_start_solve(q0, x_d, ur10, DT, limits, HJB, averaged, position_limits=box)
    coarse = own_start_commands(context, sample, steps, [0], factor=COARSE_FACTOR)[0]
    assert {name: u.shape for name, u in coarse.items()} == {name: (-(-steps // COARSE_FACTOR), 6) for name in full}
    now = multi_start_solve(q0, x_d, ur10, DT, limits, HJB, coarse, position_limits=box)
    rest = multi_start_solve(q0, x_d, ur10, DT, limits, HJB, {}, position_limits=box)
    assert before.winner == now.winner != REST_START and now.solution.cost < 0.99 * rest.solution.cost
    assert now.solution.cost == pytest.approx(before.solution.cost, rel=1e-8)


@pytest.mark.parametrize(("seed", "index", "cost", "horizon"), [(823, 57, HJB, 5.0), (841, 12, TABLE1, 20.0)])
def test_the_optimum_dls_won_is_reached_without_it(ur10, monkeypatch, seed, index, cost, horizon):
    # Workspace track samples of the ablation that dropped dls from OWN_STARTS (docs/optimal.md, "Two feedback starts,
    # not three"): the only two of 1000 fresh samples that dls won. Without it another start ends in the same optimum.
    steps, context = round(horizon / DT), policy_context("ur10", DT, "track")
    sample = generate_samples(ur10, SampleSpace.workspace(ur10), seed, "track", [index])
    x_d = reference_trajectories([sample[0].reference], np.arange(steps) * DT, 3)[0]
    now = solve_samples(context, sample, [0], x_d, DT, cost)[0]
    monkeypatch.setattr(optimum, "OWN_STARTS", (OWN_STARTS[0], ("dls", {}), *OWN_STARTS[1:]))  # the set before
    before = solve_samples(context, sample, [0], x_d, DT, cost)[0]
    assert before.winner == "dls" != now.winner
    assert now.solution.cost == pytest.approx(before.solution.cost, rel=1e-10)


def test_a_start_that_reaches_a_coarse_optimum_an_earlier_start_found_is_not_solved_again(ur10, monkeypatch):
    # Workspace reach sample 3 of seed 7 (HJB, 5 s): lqr's start leaves the solve from rest's basin for a cheaper one.
    # A second start with lqr's very commands descends the same way; its solve on the coarse grid stops where it
    # meets lqr's coarse optimum, and it is counted in that basin, instead of being solved to the end a second time.
    steps, context = 625, policy_context("ur10", DT, "reach")
    sample = generate_samples(ur10, SampleSpace.workspace(ur10), 7, "reach", [3])
    x_d = reference_trajectories([sample[0].reference], np.arange(steps) * DT, 3)[0][0]
    q0, limits, box = np.asarray(sample[0].q0), ur10.velocity_limits, (ur10.lower_limits, ur10.upper_limits)
    lqr = own_start_commands(context, sample, steps, [0], factor=COARSE_FACTOR)[0]["lqr"]
    alone = multi_start_solve(q0, x_d, ur10, DT, limits, HJB, {"lqr": lqr}, position_limits=box)
    solves = []

    def counted(*args, **kwargs):
        solves.append(solve_sample(*args, **kwargs))
        return solves[-1]

    monkeypatch.setattr(multistart, "solve_sample", counted)
    twice = multi_start_solve(q0, x_d, ur10, DT, limits, HJB, {"lqr": lqr, "copy": lqr.copy()}, position_limits=box)
    assert alone.winner == twice.winner == "lqr" and twice.solution.cost == alone.solution.cost
    assert twice.same_basin == alone.same_basin + 1
    coarse = [s for s in solves if len(s.commands) == len(x_d[::COARSE_FACTOR])]  # from rest, lqr, the copy, ...
    original, copy = coarse[1:3]
    assert original.converged and not copy.converged and copy.iterations < original.iterations / 2


def _workspace_config(out, controllers, reference_limits="joints") -> EvaluationConfig:
    """Fresh workspace samples (a seed no test or default uses), the HJB cost, controllers at their own
    settings: on 4 of these 16 samples the joint position limits bind the optimum. No reference cache: each
    run solves its own reference, so that two runs agreeing is a finding, not a lookup."""
    return EvaluationConfig(
        out=out, samples=8, seed=2024, workers=1, controllers=controllers, horizons={"reach": 4.0, "track": 4.0},
        match_effort=False, progress=False, cost="hjb", q_scale=4.0, plots=False, reference_limits=reference_limits,
        reference_cache=False,
        controller_kwargs={"lqr": {"q_scale": 1.0}} if "lqr" in controllers else {},
        space=SampleSpace.workspace(Kinematics("ur10")),
    )  # fmt: skip


@pytest.fixture(scope="module")
def workspace_run(tmp_path_factory) -> pd.DataFrame:
    out = tmp_path_factory.mktemp("workspace") / "run"
    return run_evaluation(_workspace_config(out, ("lqr", "snac-hjb", "dls", "rnn", "optimal")))


@pytest.fixture(scope="module")
def velocity_only(tmp_path_factory) -> pd.DataFrame:
    """The same samples' reference with the velocity limits only (``--reference-limits velocity``)."""
    out = tmp_path_factory.mktemp("velocity") / "run"
    rows = run_evaluation(_workspace_config(out, ("optimal",), reference_limits="velocity")).set_index(
        ["task", "sample"]
    )
    rows.attrs["summary"] = (out / "summary.md").read_text()
    return rows


def _reference(rows: pd.DataFrame, of: pd.DataFrame) -> np.ndarray:
    optimum = rows[rows.controller == "optimal"].set_index(["task", "sample"])["cost"]
    return optimum.reindex(pd.MultiIndex.from_frame(of[["task", "sample"]])).to_numpy()


def test_no_controller_inside_the_limits_is_below_the_reference(workspace_run):
    others = workspace_run[workspace_run.controller != "optimal"]
    inside = others[others["joint_limit_margin"] >= 0.0]
    assert len(inside) >= 40  # most rollouts keep the limits: the test compares something
    assert np.all(inside["cost"].to_numpy() >= _reference(workspace_run, inside) * (1 - 1e-9))
    rows = workspace_run[workspace_run.controller == "optimal"]
    assert (rows["optimal_starts"] >= 1).all() and rows["optimal_local_spread"].ge(0).all()
    starts = {REST_START, *(name for name, _ in OWN_STARTS)}
    assert all(w in starts or any(w.startswith(p) and w[len(p):].isdigit() for p in (BRANCH_PREFIX, RANDOM_PREFIX))
               for w in rows["optimal_winner"])  # fmt: skip


def test_the_reference_keeps_every_limit_and_the_limits_bind(workspace_run, velocity_only):
    rows = workspace_run[workspace_run.controller == "optimal"]
    assert (rows["joint_limit_margin"] >= 0.0).all() and (rows["peak_limit_fraction"] <= 1.0).all()
    binding = rows["joint_limit_margin"] < 1e-6
    assert binding.sum() >= 4  # the limits are active constraints here, not idle ones
    assert rows["optimal_converged"].all()
    # Without the position limits the optimum crosses them wherever they bind, and costs less there. (Not only
    # there: where the free optimum crosses a limit, the limited one may lie on another branch, inside them.)
    free = velocity_only.reindex(pd.MultiIndex.from_frame(rows[["task", "sample"]]))
    crossed = free["joint_limit_margin"].to_numpy() < 0.0
    assert crossed[binding.to_numpy()].all()
    assert np.all(free["cost"].to_numpy()[crossed] < rows["cost"].to_numpy()[crossed])
    assert np.all(free["cost"].to_numpy() <= rows["cost"].to_numpy() * (1 + 1e-9))
    assert set(free["optimal_limits"]) == {"velocity"} and set(rows["optimal_limits"]) == {"joints"}
    assert "Optimal, joint position limits ignored" in velocity_only.attrs["summary"]


def test_controllers_that_cross_a_limit_are_above_the_velocity_only_reference(workspace_run, velocity_only):
    others = workspace_run[workspace_run.controller != "optimal"]
    outside = others[others["joint_limit_margin"] < 0.0]
    assert len(outside) >= 4  # some rollouts of these samples pass a limit: they are counted apart
    free = velocity_only.reindex(pd.MultiIndex.from_frame(outside[["task", "sample"]]))["cost"].to_numpy()
    assert np.all(outside["cost"].to_numpy() >= free * (1 - 1e-9))
    assert (outside["cost"].to_numpy() < _reference(workspace_run, outside)).any()  # why they are counted apart


def test_the_reference_is_the_same_whatever_the_contestants(workspace_run, tmp_path):
    other = run_evaluation(_workspace_config(tmp_path / "run", ("dls", "optimal")))
    columns = [c for c in workspace_run.columns if c != "optimal_solve_time"]  # wall time differs run to run
    mine = workspace_run.loc[workspace_run.controller == "optimal", columns].reset_index(drop=True)
    theirs = other.loc[other.controller == "optimal", columns].reset_index(drop=True)
    pd.testing.assert_frame_equal(mine, theirs, check_exact=True)


def test_the_certified_lower_bound_is_below_every_cost_reach_and_track(workspace_run, velocity_only):
    """Every rollout, the reference's, every controller's (those that cross a limit too) and the
    velocity-only reference's, costs at least the bound: it holds for any sequence within ū."""
    bound = workspace_run[workspace_run.controller == "optimal"].set_index(["task", "sample"])["optimal_lower_bound"]
    assert bound.notna().all() and (bound > 0).all()
    keys = pd.MultiIndex.from_frame(workspace_run[["task", "sample"]])
    assert np.all(workspace_run["cost"].to_numpy() >= bound.reindex(keys).to_numpy())
    assert np.all(velocity_only["cost"].to_numpy() >= bound.reindex(velocity_only.index).to_numpy())
    assert np.all(velocity_only["cost"].to_numpy() >= velocity_only["optimal_lower_bound"].to_numpy())


def test_the_lower_bound_is_the_scalar_riccati_value_and_tends_to_the_continuous_one():
    # Continuous-time limit of the relaxed scalar LQR (ṙ = −Lv, cost q r² + v²): V = √q r₀² / L.
    assert regulation_cost_lower_bound(0.3, 200_000, 1e-4, 2.0, 4.0) == pytest.approx(
        np.sqrt(4.0) * 0.09 / 2.0, rel=1e-3
    )
    # One step: only the first error is paid for, P₀ = qΔt.
    assert regulation_cost_lower_bound(0.5, 1, 0.01, 3.0, 2.0) == pytest.approx(2.0 * 0.01 * 0.25)
    with pytest.raises(ValueError, match="lipschitz > 0"):
        regulation_cost_lower_bound(0.1, 10, 0.01, 0.0)


@pytest.mark.parametrize("robot", ["ur10", "ur5", "panda"])
def test_the_lipschitz_bound_covers_the_jacobian_everywhere(robot):
    kinematics = Kinematics(robot)
    bound = kinematics.position_lipschitz_bound()
    rng = np.random.default_rng(5)
    largest = max(kinematics.singular_values(rng.uniform(kinematics.lower_limits, kinematics.upper_limits))[0]
                  for _ in range(2000))  # fmt: skip
    assert largest <= bound < 2.5 * largest  # certified, and not vacuous
    q, step = rng.uniform(-1, 1, kinematics.n_joints), rng.normal(size=kinematics.n_joints)
    assert np.linalg.norm(kinematics.forward(q + step) - kinematics.forward(q)) <= bound * np.linalg.norm(step)


def test_workspace_samples_cover_the_reach_outside_the_cuboid(ur10):
    space, cuboid = SampleSpace.workspace(ur10), SampleSpace.for_robot(ur10)
    samples = generate_samples(ur10, space, 3, "reach", range(200))
    targets = np.array([s.reference.target for s in samples])
    starts = np.array([ur10.forward(np.asarray(s.q0)) for s in samples])
    for points in (targets, starts):
        assert (points[:, 0] > 0.2).any() and (points[:, 0] < -0.2).any()  # both sides of the base
        assert (points[:, 2] < cuboid.low[2]).any() and (points[:, 2] > cuboid.high[2]).any()  # lower and higher
        assert np.mean([cuboid.contains(p) for p in points]) < 0.3
        assert all(space.contains(p) for p in points)
    for sample in samples:
        q = np.asarray(sample.q0)
        assert ur10.singular_values(q)[-1] >= space.min_singular_value
        assert np.all(q >= ur10.lower_limits + space.joint_margin) and np.all(
            q <= ur10.upper_limits - space.joint_margin
        )
    ellipses = generate_samples(ur10, space, 3, "track", range(20))
    speeds = [abs(s.reference.angular_speed) for s in ellipses]
    assert max(speeds) <= 0.4 and any(abs(s.reference.centre[0]) > 0.2 and s.reference.centre[0] > 0 for s in ellipses)
