"""References, the observation layout and the sample space."""

import itertools

import numpy as np
import pytest

from snac_gym.observation import ObservationLayout
from snac_gym.references import PAPER_Q0, Ellipse, FixedTarget
from snac_gym.sampling import (
    SampleSpace,
    check_reachable,
    ellipse_is_feasible,
    sample_ellipse,
    sample_seed_pose,
    sample_target,
    solve_reachable,
)


def test_ellipse_velocity_is_the_derivative_of_position(rng):
    ellipse = Ellipse([-0.7, 0.1, 0.4], [0.2, 0.1], rng.uniform(-1, 1, 3), angular_speed=0.3, phase=0.7)
    for t in rng.uniform(0, 20, 5):
        h = 1e-6
        finite = (ellipse.position(t + h) - ellipse.position(t - h)) / (2 * h)
        np.testing.assert_allclose(ellipse.velocity(t), finite, atol=1e-8)
        # every point lies on the ellipse: its local coordinates satisfy (u/a)² + (v/b)² = 1
        from snac_gym.references import rotation_from_rpy

        local = rotation_from_rpy(*ellipse.orientation).T @ (ellipse.position(t) - ellipse.centre)
        assert (local[0] / 0.2) ** 2 + (local[1] / 0.1) ** 2 == pytest.approx(1.0)
        assert abs(local[2]) < 1e-12


def test_paper_circle_and_dict_round_trip():
    circle = Ellipse.paper_circle()
    np.testing.assert_allclose(circle.position(0.0), [-0.5, 0.0, 0.5])
    assert np.linalg.norm(circle.velocity(3.0)) == pytest.approx(0.2 * 0.075)
    again = Ellipse.from_dict(circle.to_dict())
    np.testing.assert_array_equal(again.position(1.234), circle.position(1.234))
    assert Ellipse.from_dict({"centre": [0, 0, 1], "radius": 0.1}).semi_axes.tolist() == [0.1, 0.1]


def test_an_unpickled_ellipse_moves_bit_for_bit_as_the_one_built(rng):
    """The evaluator pickles every sample for its workers: the ellipse travels as its one packed array."""
    import copy
    import pickle

    times = np.arange(2501) * 0.008
    for _ in range(20):
        built = Ellipse(rng.uniform(-0.8, 0.8, 3), rng.uniform(0.05, 0.3, 2), rng.uniform(-3, 3, 3),
                        angular_speed=rng.uniform(-0.5, 0.5), phase=rng.uniform(-3, 3))  # fmt: skip
        for again in (pickle.loads(pickle.dumps(built, protocol=5)), copy.deepcopy(built)):
            assert type(again) is Ellipse and again.to_dict() == built.to_dict()
            for a, b in zip(built.trajectory(times), again.trajectory(times), strict=True):
                assert a.tobytes() == b.tobytes()
            assert built.points(17).tobytes() == again.points(17).tobytes()
            assert [v.tobytes() for v in built.position_and_velocity(3.7)] == [
                v.tobytes() for v in again.position_and_velocity(3.7)
            ]
    # the arrays are views of the packed one, so it cannot go stale
    assert all(np.shares_memory(getattr(built, name), built._packed) for name in ("centre", "_major", "_axes_matrix"))


@pytest.mark.parametrize(
    "spec, message",
    [
        ({"radius": 0.1}, "needs a 'centre'"),
        ({"centre": [0, 0, 1]}, "exactly one of"),
        ({"centre": [0, 0, 1], "radius": 0.1, "speed": 1}, "unknown ellipse keys"),
        ({"centre": [0, 0], "radius": 0.1}, "centre must be 3"),
        ({"centre": [0, 0, 1], "semi_axes": [0.1, -0.1]}, "semi_axes must be positive"),
        ({"centre": [0, 0, 1], "radius": 0.1, "phase": float("nan")}, "phase must be finite"),
    ],
)
def test_bad_ellipse_specs_name_the_problem(spec, message):
    with pytest.raises(ValueError, match=message):
        Ellipse.from_dict(spec)


def test_fixed_target_is_immutable():
    target = FixedTarget([1.0, 2.0, 3.0])
    with pytest.raises(ValueError):
        target.position(0.0)[0] = 5.0
    np.testing.assert_array_equal(target.velocity(1.0), 0.0)


def test_observation_layout_pack_unpack(rng):
    layout = ObservationLayout(6, 3)
    parts = [rng.normal(size=6), rng.normal(size=6)] + [rng.normal(size=3) for _ in range(4)]
    obs = layout.pack(*parts)
    fields = layout.unpack(obs)
    assert obs.shape == (27,) and layout.size == 27
    np.testing.assert_array_equal(fields.q, parts[0])
    np.testing.assert_array_equal(fields.e, parts[2] - parts[3])
    np.testing.assert_array_equal(fields.x_c, parts[5])
    with pytest.raises(ValueError, match=r"shape \(27,\)"):
        layout.unpack(np.zeros(26))
    assert ObservationLayout(7, 3).size == 29  # nothing assumes six joints


def test_default_cuboid_corners_are_reachable(ur10):
    space = SampleSpace()
    for corner in itertools.product(*zip(space.low, space.high)):
        assert solve_reachable(ur10, np.array(corner)) is not None, corner


def test_samplers_are_seeded_and_stay_in_the_space(ur10):
    space = SampleSpace()
    draws = []
    for _ in range(2):
        rng = np.random.default_rng(7)
        draws.append(
            (
                sample_seed_pose(ur10, rng, space),
                sample_target(ur10, rng, space).target,
                sample_ellipse(ur10, rng, space),
            )
        )
    np.testing.assert_array_equal(draws[0][0], draws[1][0])
    np.testing.assert_array_equal(draws[0][1], draws[1][1])
    assert draws[0][2].to_dict() == draws[1][2].to_dict()
    q, target, ellipse = draws[0]
    assert space.contains(ur10.forward(q)) and space.contains(target)
    assert ur10.singular_values(q)[-1] >= space.min_singular_value
    assert np.all(q > ur10.lower_limits + space.joint_margin) and np.all(q < ur10.upper_limits - space.joint_margin)
    assert ellipse_is_feasible(ur10, ellipse, space)
    assert all(space.contains(pt) for pt in ellipse.points(64))


def test_unreachable_point_error_names_it(ur10):
    with pytest.raises(ValueError, match=r"\[2.0, 0.0, 0.5\].*outside the reachable workspace"):
        check_reachable(ur10, np.array([[2.0, 0.0, 0.5]]), "options['target']")
    check_reachable(ur10, np.array([ur10.forward(np.array(PAPER_Q0))]), "seed")


def test_sample_space_rejects_inverted_cuboid():
    with pytest.raises(ValueError, match="low < high"):
        SampleSpace(low=(0, 0, 0), high=(1, -1, 1))


def test_position_and_velocity_agrees_with_separate_calls(rng):
    ellipse = Ellipse([-0.6, 0.2, 0.4], [0.15, 0.05], rng.uniform(-2, 2, 3), angular_speed=-0.2, phase=1.1)
    for t in (0.0, 1.7, 33.3):
        pos, vel = ellipse.position_and_velocity(t)
        np.testing.assert_allclose(pos, ellipse.position(t), atol=1e-15)
        np.testing.assert_allclose(vel, ellipse.velocity(t), atol=1e-15)
    target = FixedTarget([0.1, 0.2, 0.3])
    assert target.position_and_velocity(2.0)[0] is target.target


def test_the_per_step_reference_is_the_array_formula_bit_for_bit(rng):
    """The env's x_d(t), ẋ_d(t) (scalar arithmetic) are the floats of c + cos·a + sin·b and (ω cos)·b − (ω sin)·a
    on 3-vectors, a = R ê₁ semi-axis a, b = R ê₂ semi-axis b, built here from the rotation, not from the ellipse's
    own derived arrays: the step's rewrite for speed changed no bit of an env's observation."""
    import math

    from snac_gym.references import rotation_from_rpy

    for _ in range(50):
        centre, axes, rpy = rng.uniform(-0.9, 0.9, 3), rng.uniform(0.01, 0.3, 2), rng.uniform(-4, 4, 3)
        w, phase = rng.choice([-1, 1]) * rng.uniform(0.001, 2.0), rng.uniform(-7, 7)
        ellipse = Ellipse(centre, axes, rpy, angular_speed=w, phase=phase)
        rotation = rotation_from_rpy(*rpy)
        major, minor = rotation[:, 0] * axes[0], rotation[:, 1] * axes[1]
        for t in np.concatenate([rng.uniform(0, 30, 20), [0.0, 1e-9, 2500 * 0.008, 1e4]]):
            angle = w * float(t) + phase
            cos, sin = math.cos(angle), math.sin(angle)
            expected = (centre + cos * major + sin * minor, (w * cos) * minor - (w * sin) * major)
            got = ellipse.position_and_velocity(float(t))
            assert [v.dtype for v in got] == [np.float64, np.float64] and [v.shape for v in got] == [(3,), (3,)]
            assert [v.tobytes() for v in got] == [v.tobytes() for v in expected], (t, got, expected)


def test_trajectory_agrees_with_per_time_calls(rng):
    ellipse = Ellipse([-0.6, 0.2, 0.4], [0.15, 0.05], rng.uniform(-2, 2, 3), angular_speed=0.3, phase=0.4)
    times = np.array([0.0, 0.5, 7.25])
    positions, velocities = ellipse.trajectory(times)
    for t, pos, vel in zip(times, positions, velocities):
        np.testing.assert_allclose(pos, ellipse.position(t), atol=1e-15)
        np.testing.assert_allclose(vel, ellipse.velocity(t), atol=1e-15)
    positions, velocities = FixedTarget([0.1, 0.2, 0.3]).trajectory(times)
    np.testing.assert_array_equal(positions, np.tile([0.1, 0.2, 0.3], (3, 1)))
    np.testing.assert_array_equal(velocities, 0.0)


def test_the_cuboid_holds_a_set_of_points_only_when_it_holds_each():
    space = SampleSpace(low=(0.0, 0.0, 0.0), high=(1.0, 1.0, 1.0))
    inside = np.array([[0.0, 0.5, 1.0], [1.0, 1.0, 1.0], [0.2, 0.3, 0.4]])
    assert space.contains(inside) and all(space.contains(p) for p in inside)
    for row, column, value in [(0, 0, -1e-6), (2, 2, 1.0 + 1e-6)]:
        outside = inside.copy()
        outside[row, column] = value
        assert not space.contains(outside) and not space.contains(outside[row])
    assert space.contains(np.array([1.0 + 5e-10, 0.5, 0.5]))  # within the default 1e-9
