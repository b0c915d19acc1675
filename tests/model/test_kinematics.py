"""The shared kinematics against PyBullet's own link state and finite differences."""

import math
import pickle

import numpy as np
import pytest

from snac_gym.model.kinematics import Kinematics
from snac_gym.physics.bullet import PyBulletSim, SimulatedArm, p
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
                [
                    (ur10.forward(q + step * np.eye(6)[j]) - ur10.forward(q - step * np.eye(6)[j])) / (2 * step)
                    for j in range(6)
                ],
                axis=1,
            )
            np.testing.assert_allclose(jac, finite, atol=1e-8)
            # PyBullet's own Jacobian (world frame, at the merged link's offset) rotated into the base frame.
            arm.set_joint_positions(q)
            lin, _ = p.calculateJacobian(
                arm.body,
                arm.ee_link,
                arm.ee_offset.tolist(),
                q.tolist(),
                [0.0] * 6,
                [0.0] * 6,
                physicsClientId=sim.client,
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
    for q_i, x_i, jac_i in zip(qs, positions, jacobians):  # the batch is vectorised: same to rounding
        np.testing.assert_allclose(x_i, ur10.forward(q_i), rtol=0, atol=1e-15)
        np.testing.assert_allclose(jac_i, ur10.jacobian(q_i), rtol=0, atol=1e-15)
    np.testing.assert_array_equal(ur10.jacobian_batch(qs), jacobians)
    with pytest.raises(ValueError, match=r"shape \(B, 6\)"):
        ur10.forward_and_jacobian_batch(np.zeros((2, 5)))


@pytest.mark.parametrize("robot", ["ur3", "ur5", "ur10"])
def test_batch_chain_matches_pinocchio_over_the_whole_joint_range(robot):
    kinematics = Kinematics(robot)
    assert kinematics._chain is not None  # the UR arms take the vectorised path
    qs = np.random.default_rng(7).uniform(-2 * np.pi, 2 * np.pi, (200, 6))
    positions, jacobians = kinematics.forward_and_jacobian_batch(qs)
    for q, x, jac in zip(qs, positions, jacobians):
        np.testing.assert_allclose(x, kinematics.forward(q), rtol=0, atol=1e-12)
        np.testing.assert_allclose(jac, kinematics.jacobian(q), rtol=0, atol=1e-12)


def test_a_batch_row_does_not_depend_on_the_rest_of_the_batch(ur10):
    """The evaluator's results must not depend on how samples are cut into jobs: rows are bit-identical."""
    qs = np.random.default_rng(11).uniform(-3, 3, (600, 6))
    whole_x, whole_jac = (a.copy() for a in ur10.forward_and_jacobian_batch(qs))
    for start, size in [(0, 1), (5, 7), (100, 64), (37, 500)]:
        x, jac = ur10.forward_and_jacobian_batch(qs[start : start + size])
        np.testing.assert_array_equal(x, whole_x[start : start + size])
        np.testing.assert_array_equal(jac, whole_jac[start : start + size])


def test_the_last_batch_is_reused_only_for_equal_configurations_and_is_read_only(ur10):
    qs = np.random.default_rng(12).uniform(-3, 3, (5, 6))
    x, jac = ur10.forward_and_jacobian_batch(qs)
    assert ur10.jacobian_batch(qs.copy()) is jac and ur10.forward_batch(qs) is x
    with pytest.raises(ValueError, match="read-only"):
        jac[0, 0, 0] = 1.0
    moved = qs.copy()
    moved[3, 2] += 1e-9
    x_moved = ur10.forward_batch(moved)
    assert x_moved is not x
    np.testing.assert_array_equal(x_moved[:3], x[:3])
    assert not np.array_equal(x_moved[3], x[3])
    qs[0, 0] += 0.5  # changing the caller's array in place must not return the stale result
    np.testing.assert_allclose(ur10.forward_batch(qs)[0], ur10.forward(qs[0]), atol=1e-15)
    # Reused for the same bits only: -0.0 equals 0.0 as a number but is computed anew (its output may differ in a
    # zero's sign); the same values through a strided view are the same bits.
    zeros = np.zeros((2, 6))
    at_zero = ur10.forward_batch(zeros)
    assert ur10.forward_batch(-zeros) is not at_zero
    wide = np.repeat(qs, 2, axis=1)[:, ::2]  # a non-contiguous view holding qs's values
    assert not wide.flags.c_contiguous
    assert ur10.forward_batch(qs) is ur10.forward_batch(wide)


_GENERAL_URDF = """<robot name="general">
  <link name="base"/><link name="a"/><link name="b"/><link name="c"/><link name="d"/>
  <joint name="j1" type="revolute"><parent link="base"/><child link="a"/>
    <origin xyz="0.1 0 0.2" rpy="0.3 -0.2 0.1"/><axis xyz="0 0.6 0.8"/>
    <limit lower="-3" upper="3" velocity="2" effort="1"/></joint>
  <joint name="j2" type="prismatic"><parent link="a"/><child link="b"/>
    <origin xyz="0 0.3 0" rpy="0 0.5 0"/><axis xyz="1 0 0"/>
    <limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
  <joint name="j3" type="revolute"><parent link="b"/><child link="c"/>
    <origin xyz="0 0 0.25" rpy="0 0 0"/><axis xyz="0 0 -1"/>
    <limit lower="-3" upper="3" velocity="2" effort="1"/></joint>
  <joint name="j4" type="revolute"><parent link="c"/><child link="d"/>
    <origin xyz="0.2 0 0" rpy="1.0 0 0"/><axis xyz="0 1 0"/>
    <limit lower="-3" upper="3" velocity="2" effort="1"/></joint>
  <link name="tip"/>
  <joint name="tip_fixed" type="fixed"><parent link="d"/><child link="tip"/><origin xyz="0.05 0.1 0.02"/></joint>
</robot>
"""


def test_batch_chain_handles_unaligned_negative_and_prismatic_axes(tmp_path):
    urdf = tmp_path / "general.urdf"
    urdf.write_text(_GENERAL_URDF)
    kinematics = Kinematics(urdf_path=urdf, ee_frame="tip", base_frame="base")
    assert kinematics._chain is not None
    qs = np.random.default_rng(5).uniform(-1, 1, (50, 4))
    positions, jacobians = kinematics.forward_and_jacobian_batch(qs)
    for q, x, jac in zip(qs, positions, jacobians):
        np.testing.assert_allclose(x, kinematics.forward(q), rtol=0, atol=1e-12)
        np.testing.assert_allclose(jac, kinematics.jacobian(q), rtol=0, atol=1e-12)
    kinematics._chain = None  # the per-configuration Pinocchio loop gives the same
    kinematics._last_batch = None
    looped_x, looped_jac = kinematics.forward_and_jacobian_batch(qs)
    np.testing.assert_allclose(looped_x, positions, rtol=0, atol=1e-12)
    np.testing.assert_allclose(looped_jac, jacobians, rtol=0, atol=1e-12)


def _chain_in_python_floats(q, rotations, translations, axes, revolute, columns, ee_offset, n_joints):
    """The chain kernel's arithmetic (snac_gym/kernels/chain.py's docstring) in Python floats, each sum in the
    kernel's order and no fused multiply-add: what the compiled kernel must give bit for bit."""
    parent_rotation, origin, jacobian, frames = None, None, [[0.0] * n_joints for _ in range(3)], []
    for s in range(len(rotations)):
        m, t = rotations[s].tolist(), translations[s].tolist()
        if parent_rotation is None:
            origin, frame = list(t), m
        else:
            r = parent_rotation
            origin = [origin[i] + (r[i][0] * t[0] + r[i][1] * t[1] + r[i][2] * t[2]) for i in range(3)]
            frame = [[r[i][0] * m[0][j] + r[i][1] * m[1][j] + r[i][2] * m[2][j] for j in range(3)] for i in range(3)]
        a = axes[s].tolist()
        z = [frame[i][0] * a[0] + frame[i][1] * a[1] + frame[i][2] * a[2] for i in range(3)]
        angle = float(q[columns[s]])
        if not revolute[s]:
            origin = [origin[i] + z[i] * angle for i in range(3)]
            parent_rotation = frame
        else:
            c, sn = math.cos(angle), math.sin(angle)
            v = 1.0 - c
            parent_rotation = []
            for i in range(3):
                f0, f1, f2 = frame[i]
                along = z[i] * v
                parent_rotation.append([c * f0 + sn * (f1 * a[2] - f2 * a[1]) + along * a[0],
                                        c * f1 + sn * (f2 * a[0] - f0 * a[2]) + along * a[1],
                                        c * f2 + sn * (f0 * a[1] - f1 * a[0]) + along * a[2]])  # fmt: skip
        frames.append((list(origin), z, revolute[s], columns[s]))
    r, e = parent_rotation, ee_offset.tolist()
    x = [origin[i] + (r[i][0] * e[0] + r[i][1] * e[1] + r[i][2] * e[2]) for i in range(3)]
    for p_s, z, is_revolute, column in frames:
        if not is_revolute:
            column_values = z
        else:
            l0, l1, l2 = x[0] - p_s[0], x[1] - p_s[1], x[2] - p_s[2]
            column_values = [z[1] * l2 - z[2] * l1, z[2] * l0 - z[0] * l2, z[0] * l1 - z[1] * l0]
        for i in range(3):
            jacobian[i][column] = column_values[i]
    return x, jacobian


@pytest.mark.parametrize("robot", ["ur10", "panda", "general"])
def test_the_compiled_chain_is_its_arithmetic_bit_for_bit(robot, tmp_path):
    """The evaluator's rows do not move when the kernel is rewritten for speed: f(θ) and J(θ) are the docstring's
    arithmetic in its order, to the last bit (a UR10, a 7-joint Panda, a chain with a prismatic joint and tilted
    axes)."""
    if robot == "general":
        urdf = tmp_path / "general.urdf"
        urdf.write_text(_GENERAL_URDF)
        kinematics = Kinematics(urdf_path=urdf, ee_frame="tip", base_frame="base")
    else:
        kinematics = Kinematics(robot)
    arrays = kinematics._chain._kernel_arrays
    qs = np.random.default_rng(21).uniform(-3.0, 3.0, (40, kinematics.n_joints))
    positions, jacobians = kinematics.forward_and_jacobian_batch(qs)
    for q, x, jac in zip(qs, positions, jacobians):
        expected_x, expected_jac = _chain_in_python_floats(q, *arrays)
        assert x.tolist() == expected_x
        assert jac.tolist() == expected_jac


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


def test_the_compiled_damped_resolve_is_numpys_solve_and_a_row_is_the_row_alone(ur10):
    from snac_gym.model.kinematics import damped_least_squares, damped_resolve_rows

    rng = np.random.default_rng(11)
    qs = rng.uniform(-3.0, 3.0, size=(300, 6))
    qs[0] = 0.0  # the UR10 at zero: singular (the forearm and the wrist in line), where the damping matters
    jacobians = np.array([ur10.jacobian(q) for q in qs])
    velocities = rng.normal(size=(300, 3))
    for damping in (0.01, 0.3):
        found = damped_resolve_rows(jacobians, velocities, damping)
        expected = damped_least_squares(jacobians, velocities[..., None], damping**2 * np.eye(3))[..., 0]
        np.testing.assert_allclose(found, expected, rtol=1e-9, atol=1e-9)
        for i in (0, 7, 299):
            assert damped_resolve_rows(jacobians[i], velocities[i], damping).tobytes() == found[i].tobytes()


@pytest.mark.parametrize("steps", [0, 1, 2, 150, 2501])
def test_the_joint_path_is_numpys_cumulative_sum_bit_for_bit(steps):
    """θ₁..θ_K of a plan (the optimum's every cost evaluation), compiled: ``q0 + cumsum(commands, axis=0) * dt``
    exactly, for 6 and 7 joints, commands of every magnitude, and views that are not contiguous."""
    from snac_gym.model.kinematics import joint_path

    rng = np.random.default_rng(steps)
    for joints in (6, 7):
        commands = rng.standard_normal((steps, joints)) * 10.0 ** rng.integers(-6, 3, (steps, joints))
        q0, dt = rng.uniform(-3.0, 3.0, joints), 1.0 / 125.0
        np.testing.assert_array_equal(joint_path(q0, commands, dt), q0 + np.cumsum(commands, axis=0) * dt)
        wide = np.repeat(commands, 2, axis=1)[:, ::2]  # the same values, strided
        np.testing.assert_array_equal(joint_path(q0, wide, dt), q0 + np.cumsum(wide, axis=0) * dt)
