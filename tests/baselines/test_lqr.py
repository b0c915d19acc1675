"""The frozen-Jacobian LQR controller (baselines/lqr.py): its command against SciPy's Riccati
solver, its realised cost against the value function, the paper's tasks in the PyBullet env,
the batch protocol, its parameters and a tiny evaluation."""

import inspect
import math

import numpy as np
import pytest
from scipy.linalg import solve_continuous_are
from snac_gym.baselines.lqr import LQRPolicy
from snac_gym.evaluation import EvaluationConfig, run_evaluation

import snac_gym
from snac_gym import make_policy
from snac_gym.control.cost import trajectory_cost
from snac_gym.policies.base import BasePolicy, Policy, PolicyContext
from snac_gym.references import PAPER_Q0, PAPER_TARGET, Ellipse

UPRIGHT = np.array([0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0])


def _spd(rng, size):
    a = rng.normal(size=(size, size))
    return a @ a.T + 0.5 * np.eye(size)


def _observation(env, q, x_d, xdot_d=(0.0, 0.0, 0.0)):
    base = env.unwrapped
    q = np.asarray(q, float)
    return base.obs_layout.pack(
        q,
        np.zeros_like(q),
        base.kinematics.forward(q),
        np.asarray(x_d, float),
        np.asarray(xdot_d, float),
        np.asarray(x_d, float),
    )


def _care(jac, Q, R):
    """P* and K* = R⁻¹JᵀP* from SciPy's continuous-time ARE with A = 0, B = J."""
    P = solve_continuous_are(np.zeros((3, 3)), jac, Q, R)
    return P, np.linalg.solve(R, jac.T @ P)


def test_registered_listed_and_uses_the_shared_kinematics(reach_env):
    assert "lqr" in snac_gym.available_policies()
    policy = make_policy("lqr", reach_env)
    assert type(policy) is LQRPolicy and isinstance(policy, BasePolicy) and isinstance(policy, Policy)
    assert policy.kinematics is reach_env.unwrapped.kinematics
    # The evaluator's effort knob: a constructor argument held as a positive scalar attribute.
    assert LQRPolicy.effort_parameter == "q_scale" in inspect.signature(LQRPolicy).parameters
    assert policy.q_scale > 0


def test_regulation_command_is_the_riccati_feedback(reach_env, rng):
    kin = reach_env.unwrapped.kinematics
    Q, R = _spd(rng, 3), _spd(rng, 6)
    policy = LQRPolicy(reach_env, Q=Q, R=R, q_scale=2.5)
    q = np.array(PAPER_Q0) + rng.normal(scale=0.1, size=6)
    x_d = kin.forward(q) + np.array([0.01, -0.02, 0.015])
    P, K = _care(kin.jacobian(q), 2.5 * Q, R)
    e = kin.forward(q) - x_d
    expected = -K @ e
    assert np.all(np.abs(expected) < kin.velocity_limits)
    np.testing.assert_allclose(policy.act(_observation(reach_env, q, x_d)), expected, rtol=1e-8, atol=1e-12)
    assert policy.internals["saturation_scale"] == 1.0
    assert policy.internals["value"] == pytest.approx(e @ P @ e, rel=1e-8)


def test_tracking_command_adds_the_least_effort_feedforward(track_env, rng):
    kin = track_env.unwrapped.kinematics
    R = _spd(rng, 6)
    policy = LQRPolicy(track_env, R=R)
    q = np.array(PAPER_Q0)
    x_d, xdot_d = kin.forward(q) + np.array([0.004, 0.0, -0.003]), np.array([0.01, -0.02, 0.005])
    jac = kin.jacobian(q)
    _, K = _care(jac, 9.0 * np.eye(3), R)  # the default q_scale
    # Feed-forward: argmin uᵀRu s.t. J u = ẋ_d, from its KKT system.
    kkt = np.block([[2 * R, jac.T], [jac, np.zeros((3, 3))]])
    feedforward = np.linalg.solve(kkt, np.concatenate([np.zeros(6), xdot_d]))[:6]
    expected = feedforward - K @ (kin.forward(q) - x_d)
    np.testing.assert_allclose(policy.act(_observation(track_env, q, x_d, xdot_d)), expected, rtol=1e-8, atol=1e-12)


def test_realised_cost_of_a_short_reach_is_the_value_function(reach_env, rng):
    """ė = J u with J nearly frozen (a 2 cm reach, Δt = 1 ms): ∫ eᵀQe + uᵀRu dt ≈ e₀ᵀP*e₀."""
    base = reach_env.unwrapped
    kin = base.kinematics
    dt = 1e-3
    context = PolicyContext(kin, dt, base.velocity_limits, base.obs_layout, "reach")
    Q, R = np.diag([1.0, 2.0, 0.5]), _spd(rng, 6)
    policy = LQRPolicy(context, Q=Q, R=R, q_scale=4.0)
    q = np.array(PAPER_Q0)
    x_d = kin.forward(q) + np.array([0.012, -0.01, 0.012])
    P, K = _care(kin.jacobian(q), 4.0 * Q, R)
    slowest = -np.linalg.eigvals(-kin.jacobian(q) @ K).real.max()
    steps = math.ceil(12.0 / slowest / dt)  # e^{-12}: the tail is negligible
    errors, commands = [], []
    zero3 = np.zeros(3)
    for _ in range(steps):
        x = kin.forward(q)
        obs = base.obs_layout.pack(q, np.zeros(6), x, x_d, zero3, x_d)
        u = policy.act(obs)
        assert policy.internals["saturation_scale"] == 1.0
        errors.append(x - x_d)
        commands.append(u)
        q = q + u * dt
    terms = trajectory_cost(np.array(errors), np.array(commands), dt, Q=4.0 * Q, R=R)
    e0 = errors[0]
    assert terms.error + terms.effort == pytest.approx(e0 @ P @ e0, rel=0.02)


def _env_episode(env, policy, options=None):
    obs, _ = env.reset(options=options)
    policy.reset()
    errors, truncated = [], False
    limits = env.unwrapped.velocity_limits
    while not truncated:
        u = policy.act(obs)
        assert np.all(np.abs(u) <= limits)
        obs, _, _, truncated, info = env.step(u)
        errors.append(info["error_norm"])
    return np.array(errors)


def test_paper_reach_within_1mm(reach_env):
    errors = _env_episode(reach_env, make_policy("lqr", reach_env), options={"q0": list(PAPER_Q0)})
    assert np.allclose(reach_env.unwrapped.reference.position(0.0), PAPER_TARGET)
    assert len(errors) == 1000 and errors[-1] <= 1e-3


def test_paper_circle_tracked_under_5mm_after_the_transient(track_env):
    errors = _env_episode(track_env, make_policy("lqr", track_env), options={"q0": list(PAPER_Q0)})
    assert track_env.unwrapped.reference.to_dict() == Ellipse.paper_circle().to_dict()
    assert errors[math.ceil(5.0 / track_env.unwrapped.dt) :].max() < 5e-3


@pytest.mark.parametrize("env_name", ["reach_env", "track_env"])
def test_act_batch_rows_equal_act(env_name, request, rng, monkeypatch):
    """Bit for bit given the same J; ``act`` takes J from Pinocchio and ``act_batch`` from the
    vectorised chain, which round differently (~1e-16), so the test hands ``act`` the chain's J."""
    env = request.getfixturevalue(env_name)
    kin = env.unwrapped.kinematics
    monkeypatch.setattr(kin, "jacobian", lambda q: kin.jacobian_batch(np.asarray(q)[None])[0])
    rows = []
    for k in range(12):  # near and far targets: some rows saturate at q_scale = 400
        q = np.array(PAPER_Q0) + rng.normal(scale=0.3, size=6)
        reach = 0.005 if k % 2 else 0.4
        rows.append(
            _observation(env, q, kin.forward(q) + rng.uniform(-reach, reach, 3), rng.normal(scale=0.05, size=3))
        )
    obs = np.array(rows)
    policy = LQRPolicy(env, R=_spd(rng, 6), q_scale=400.0)
    policy.reset_batch(list(range(len(obs))))
    batch = policy.act_batch(obs)
    scales = []
    for row, expected in zip(obs, batch, strict=True):
        np.testing.assert_array_equal(policy.act(row), expected)
        scales.append(policy.internals["saturation_scale"])
    assert min(scales) == 1.0 and max(scales) > 1.0  # both branches of the saturation


def test_saturated_command_keeps_its_direction(reach_env):
    kin = reach_env.unwrapped.kinematics
    q = np.array(PAPER_Q0)
    obs = _observation(reach_env, q, kin.forward(q) + np.array([0.5, -0.5, 0.3]))
    policy = LQRPolicy(reach_env, q_scale=400.0)
    u = policy.act(obs)
    _, K = _care(kin.jacobian(q), 400.0 * np.eye(3), np.eye(6))
    assert policy.internals["saturation_scale"] > 1
    assert np.max(np.abs(u) / kin.velocity_limits) == pytest.approx(1.0)
    np.testing.assert_allclose(u * policy.internals["saturation_scale"], K @ np.array([0.5, -0.5, 0.3]), rtol=1e-8)


def test_effort_grows_as_the_square_root_of_q_scale(reach_env):
    kin = reach_env.unwrapped.kinematics
    q = np.array(PAPER_Q0)
    obs = _observation(reach_env, q, kin.forward(q) + np.array([0.05, -0.03, 0.02]))
    norms = [np.linalg.norm(LQRPolicy(reach_env, q_scale=s).act(obs)) for s in (1.0, 4.0, 16.0)]
    np.testing.assert_allclose(np.array(norms[1:]) / norms[:-1], 2.0, rtol=1e-9)  # K* ∝ √q_scale


def test_commands_stay_finite_and_bounded_at_a_singularity(reach_env):
    kin = reach_env.unwrapped.kinematics
    assert np.linalg.svd(kin.jacobian(UPRIGHT), compute_uv=False)[-1] < 1e-9
    policy = LQRPolicy(reach_env, q_scale=1.0)
    offset = np.array([0.03, -0.02, 0.01])
    u = policy.act(_observation(reach_env, UPRIGHT, kin.forward(UPRIGHT) + offset))
    assert np.all(np.isfinite(u)) and np.linalg.norm(u) <= np.linalg.norm(offset) * (1 + 1e-9)  # ‖K*‖ = 1


@pytest.mark.parametrize(
    "kwargs, message",
    [
        ({"Q": np.eye(2)}, "Q must be a \\(3, 3\\) matrix"),
        ({"R": np.diag([1.0, 1.0, -1.0, 1.0, 1.0, 1.0])}, "R must be positive definite"),
        ({"R": np.triu(np.ones((6, 6)))}, "R must be symmetric"),
        ({"Q": np.full((3, 3), np.inf)}, "Q must be finite"),
        ({"q_scale": 0.0}, "q_scale"),
        ({"q_scale": float("nan")}, "q_scale"),
    ],
)
def test_bad_parameters_raise_clear_errors(kwargs, message, reach_env):
    with pytest.raises(ValueError, match=message):
        make_policy("lqr", reach_env, **kwargs)


def test_wrong_observation_shape_raises(reach_env):
    policy = make_policy("lqr", reach_env)
    with pytest.raises(ValueError, match="shape"):
        policy.act(np.zeros(5))
    with pytest.raises(ValueError, match="shape"):
        policy.act_batch(np.zeros((2, 5)))


def test_a_tiny_evaluation_calibrates_the_q_scale_knob(tmp_path):
    config = EvaluationConfig(
        out=tmp_path,
        samples=3,
        effort_samples=0,
        horizons={"reach": 0.3, "track": 0.3},
        progress=False,
        controllers=("snac", "lqr"),
        plots=False,
    )
    results = run_evaluation(config)
    lqr = results[results["controller"] == "lqr"]
    assert len(lqr) == 6 and np.isfinite(lqr["cost"]).all()
    assert (lqr["effort_parameter"] == "q_scale").all() and (lqr["effort_value"] > 0).all()
