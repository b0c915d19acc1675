"""Newton's step in the trajectory optimiser: the error term's second-order blocks against finite differences of the
Jacobian, and Newton's solve against Gauss-Newton's where Gauss-Newton converges linearly (the same local optimum,
reached in a few steps instead of hundreds, and nearer the optimum a solve run to rounding finds)."""

from __future__ import annotations

import numpy as np
import pytest
from snac_gym.evaluation.samples import generate_samples

from snac_gym.control.cost import CostConvention
from snac_gym.control.gauss_newton import GaussNewtonSolver, gauss_newton
from snac_gym.control.shooting import angles, errors_and_jacobians
from snac_gym.control.trajopt import FTOL, GTOL, solve_sample
from snac_gym.kernels.chain import chain_forward_and_jacobian
from snac_gym.kernels.trajopt import chain_error_curvature
from snac_gym.model.kinematics import Kinematics
from snac_gym.rollout import reference_trajectories
from snac_gym.sampling import SampleSpace

DT = 0.008


def _finite_difference_curvature(jacobians_at, qs: np.ndarray, errors: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """Σᵢ eᵢ ∂Jᵢₐ/∂θ_b by central differences of the Jacobian: an independent computation of the kernel's blocks."""
    count, m = qs.shape
    out = np.zeros((count, m, m))
    for b in range(m):
        up, down = qs.copy(), qs.copy()
        up[:, b] += h
        down[:, b] -= h
        out[:, :, b] = np.einsum("ki,kia->ka", errors, (jacobians_at(up) - jacobians_at(down)) / (2 * h))
    return out


@pytest.mark.parametrize("robot", ["ur10", "panda", "xarm7"])
def test_the_curvature_blocks_are_the_derivative_of_the_jacobian_along_the_error(robot):
    kinematics = Kinematics(robot)
    rng = np.random.default_rng(3)
    qs = rng.uniform(kinematics.lower_limits, kinematics.upper_limits, (200, kinematics.n_joints))
    errors = rng.normal(size=(200, 3))
    blocks = kinematics.error_curvature_batch(qs, errors)
    expected = _finite_difference_curvature(lambda q: np.array(kinematics.jacobian_batch(q)), qs, errors)
    np.testing.assert_allclose(blocks, expected, atol=1e-7)
    np.testing.assert_array_equal(blocks, np.swapaxes(blocks, 1, 2))


def test_a_prismatic_joint_contributes_through_the_revolute_joints_before_it_only():
    # A revolute joint about z, a prismatic one along its x, a revolute one about y: the kernel's three cases.
    chain = (np.stack([np.eye(3)] * 3),
             np.array([[0.0, 0.0, 0.3], [0.2, 0.0, 0.0], [0.0, 0.1, 0.0]]),
             np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]), np.array([True, False, True]),
             np.array([0, 1, 2], dtype=np.int64), np.array([0.0, 0.0, 0.4]), 3)  # fmt: skip
    rng = np.random.default_rng(5)
    qs, errors = rng.uniform(-2.0, 2.0, (50, 3)), rng.normal(size=(50, 3))
    blocks = chain_error_curvature(qs, errors, *chain)
    expected = _finite_difference_curvature(lambda q: chain_forward_and_jacobian(q, *chain)[1], qs, errors)
    np.testing.assert_allclose(blocks, expected, atol=1e-7)
    assert np.all(blocks[:, 1, 1] == 0.0)  # a translation does not turn itself


def _coarse_problem(seed: int, task: str, index: int) -> tuple[Kinematics, np.ndarray, np.ndarray]:
    ur10 = Kinematics("ur10")
    (sample,) = generate_samples(ur10, SampleSpace.workspace(ur10), seed, task, [index])
    x_d = reference_trajectories([sample.reference], np.arange(625) * DT, 3)[0][0]
    return ur10, np.asarray(sample.q0), x_d[::10]  # the reference's coarse grid: Δt × 10 over 5 s


@pytest.mark.parametrize(("seed", "task", "index"), [(5, "reach", 7), (3, "track", 0)])
def test_newton_reaches_the_optimum_gauss_newton_creeps_to_in_a_few_steps(seed, task, index):
    # Workspace samples, Table I's cost, the coarse grid from rest: Gauss-Newton's steps shrink by a constant factor
    # (the errors stay large, so the Hessian's second-order part is not small), and it stops on its own test with
    # the cost still above the optimum by more than that test's 1e-7.
    ur10, q0, x_d = _coarse_problem(seed, task, index)
    convention, dt = CostConvention(), DT * 10
    plain = solve_sample(q0, x_d, ur10, dt, ur10.velocity_limits, convention=convention)
    newton = solve_sample(q0, x_d, ur10, dt, ur10.velocity_limits, convention=convention, newton=True)
    tight = solve_sample(q0, x_d, ur10, dt, ur10.velocity_limits, convention=convention, gap_rtol=0.0, gtol=0.0,
                         ftol=1e-16)  # fmt: skip
    assert not plain.bounded and not newton.bounded and newton.converged
    assert plain.iterations > 60 and newton.iterations <= 8, (plain.iterations, newton.iterations)
    # The same local optimum: the path within a thousandth of a radian of the solve run until rounding stops it.
    np.testing.assert_allclose(angles(newton.commands, q0, dt), angles(tight.commands, q0, dt), atol=1e-3)
    assert abs(newton.cost - tight.cost) <= 1e-9 * tight.cost < plain.cost - tight.cost


def test_where_the_hessian_is_not_positive_definite_the_gauss_newton_step_is_taken(monkeypatch):
    ur10, q0, x_d = _coarse_problem(5, "reach", 7)
    convention, dt = CostConvention(), DT * 10
    start = np.zeros((len(x_d), 6))
    errors, jacobians = errors_and_jacobians(ur10, angles(start, q0, dt), x_d)
    solver = GaussNewtonSolver(len(x_d), 6, dt, convention)
    grad = np.ones_like(start)
    with pytest.raises(np.linalg.LinAlgError, match="not positive definite"):
        solver.direction(jacobians, grad, curvature=np.tile(-1e6 * np.eye(6), (len(x_d), 1, 1)))
    # Every Newton step refused: the solve is Gauss-Newton's, step for step.
    indefinite = lambda self, qs, errors: np.tile(-1e6 * np.eye(6), (len(qs), 1, 1))  # noqa: E731
    monkeypatch.setattr(Kinematics, "error_curvature_batch", indefinite)
    refused = gauss_newton(q0, x_d, ur10, dt, start, GTOL, FTOL, 400, convention, newton=True)
    plain = gauss_newton(q0, x_d, ur10, dt, start, GTOL, FTOL, 400, convention)
    np.testing.assert_array_equal(refused[0], plain[0])
    assert refused[3] == plain[3]


def test_a_pose_task_takes_the_gauss_newton_steps_it_always_took():
    # The curvature is that of f(θ) − x_d; a pose task's error is a logarithm, so its solve ignores newton=True (its
    # kinematics would otherwise lend it the position kinematics' curvature).
    from snac_gym.model.pose_kinematics import PoseKinematics

    pose = PoseKinematics("ur10")
    q0 = np.array([0.3, -1.2, 1.4, -1.8, -1.5, 0.2])
    x_d = np.tile(pose.forward(q0 + 0.3), (40, 1))
    convention, dt = CostConvention(), DT * 10
    newton = gauss_newton(q0, x_d, pose, dt, np.zeros((40, 6)), GTOL, FTOL, 50, convention, newton=True)
    plain = gauss_newton(q0, x_d, pose, dt, np.zeros((40, 6)), GTOL, FTOL, 50, convention)
    assert plain[3] > 1
    np.testing.assert_array_equal(newton[0], plain[0])
