"""Joint position limits on the redundant arms: the box Ω(θ), each controller's use of it, and the
``joint_limit_margin`` column of the evaluator's metrics."""

import numpy as np
import pytest
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.samples import EvaluationSample

from snac_gym.metrics import rollout_metrics
from snac_gym.model.joint_limits import POSITION_LIMIT_MARGIN, JointLimitBox, joint_limit_margins
from snac_gym.model.kinematics import Kinematics
from snac_gym.policies import make_policy
from snac_gym.references import FixedTarget
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import nominal_configuration, solve_reachable

CONTROLLERS = ["snac", "rnn", "svf", "dls", "lqr"]


@pytest.fixture(scope="module")
def panda() -> Kinematics:
    return Kinematics("panda")


def test_far_from_the_limits_the_box_is_the_velocity_box_bit_for_bit(panda):
    box = JointLimitBox(panda, panda.velocity_limits, 1 / 125)
    middle = (panda.lower_limits + panda.upper_limits) / 2
    lower, upper = box.bounds(middle)
    assert np.array_equal(lower, -panda.velocity_limits) and np.array_equal(upper, panda.velocity_limits)


def test_no_command_sequence_leaves_the_inner_range(panda):
    """θₖ₊₁ = θₖ + clamp(uₖ)Δt from the inner range stays in it, whatever the commands (κΔt ≤ 1)."""
    dt, rng = 1 / 125, np.random.default_rng(0)
    box = JointLimitBox(panda, panda.velocity_limits, dt)
    q = np.tile((panda.lower_limits + panda.upper_limits) / 2, (50, 1))
    drift = rng.choice([-1.0, 1.0], size=q.shape)  # each joint pushed towards one of its limits
    for _ in range(1000):
        noise = rng.uniform(-1.0, 1.0, size=q.shape)
        q = q + box.clamp(q, (drift + noise) * 2 * panda.velocity_limits) * dt
    inner = POSITION_LIMIT_MARGIN - 1e-12
    assert np.all(q >= panda.lower_limits + inner) and np.all(q <= panda.upper_limits - inner)
    assert joint_limit_margins(q[:, None], panda.lower_limits, panda.upper_limits).min() < POSITION_LIMIT_MARGIN + 0.01


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_the_box_is_on_for_the_redundant_arms_only(controller):
    assert make_policy(controller, policy_context("ur10", 1 / 125, "reach")).limit_box is None
    assert make_policy(controller, policy_context("panda", 1 / 125, "reach")).limit_box is not None
    off = make_policy(controller, policy_context("panda", 1 / 125, "reach"), joint_limits=False)
    assert off.limit_box is None


def _pushing_sample(kin: Kinematics) -> EvaluationSample:
    """The ready pose with the shoulder (joint 2) 0.12 rad from its upper limit, and the target that
    leaning 0.3 rad further would reach: reachable inside the limits, but the least-norm motion
    goes through the limit (unguarded DLS by 0.09 rad)."""
    q0 = nominal_configuration(kin)
    q0[1] = kin.upper_limits[1] - 0.12
    beyond = q0.copy()
    beyond[1] += 0.3
    assert solve_reachable(kin, kin.forward(beyond), q0) is not None  # inside the limits
    return EvaluationSample("reach", 0, q0, FixedTarget(kin.forward(beyond)))


@pytest.mark.parametrize("controller", CONTROLLERS)
def test_every_controller_keeps_the_margin_where_the_unguarded_one_crosses(controller, panda):
    context = policy_context("panda", 1 / 125, "reach")
    sample = _pushing_sample(panda)
    limits = (panda.lower_limits, panda.upper_limits)
    margins = {}
    for guarded in (True, False):
        rollouts = simulate_kinematic(
            context, lambda g=guarded: make_policy(controller, context, joint_limits=g), [sample], 1500, [0]
        )
        margins[guarded] = rollout_metrics(rollouts, "reach", context.velocity_limits, None, limits)
    assert margins[True]["joint_limit_margin"].iloc[0] >= POSITION_LIMIT_MARGIN - 1e-9
    assert margins[False]["joint_limit_margin"].iloc[0] < 0  # unguarded, every one crosses
    if controller == "rnn":  # P_Ω inside the network: the other joints do the task motion
        assert margins[True]["final_error"].iloc[0] < 1e-3


def test_the_margin_column_rebuilt_from_commands_equals_the_logged_states(panda):
    context = policy_context("panda", 1 / 125, "reach")
    sample = _pushing_sample(panda)
    limits = (panda.lower_limits, panda.upper_limits)
    kept, rebuilt = (
        simulate_kinematic(
            context, lambda: make_policy("dls", context, joint_limits=False), [sample], 300, [0], keep_states=keep
        )
        for keep in (True, False)
    )
    assert rebuilt.q is None and kept.q is not None
    expected = joint_limit_margins(np.concatenate([kept.q, kept.final_q[:, None]], axis=1), *limits)
    column = rollout_metrics(rebuilt, "reach", context.velocity_limits, None, limits)["joint_limit_margin"]
    np.testing.assert_allclose(column.to_numpy(), expected, rtol=0, atol=1e-12)
    assert expected[0] < 0  # unguarded DLS straightens the elbow through its limit here


def test_a_rollout_that_crosses_a_joint_limit_does_not_succeed(panda):
    """Unguarded DLS reaches the pushing sample's target through the shoulder's limit: on target, not a success;
    guarded RNN reaches it inside the limits: a success."""
    context = policy_context("panda", 1 / 125, "reach")
    sample = _pushing_sample(panda)
    limits = (panda.lower_limits, panda.upper_limits)
    rows = {}
    for controller, guarded in (("dls", False), ("rnn", True)):
        rollouts = simulate_kinematic(
            context, lambda c=controller, g=guarded: make_policy(c, context, joint_limits=g), [sample], 1500, [0]
        )
        rows[controller] = rollout_metrics(rollouts, "reach", context.velocity_limits, None, limits).iloc[0]
    assert rows["dls"]["final_error"] < 1e-3 and rows["dls"]["joint_limit_margin"] < 0
    assert not rows["dls"]["success"]
    assert rows["rnn"]["final_error"] < 1e-3 and rows["rnn"]["joint_limit_margin"] >= 0 and rows["rnn"]["success"]
