"""The kinds of ``--model-error`` beyond the first three: link lengths, axis tilts, the base, a random rigid
error of every placement, and another robot's model.

Each wrong model is checked against an independent computation: the URDF text itself edited as the
error says (each joint's ``<origin xyz rpy>`` changed, rotations from scipy), built with
``pinocchio.buildModelFromXML`` and read as the tool0 position in the ``base`` frame, against
:class:`~snac_gym.model.kinematics.Kinematics`' Pinocchio path, its compiled batch chain and the position
chain, positions and Jacobians.
"""

import warnings
import xml.etree.ElementTree as ET

import numpy as np
import pinocchio as pin
import pytest
from scipy.spatial.transform import Rotation

from snac_gym.model.kinematics import Kinematics, PositionChain, resolved_urdf_text, robot_urdf_path
from snac_gym.model.model_error import ModelError, tilt_directions, tool_displacement

JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")
TOOL_JOINT = "wrist_3_link-tool0_fixed_joint"
BASE_JOINT = "base_link-base_fixed_joint"


def _pose(element):
    """The SE3 of a URDF ``<origin>`` (absent: identity)."""
    origin = element.find("origin")
    xyz = [float(v) for v in origin.get("xyz", "0 0 0").split()] if origin is not None else [0.0] * 3
    rpy = [float(v) for v in origin.get("rpy", "0 0 0").split()] if origin is not None else [0.0] * 3
    return pin.SE3(Rotation.from_euler("xyz", rpy).as_matrix(), np.array(xyz))


def _set_pose(element, pose):
    origin = element.find("origin")
    if origin is None:
        origin = ET.SubElement(element, "origin")
    origin.set("xyz", " ".join(repr(float(v)) for v in pose.translation))
    with warnings.catch_warnings():  # UR's π/2 pitches are a gimbal lock: the angles differ, not the rotation
        warnings.simplefilter("ignore", UserWarning)
        rpy = Rotation.from_matrix(pose.rotation).as_euler("xyz")
    origin.set("rpy", " ".join(repr(float(v)) for v in rpy))


def _rotation(rotvec):
    return pin.SE3(Rotation.from_rotvec(rotvec).as_matrix(), np.zeros(3))


def _edited_urdf(joint_offset=(), link_scale=0.0, tool_offset=(0, 0, 0), link_length=(), joint_axis_tilt=(),
                 base=(0,) * 6, random=None):  # fmt: skip
    """UR10's URDF with every joint origin changed as docs/model-error.md and the module docstring say:
    origin ← (R, t̃) · E · exp(αu + βv) · exp(aω), T_base in front for the root joint, the tool's
    (R, (1 + s) t) · E · (I, offset); t̃ is t scaled by 1 + s, then lengthened by d along itself."""
    root = ET.fromstring(resolved_urdf_text(robot_urdf_path("ur10")))
    joints = {joint.get("name"): joint for joint in root.findall("joint")}
    draws = np.zeros((7, 6)) if random is None else random[0] * np.random.default_rng(random[1]).standard_normal((7, 6))
    tilts = np.zeros((2, 6))
    tilts.reshape(-1)[: len(joint_axis_tilt)] = joint_axis_tilt
    base_link = _pose(joints[BASE_JOINT])  # the base frame in base_link
    for index, name in enumerate(JOINTS):
        joint = joints[name]
        pose = _pose(joint)
        t = (1 + link_scale) * pose.translation
        if link_length:
            t = t / np.linalg.norm(t) * (np.linalg.norm(t) + link_length[index])
        pose = pin.SE3(pose.rotation, t)
        pose = pose * pin.SE3(Rotation.from_rotvec(draws[index, 3:]).as_matrix(), draws[index, :3])
        axis = np.array([float(v) for v in joint.find("axis").get("xyz").split()])
        least = np.argmin(np.abs(axis))
        u = np.cross(axis, np.eye(3)[least])
        u /= np.linalg.norm(u)
        v = np.cross(axis, u)
        pose = pose * _rotation(tilts[0, index] * u + tilts[1, index] * v)
        if joint_offset:
            pose = pose * _rotation(joint_offset[index] * axis)
        if index == 0:  # the root joint: the model's base is displaced by T, in the base frame
            shift = pin.SE3(Rotation.from_rotvec(base[3:]).as_matrix(), np.array(base[:3], dtype=float))
            pose = base_link * shift * base_link.inverse() * pose
        _set_pose(joint, pose)
    tool = _pose(joints[TOOL_JOINT])
    tool = pin.SE3(tool.rotation, (1 + link_scale) * tool.translation)
    tool = tool * pin.SE3(Rotation.from_rotvec(draws[6, 3:]).as_matrix(), draws[6, :3])
    _set_pose(joints[TOOL_JOINT], tool * pin.SE3(np.eye(3), np.array(tool_offset, dtype=float)))
    return ET.tostring(root, encoding="unicode")


def _independent(urdf_text, qs):
    """The tool0 position and position Jacobian in the base frame, from the edited URDF through Pinocchio."""
    model = pin.buildModelFromXML(urdf_text)
    data = model.createData()
    base, tool = model.getFrameId("base"), model.getFrameId("tool0")
    positions, jacobians = [], []
    for q in qs:
        world = pin.computeFrameJacobian(model, data, q, tool, pin.LOCAL_WORLD_ALIGNED)[:3]
        pin.updateFramePlacements(model, data)
        frame = data.oMf[base]
        positions.append(frame.actInv(data.oMf[tool]).translation)
        jacobians.append(frame.rotation.T @ world)
    return np.array(positions), np.array(jacobians)


def _check(kinematics, urdf_text, qs):
    positions, jacobians = _independent(urdf_text, qs)
    assert kinematics._chain is not None  # the compiled chain path is the one under test
    np.testing.assert_allclose(kinematics.forward_batch(qs), positions, rtol=0, atol=1e-9)
    np.testing.assert_allclose(kinematics.jacobian_batch(qs), jacobians, rtol=0, atol=1e-9)
    np.testing.assert_allclose(PositionChain.from_kinematics(kinematics).forward(qs), positions, rtol=0, atol=1e-9)
    for q, position, jacobian in zip(qs, positions, jacobians, strict=True):
        np.testing.assert_allclose(kinematics.forward(q), position, rtol=0, atol=1e-9)
        np.testing.assert_allclose(kinematics.jacobian(q), jacobian, rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def qs(ur10):
    return np.random.default_rng(5).uniform(ur10.lower_limits, ur10.upper_limits, size=(8, 6))


def test_the_edited_urdf_without_an_error_is_the_true_model(ur10, qs):
    _check(ur10, _edited_urdf(), qs)


KINDS = {
    "link_length": {"link_length": (0.05, -0.03, 0.1, -0.2, 0.02, 0.01)},
    "joint_axis_tilt (m)": {"joint_axis_tilt": (0.02, -0.05, 0.1, 0.03, -0.04, 0.2)},
    "joint_axis_tilt (2m)": {"joint_axis_tilt": (0.02, -0.05, 0.1, 0.03, -0.04, 0.2,
                                                 -0.1, 0.3, 0.05, -0.02, 0.01, 0.4)},
    "base": {"base": (0.1, -0.05, 0.2, 0.1, -0.2, 0.3)},
    "random": {"random": (0.01, 7)},
    "every part": {
        "joint_offset": (0.1, -0.2, 0.3, 0.2, -0.3, 0.2), "link_scale": 0.05, "tool_offset": (0.02, -0.02, 0.05),
        "link_length": (0.05, -0.03, 0.1, -0.2, 0.02, 0.01), "joint_axis_tilt": (0.02, -0.05, 0.1, 0.03, -0.04, 0.2),
        "base": (0.1, -0.05, 0.2, 0.1, -0.2, 0.3), "random": (0.005, 3),
    },
}  # fmt: skip


@pytest.mark.parametrize("kind", KINDS)
def test_each_kind_is_the_urdf_edited_as_documented(kind, ur10, qs):
    error = ModelError(**KINDS[kind])
    model = ur10.with_model_error(error.spec())  # through the text, as --model-error gives it
    assert model.model_error == error
    _check(model, _edited_urdf(**KINDS[kind]), qs)
    assert tool_displacement(ur10, model, qs).min() > 1e-4  # and the error does move the tool


def test_a_base_error_is_the_base_frame_moved_the_other_way(ur10, qs):
    """f_model = T f: the same as the true arm seen from a base frame moved by T⁻¹ (a second, separate edit)."""
    base = (0.1, -0.05, 0.2, 0.1, -0.2, 0.3)
    root = ET.fromstring(resolved_urdf_text(robot_urdf_path("ur10")))
    joint = next(j for j in root.findall("joint") if j.get("name") == BASE_JOINT)
    shift = pin.SE3(Rotation.from_rotvec(base[3:]).as_matrix(), np.array(base[:3]))
    _set_pose(joint, _pose(joint) * shift.inverse())
    _check(ur10.with_model_error(ModelError(base=base)), ET.tostring(root, encoding="unicode"), qs)


def test_the_tilt_directions_are_perpendicular_and_as_documented():
    np.testing.assert_array_equal(np.array(tilt_directions([0, 0, 1])), [[0, 1, 0], [-1, 0, 0]])
    np.testing.assert_array_equal(np.array(tilt_directions([0, 1, 0])), [[0, 0, -1], [-1, 0, 0]])
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    u, v = tilt_directions(axis)
    np.testing.assert_allclose([u @ axis, v @ axis, u @ v, u @ u, v @ v], [0, 0, 0, 1, 1], atol=1e-15)


def test_the_random_draw_depends_on_sigma_seed_and_count_only():
    draws = ModelError(random=(0.01, 4)).random_draws(6)
    np.testing.assert_array_equal(draws, 0.01 * np.random.default_rng(4).standard_normal((7, 6)))
    np.testing.assert_allclose(ModelError(random=(0.02, 4)).random_draws(6), 2 * draws, rtol=1e-15)
    assert not np.array_equal(ModelError(random=(0.01, 5)).random_draws(6), draws)
    np.testing.assert_array_equal(ModelError(random=(0.0, 4)).random_draws(6), 0.0)
    assert ModelError(random=(0.0, 4)).is_zero and not ModelError(random=(0.01, 4)).is_zero


def test_model_names_another_robot(ur10, qs):
    ur5 = Kinematics("ur5")
    wrong = ur10.with_model_error("model=ur5")
    assert wrong.robot == "ur5" and wrong.model_error is None
    np.testing.assert_array_equal(wrong.forward_batch(qs), ur5.forward_batch(qs))
    np.testing.assert_array_equal(wrong.jacobian(qs[0]), ur5.jacobian(qs[0]))
    distance = tool_displacement(ur10, wrong, qs)
    assert 0.1 < np.median(distance) < 1.0  # tens of centimetres
    # the other parts apply on top of the other robot
    combined = ur10.with_model_error("model=ur5;joint_offset=0,0,0.3,0,0,0;random=0.002,1")
    expected = Kinematics("ur5", model_error="joint_offset=0,0,0.3,0,0,0;random=0.002,1")
    np.testing.assert_array_equal(combined.forward_batch(qs), expected.forward_batch(qs))
    # naming the arm itself changes nothing
    np.testing.assert_array_equal(ur10.with_model_error("model=ur10").forward_batch(qs), ur10.forward_batch(qs))
    assert Kinematics("ur10", model_error="model=UR10").model_error is None


def test_kinematics_itself_does_not_silently_become_another_robot():
    with pytest.raises(ValueError, match=r"model=ur5: Kinematics\('ur10'\) does not become another robot"):
        Kinematics("ur10", model_error="model=ur5")


def test_a_model_with_another_joint_count_is_refused_naming_both():
    with pytest.raises(ValueError, match="model=panda has 7 joints but ur10 has 6"):
        Kinematics("ur10").with_model_error("model=panda")
    xarm = Kinematics("panda").with_model_error("model=xarm7")  # 7 and 7: its own frames, panda's are not there
    assert (xarm.robot, xarm.ee_frame, xarm.base_frame) == ("xarm7", "link_eef", "link_base")


def test_a_length_change_needs_a_length():
    with pytest.raises(ValueError, match="joint 'panda_joint2' has a zero-length placement, so its change must be 0"):
        Kinematics("panda", model_error="link_length=0,0.01,0,0,0,0,0")
    Kinematics("panda", model_error="link_length=0.01,0,0,0,0,0,0")
    with pytest.raises(ValueError, match="-0.2 m leaves no length to the placement of joint 'shoulder_pan_joint'"):
        Kinematics("ur10", model_error="link_length=-0.2,0,0,0,0,0")


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("link_length=0.1,0,0", "link_length needs 6 values"),
        ("link_length=0.6,0,0,0,0,0", r"link_length \(m\) must be a finite number in \[-0.5, 0.5\], got 0.6"),
        (
            "joint_axis_tilt=0.1,0,0,0",
            r"joint_axis_tilt needs 6 values \(one per joint\) or 12 \(two per joint\), got 4",
        ),
        ("joint_axis_tilt=0.1,0,0,0,0,inf", r"joint_axis_tilt \(rad\) must be a finite number in \[-0.5, 0.5\]"),
        ("base=0,0,0", "base must be 6 finite numbers"),
        ("base=2,0,0,0,0,0", r"base x,y,z \(m\) must be a finite number in \[-1, 1\], got 2.0"),
        ("base=0,0,0,3,3,0", "base rotation vector rx,ry,rz must have a norm of at most pi"),
        ("random=0.01", r"random must be 2 numbers \(sigma, seed\)"),
        ("random=0.2,1", r"random sigma must be a finite number in \[0, 0.1\], got 0.2"),
        ("random=-0.01,1", r"random sigma must be a finite number in \[0, 0.1\]"),
        ("random=0.01,-1", "random seed must be a whole number"),
        ("random=0.01,1.5", "random seed must be a whole number"),
        ("random=0.01,x", r"random='0.01,x' is not a comma-separated list of numbers"),
        ("model=nosuch", "model error model: unknown robot 'nosuch'"),
        ("model=", "model error model must name a registered robot"),
        ("model=ur5;model=ur3", "model is given twice"),
        (
            "tilt=0.1",
            "NAME one of joint_offset, link_scale, tool_offset, link_length, joint_axis_tilt, base, random, model",
        ),
    ],
)
def test_a_bad_part_is_refused_naming_it(spec, message):
    with pytest.raises(ValueError, match=message):
        ModelError.parse(spec).check_joints(6)


@pytest.mark.parametrize(
    "spec",
    [
        "link_length=0.05,-0.03,0.1,-0.2,0.02,0.01",
        "joint_axis_tilt=0.02,-0.05,0.1,0.03,-0.04,0.2",
        "joint_axis_tilt=0.02,-0.05,0.1,0.03,-0.04,0.2,-0.1,0.3,0.05,-0.02,0.01,0.4",
        "base=0.1,-0.05,0.2,0.1,-0.2,0.3",
        "random=0.005,1",
        "random=0.001,18446744073709",
        "model=ur5",
        "model=UR5;random=0.002,3;joint_offset=0,0,0.3,0,0,0;link_scale=0.01;tool_offset=0,0,0.03;base=0,0,0.01,0,0,0",
    ],
)
def test_the_specification_round_trips(spec):
    error = ModelError.parse(spec)
    assert ModelError.parse(error.spec()) == error
    assert not error.is_zero


def test_tool_displacement_is_the_distance_of_the_tool_points(ur10, qs):
    model = ur10.with_model_error("tool_offset=0,0,0.03")
    np.testing.assert_allclose(tool_displacement(ur10, model, qs), 0.03, rtol=1e-12)
    with pytest.raises(ValueError, match="same joint count, got 6 and 7"):
        tool_displacement(ur10, Kinematics("panda"), qs)


def test_another_robots_model_keeps_the_arms_velocity_limits_and_name_for_the_controllers():
    """Under model=ur5 the UR10 is still the arm: its limits clip the commands, and a policy trained on it runs."""
    from snac_gym.evaluation.execution.jobs import policy_context

    from snac_gym.policies.registry import make_policy

    context = policy_context("ur10", 1 / 125, "reach", "model=ur5")
    assert context.kinematics.robot == "ur5" and context.arm_robot == "ur10"
    np.testing.assert_array_equal(context.velocity_limits, Kinematics("ur10").velocity_limits)
    assert not np.array_equal(context.velocity_limits, Kinematics("ur5").velocity_limits)  # the case that matters
    policy = make_policy("ppo", context)  # trained on the UR10: refused before, naming 'ur5' as the env's robot
    policy.reset(seed=0)
    assert np.isfinite(policy.act(np.full(context.layout.size, 0.1))).all()


def test_the_evaluator_refuses_another_robots_model_with_another_joint_count_before_writing(tmp_path):
    from snac_gym.evaluation.run_config import EvaluationConfig
    from snac_gym.evaluation.runner import run_evaluation

    config = EvaluationConfig(out=tmp_path / "run", controllers=("lqr",), samples=2, model_error="model=panda")
    with pytest.raises(ValueError, match="model=panda has 7 joints but ur10 has 6"):
        run_evaluation(config)
    assert not (tmp_path / "run").exists() or not any((tmp_path / "run").iterdir())
