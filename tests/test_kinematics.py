"""The shared kinematics against PyBullet's own link state and finite differences."""

import pickle

import numpy as np
import pytest

from snac_gym.envs.robot import SimulatedArm
from snac_gym.envs.sim import PyBulletSim, p
from snac_gym.kinematics import Kinematics
from snac_gym.references import PAPER_Q0


def _random_configurations(kin: Kinematics, rng: np.random.Generator, count: int) -> np.ndarray:
    low = np.maximum(kin.lower_limits, -np.pi)
    high = np.minimum(kin.upper_limits, np.pi)
    return rng.uniform(low, high, size=(count, kin.n_joints))


@pytest.mark.parametrize("robot", ["ur3", "ur5", "ur10"])
def test_forward_kinematics_matches_pybullet_link_state(robot, rng):
    kin = Kinematics(robot)
    sim = PyBulletSim(dt=1 / 125, n_substeps=1)
    try:
        arm = SimulatedArm(sim, kin)
        for q in _random_configurations(kin, rng, 20):
            arm.set_joint_positions(q)
            np.testing.assert_allclose(kin.base_to_world(kin.forward(q)), arm.ee_world_position(), atol=1e-6)
    finally:
        sim.close()


def test_jacobian_matches_pybullet_and_finite_differences(ur10, rng):
    sim = PyBulletSim(dt=1 / 125, n_substeps=1)
    try:
        arm = SimulatedArm(sim, ur10)
        for q in _random_configurations(ur10, rng, 10):
            jac = ur10.jacobian(q)
            step = 1e-6
            finite = np.stack(
                [(ur10.forward(q + step * np.eye(6)[j]) - ur10.forward(q - step * np.eye(6)[j])) / (2 * step) for j in range(6)],
                axis=1,
            )
            np.testing.assert_allclose(jac, finite, atol=1e-8)
            # PyBullet's own Jacobian (world frame, at the merged link's offset) rotated into the base frame.
            arm.set_joint_positions(q)
            lin, _ = p.calculateJacobian(
                arm.body, arm.ee_link, arm.ee_offset.tolist(), q.tolist(), [0.0] * 6, [0.0] * 6, physicsClientId=sim.client
            )
            base_from_world = ur10._base_from_world
            np.testing.assert_allclose(jac, base_from_world @ np.array(lin), atol=1e-6)
    finally:
        sim.close()


def test_paper_seed_pose_position_in_base_frame(ur10):
    # base is base_link rotated by π about z: x and y flip sign relative to base_link.
    x = ur10.forward(np.array(PAPER_Q0))
    x_base_link = ur10.base_to_world(x)
    np.testing.assert_allclose(x[:2], -x_base_link[:2])
    np.testing.assert_allclose(x[2], x_base_link[2])
    assert x.shape == (3,)


def test_limits_come_from_the_urdf(ur10):
    np.testing.assert_allclose(ur10.velocity_limits, [2.16, 2.16, 3.15, 3.2, 3.2, 3.2])
    assert ur10.joint_names[0] == "shoulder_pan_joint" and ur10.n_joints == 6
    np.testing.assert_allclose(ur10.lower_limits[2], -np.pi)


def test_forward_and_jacobian_agree_with_separate_calls(ur10, rng):
    q = _random_configurations(ur10, rng, 1)[0]
    x, jac = ur10.forward_and_jacobian(q)
    np.testing.assert_array_equal(x, ur10.forward(q))
    np.testing.assert_array_equal(jac, ur10.jacobian(q))
    np.testing.assert_allclose(ur10.forward_batch(np.stack([q, q])), np.stack([x, x]))
    qs = _random_configurations(ur10, np.random.default_rng(3), 4)
    positions, jacobians = ur10.forward_and_jacobian_batch(qs)
    for q_i, x_i, jac_i in zip(qs, positions, jacobians):
        np.testing.assert_array_equal(x_i, ur10.forward(q_i))
        np.testing.assert_array_equal(jac_i, ur10.jacobian(q_i))
    np.testing.assert_array_equal(ur10.jacobian_batch(qs), jacobians)
    with pytest.raises(ValueError, match=r"shape \(B, 6\)"):
        ur10.forward_and_jacobian_batch(np.zeros((2, 5)))


def test_inverse_position_reaches_a_forward_point(ur10, rng):
    q_true = np.array(PAPER_Q0) + rng.uniform(-0.3, 0.3, 6)
    target = ur10.forward(q_true)
    q, ok = ur10.inverse_position(target, np.array(PAPER_Q0))
    assert ok and np.linalg.norm(ur10.forward(q) - target) < 1e-6
    _, ok = ur10.inverse_position(np.array([3.0, 0.0, 0.0]), np.array(PAPER_Q0))
    assert not ok


def test_bad_arguments_raise_clear_errors(ur10):
    with pytest.raises(ValueError, match="unknown robot"):
        Kinematics("ur99")
    with pytest.raises(ValueError, match="frame 'nope'"):
        Kinematics(ee_frame="nope")
    with pytest.raises(ValueError, match=r"shape \(6,\)"):
        ur10.forward(np.zeros(5))


def test_kinematics_pickles_by_arguments(ur10):
    clone = pickle.loads(pickle.dumps(ur10))
    q = np.array(PAPER_Q0)
    np.testing.assert_array_equal(clone.forward(q), ur10.forward(q))
    assert clone.robot == "ur10" and clone.ee_frame == "tool0"
