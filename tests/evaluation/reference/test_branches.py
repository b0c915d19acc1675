"""The reference's starts on the other IK branches (evaluation/reference/branches.py): the goals, the starts, what
is dropped before a solve, the coarse screen (evaluation/reference/optimum.py), and held-out samples where every
other start descended to a dearer optimum."""

from __future__ import annotations

import numpy as np
import pytest
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.reference.branches import (
    BRANCH_SEPARATION,
    LIMIT_STOP_RESIDUAL,
    NEAR_SINGULAR,
    branch_commands,
    branch_goals,
    needs_branches,
    worth_trying,
)
from snac_gym.evaluation.reference.optimum import check_reference_row, coarse_commands, solve_samples
from snac_gym.evaluation.samples import generate_samples

from snac_gym.control.cost import CostConvention
from snac_gym.control.trajopt import angles
from snac_gym.model.joint_goal import GOAL_MARGIN, nearest_goals
from snac_gym.model.kinematics import shared_kinematics
from snac_gym.rollout import reference_trajectories
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import get_task

DT = 1.0 / 125.0


@pytest.fixture(scope="module")
def ur10():
    return shared_kinematics("ur10")


def _workspace(kinematics, task, seed, indices, steps=None):
    samples = generate_samples(kinematics, SampleSpace.workspace(kinematics), seed, task, indices)
    steps = steps or round(get_task(task).horizon_s / DT)
    x_d = reference_trajectories([s.reference for s in samples], np.arange(steps) * DT, 3)[0]
    return samples, x_d


def test_the_goals_are_distinct_in_limit_solutions_nearest_first(ur10):
    samples, x_d = _workspace(ur10, "reach", 5, range(12), steps=2)
    q0s = np.array([s.q0 for s in samples])
    goals = branch_goals(ur10, q0s, x_d[:, 0])
    nearest, found = nearest_goals(ur10, q0s, x_d[:, 0])
    assert sum(len(g) > 1 for g in goals) >= 10  # the arm's whole reach: most targets have several branches
    low, high = ur10.lower_limits + GOAL_MARGIN, ur10.upper_limits - GOAL_MARGIN
    stops_seen = 0
    for i, all_goals in enumerate(goals):
        assert (all_goals >= ur10.lower_limits).all() and (all_goals <= ur10.upper_limits).all()
        for a in range(len(all_goals)):
            for b in range(a):
                assert np.abs(all_goals[a] - all_goals[b]).max() >= BRANCH_SEPARATION
        # The goals that reach the target first, nearest θ₀ first; then the IK ends a limit stopped short of it.
        residuals = np.linalg.norm(ur10.forward_batch(all_goals) - x_d[i, :1], axis=1)
        reaching = int(np.sum(residuals <= 1e-8))
        assert reaching >= 1 and (residuals[:reaching] <= 1e-8).all()
        stops = all_goals[reaching:]
        stops_seen += len(stops)
        assert (residuals[reaching:] <= LIMIT_STOP_RESIDUAL).all()
        assert ((stops <= low + 1e-12) | (stops >= high - 1e-12)).any(axis=1).all()  # each pressed against a limit
        found_goals = all_goals[:reaching]
        distances = np.linalg.norm(found_goals - q0s[i], axis=1)
        assert (np.diff(distances) >= 0).all()
        if found[i]:  # the joint-goal controller's goal is one of them, or as near
            assert distances[0] <= np.linalg.norm(nearest[i] - q0s[i]) + 1e-9
    assert stops_seen >= 1, "no IK end stopped by a limit on the whole workspace: the case is not exercised"


@pytest.mark.parametrize("task", ["reach", "track"])
def test_a_branch_start_keeps_every_limit_and_gets_there(ur10, task):
    samples, x_d = _workspace(ur10, task, 5, range(4))
    q0s = np.array([s.q0 for s in samples])
    reaching = [g[np.linalg.norm(ur10.forward_batch(g) - x_d[i, 0], axis=1) <= 1e-8]
                for i, g in enumerate(branch_goals(ur10, q0s, x_d[:, 0]))]  # fmt: skip
    goals = np.array([g[-1] for g in reaching])  # the farthest branch of each
    commands = branch_commands(ur10, q0s, goals, x_d, DT, ur10.velocity_limits)
    assert (np.abs(commands) <= ur10.velocity_limits * (1 + 1e-12)).all()
    paths = q0s[:, None] + np.cumsum(commands, axis=1) * DT
    assert (paths >= ur10.lower_limits - 1e-9).all() and (paths <= ur10.upper_limits + 1e-9).all()
    errors = np.linalg.norm(ur10.forward_batch(paths[:, -1]) - x_d[:, -1], axis=1)
    assert errors.max() < 1e-3, errors


def test_a_goal_on_a_known_branch_or_too_far_to_pay_for_is_dropped():
    q0 = np.zeros(6)
    goal = np.array([2.0, 0, 0, 0, 0, 0])
    assert worth_trying(goal, q0, 10.0, [], best_cost=1.0)  # (2 − 0.5)²/10 = 0.225 < 1
    assert not worth_trying(goal, q0, 10.0, [], best_cost=0.2)  # the travel alone costs more than the best
    assert not worth_trying(goal, q0, 10.0, [goal + 0.4], best_cost=1.0)  # the branch an optimum already ends on


def test_a_winning_branch_is_a_start_of_the_reference(reference_job):
    from snac_gym.evaluation.reference.optimum import run_optimal_job

    row = run_optimal_job(reference_job).metrics.iloc[0].to_dict()
    check_reference_row({**row, "optimal_winner": "branch-3"}, "reach")
    for name in ("branch-x", "branch-", "lqr2"):
        with pytest.raises(ValueError, match=f"optimal_winner = '{name}' is not a start of the reference"):
            check_reference_row({**row, "optimal_winner": name}, "reach")


def test_the_elbow_flip_ipopt_found_from_rest_is_the_reference_now(ur10):
    """UR10, whole workspace, HJB cost (Q = 4I), track seed 101 sample 7 (a held-out audit's seed): the solve from
    rest and the three feedback starts all descend to 6.6798501, with wrist 2 against its limit; IPOPT from rest
    flips the elbow (Δθ₃ = 4.6 rad) to 6.4559152, a KKT point of the project's solver too. The elbow's branch is a
    start of the reference now."""
    samples, x_d = _workspace(ur10, "track", 101, [7])
    context = policy_context("ur10", DT, "track")
    (reference,) = solve_samples(context, samples, [7], x_d, DT, CostConvention("hjb", "rest", 4.0))
    assert reference.winner.startswith("branch-")
    assert reference.solution.cost <= 6.4559152 * (1 + 1e-6), reference.solution.cost
    ipopt = pytest.importorskip("snac_gym.evaluation.reference.ipopt", exc_type=ImportError)
    pytest.importorskip("casadi")
    rest = ipopt.solve_with_ipopt(samples[0].q0, x_d[0], ur10, DT, ur10.velocity_limits,
                                  position_limits=(ur10.lower_limits, ur10.upper_limits),
                                  convention=CostConvention("hjb", "rest", 4.0))  # fmt: skip
    assert reference.solution.cost <= rest.cost * (1 + 1e-6)


def test_random_starts_are_the_samples_own_and_inside_the_box(ur10):
    from snac_gym.evaluation.reference.branches import RANDOM_STARTS, random_configurations

    samples, x_d = _workspace(ur10, "reach", 5, range(2), steps=2)
    first = random_configurations(ur10, samples[0].q0, x_d[0, 0])
    assert first.shape == (RANDOM_STARTS, 6)
    np.testing.assert_array_equal(first, random_configurations(ur10, np.array(samples[0].q0), x_d[0, 0].copy()))
    assert not np.allclose(first, random_configurations(ur10, samples[1].q0, x_d[1, 0]))  # another sample, others
    assert (first > ur10.lower_limits).all() and (first < ur10.upper_limits).all()


def test_a_tracking_optimum_on_a_later_points_branch_is_found(ur10):
    """Workspace track sample 26 of seed 223, HJB cost: rest, the feedback starts and every branch of the ellipse's
    first point end at 13.151469; IPOPT from a random in-limit start reached 10.045906 (a held-out cross-check)."""
    samples, x_d = _workspace(ur10, "track", 223, [26])
    context = policy_context("ur10", DT, "track")
    (reference,) = solve_samples(context, samples, [26], x_d, DT, CostConvention("hjb", "rest", 4.0))
    assert reference.winner.startswith(("random-", "branch-"))  # a local IK goal leads there too now (branch-0)
    assert reference.solution.cost <= 10.045906 * (1 + 1e-6), reference.solution.cost


def test_block_averaged_commands_pass_through_the_same_angles_on_the_coarse_grid():
    commands = np.random.default_rng(3).normal(size=(25, 6))
    q0 = np.linspace(-1.0, 1.0, 6)
    coarse = coarse_commands(commands, 10)  # blocks of 10, 10 and 5 steps
    assert coarse.shape == (3, 6)
    np.testing.assert_allclose(coarse[2], commands[20:].mean(axis=0))
    fine, on_grid = angles(commands, q0, DT), angles(coarse, q0, 10 * DT)
    np.testing.assert_allclose(on_grid, fine[::10], atol=1e-12)


def test_a_tracking_optimum_on_a_branch_near_the_seed_pose_is_found(ur10):
    """Workspace track sample 19 of seed 223, HJB cost (q = 4): every start ended at 3.4930 or above; IPOPT from a
    random start reached 2.8758 (a held-out cross-check). The IK solution of the ellipse's first point nearest θ₀
    (1.91 rad away) is a distance minimum that the IK from θ₀ and the 23 spread starts miss, and a start near θ₀
    finds; the start towards it descends to IPOPT's optimum."""
    samples, x_d = _workspace(ur10, "track", 223, [19])
    context = policy_context("ur10", DT, "track")
    (reference,) = solve_samples(context, samples, [19], x_d, DT, CostConvention("hjb", "rest", 4.0))
    assert reference.solution.cost <= 2.875821, reference.solution.cost


def test_a_reach_optimum_past_a_limit_is_found_by_the_coarse_screen(ur10):
    """Workspace reach sample 51 of seed 211, HJB cost (q = 4): the reference ended at 14.530, IPOPT at 13.359 (a
    held-out cross-check). The interior point reaches 13.359 from branch-10's start, whose three unconstrained
    Gauss-Newton steps (the old screen) left the limits at 28.5; on the coarse grid the constrained solve from the
    incumbent's own commands already ends in that basin, and the polish on the full grid reaches it."""
    samples, x_d = _workspace(ur10, "reach", 211, [51])
    context = policy_context("ur10", DT, "reach")
    (reference,) = solve_samples(context, samples, [51], x_d, DT, CostConvention("hjb", "rest", 4.0))
    assert reference.solution.cost <= 13.359014, reference.solution.cost


class _Rest:
    bounded = False


def test_a_moving_reference_followed_near_a_singular_arm_opens_the_branch_search(ur10):
    """The gate on the branch search: a fixed target the path stops short of stays closed; a moving one opens it
    only where the path comes near a singular arm (the smallest singular value of J below NEAR_SINGULAR)."""
    singular = np.array([0.0, -1.57, 0.0, -1.57, 0.0, 0.0])  # the elbow stretched out: J loses a rank
    bent = np.array([0.0, -1.2, 1.5, -1.8, -1.57, 0.0])
    assert np.linalg.svd(ur10.jacobian(singular), compute_uv=False)[-1] < NEAR_SINGULAR
    assert np.linalg.svd(ur10.jacobian(bent), compute_uv=False)[-1] > 2 * NEAR_SINGULAR
    far = ur10.forward(bent) + np.array([0.0, 0.0, 0.3])  # 30 cm beyond the path's end: not reached
    fixed = np.repeat(far[None], 10, axis=0)
    moving = fixed + np.linspace(0.0, 0.05, 10)[:, None] * np.array([1.0, 0.0, 0.0])
    for q in (singular, bent):
        assert not needs_branches(ur10, _Rest(), np.repeat(q[None], 11, axis=0), fixed)
    assert needs_branches(ur10, _Rest(), np.repeat(singular[None], 11, axis=0), moving)
    assert not needs_branches(ur10, _Rest(), np.repeat(bent[None], 11, axis=0), moving)


def test_a_tracking_optimum_on_another_branch_past_a_near_singular_path_is_found(ur10):
    """Workspace track sample 25 of seed 409, HJB cost (q = 4): the solve from rest lags the ellipse's end by 2.8 cm,
    so the branch search stayed closed and the reference was 3.9554; IPOPT reached 3.7903 from another branch (a
    held-out cross-check). The solve from rest's path passes within 0.13 of a singular arm: the search opens, and
    the start towards the third branch descends to IPOPT's optimum."""
    samples, x_d = _workspace(ur10, "track", 409, [25])
    context = policy_context("ur10", DT, "track")
    (reference,) = solve_samples(context, samples, [25], x_d, DT, CostConvention("hjb", "rest", 4.0))
    assert reference.solution.cost <= 3.790325, reference.solution.cost
    assert reference.winner.startswith("branch-")


def test_a_goal_is_turned_the_short_way_round_each_joint_inside_the_limits():
    from snac_gym.evaluation.reference.branches import wrapped_towards

    two_pi = 2.0 * np.pi
    lower, upper = np.array([-two_pi, -two_pi, -np.pi]), np.array([two_pi, two_pi, np.pi])
    q0 = np.array([-1.9, 1.25, 3.0])
    goal = np.array([5.3, 4.43, -3.0])  # joints 1 and 2 shorter the other way round; joint 3's range is one turn
    np.testing.assert_allclose(wrapped_towards(goal, q0, lower, upper), [5.3 - two_pi, 4.43 - two_pi, -3.0])
    assert np.abs(wrapped_towards(goal, q0, lower, upper) - q0).max() < np.abs(goal - q0).max()
    edge = np.array([0.2, 0.2, 0.0])  # 0.2 − 2π is the nearer way to θ₀ = −6, but below the lower limit given
    np.testing.assert_allclose(wrapped_towards(edge, np.array([-6.0, 0.0, 0.0]), lower + 0.5, upper - 0.5), edge)


def test_a_tracking_optimum_the_other_way_round_the_shoulder_is_found(ur10):
    """Workspace track sample 31 of seed 409, HJB cost (q = 4): every start ended at 6.0595 or above; IPOPT from rest
    reached 6.003371 (a held-out cross-check), the shoulder turned 3.1 rad the short way where every IK goal turned it
    3.2 rad the other. The goals turned the short way round each joint hold IPOPT's optimum."""
    samples, x_d = _workspace(ur10, "track", 409, [31])
    context = policy_context("ur10", DT, "track")
    (reference,) = solve_samples(context, samples, [31], x_d, DT, CostConvention("hjb", "rest", 4.0))
    assert reference.solution.cost <= 6.003372, reference.solution.cost
    assert reference.winner.startswith("branch-")


def test_a_reach_optimum_against_a_limit_short_of_the_target_is_found(ur10):
    """Workspace reach sample 32 of seed 431, HJB cost (q = 4): every start, IPOPT's from the IK goals included, ended
    at 10.029696 with the base turned 2.35 rad; IPOPT from rest reached 9.3220208 with the base against its limit and
    the shoulder swung back, 6 mm short of the target (a held-out cross-check). That branch reaches the target only
    past the base's limit; the IK end the limit stopped 5.4 cm short is a start now, and descends there."""
    samples, x_d = _workspace(ur10, "reach", 431, [32])
    context = policy_context("ur10", DT, "reach")
    (reference,) = solve_samples(context, samples, [32], x_d, DT, CostConvention("hjb", "rest", 4.0))
    assert reference.solution.cost <= 9.3220209, reference.solution.cost
    assert reference.winner.startswith("branch-")
