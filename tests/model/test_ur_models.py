"""The UR model table: the written URDFs against independent ones, the datasheet limits the real arm is held to."""

import math

import numpy as np
import pinocchio as pin
import pytest

from snac_gym.apps.real import UR_ROBOTS, run_setup
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.robots import robot_names
from snac_gym.model.ur_models import (
    E_SERIES_URDF_DIR,
    UR_MODELS,
    datasheet_velocity_limits,
    flange_transform,
    series_of,
    urdf_text,
    velocity_limits,
)
from snac_gym.real.safety import SafetyLayer, SafetyLimits


def _tool_pose(kinematics: Kinematics, q: np.ndarray) -> np.ndarray:
    pin.framesForwardKinematics(kinematics.model, kinematics.data, q)
    return kinematics.data.oMf[kinematics._ee_id].homogeneous.copy()


@pytest.mark.parametrize("robot", ["ur3", "ur5", "ur10"])
def test_the_urdf_writer_reproduces_example_robot_data_on_the_cb3_arms(robot, tmp_path):
    """The writer's frames checked against URDFs it did not write: example-robot-data's CB3 arms, written
    from the same kind of DH rows, give tool0's pose in the base frame to 1e-12 at random angles."""
    path = tmp_path / f"{robot}.urdf"
    path.write_text(urdf_text(robot))
    written, shipped = Kinematics("written", urdf_path=str(path)), Kinematics(robot)
    assert written.joint_names == shipped.joint_names
    np.testing.assert_allclose(written.lower_limits, shipped.lower_limits, atol=1e-9)  # elbow ±π, the rest ±2π
    for q in np.random.default_rng(11).uniform(-2 * math.pi, 2 * math.pi, (40, 6)):
        np.testing.assert_allclose(_tool_pose(written, q), _tool_pose(shipped, q), atol=1e-12)
        np.testing.assert_allclose(flange_transform(robot, q), _tool_pose(shipped, q), atol=1e-12)


@pytest.mark.parametrize("robot", [name for name, model in UR_MODELS.items() if model.series == "e"])
def test_the_shipped_e_series_urdfs_are_the_writers_and_are_registered(robot):
    assert (E_SERIES_URDF_DIR / f"{robot}.urdf").read_text() == urdf_text(robot), "run tools/write_ur_urdfs.py"
    assert robot in robot_names() and robot in UR_ROBOTS
    kinematics = Kinematics(robot)
    np.testing.assert_allclose(kinematics.velocity_limits, datasheet_velocity_limits(robot))
    for q in np.random.default_rng(12).uniform(-math.pi, math.pi, (20, 6)):
        np.testing.assert_allclose(_tool_pose(kinematics, q), flange_transform(robot, q), atol=1e-12)


def test_each_model_reaches_about_its_datasheet_reach():
    """A check on the DH rows against an independent number: the farthest flange position from the
    shoulder, over random angles, is 1.0-1.25 × the datasheet's reach (UR quotes a working radius short
    of the stretched arm)."""
    rng = np.random.default_rng(3)
    for name, model in UR_MODELS.items():
        q = rng.uniform(-math.pi, math.pi, (3000, 6))
        shoulder = np.array([0.0, 0.0, model.dh[0]])
        farthest = max(np.linalg.norm(flange_transform(name, row)[:3, 3] - shoulder) for row in q)
        assert 1.0 <= farthest / model.reach <= 1.25, (name, farthest, model.reach)


def test_a_real_arm_is_never_commanded_past_its_datasheet_speed():
    """example-robot-data's UR10 allows 2.16 rad/s (123.8 °/s) at the base and shoulder, 3.2 rad/s at the
    wrists; the datasheet says 120 °/s and 180 °/s. The safety layer holds the lower."""
    kinematics = Kinematics("ur10")
    np.testing.assert_allclose(kinematics.velocity_limits, [2.16, 2.16, 3.15, 3.2, 3.2, 3.2])
    expected = np.radians([120, 120, 180, 180, 180, 180])
    np.testing.assert_allclose(velocity_limits("ur10", kinematics.velocity_limits), expected)
    layer = SafetyLayer(kinematics, SafetyLimits(speed_scale=1.0, max_joint_acceleration=40.0), 0.008)
    np.testing.assert_allclose(layer.speed_bound, expected)
    # The UR3's URDF is below its datasheet (2.16 < π rad/s at the base): the URDF's holds there.
    ur3 = Kinematics("ur3")
    np.testing.assert_allclose(velocity_limits("ur3", ur3.velocity_limits), [2.16, 2.16, math.pi, 3.2, 3.2, 3.2])
    # Another robot keeps its URDF's.
    panda = Kinematics("panda")
    np.testing.assert_array_equal(velocity_limits("panda", panda.velocity_limits), panda.velocity_limits)


def test_every_ur_urdf_stays_inside_the_datasheet_joint_range():
    for name in UR_MODELS:
        kinematics = Kinematics(name)
        assert np.all(kinematics.lower_limits >= -2 * math.pi - 1e-9) and np.all(
            kinematics.upper_limits <= 2 * math.pi + 1e-9
        )


def test_the_series_defaults_to_the_arms_and_a_cb3_arm_refuses_500_hz():
    assert series_of("ur5") == "cb" and series_of("ur5e") == "e" and series_of("ur5e", "cb") == "cb"
    with pytest.raises(ValueError, match="the UR10 is a CB3 arm"):
        series_of("ur10", "e")
    with pytest.raises(ValueError, match="not a UR model; choose one of ur3, ur5, ur10, ur3e"):
        series_of("panda")


def test_the_setup_names_its_limits_and_refuses_a_reference_beyond_the_datasheet_reach():
    setup = run_setup("reach", "ur10e", None, None, SafetyLimits())
    assert setup["series"] == "e" and setup["reach"] == 1.3
    np.testing.assert_allclose(setup["speed_limits"], np.radians([120, 120, 180, 180, 180, 180]))
    assert "e-Series User Manual, UR10e" in setup["speed_limits_source"]
    # 0.95 m from the UR5e's shoulder: inside the arm's kinematic reach (0.96 m), beyond the datasheet's 0.85 m.
    kinematics = Kinematics("ur5e")
    q0 = [0.0, -1.2, 1.6, -1.9, -1.57, 0.0]
    far = np.array([0.0, 0.0, 0.1625]) + 0.95 * np.array([-0.8, 0.6, 0.0])
    assert np.linalg.norm(far - [0, 0, 0.1625]) < 0.96 and kinematics.forward(np.array(q0)).shape == (3,)
    with pytest.raises(ValueError, match=r"beyond the UR5e's datasheet reach of 0.850 m"):
        run_setup("reach", "ur5e", q0, far.tolist(), SafetyLimits(box_low=(-2, -2, -2), box_high=(2, 2, 2)))
