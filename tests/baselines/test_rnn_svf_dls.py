"""The baseline controllers (RNN, SVF, DLS): each update against an independent computation,
the bounds they promise, and their acceptance runs in the PyBullet env."""

import inspect
import math
import pickle

import numpy as np
import pytest
from scipy.optimize import minimize
from snac_gym.baselines.dls import DLSPolicy
from snac_gym.baselines.rnn import RNNPolicy
from snac_gym.baselines.svf import SVFPolicy, filtered_singular_values

import snac_gym
from snac_gym import make_policy
from snac_gym.policies.base import BasePolicy, Policy
from snac_gym.references import PAPER_Q0, PAPER_TARGET, Ellipse

CONTROLLERS = {"dls": DLSPolicy, "svf": SVFPolicy, "rnn": RNNPolicy}
#: Outstretched-upwards UR10 (shoulder lift and wrist 1 at −π/2): sweeping the elbow (joint 3)
#: through 0 passes a configuration where the position Jacobian loses rank.
UPRIGHT = np.array([0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0])


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


def _kinematic_rollout(env, policy, q0, reference, steps):
    """θₖ₊₁ = θₖ + uₖΔt with the shared kinematics: errors ‖e‖ (steps + 1) and commands."""
    base = env.unwrapped
    q = np.array(q0, float)
    errors, commands = [], []
    policy.reset()
    for k in range(steps + 1):
        t = k * base.dt
        x_d = reference.position(t)
        x = base.kinematics.forward(q)
        errors.append(np.linalg.norm(x - x_d))
        if k == steps:
            break
        obs = base.obs_layout.pack(q, np.zeros_like(q), x, x_d, reference.velocity(t), reference.centre)
        u = policy.act(obs)
        commands.append(u)
        q = q + u * base.dt
    return np.array(errors), np.array(commands)


# -- registry and interface ------------------------------------------------------------------


@pytest.mark.parametrize("name", CONTROLLERS)
def test_registered_and_use_the_shared_kinematics(name, reach_env):
    policy = make_policy(name, reach_env)
    assert type(policy) is CONTROLLERS[name]
    assert isinstance(policy, BasePolicy) and isinstance(policy, Policy)
    assert policy.kinematics is reach_env.unwrapped.kinematics  # no private FK/Jacobian


@pytest.mark.parametrize("name", CONTROLLERS)
def test_effort_parameter_names_a_gain_that_scales_the_effort(name, reach_env):
    cls = CONTROLLERS[name]
    parameters = inspect.signature(cls).parameters
    assert cls.effort_parameter in parameters
    base = reach_env.unwrapped
    peaks = []
    for gain in (0.5, 1.0, 2.0):
        policy = cls(reach_env, **{cls.effort_parameter: gain})
        _, commands = _kinematic_rollout(reach_env, policy, PAPER_Q0, base.task.paper(), 150)
        peaks.append(np.linalg.norm(commands, axis=1).max())
    # Unsaturated from the paper's pose: the peak effort is about proportional to the gain.
    assert peaks[1] / peaks[0] == pytest.approx(2.0, rel=0.1)
    assert peaks[2] / peaks[1] == pytest.approx(2.0, rel=0.1)


@pytest.mark.parametrize(
    "name, kwargs",
    [
        ("dls", {"gain": 0}),
        ("dls", {"damping": -1}),
        ("svf", {"gain": float("nan")}),
        ("svf", {"sigma0": 0.5}),
        ("svf", {"nu": 0}),
        ("rnn", {"epsilon": 0}),
        ("rnn", {"integrator": "rk4"}),
        ("rnn", {"gain": 300.0}),
    ],
)
def test_bad_parameters_raise(name, kwargs, reach_env):
    with pytest.raises(ValueError):
        make_policy(name, reach_env, **kwargs)


@pytest.mark.parametrize("name", CONTROLLERS)
def test_wrong_observation_shape_raises(name, reach_env):
    with pytest.raises(ValueError, match="shape"):
        make_policy(name, reach_env).act(np.zeros(5))


@pytest.mark.parametrize("name", CONTROLLERS)
def test_policies_pickle_with_their_state(name, track_env):
    obs, _ = track_env.reset(seed=1)
    policy = make_policy(name, track_env)
    policy.act(obs)  # the RNN's network state is no longer zero
    clone = pickle.loads(pickle.dumps(policy))  # e.g. for process-parallel evaluation
    np.testing.assert_array_equal(clone.act(obs), policy.act(obs))


# -- SVF -------------------------------------------------------------------------------------


def test_svf_filter_is_bounded_below_and_follows_sigma():
    nu, sigma0 = 10.0, 0.005
    sigma = np.concatenate([[0.0], np.logspace(-8, 1, 400)])
    h = filtered_singular_values(sigma, nu, sigma0)
    expected = (sigma**3 + nu * sigma**2 + 2 * sigma + 2 * sigma0) / (sigma**2 + nu * sigma + 2)
    np.testing.assert_allclose(h, expected, rtol=1e-14)
    assert h[0] == pytest.approx(sigma0)
    assert np.all(h >= sigma0 * (1 - 1e-12))
    big = sigma > 0.5
    np.testing.assert_allclose(h[big] / sigma[big], 1.0, rtol=0.02)


def test_svf_pseudoinverse_matches_an_explicit_svd_formula(reach_env, rng):
    policy = SVFPolicy(reach_env, nu=7.0, sigma0=0.01)
    kin = reach_env.unwrapped.kinematics
    for _ in range(5):
        jac = kin.jacobian(rng.uniform(-np.pi, np.pi, 6))
        # Full SVD, Σ⁺-like 6×3 matrix built element by element.
        u_full, sigma, vt_full = np.linalg.svd(jac, full_matrices=True)
        filtered_inverse = np.zeros((6, 3))
        for i, s in enumerate(sigma):
            filtered_inverse[i, i] = (s**2 + 7.0 * s + 2) / (s**3 + 7.0 * s**2 + 2 * s + 2 * 0.01)
        np.testing.assert_allclose(
            policy.filtered_pseudoinverse(jac), vt_full.T @ filtered_inverse @ u_full.T, atol=1e-12
        )


def test_svf_act_is_the_filtered_closed_loop_law(track_env):
    policy = SVFPolicy(track_env, gain=1.5)
    q = np.array(PAPER_Q0)
    x_d, xdot_d = np.array([-0.7, 0.1, 0.45]), np.array([0.01, -0.02, 0.005])
    obs = _observation(track_env, q, x_d, xdot_d)
    kin = track_env.unwrapped.kinematics
    expected = policy.filtered_pseudoinverse(kin.jacobian(q)) @ (xdot_d + 1.5 * (x_d - kin.forward(q)))
    assert np.all(np.abs(expected) < kin.velocity_limits)  # unsaturated case
    np.testing.assert_allclose(policy.act(obs), expected, atol=1e-12)


def test_svf_inverse_stays_bounded_through_a_singularity(reach_env):
    policy = SVFPolicy(reach_env)
    kin = reach_env.unwrapped.kinematics
    smallest, filtered_norms, plain_norms = [], [], []
    for elbow in np.linspace(-0.2, 0.2, 401):  # passes elbow = 0 exactly
        q = UPRIGHT.copy()
        q[2] = elbow
        jac = kin.jacobian(q)
        smallest.append(np.linalg.svd(jac, compute_uv=False)[-1])
        filtered_norms.append(np.linalg.norm(policy.filtered_pseudoinverse(jac), 2))
        plain_norms.append(np.linalg.norm(np.linalg.pinv(jac, rcond=1e-15), 2))
        u = policy.act(_observation(reach_env, q, kin.forward(q) + np.array([0.3, -0.2, 0.1])))
        assert np.all(np.isfinite(u)) and np.all(np.abs(u) <= kin.velocity_limits)
    assert min(smallest) < 1e-6  # the sweep really crosses the singularity
    assert max(filtered_norms) <= 1 / policy.sigma0 * (1 + 1e-9)
    assert max(plain_norms) > 10 / policy.sigma0  # the unfiltered inverse blows up there


# -- DLS -------------------------------------------------------------------------------------


def test_dls_matches_the_normal_equations_and_the_pseudoinverse_limit(reach_env, rng):
    kin = reach_env.unwrapped.kinematics
    for _ in range(5):
        jac = kin.jacobian(rng.uniform(-np.pi, np.pi, 6))
        v = rng.normal(size=3)
        damping = 0.05
        # Primal form: argmin ‖J u − v‖² + λ²‖u‖² solves (JᵀJ + λ²I) u = Jᵀv (6×6, independent of the 3×3 form).
        primal = np.linalg.solve(jac.T @ jac + damping**2 * np.eye(6), jac.T @ v)
        np.testing.assert_allclose(DLSPolicy(reach_env, damping=damping).resolve(jac, v), primal, atol=1e-10)
        tiny = DLSPolicy(reach_env, damping=1e-7).resolve(jac, v)
        np.testing.assert_allclose(tiny, np.linalg.pinv(jac) @ v, rtol=1e-6, atol=1e-8)


def test_dls_step_is_bounded_at_a_singularity(reach_env):
    policy = DLSPolicy(reach_env, damping=0.02)
    jac = reach_env.unwrapped.kinematics.jacobian(UPRIGHT)
    assert np.linalg.svd(jac, compute_uv=False)[-1] < 1e-9
    v = np.array([0.1, -0.3, 0.2])
    assert np.linalg.norm(policy.resolve(jac, v)) <= np.linalg.norm(v) / (2 * 0.02) * (1 + 1e-9)


@pytest.mark.parametrize("name", ["dls", "svf"])
def test_resolved_rate_commands_are_scaled_into_the_limits(name, reach_env):
    policy = make_policy(name, reach_env, gain=50.0)
    kin = reach_env.unwrapped.kinematics
    q = np.array(PAPER_Q0)
    obs = _observation(reach_env, q, kin.forward(q) + np.array([0.5, -0.5, 0.3]))
    u = policy.act(obs)
    unsaturated = policy.resolve(kin.jacobian(q), 50.0 * np.array([0.5, -0.5, 0.3]))
    assert policy.internals["saturation_scale"] > 1
    assert np.max(np.abs(u) / kin.velocity_limits) == pytest.approx(1.0)  # on the box boundary
    np.testing.assert_allclose(u * policy.internals["saturation_scale"], unsaturated, rtol=1e-12)  # same direction


# -- RNN -------------------------------------------------------------------------------------


def test_rnn_euler_steps_match_hand_written_updates(track_env):
    kin = track_env.unwrapped.kinematics
    dt, eps, gain, limits = track_env.unwrapped.dt, 0.05, 3.0, kin.velocity_limits
    policy = RNNPolicy(track_env, gain=gain, epsilon=eps, integrator="euler")
    policy.reset()
    lam = np.zeros(3)
    states = [
        (np.array(PAPER_Q0), [-0.7, 0.2, 0.5], [0.01, 0.0, -0.02]),
        (np.array(PAPER_Q0) + 0.05, [-0.6, 0.3, 0.45], [0.0, 0.03, 0.0]),
    ]
    for q, x_d, xdot_d in states:
        jac = kin.jacobian(q)
        assert dt * np.sum(jac**2) / eps <= 1.0  # one sub-step at this ε
        r = np.asarray(xdot_d) + gain * (np.asarray(x_d) - kin.forward(q))
        lam = lam + dt / eps * (r - jac @ np.clip(jac.T @ lam, -limits, limits))
        u = policy.act(_observation(track_env, q, x_d, xdot_d))
        np.testing.assert_allclose(policy.dual_state, lam, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(u, np.clip(jac.T @ lam, -limits, limits), rtol=1e-12, atol=1e-15)


def test_rnn_semi_implicit_step_matches_the_linearly_implicit_euler_formula(track_env):
    kin = track_env.unwrapped.kinematics
    dt, eps, gain, limits = track_env.unwrapped.dt, 1e-3, 40.0, kin.velocity_limits
    policy = RNNPolicy(track_env, gain=gain, epsilon=eps)
    lam = np.zeros(3)
    saw_active_bound = False
    for step in range(4):  # a large gain so that some outputs saturate
        q = np.array(PAPER_Q0) + 0.03 * step
        x_d, xdot_d = np.array([-0.5, 0.5, 0.6]), np.array([0.02, 0.0, 0.0])
        jac = kin.jacobian(q)
        r = xdot_d + gain * (x_d - kin.forward(q))
        z = jac.T @ lam
        d = np.diag((np.abs(z) < limits).astype(float))
        rhs_jacobian = -jac @ d @ jac.T / eps  # ∂/∂λ of (r − J P_Ω(Jᵀλ))/ε
        lam = lam + np.linalg.inv(np.eye(3) - dt * rhs_jacobian) @ (dt * (r - jac @ np.clip(z, -limits, limits)) / eps)
        u = policy.act(_observation(track_env, q, x_d, xdot_d))
        np.testing.assert_allclose(policy.dual_state, lam, rtol=1e-10)
        np.testing.assert_allclose(u, np.clip(jac.T @ lam, -limits, limits), rtol=1e-10)
        saw_active_bound |= bool(policy.internals["active_bounds"].any())
    assert saw_active_bound


def test_rnn_semi_implicit_tends_to_euler_for_a_slow_network(track_env):
    obs = _observation(track_env, PAPER_Q0, [-0.7, 0.2, 0.5], [0.01, 0.0, -0.02])
    implicit = RNNPolicy(track_env, epsilon=50.0).act(obs)
    explicit = RNNPolicy(track_env, epsilon=50.0, integrator="euler").act(obs)
    jac = track_env.unwrapped.kinematics.jacobian(np.array(PAPER_Q0))
    step_ratio = track_env.unwrapped.dt * np.linalg.norm(jac @ jac.T, 2) / 50.0  # (Δt/ε)‖JJᵀ‖ ≪ 1
    # The two schemes differ by a factor (I + (Δt/ε)JJᵀ)⁻¹ = I + O((Δt/ε)‖JJᵀ‖).
    assert np.linalg.norm(implicit - explicit) <= step_ratio * np.linalg.norm(explicit)


@pytest.mark.parametrize("integrator", ["semi-implicit", "euler"])
def test_rnn_network_is_stable_where_plain_euler_is_not_and_solves_the_qp(integrator, track_env):
    """With J and the input frozen the network must settle on the QP's solution. At the default
    ε a single explicit Euler step per control period is unstable (Δt‖JJᵀ‖/ε > 2)."""
    kin = track_env.unwrapped.kinematics
    dt, limits = track_env.unwrapped.dt, kin.velocity_limits
    policy = RNNPolicy(track_env, integrator=integrator)
    q = np.array(PAPER_Q0)
    jac = kin.jacobian(q)
    assert dt * np.linalg.norm(jac @ jac.T, 2) / policy.epsilon > 2
    # A task velocity whose least-norm solution breaks a bound but that the box can still produce.
    signs = np.array([1, -1, 1, 1, -1, 1])
    r = jac @ (0.9 * limits * signs)
    assert np.any(np.abs(np.linalg.pinv(jac) @ r) > limits)
    obs = _observation(track_env, q, kin.forward(q), r)  # e = 0, so the input is ẋ_d = r

    lam = np.zeros(3)  # plain explicit Euler at the control period, written out
    for _ in range(300):
        lam = lam + dt / policy.epsilon * (r - jac @ np.clip(jac.T @ lam, -limits, limits))
    assert np.linalg.norm(r - jac @ np.clip(jac.T @ lam, -limits, limits)) > 1e-2

    for _ in range(300):
        u = policy.act(obs)
    assert np.all(np.abs(u) <= limits)
    np.testing.assert_allclose(jac @ u, r, atol=1e-8)
    qp = minimize(
        lambda v: 0.5 * v @ v,
        np.zeros(6),
        jac=lambda v: v,
        method="SLSQP",
        bounds=list(zip(-limits, limits)),
        constraints=[{"type": "eq", "fun": lambda v: jac @ v - r, "jac": lambda v: jac}],
        options={"ftol": 1e-14, "maxiter": 500},
    )
    assert qp.success
    np.testing.assert_allclose(u, qp.x, atol=1e-5)


@pytest.mark.parametrize("epsilon", [1e-6, 1e-3, 1e-1])
def test_rnn_closed_loop_converges_for_any_epsilon(epsilon, reach_env):
    """Network and arm together (x ← x + Δt J u, J frozen) at k·Δt = 0.8: the discrete loop
    is stable whatever ε, as the docstring's analysis says (kΔt < 2 suffices)."""
    kin = reach_env.unwrapped.kinematics
    dt = reach_env.unwrapped.dt
    q = np.array(PAPER_Q0)
    jac = kin.jacobian(q)
    gain = 0.8 / dt
    policy = RNNPolicy(reach_env, gain=gain, epsilon=epsilon)
    layout = reach_env.unwrapped.obs_layout
    x_d = kin.forward(q)
    x = x_d + np.array([1e-3, -2e-3, 1e-3])  # small: no bound becomes active
    zero3, zero6 = np.zeros(3), np.zeros(6)
    norms = []
    for _ in range(2000):
        u = policy.act(layout.pack(q, zero6, x, x_d, zero3, x_d))
        assert not policy.internals["active_bounds"].any()
        x = x + dt * jac @ u
        norms.append(np.linalg.norm(x - x_d))
    assert max(norms) < 1e-2  # no blow-up
    assert norms[-1] < 1e-2 * norms[0]


def test_rnn_outputs_always_lie_inside_the_bounds(reach_env, rng):
    kin = reach_env.unwrapped.kinematics
    policy = RNNPolicy(reach_env, gain=20.0)
    policy.reset()
    hits = 0
    q = np.array(PAPER_Q0)
    for _ in range(300):  # far targets and a high gain: the network keeps asking for more
        q = q + rng.normal(scale=0.02, size=6)
        u = policy.act(_observation(reach_env, q, kin.forward(q) + rng.uniform(-1, 1, 3)))
        assert np.all(np.abs(u) <= kin.velocity_limits)
        hits += int(np.any(np.abs(u) == kin.velocity_limits))
    assert hits > 50  # the projection was exercised


def test_rnn_state_persists_and_reset_clears_it(reach_env):
    policy = RNNPolicy(reach_env)
    base = reach_env.unwrapped
    first, _ = _kinematic_rollout(reach_env, policy, PAPER_Q0, base.task.paper(), 50)
    assert np.linalg.norm(policy.dual_state) > 0
    policy.reset()
    assert np.all(policy.dual_state == 0)
    again, _ = _kinematic_rollout(reach_env, policy, PAPER_Q0, base.task.paper(), 50)
    np.testing.assert_array_equal(first, again)


# -- acceptance: the paper's tasks in the PyBullet env, a few random episodes -----------------


def _env_episode(env, policy, options=None, seed=None):
    obs, _ = env.reset(seed=seed, options=options)
    policy.reset()
    errors, truncated = [], False
    limits = env.unwrapped.velocity_limits
    while not truncated:
        u = policy.act(obs)
        assert np.all(np.abs(u) <= limits)  # the policy itself respects the limits
        obs, _, _, truncated, info = env.step(u)
        errors.append(info["error_norm"])
    return np.array(errors)


@pytest.mark.parametrize("name", CONTROLLERS)
def test_paper_reach_within_1mm(name, reach_env):
    errors = _env_episode(reach_env, make_policy(name, reach_env), options={"q0": list(PAPER_Q0)})
    assert np.allclose(reach_env.unwrapped.reference.position(0.0), PAPER_TARGET)
    assert len(errors) == 1000 and errors[-1] <= 1e-3


@pytest.mark.parametrize("name", CONTROLLERS)
def test_paper_circle_tracked_under_5mm_after_the_transient(name, track_env):
    errors = _env_episode(track_env, make_policy(name, track_env), options={"q0": list(PAPER_Q0)})
    assert track_env.unwrapped.reference.to_dict() == Ellipse.paper_circle().to_dict()
    transient = math.ceil(5.0 / track_env.unwrapped.dt)  # the first 5 s
    assert errors[transient:].max() < 5e-3


@pytest.mark.parametrize("name", CONTROLLERS)
def test_random_episodes_succeed(name, reach_env, track_env):
    for seed in range(3):
        reach = _env_episode(reach_env, make_policy(name, reach_env), seed=seed)
        assert reach[-1] <= 1e-3, f"reach seed {seed}"
        track = _env_episode(track_env, make_policy(name, track_env), seed=seed)
        assert track[len(track) // 2 :].mean() <= 5e-3, f"track seed {seed}"


def test_baselines_are_listed_as_available_policies():
    assert {"dls", "svf", "rnn"} <= set(snac_gym.available_policies())
