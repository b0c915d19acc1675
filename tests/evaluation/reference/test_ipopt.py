"""The IPOPT cross-check (evaluation/reference/ipopt.py): its kinematics, its objective, and its optima
against the project's own solver (evaluation/reference/optimum.py)."""

from __future__ import annotations

import sys

import numpy as np
import pytest

pytest.importorskip("casadi")

from snac_gym.evaluation.reference.ipopt import (  # noqa: E402  (after the skip)
    MISSING_CASADI,
    casadi_forward_kinematics,
    ipopt_objective,
    solve_with_ipopt,
)
from snac_gym.evaluation.samples import generate_samples  # noqa: E402

from snac_gym.control.cost import CostConvention  # noqa: E402
from snac_gym.control.trajopt import solve_sample, trajectory_cost_and_gradient  # noqa: E402
from snac_gym.model.kinematics import shared_kinematics  # noqa: E402
from snac_gym.rollout import reference_trajectories  # noqa: E402
from snac_gym.sampling import SampleSpace  # noqa: E402

DT = 1.0 / 125.0
#: Steps of the solves here: 2.4 s, enough for the optimum to move well away from rest.
STEPS = 300


@pytest.fixture(scope="module")
def ur10():
    return shared_kinematics("ur10")


def _sample(kinematics, task: str, steps: int = STEPS) -> tuple[np.ndarray, np.ndarray]:
    """(θ₀, x_d) of sample 0 of ``task``, as the evaluator draws it."""
    sample = generate_samples(kinematics, SampleSpace.for_robot(kinematics), 0, task, [0])[0]
    x_d = reference_trajectories([sample.reference], np.arange(steps) * DT)[0][0]
    return np.asarray(sample.q0, dtype=float), x_d


@pytest.fixture(scope="module")
def track(ur10):
    """The track sample, and IPOPT's optimum of it under the URDF's velocity limits (none binds)."""
    q0, x_d = _sample(ur10, "track")
    return q0, x_d, solve_with_ipopt(q0, x_d, ur10, DT, ur10.velocity_limits)


@pytest.mark.parametrize("robot", ["ur10", "panda"])
def test_casadi_forward_kinematics_is_pinocchios(robot):
    kinematics = shared_kinematics(robot)
    forward = casadi_forward_kinematics(kinematics)
    rng = np.random.default_rng(3)
    for q in rng.uniform(kinematics.lower_limits, kinematics.upper_limits, size=(25, kinematics.n_joints)):
        np.testing.assert_allclose(np.asarray(forward(q)).ravel(), kinematics.forward(q), rtol=0, atol=1e-12)


CONVENTIONS = [
    CostConvention(),
    CostConvention("hjb"),
    CostConvention("table1", "first"),
    CostConvention("table1", "rest", q_scale=50.0),
    CostConvention("hjb", "first", q_scale=1e4),
]


@pytest.mark.parametrize("convention", CONVENTIONS, ids=["table1", "hjb", "table1-first", "table1-q50", "hjb-q1e4"])
def test_the_nlp_objective_is_the_projects_cost(ur10, convention):
    q0, x_d = _sample(ur10, "track", 40)
    commands = np.random.default_rng(0).normal(scale=0.3, size=(40, ur10.n_joints))
    expected = trajectory_cost_and_gradient(commands, q0, x_d, ur10, DT, convention)[0]
    assert ipopt_objective(commands, q0, x_d, ur10, DT, convention) == pytest.approx(expected, rel=1e-10)


@pytest.mark.parametrize("task", ["reach", "track"])
def test_ipopt_and_the_project_find_the_same_unconstrained_optimum(ur10, track, task):
    if task == "track":
        q0, x_d, ipopt = track
    else:
        q0, x_d = _sample(ur10, task)
        ipopt = solve_with_ipopt(q0, x_d, ur10, DT, ur10.velocity_limits)
    project = solve_sample(q0, x_d, ur10, DT, ur10.velocity_limits)
    assert ipopt.success and ipopt.status == "Solve_Succeeded", ipopt.status
    assert project.converged and not project.bounded
    assert ipopt.cost == pytest.approx(project.cost, rel=1e-6)
    assert ipopt.cost == pytest.approx(ipopt.ipopt_cost, rel=1e-12)  # IPOPT's V is the project's V


def test_a_binding_velocity_limit_is_kept(ur10, track):
    q0, x_d, free = track
    limits = 0.5 * np.abs(free.commands).max(axis=0) + 1e-3
    bounded = solve_with_ipopt(q0, x_d, ur10, DT, limits)
    assert bounded.success, bounded.status
    assert (np.abs(bounded.commands) <= limits + 1e-9).all()
    assert (np.abs(bounded.commands).max(axis=0) >= limits - 1e-6).any()  # it binds
    assert bounded.cost >= free.cost
    assert bounded.cost == pytest.approx(solve_sample(q0, x_d, ur10, DT, limits).cost, rel=1e-6)


def test_a_binding_position_limit_is_kept(ur10, track):
    q0, x_d, free = track
    travel = DT * np.cumsum(free.commands, axis=0)  # θₖ − θ₀, k = 1..K
    step, joint = np.unravel_index(np.argmax(np.abs(travel)), travel.shape)
    lower, upper = ur10.lower_limits.copy(), ur10.upper_limits.copy()
    if travel[step, joint] > 0:  # halve the joint's largest excursion
        upper[joint] = q0[joint] + 0.5 * travel[step, joint]
    else:
        lower[joint] = q0[joint] + 0.5 * travel[step, joint]
    bounded = solve_with_ipopt(q0, x_d, ur10, DT, ur10.velocity_limits, position_limits=(lower, upper))
    assert bounded.success, bounded.status
    angles = q0 + DT * np.cumsum(bounded.commands, axis=0)
    assert (angles >= lower - 1e-9).all() and (angles <= upper + 1e-9).all()
    assert (np.abs(bounded.commands) <= ur10.velocity_limits + 1e-9).all()
    assert np.minimum(angles - lower, upper - angles)[:, joint].min() <= 1e-6  # it binds
    assert bounded.cost >= free.cost
    project = solve_sample(q0, x_d, ur10, DT, ur10.velocity_limits, position_limits=(lower, upper))
    assert bounded.cost == pytest.approx(project.cost, rel=1e-6)


def test_only_position_tasks(ur10):
    q0, x_d = _sample(ur10, "reach", 10)
    with pytest.raises(ValueError, match="position task"):
        solve_with_ipopt(q0, np.hstack([x_d, x_d]), ur10, DT, ur10.velocity_limits)


def test_without_casadi_it_says_what_to_install(ur10, monkeypatch):
    monkeypatch.setitem(sys.modules, "casadi", None)  # `import casadi` raises ImportError
    q0, x_d = _sample(ur10, "reach", 10)
    with pytest.raises(ImportError, match=r'pip install -e "\.\[check\]"') as error:
        solve_with_ipopt(q0, x_d, ur10, DT, ur10.velocity_limits)
    assert str(error.value) == MISSING_CASADI


#: (cost, task, sample, binds) of workspace samples of seed 2024 over 4 s: on the first five a UR10 joint
#: position limit (the success rule's) binds the optimum, on the last three none does (on track 2 the unconstrained
#: optimum crosses the elbow's limit, and the constrained one is on another branch, clear of it).
WORKSPACE_CASES = [
    ("hjb", "reach", 0, True), ("hjb", "reach", 4, True), ("hjb", "track", 1, True), ("hjb", "track", 5, True),
    ("table1", "reach", 0, True), ("table1", "reach", 1, False), ("table1", "track", 2, False),
    ("hjb", "track", 0, False),
]  # fmt: skip


@pytest.mark.parametrize(("cost", "task", "index", "binds"), WORKSPACE_CASES)
def test_the_constrained_reference_matches_ipopt_or_is_cheaper(ur10, cost, task, index, binds):
    from snac_gym.control.trajopt import next_angles

    convention = CostConvention(cost, "rest", 4.0 if cost == "hjb" else 1.0)
    sample = generate_samples(ur10, SampleSpace.workspace(ur10), 2024, task, [index])[0]
    x_d = reference_trajectories([sample.reference], np.arange(500) * DT)[0][0]
    q0, limits = np.asarray(sample.q0, dtype=float), (ur10.lower_limits, ur10.upper_limits)
    ours = solve_sample(q0, x_d, ur10, DT, ur10.velocity_limits, convention=convention, position_limits=limits)
    ipopt = solve_with_ipopt(q0, x_d, ur10, DT, ur10.velocity_limits, position_limits=limits, convention=convention)
    assert ipopt.success and ours.converged
    assert ours.cost <= ipopt.cost * (1 + 1e-4)
    angles = next_angles(ours.commands, q0, DT)
    margin = min(float((angles - limits[0]).min()), float((limits[1] - angles).min()))
    assert margin >= 0.0 and np.all(np.abs(ours.commands) <= ur10.velocity_limits)
    assert (margin < 1e-6) == binds
