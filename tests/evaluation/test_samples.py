"""The evaluator's parts: sample sets and their CSV form, the batched references, the kinematic
and PyBullet engines, the optional batch protocol, the per-rollout metrics and the knob search."""

from __future__ import annotations

import functools
import itertools
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from snac_gym.evaluation.effort.search import match_effort
from snac_gym.evaluation.samples import (
    EvaluationSample,
    SampleFileError,
    column_names,
    generate_samples,
    policy_seed,
    read_samples_csv,
    write_samples_csv,
)

from snac_gym.control.cost import trajectory_cost
from snac_gym.metrics import rollout_metrics
from snac_gym.observation import ObservationLayout
from snac_gym.policies.base import BasePolicy, LockstepPolicies, PolicyContext, supports_batch
from snac_gym.references import PAPER_Q0, PAPER_TARGET, Ellipse, FixedTarget
from snac_gym.rollout import RolloutError, Rollouts, reference_trajectories, simulate_env, simulate_kinematic
from snac_gym.sampling import SampleSpace, ellipse_is_feasible

DT = 1.0 / 125.0


class PseudoInversePolicy(BasePolicy):
    """Resolved-rate test controller ``u = J⁺(ẋ_d − gain·e)``, clipped; records what it observes."""

    effort_parameter = "gain"

    def __init__(self, env, gain: float = 2.0) -> None:
        super().__init__(env)
        self.gain = float(gain)
        self.seen: list[np.ndarray] = []

    def reset(self, seed=None) -> None:
        self.seen = []
        self.internals = {}

    def _act(self, obs):
        self.seen.append(np.array(obs))
        fields = self.layout.unpack(obs)
        jacobian = self.kinematics.jacobian(fields.q)
        command = np.linalg.pinv(jacobian) @ (fields.xdot_d - self.gain * fields.e)
        return np.clip(command, -self.velocity_limits, self.velocity_limits)


class BatchPseudoInversePolicy(PseudoInversePolicy):
    """The same controller offering the optional batch protocol."""

    def reset_batch(self, seeds) -> None:
        self.batch_seeds = list(seeds)

    def act_batch(self, obs_batch):
        s = self.layout.slices
        jacobians = np.stack([self.kinematics.jacobian(q) for q in obs_batch[:, s["q"]]])
        velocity = obs_batch[:, s["xdot_d"]] - self.gain * obs_batch[:, s["e"]]
        commands = np.einsum("bij,bj->bi", np.linalg.pinv(jacobians), velocity)
        return np.clip(commands, -self.velocity_limits, self.velocity_limits)


class NaNPolicy(PseudoInversePolicy):
    """Returns NaN from its fourth step (k = 3) on."""

    def _act(self, obs):
        command = super()._act(obs)
        return np.full(6, np.nan) if len(self.seen) > 3 else command


@pytest.fixture(scope="module")
def space(ur10):
    return SampleSpace.for_robot(ur10)


@pytest.fixture(scope="module")
def context_of(ur10):
    layout = ObservationLayout(ur10.n_joints, ur10.task_dim)
    return lambda task: PolicyContext(ur10, DT, ur10.velocity_limits.copy(), layout, task)


@pytest.fixture(scope="module")
def track_samples(ur10, space):
    return generate_samples(ur10, space, 3, "track", range(3))


@pytest.fixture(scope="module")
def reach_samples(ur10, space):
    return generate_samples(ur10, space, 3, "reach", range(4))


# -- samples ----------------------------------------------------------------------------------


def test_sample_i_depends_only_on_seed_task_and_index(ur10, space, reach_samples):
    again = generate_samples(ur10, space, 3, "reach", [2, 0])
    assert np.array_equal(again[0].q0, reach_samples[2].q0)
    assert np.array_equal(again[1].reference.target, reach_samples[0].reference.target)
    other_seed = generate_samples(ur10, space, 4, "reach", [0])[0]
    assert not np.array_equal(other_seed.reference.target, reach_samples[0].reference.target)
    assert policy_seed(3, "reach", 1) == policy_seed(3, "reach", 1) != policy_seed(3, "track", 1)


def test_random_samples_lie_in_the_documented_space(ur10, space, reach_samples, track_samples):
    for sample in reach_samples + track_samples:
        assert space.contains(ur10.forward(sample.q0))
        assert np.all(sample.q0 >= ur10.lower_limits + space.joint_margin)
        assert np.all(sample.q0 <= ur10.upper_limits - space.joint_margin)
        assert ur10.singular_values(sample.q0)[-1] >= space.min_singular_value
    assert all(space.contains(s.reference.target) for s in reach_samples)
    assert all(ellipse_is_feasible(ur10, s.reference, space) for s in track_samples)


def test_csv_round_trip_is_exact(tmp_path, ur10, reach_samples, track_samples):
    path = write_samples_csv(reach_samples + track_samples, tmp_path / "s.csv", ur10.n_joints)
    read = read_samples_csv(path, ur10)
    assert [s.index for s in read["reach"]] == [0, 1, 2, 3] and len(read["track"]) == 3
    for a, b in zip(reach_samples + track_samples, read["reach"] + read["track"], strict=True):
        assert np.array_equal(a.q0, b.q0)
        assert a.reference.to_dict() == b.reference.to_dict()


def _write(path: Path, header: list[str], rows: list[dict[str, str]]) -> Path:
    lines = [",".join(header)] + [",".join(row.get(c, "") for c in header) for row in rows]
    path.write_text("\n".join(lines) + "\n")
    return path


def _q0_cells(q0=PAPER_Q0) -> dict[str, str]:
    return {f"q0_{j}": str(v) for j, v in enumerate(q0)}


def test_hand_written_csv_with_defaults(tmp_path, ur10):
    header = (
        ["task"]
        + [f"q0_{j}" for j in range(6)]
        + ["target_0", "target_1", "target_2", "centre_0", "centre_1", "centre_2", "semi_axis_0", "semi_axis_1"]
    )
    reach = {"task": "reach", **_q0_cells(), **{f"target_{i}": str(v) for i, v in enumerate(PAPER_TARGET)}}
    track = {
        "task": "track",
        **_q0_cells(),
        "centre_0": "-0.7",
        "centre_1": "0",
        "centre_2": "0.5",
        "semi_axis_0": "0.2",
        "semi_axis_1": "0.1",
    }
    samples = read_samples_csv(_write(tmp_path / "hand.csv", header, [reach, track, dict(reach)]), ur10)
    assert [s.index for s in samples["reach"]] == [0, 1]
    ellipse = samples["track"][0].reference
    assert ellipse.angular_speed == pytest.approx(0.075) and ellipse.phase == 0.0
    assert np.array_equal(ellipse.orientation, np.zeros(3))
    assert samples["track"][0].reset_options()["ellipse"]["semi_axes"] == [0.2, 0.1]


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"target_1": "abc"}, "row 2 (line 3), column 'target_1': 'abc' is not a number"),
        ({"target_0": "3.0"}, "row 2 (line 3), column 'target_0..target_2': unreachable"),
        ({"q0_2": "9"}, "row 2 (line 3), column 'q0_2': 9.0 rad is outside the joint limits"),
        ({"task": "wave"}, "row 2 (line 3), column 'task': 'wave' is not one of"),
        ({"sample": "0"}, "row 2 (line 3), column 'sample': sample id 0 appears twice"),
        ({"q0_5": ""}, "row 2 (line 3), column 'q0_5': a number is required"),
        ({"centre_0": "1"}, "row 2 (line 3), column 'centre_0': must be empty on a 'reach' row"),
    ],
)
def test_bad_rows_name_row_and_column(tmp_path, ur10, change, message):
    good = {
        "task": "reach",
        "sample": "0",
        **_q0_cells(),
        **{f"target_{i}": str(v) for i, v in enumerate(PAPER_TARGET)},
    }
    bad = {**good, "sample": "1", **change}
    path = _write(tmp_path / "bad.csv", column_names(6), [good, bad])
    with pytest.raises(SampleFileError, match=message.replace("(", r"\(").replace(")", r"\)").replace(".", r"\.")):
        read_samples_csv(path, ur10)


def test_unreachable_ellipse_and_missing_columns_are_named(tmp_path, ur10):
    track = {
        "task": "track",
        "sample": "0",
        **_q0_cells(),
        "centre_0": "-0.7",
        "centre_1": "0",
        "centre_2": "0.5",
        "semi_axis_0": "0.9",
        "semi_axis_1": "0.9",
    }
    with pytest.raises(SampleFileError, match=r"row 1 \(line 2\), column 'centre_0\.\.phase': unreachable"):
        read_samples_csv(_write(tmp_path / "e.csv", column_names(6), [track]), ur10)
    with pytest.raises(SampleFileError, match=r"lacks the column\(s\) \['q0_5'\]"):
        read_samples_csv(_write(tmp_path / "m.csv", ["task"] + [f"q0_{j}" for j in range(5)], []), ur10)
    with pytest.raises(SampleFileError, match="no such samples file"):
        read_samples_csv(tmp_path / "missing.csv", ur10)


# -- references and engines ------------------------------------------------------------------


def test_batched_references_equal_the_reference_methods(track_samples):
    references = [s.reference for s in track_samples] + [FixedTarget(PAPER_TARGET)]
    times = np.arange(40) * 0.37
    positions, velocities, centres = reference_trajectories(references, times)
    for i, reference in enumerate(references):
        assert np.array_equal(centres[i], reference.centre)
        for k, t in enumerate(times):
            x_d, xdot_d = reference.position_and_velocity(t)
            np.testing.assert_allclose(positions[i, k], x_d, rtol=0, atol=1e-14)
            np.testing.assert_allclose(velocities[i, k], xdot_d, rtol=0, atol=1e-15)


@pytest.mark.parametrize("steps", [1, 128, 533, 534, 2501])  # 60 ellipses: blocks of 533 steps
def test_the_step_major_trajectories_are_the_per_sample_ones_bit_for_bit(ur10, steps):
    """The lockstep loop's step-major x_d and ẋ_d (every ellipse at once, in blocks of steps) are each reference's
    own ``trajectory(times)`` exactly, for ellipses, fixed targets, a mix and a reference of another type, and those
    are the 3-vector formula of :class:`Ellipse` evaluated one ellipse at a time."""
    from snac_gym.rollout.kinematic import step_major_trajectories

    track = generate_samples(ur10, SampleSpace.workspace(ur10), 21, "track", range(60))
    reach = generate_samples(ur10, SampleSpace.workspace(ur10), 21, "reach", range(5))

    class Shifted:  # any object with a trajectory(times) and a centre
        centre = np.array([0.1, 0.2, 0.3])

        def trajectory(self, times):
            return np.tile(self.centre, (len(times), 1)) + times[:, None], np.ones((len(times), 3))

    times = np.arange(steps) / 125.0
    ellipses, targets = [s.reference for s in track], [s.reference for s in reach]
    for references in (ellipses, targets, [*ellipses[:7], *targets, Shifted()]):
        x_d, xdot_d, centres = step_major_trajectories(references, times)
        for i, reference in enumerate(references):
            position, velocity = reference.trajectory(times)
            np.testing.assert_array_equal(x_d[:, i], position)
            np.testing.assert_array_equal(xdot_d[:, i], velocity)
            np.testing.assert_array_equal(centres[i], reference.centre)
    for e in ellipses:
        angles = e.angular_speed * times + e.phase
        cos, sin = np.cos(angles)[:, None], np.sin(angles)[:, None]
        position, velocity = e.trajectory(times)
        np.testing.assert_array_equal(position, e.centre + cos * e._major + sin * e._minor)
        np.testing.assert_array_equal(velocity, (e.angular_speed * cos) * e._minor - (e.angular_speed * sin) * e._major)


def test_kinematic_engine_integrates_exactly_and_observes_like_the_env(ur10, context_of, track_samples):
    context = context_of("track")
    policies = []

    def make():
        policies.append(PseudoInversePolicy(context, gain=3.0))
        return policies[-1]

    steps = 30
    out = simulate_kinematic(context, make, track_samples, steps, [1, 2, 3], use_batch=True)
    assert out.q.shape == (3, steps, 6) and out.final_errors.shape == (3, 3)
    layout = context.layout
    for i, sample in enumerate(track_samples):
        q, held = sample.q0.copy(), np.zeros(6)
        for k in range(steps):
            x_d, xdot_d = sample.reference.position_and_velocity(k * DT)
            expected = layout.pack(q, held, ur10.forward(q), x_d, xdot_d, sample.reference.centre)
            np.testing.assert_allclose(policies[i].seen[k], expected, rtol=0, atol=1e-13)
            assert np.array_equal(out.q[i, k], q)
            held = out.commands[i, k]
            assert np.all(np.abs(held) <= ur10.velocity_limits)
            q = q + held * DT
        assert np.array_equal(out.final_q[i], q)
        np.testing.assert_allclose(
            out.final_errors[i], ur10.forward(q) - sample.reference.position(steps * DT), atol=1e-13
        )


def test_batch_protocol_gives_the_per_sample_results(context_of, reach_samples):
    context = context_of("reach")
    assert supports_batch(BatchPseudoInversePolicy) and not supports_batch(PseudoInversePolicy)
    make = functools.partial(BatchPseudoInversePolicy, context, gain=2.5)
    driven = LockstepPolicies(make, [5, 6, 7, 8])
    assert driven.batched and driven._batch_policy.batch_seeds == [5, 6, 7, 8]
    batched = simulate_kinematic(context, make, reach_samples, 60, [5, 6, 7, 8], use_batch=True)
    looped = simulate_kinematic(context, make, reach_samples, 60, [5, 6, 7, 8], use_batch=False)
    np.testing.assert_allclose(batched.commands, looped.commands, rtol=0, atol=1e-12)
    np.testing.assert_allclose(batched.final_errors, looped.final_errors, rtol=0, atol=1e-12)


def test_commands_beyond_the_limits_are_clipped_like_the_env(ur10, context_of, reach_samples):
    context = context_of("reach")

    class Overdrive(PseudoInversePolicy):
        def _act(self, obs):
            return 10.0 * self.velocity_limits * np.array([1, -1, 1, -1, 1, -1])

    out = simulate_kinematic(context, lambda: Overdrive(context), reach_samples[:1], 3, [0])
    limits = ur10.velocity_limits * np.array([1, -1, 1, -1, 1, -1])
    assert np.array_equal(out.commands[0], np.tile(limits, (3, 1)))
    assert np.array_equal(out.final_q[0], reach_samples[0].q0 + limits * DT + limits * DT + limits * DT)


def test_a_non_finite_command_names_controller_sample_and_step(context_of, reach_samples):
    context = context_of("reach")
    with pytest.raises(RolloutError, match=r"nan-test: non-finite command at step 3 of reach sample 0"):
        simulate_kinematic(context, lambda: NaNPolicy(context), reach_samples[:1], 10, [0], label="nan-test")


@pytest.mark.parametrize("engine", ["pybullet", "mujoco"])
def test_simulated_engines_follow_the_kinematic_model(context_of, reach_samples, engine):
    if engine == "mujoco":
        pytest.importorskip("mujoco", reason="the mujoco engine needs the mujoco extra")
    context = context_of("reach")
    samples, steps = reach_samples[:2], 60
    physics, logs = simulate_env(
        "ur10", "reach", DT, lambda env: PseudoInversePolicy(env, gain=2.0), samples, steps, [0, 1], physics=engine
    )
    exact = simulate_kinematic(context, lambda: PseudoInversePolicy(context, gain=2.0), samples, steps, [0, 1])
    assert len(logs) == 2 and len(logs[0]) == steps
    np.testing.assert_allclose(
        physics.commands[:, 0], exact.commands[:, 0], atol=1e-12
    )  # same start, same first command
    np.testing.assert_allclose(physics.q, exact.q, atol=5e-3)  # motors lag the exact integration by milliradians
    cost_physics = trajectory_cost(physics.errors, physics.commands, DT).total
    cost_exact = trajectory_cost(exact.errors, exact.commands, DT).total
    np.testing.assert_allclose(cost_physics, cost_exact, rtol=0.05)


# -- metrics ------------------------------------------------------------------------------------


def test_metrics_of_a_hand_made_rollout():
    limits = np.array([2.0, 2.0, 3.0, 3.0, 3.0, 3.0])
    steps = 4
    errors = np.array([[[0.01, 0, 0], [0.002, 0, 0], [0.0009, 0, 0], [0.0005, 0, 0]]])
    commands = np.zeros((1, steps, 6))
    commands[0, :, 0] = [2.0, 1.0, -0.5, 0.0]
    commands[0, 1, 2] = -3.0
    rollouts = Rollouts(
        DT,
        np.arange(steps) * DT,
        np.zeros((1, steps, 6)),
        commands,
        errors,
        errors * 0,
        errors * 0,
        errors,
        np.zeros((1, 6)),
        np.zeros((1, 3)),
        np.array([[0.0002, 0, 0]]),
    )
    row = rollout_metrics(rollouts, "reach", limits).iloc[0]
    terms = trajectory_cost(errors, commands, DT)
    assert row["cost"] == pytest.approx(float(terms.total[0]))
    assert row["cost_smoothness_start"] == pytest.approx(2.0**2 / DT)
    assert row["time_to_1mm"] == pytest.approx(2 * DT)
    assert row["settle_time"] == pytest.approx(2 * DT)  # within 1 mm from e_2 on, e_K included
    assert row["final_error"] == pytest.approx(0.0002) and bool(row["success"])
    assert row["max_abs_u"] == 3.0 and row["max_norm_u"] == pytest.approx(np.hypot(1.0, 3.0))
    assert row["peak_limit_fraction"] == 1.0 and row["peak_step"] == 0
    assert row["steps_at_limit"] == 2
    assert row["max_abs_udot"] == pytest.approx(3.0 / DT)
    assert row["mean_error_2nd_half"] == pytest.approx(0.0007)
    track = rollout_metrics(rollouts, "track", limits).iloc[0]
    assert bool(track["success"]) and track["settle_time"] == pytest.approx(1 * DT)  # within 5 mm from e_1 on
    far = Rollouts(
        DT,
        rollouts.times,
        rollouts.q,
        commands,
        errors * 10,
        errors,
        errors,
        errors * 10,
        rollouts.final_q,
        rollouts.final_x,
        rollouts.final_errors * 100,
    )
    far_row = rollout_metrics(far, "reach", limits).iloc[0]
    assert np.isnan(far_row["time_to_1mm"]) and np.isnan(far_row["settle_time"]) and not far_row["success"]


@pytest.mark.parametrize(
    ("cost", "udot_start", "q_scale"), [("table1", "rest", 1.0), ("table1", "first", 1e6), ("hjb", "rest", 100.0)]
)
def test_cost_conventions_score_the_same_rollout_by_hand(cost, udot_start, q_scale):
    """cost, cost_table1, cost_table1_first and cost_hjb against sums written out step by step."""
    from snac_gym.control.cost import CostConvention

    rng = np.random.default_rng(3)
    errors, commands = rng.normal(scale=0.05, size=(2, 5, 3)), rng.normal(size=(2, 5, 6))
    rollouts = Rollouts(
        DT,
        np.arange(5) * DT,
        None,
        commands,
        None,
        errors * 0,
        errors * 0,
        errors,
        np.zeros((2, 6)),
        np.zeros((2, 3)),
        np.zeros((2, 3)),
    )
    rows = rollout_metrics(rollouts, "reach", np.full(6, 10.0), CostConvention(cost, udot_start, q_scale))
    for b in range(2):
        error = sum(q_scale * errors[b, k] @ errors[b, k] * DT for k in range(5))
        effort = sum(commands[b, k] @ commands[b, k] * DT for k in range(5))
        jumps = [commands[b, 0]] + [commands[b, k] - commands[b, k - 1] for k in range(1, 5)]
        smooth_rest = sum(j @ j / DT for j in jumps)
        smooth_first = smooth_rest - jumps[0] @ jumps[0] / DT
        row = rows.iloc[b]
        assert row["cost_table1"] == pytest.approx(error + effort + smooth_rest, rel=1e-12)
        assert row["cost_table1_first"] == pytest.approx(error + effort + smooth_first, rel=1e-12)
        assert row["cost_hjb"] == pytest.approx(error + effort, rel=1e-12)
        expected = {"table1": smooth_rest if udot_start == "rest" else smooth_first, "hjb": 0.0}[cost]
        assert row["cost"] == pytest.approx(error + effort + expected, rel=1e-12)
    with pytest.raises(ValueError, match="cost must be one of"):
        CostConvention("total")
    with pytest.raises(ValueError, match="q_scale must be a positive finite number"):
        CostConvention(q_scale=float("nan"))


def test_a_controller_that_fails_the_task_is_never_ranked_cheapest():
    from snac_gym.evaluation.reports.summary import summarise

    rows = []
    for controller, cost, success in (("cheap_but_fails", 1.0, False), ("snac", 5.0, True), ("dls", 3.0, True)):
        for sample in range(4):
            rows.append(
                {
                    "task": "reach",
                    "controller": controller,
                    "sample": sample,
                    "cost": cost,
                    "success": success,
                    "final_error": 0.1 if not success else 1e-4,
                    "time_to_1mm": np.nan,
                    "settle_time": np.nan,
                    "max_abs_u": 1.0,
                    "peak_limit_fraction": 0.5,
                    "max_norm_u": 1.0,
                    "median_error_2nd_half": 0.1,
                    **{term: cost / 3 for term in ("cost_error", "cost_effort", "cost_smoothness")},
                    "cost_smoothness_start": 0.0,
                }
            )
    summary = summarise(pd.DataFrame(rows), [], ["reach"], ["cheap_but_fails", "snac", "dls"], 0.95).set_index(
        "controller"
    )
    assert not summary.loc["cheap_but_fails", "reach_qualified"]
    assert np.isnan(summary.loc["cheap_but_fails", "reach_rank"]) and np.isnan(
        summary.loc["cheap_but_fails", "reach_ratio_to_best"]
    )
    assert summary.loc["dls", "reach_rank"] == 1 and summary.loc["snac", "reach_rank"] == 2
    assert summary.loc["snac", "reach_ratio_to_best"] == pytest.approx(5 / 3)
    assert summary.loc["dls", "reach_ratio_to_snac"] == pytest.approx(3 / 5)


# -- knob search ---------------------------------------------------------------------------------


def test_match_effort_on_a_proportional_effort():
    result = match_effort(lambda c: 0.3 * c**1.1, target=1.7, start=2.0, tolerance=0.005)
    assert result.matched and abs(result.effort / 1.7 - 1) <= 0.005
    assert len(result.evaluations) <= 8


def test_match_effort_at_the_ceiling_returns_the_least_aggressive_knob():
    result = match_effort(lambda c: min(1.0, 0.25 * c), target=1.0, start=2.0, tolerance=0.005)
    assert result.matched and 3.98 <= result.value <= 4.0 + 1e-9


def test_match_effort_reports_a_target_out_of_reach():
    result = match_effort(lambda c: min(0.8, 0.25 * c), target=1.0, start=2.0, tolerance=0.005)
    assert not result.matched and "saturates at about 0.8" in result.reason
    assert result.value == pytest.approx(2.0 * (1.0 / 0.5) * 1.03)  # the smallest knob on the plateau

    floor = match_effort(lambda c: max(0.9, min(1.0, c)), target=0.5, start=2.0, tolerance=0.005)
    assert not floor.matched and "does not fall below about 0.9" in floor.reason
    at_target = match_effort(lambda c: 1.0, target=1.0, start=2.0, tolerance=0.005)
    assert at_target.matched and at_target.value < 2.0  # flat at the target: the smallest knob tried

    def picky(c):
        if c > 3:
            raise ValueError("gain * dt must be below 2")
        return 0.1 * c

    rejected = match_effort(picky, target=1.0, start=2.0, tolerance=0.005)
    assert not rejected.matched and "rejects" in rejected.reason


def test_samples_carry_reset_options_for_the_envs(reach_samples, track_samples):
    reach = reach_samples[0].reset_options()
    assert set(reach) == {"q0", "target"} and reach["target"] == reach_samples[0].reference.target.tolist()
    track = track_samples[0].reset_options()
    assert Ellipse.from_dict(track["ellipse"]).to_dict() == track_samples[0].reference.to_dict()
    assert isinstance(reach_samples[0], EvaluationSample)


def _timed_job(item: tuple[str, float]) -> tuple[str, float, float]:
    """A job for the executor tests: its label and when it started and ended (wall clock)."""
    import time

    label, seconds = item
    started = time.time()
    time.sleep(seconds)
    return label, started, time.time()


#: Python 3.12's warning on a fork beside native threads (OpenBLAS's pools): no hazard here, worker_setup.start_method.
FORK_BESIDE_NATIVE_THREADS = pytest.mark.filterwarnings(
    r"ignore:This process \(pid=\d+\) is multi-threaded, use of fork\(\):DeprecationWarning"
)


@FORK_BESIDE_NATIVE_THREADS
def test_process_executor_runs_urgent_jobs_first_and_keeps_a_reserved_worker_free():
    import threading

    from snac_gym.evaluation.execution.executors import ProcessExecutor

    executor = ProcessExecutor(2)
    try:
        executor.reserve(1)  # while a knob search runs: full passes get one worker only
        passes: dict[int, tuple] = {}

        def run_passes():
            passes.update(executor.run(_timed_job, [(f"pass{i}", 0.15) for i in range(4)], priority=1))

        thread = threading.Thread(target=run_passes)
        thread.start()
        urgent = dict(executor.run(_timed_job, [("search", 0.05)], priority=0))
        thread.join()
        executor.reserve(0)
        free = dict(executor.run(_timed_job, [(f"free{i}", 0.15) for i in range(2)], priority=1))
    finally:
        executor.close()
    intervals = sorted((start, end) for _, start, end in passes.values())
    assert len(intervals) == 4
    # one pass at a time while a worker is reserved...
    assert all(later[0] >= earlier[1] for earlier, later in itertools.pairwise(intervals))
    # ...so the search, submitted after all four, did not wait for the queued ones
    assert urgent[0][1] < intervals[-1][0]
    # without the reservation both workers take passes
    (_, a0, a1), (_, b0, b1) = free.values()
    assert max(a0, b0) < min(a1, b1)


@FORK_BESIDE_NATIVE_THREADS
def test_process_executor_passes_job_errors_through():
    from snac_gym.evaluation.execution.executors import ProcessExecutor

    executor = ProcessExecutor(2)
    try:
        with pytest.raises(ValueError, match="not enough values to unpack"):
            list(executor.run(_timed_job, [("ok", 0.0), ("bad",)]))
    finally:
        executor.close()


def test_concurrent_effort_matches_raise_the_failure_not_the_cancellations(tmp_path):
    import threading
    import time

    import snac_gym.evaluation.execution.passes as passes_module
    from snac_gym.evaluation.run_config import EvaluationConfig

    class Concurrent:
        concurrent = True

        def terminate(self) -> None:
            """What a failed pipeline asks of the executor (stop every job)."""

    config = EvaluationConfig(out=tmp_path, workers=2, progress=False)
    evaluation = passes_module.EvaluationRun(config, None, Concurrent(), {}, None)
    started = threading.Event()

    def waits_for_cancellation():
        started.set()
        while True:  # a pipeline between two steps
            evaluation._check_cancelled()
            time.sleep(0.01)

    def fails():
        started.wait()
        time.sleep(0.05)
        raise RuntimeError("policy exploded")

    with pytest.raises(RuntimeError, match="policy exploded"):
        evaluation.concurrently([waits_for_cancellation, fails])
    assert evaluation.cancelled.is_set()
    serial = passes_module.EvaluationRun(config, None, object(), {}, None)
    assert serial.concurrently([lambda: 1, lambda: 2]) == [1, 2]


def test_knob_search_evaluations_are_spread_over_the_workers(tmp_path):
    from types import SimpleNamespace

    import snac_gym.evaluation.execution.passes as passes_module
    from snac_gym.evaluation.run_config import EvaluationConfig

    config = EvaluationConfig(out=tmp_path, workers=3, progress=False)  # chunk_size 500
    evaluation = passes_module.EvaluationRun(config, None, None, {}, None)
    samples = [SimpleNamespace(index=i) for i in range(100)]

    def sizes(**kwargs):
        return [len(job.samples) for job in evaluation._jobs("reach", "dls", {}, samples, 10, False, **kwargs)]

    assert sizes() == [100]  # a full pass: chunks of chunk_size
    assert sizes(spread=True) == [34, 34, 32]  # a search: one job per worker
    evaluation.spread_searches = False  # as many searches as workers run at once: keep jobs whole
    assert sizes(spread=True) == [100]


def test_effort_statistics_reduce_their_columns_and_bad_names_are_refused(tmp_path):
    import pandas as pd
    from snac_gym.evaluation.effort.statistics import EFFORT_STATISTICS, effort_statistic_named
    from snac_gym.evaluation.run_config import EvaluationConfig

    rows = pd.DataFrame({"max_abs_u": [1.0, 3.15, 2.0], "peak_limit_fraction": [0.2, 1.0, 0.5]})
    assert EFFORT_STATISTICS["max"].of(rows) == 3.15  # the maximum |u| over the set, rad/s
    assert EFFORT_STATISTICS["median-peak"].of(rows) == 0.5
    with pytest.raises(ValueError, match="no rollouts"):
        EFFORT_STATISTICS["max"].of(rows.iloc[:0])
    message = "--effort-statistic must be one of max, median-peak, mean-peak, peak-ratio, got 'mean'"
    with pytest.raises(ValueError, match=message):
        effort_statistic_named("mean")
    with pytest.raises(ValueError, match=message):
        EvaluationConfig(out=tmp_path, effort_statistic="mean").validate()


def _crossing(measure, level: float) -> float:
    """The smallest knob whose effort reaches ``level`` (to 1e-12)."""
    low, high = 1e-3, 1e3
    for _ in range(200):
        middle = (low * high) ** 0.5
        low, high = (middle, high) if measure(middle) < level else (low, middle)
    return high


def test_match_effort_needs_few_evaluations_on_saturating_statistics():
    """The median and the maximum of clipped per-rollout peaks, targets inside and at the ceiling."""
    counts = []
    for seed in range(20):
        rng = np.random.default_rng(seed)
        gains = np.exp(rng.normal(np.log(0.26), 0.5, 100))
        power = rng.uniform(0.7, 1.1)

        def median(k, gains=gains, power=power):
            return float(np.median(np.minimum(1.0, gains * k**power)))

        def maximum(k, gains=gains, power=power):
            return float(np.max(np.minimum(3.15, 3 * gains * k**power)))

        for measure, target, start in [
            (median, 1.0, 1.0),
            (median, median(2.0), 1.0),
            (maximum, 3.15, 5.0),
            (maximum, 3.15, 0.3),
        ]:
            result = match_effort(measure, target=target, start=start, tolerance=0.005)
            assert result.matched and target * (1 - 0.005) <= result.effort <= target * (1 + 0.005)
            # Between the smallest knobs reaching the lower and the upper edge of the band (by plain
            # bisection), up to the final bracket's width (2 %): the least aggressive knob, also at a ceiling.
            assert _crossing(measure, target * (1 - 0.005)) <= result.value
            assert result.value <= 1.02 * _crossing(measure, min(target * (1 + 0.005), measure(1e3)))
            counts.append(len(result.evaluations))
    assert max(counts) <= 12, counts
