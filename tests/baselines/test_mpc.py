"""The receding-horizon controller ``mpc`` (baselines/mpc.py): its first command against an independent
open-loop solve of the same short horizon, closed-loop reaching, the batch protocol, the reference
predictor and its parameters."""

import numpy as np
import pytest
from snac_gym.baselines.mpc import MPCPolicy
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.samples import generate_samples

import snac_gym
from snac_gym.control.cost import CostConvention
from snac_gym.control.trajopt import solve_sample
from snac_gym.policies.base import LockstepPolicies
from snac_gym.references import Ellipse
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import SampleSpace

DT = 1 / 125


@pytest.fixture(scope="module")
def reach():
    return policy_context("ur10", DT, "reach")


@pytest.fixture(scope="module")
def track():
    return policy_context("ur10", DT, "track")


def _observation(context, q, x_d, xdot_d=np.zeros(3), x_c=None):
    x = context.kinematics.forward(q)
    return context.layout.pack(q, np.zeros_like(q), x, x_d, xdot_d, x_d if x_c is None else x_c)


def _samples(context, count, seed=3):
    return generate_samples(context.kinematics, SampleSpace(), seed, context.task, range(count))


def test_registered_with_a_q_scale_knob(reach):
    assert "mpc" in snac_gym.available_policies()
    policy = snac_gym.make_policy("mpc", reach)
    assert type(policy) is MPCPolicy and MPCPolicy.effort_parameter == "q_scale" and policy.q_scale == 1.0


@pytest.mark.parametrize(("cost", "udot_start"), [("hjb", "rest"), ("table1", "rest"), ("table1", "first")])
def test_first_command_is_the_open_loop_optimum_of_the_same_horizon(reach, cost, udot_start):
    """Without the terminal cost and on the control grid (block = 1), the MPC's problem from θ₀ is
    exactly solve_sample's over the horizon, so its converged first command is the optimum's."""
    sample = _samples(reach, 1)[0]
    q0, target = np.asarray(sample.q0, float), sample.reference.position(0.0)
    steps, convention = 20, CostConvention(cost, udot_start, 2.0)
    optimum = solve_sample(
        q0, np.repeat(target[None], steps, axis=0), reach.kinematics, DT, reach.velocity_limits, convention=convention
    )
    policy = MPCPolicy(reach, horizon=steps * DT, block=1, iterations=40, terminal=False, cost=cost,
                       udot_start=udot_start, Q=[2.0] * 3)  # fmt: skip
    policy.reset(0)
    command = policy.act(_observation(reach, q0, target))
    assert not np.any(np.abs(optimum.commands[0]) > reach.velocity_limits)  # no clipping in this comparison
    # Both stop at a gradient tolerance: agree to 1e-5 of the plan's largest command.
    np.testing.assert_allclose(command, optimum.commands[0], rtol=1e-5, atol=1e-5 * np.abs(optimum.commands).max())


def test_reaches_the_target(reach):
    samples = _samples(reach, 3)
    make = lambda: MPCPolicy(reach, q_scale=100.0, cost="hjb")  # noqa: E731  (√q = 10: within 1 mm in ~2 s)
    rollouts = simulate_kinematic(reach, make, samples, 500, [0, 1, 2])
    assert np.all(np.linalg.norm(rollouts.final_errors, axis=1) < 1e-3)
    assert np.all(np.abs(rollouts.commands) <= reach.velocity_limits)


@pytest.mark.parametrize("task", ["reach", "track"])
def test_batch_rows_equal_single_episodes(reach, track, task):
    context = reach if task == "reach" else track
    samples = _samples(context, 3)

    def make():
        return MPCPolicy(context, period=2, iterations=3)

    steps = 40
    batched = simulate_kinematic(context, make, samples, steps, [0, 1, 2], use_batch=True)
    single = simulate_kinematic(context, make, samples, steps, [0, 1, 2], use_batch=False)
    assert LockstepPolicies(make, [0]).batched
    np.testing.assert_allclose(batched.commands, single.commands, rtol=1e-12, atol=1e-14)


def test_prediction_of_an_ellipse_is_exact(track):
    """The harmonic predictor from two observations against the ellipse itself, one horizon ahead."""
    ellipse = Ellipse(centre=[0.6, 0.1, 0.4], semi_axes=[0.25, 0.1], orientation=[0.3, -0.2, 0.5], angular_speed=0.4)
    policy = MPCPolicy(track, horizon=1.0)
    policy.reset(0)
    q = np.array([0.0, -1.2, 1.5, -1.8, -1.57, 0.0])
    for k in range(2):
        x_d, xdot_d = ellipse.position_and_velocity(k * DT)
        predicted, end_velocity = policy._references(_observation(track, q, x_d, xdot_d, ellipse.centre)[None])
    times = DT + np.arange(policy.steps + 1) * policy.solver_dt
    positions, velocities = ellipse.trajectory(times)
    np.testing.assert_allclose(predicted[0], positions, atol=1e-8)
    np.testing.assert_allclose(end_velocity[0], velocities[-1], rtol=1e-5)  # ω from two steps: O((ωΔt)²)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"horizon": 0}, "horizon must be a positive"),
        ({"horizon": 0.01, "block": 5}, "shorter than one solver step"),
        ({"block": 0}, "block must be a positive integer"),
        ({"iterations": 1.5}, "iterations must be a positive integer"),
        ({"period": 100, "horizon": 0.2}, "period .* must not exceed the horizon"),
        ({"q_scale": -1}, "q_scale must be a positive"),
        ({"cost": "l2"}, "cost must be one of"),
        ({"udot_start": "never"}, "udot_start must be one of"),
        ({"reference": "guess"}, "reference must be one of"),
        ({"terminal": "yes"}, "terminal must be true or false"),
        ({"Q": [1.0, 2.0, 3.0]}, "Q must be a positive multiple of the identity"),
    ],
)
def test_bad_parameters_are_refused(reach, kwargs, message):
    with pytest.raises(ValueError, match=message):
        MPCPolicy(reach, **kwargs)


def test_the_limits_are_constraints_of_the_re_solve():
    """Workspace reach sample 2 of seed 11 (HJB cost, q = 4): unconstrained, the MPC turns joint 2 past its
    limit by 2.9 rad; with the limits in its re-solve (the default) it keeps every position and velocity
    limit on every step."""
    from snac_gym.control.cost import CostConvention
    from snac_gym.metrics import rollout_metrics

    context = policy_context("ur10", DT, "reach")
    kinematics = context.kinematics
    sample = generate_samples(kinematics, SampleSpace.workspace(kinematics), 11, "reach", [2])
    margins = {}
    for constraints in (False, True):
        make = lambda c=constraints: MPCPolicy(context, cost="hjb", Q=[4.0] * 3, constraints=c)  # noqa: E731
        rollouts = simulate_kinematic(context, make, sample, 1500, [0])
        metrics = rollout_metrics(rollouts, "reach", context.velocity_limits, CostConvention("hjb", q_scale=4.0),
                                  (kinematics.lower_limits, kinematics.upper_limits))  # fmt: skip
        margins[constraints] = float(metrics["joint_limit_margin"][0])
        assert np.all(np.abs(rollouts.commands) <= context.velocity_limits)
    assert margins[False] < -1.0 and margins[True] >= 0.0


def test_constraints_must_be_a_boolean(reach):
    with pytest.raises(ValueError, match="constraints must be true or false"):
        MPCPolicy(reach, constraints="yes")
