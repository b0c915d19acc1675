"""SNAC (Sections III, IV): the basis, the control laws (eqs. 15, 36) and weight laws (eqs. 19, 38)
against an independent hand-expanded computation on random states, and the policy's contract."""

import copy
import math
import pickle
import re

import numpy as np
import pytest
from scipy.integrate import quad_vec

from snac_gym.observation import ObservationLayout
from snac_gym.policies.base import PolicyContext
from snac_gym.policies.snac import PAPER_SCHEDULES, QuadraticBasis, SNACPolicy

DT = 1.0 / 125.0


# -- independent computation: explicit loops over the terms, no shared helper ------------------
def _terms(dim):
    """Paper order: s1², s1s2, ..., s1sd, s2², ..., sd² (0-based index pairs)."""
    out = []
    for i in range(dim):
        for j in range(i, dim):
            out.append((i, j))
    return out


def _basis_gradient_loops(s):
    """∂σ_k/∂s_r by hand: d(s_i s_j)/ds_r = δ_ri s_j + δ_rj s_i."""
    terms = _terms(len(s))
    grad = [[0.0] * len(s) for _ in terms]
    for k, (i, j) in enumerate(terms):
        for r in range(len(s)):
            value = 0.0
            if r == i:
                value += s[j]
            if r == j:
                value += s[i]
            grad[k][r] = value
    return grad


def _laws_loops(s, weights, jac, r_inverse, n):
    """û = −½ R⁻¹ Gᵀ ∇σᵀ Ŵ and ∇σ G R⁻¹ Gᵀ s (the weight-law direction, α = 1), G = [J; 0]."""
    d, m = len(s), len(jac[0])
    grad = _basis_gradient_loops(s)
    G = [[jac[r][c] if r < n else 0.0 for c in range(m)] for r in range(d)]
    value_gradient = [sum(grad[k][r] * weights[k] for k in range(len(weights))) for r in range(d)]
    gt_vg = [sum(G[r][c] * value_gradient[r] for r in range(d)) for c in range(m)]
    command = [-0.5 * sum(r_inverse[p][c] * gt_vg[c] for c in range(m)) for p in range(m)]
    gt_s = [sum(G[r][c] * s[r] for r in range(d)) for c in range(m)]
    rinv_gt_s = [sum(r_inverse[p][c] * gt_s[c] for c in range(m)) for p in range(m)]
    g_rinv_gt_s = [sum(G[r][p] * rinv_gt_s[p] for p in range(m)) for r in range(d)]
    direction = [sum(grad[k][r] * g_rinv_gt_s[r] for r in range(d)) for k in range(len(weights))]
    return np.array(command), np.array(direction)


def _context(kinematics, task, limit=1e9):
    layout = ObservationLayout(kinematics.n_joints, kinematics.task_dim)
    return PolicyContext(kinematics, DT, np.full(kinematics.n_joints, float(limit)), layout, task)


def _random_observation(kinematics, layout, rng):
    q = rng.uniform(-np.pi, np.pi, kinematics.n_joints)
    x = kinematics.forward(q)
    x_d = x + rng.normal(scale=0.2, size=kinematics.task_dim)
    x_c = x_d + rng.normal(scale=0.2, size=kinematics.task_dim)
    xdot_d = rng.normal(scale=0.05, size=kinematics.task_dim)
    return layout.pack(q, rng.normal(size=kinematics.n_joints), x, x_d, xdot_d, x_c)


def _critic_state(layout, obs, task, tracking_state="paper"):
    """e (reach); ξ = [e; x_d] (eq. 31) or, centred, [e; x_d − x_c] (track)."""
    f = layout.unpack(obs)
    if task == "reach":
        return f.e.copy()
    return np.concatenate([f.e, f.x_d - (f.x_c if tracking_state == "centred" else 0.0)])


def _random_spd(rng, m):
    a = rng.normal(size=(m, m))
    return a @ a.T + m * np.eye(m)


# -- the basis ----------------------------------------------------------------------------------
def test_basis_order_is_the_papers():
    assert QuadraticBasis(3).labels(["e1", "e2", "e3"]) == ["e1^2", "e1*e2", "e1*e3", "e2^2", "e2*e3", "e3^2"]
    paper_21 = [  # w1..w21 of Section V-C
        "x1^2",
        "x1*x2",
        "x1*x3",
        "x1*x4",
        "x1*x5",
        "x1*x6",
        "x2^2",
        "x2*x3",
        "x2*x4",
        "x2*x5",
        "x2*x6",
        "x3^2",
        "x3*x4",
        "x3*x5",
        "x3*x6",
        "x4^2",
        "x4*x5",
        "x4*x6",
        "x5^2",
        "x5*x6",
        "x6^2",
    ]
    assert QuadraticBasis(6).labels([f"x{i}" for i in range(1, 7)]) == paper_21


@pytest.mark.parametrize("dim", [1, 2, 3, 4, 6, 7])
def test_basis_size_and_values_follow_the_dimension(dim, rng):
    basis = QuadraticBasis(dim)
    assert basis.size == dim * (dim + 1) // 2
    s = rng.normal(size=dim)
    expected = [s[i] * s[j] for i, j in _terms(dim)]
    np.testing.assert_allclose(basis(s), expected, rtol=0, atol=1e-15)


@pytest.mark.parametrize("dim", [2, 3, 6])
def test_basis_gradient_matches_finite_differences_and_loops(dim, rng):
    basis = QuadraticBasis(dim)
    for _ in range(5):
        s = rng.normal(size=dim)
        grad = basis.gradient(s)
        step = 1e-6
        finite = np.stack(
            [(basis(s + step * np.eye(dim)[r]) - basis(s - step * np.eye(dim)[r])) / (2 * step) for r in range(dim)],
            axis=1,
        )
        np.testing.assert_allclose(grad, finite, atol=1e-8)
        np.testing.assert_array_equal(grad, np.array(_basis_gradient_loops(list(s))))
        out = np.full((basis.size, dim), np.nan)  # any previous content is overwritten
        assert basis.gradient(s, out=out) is out
        np.testing.assert_array_equal(out, grad)


# -- the laws against the independent computation -------------------------------------------------
@pytest.mark.parametrize("task", ["reach", "track"])
@pytest.mark.parametrize("r_kind", ["identity", "diagonal", "full"])
@pytest.mark.parametrize("unit", ["per_step", "per_second"])
@pytest.mark.parametrize("clock", ["steps", "seconds"])
@pytest.mark.parametrize("tracking_state", ["paper", "centred"])
def test_command_and_weight_update_match_hand_expansion(ur10, rng, task, r_kind, unit, clock, tracking_state):
    m = ur10.n_joints
    R = {"identity": None, "diagonal": rng.uniform(0.5, 2.0, m), "full": _random_spd(rng, m)}[r_kind]
    R_matrix = np.eye(m) if R is None else (np.diag(R) if np.ndim(R) == 1 else R)
    r_inverse = np.linalg.inv(R_matrix).tolist()
    ctx = _context(ur10, task)
    n = ur10.task_dim
    size = QuadraticBasis(n if task == "reach" else 2 * n).size
    weights0 = rng.normal(size=size)
    policy = SNACPolicy(
        ctx,
        R=R,
        initial_weights=weights0,
        learning_rate_unit=unit,
        weight_update="euler",
        schedule_clock=clock,
        tracking_state=tracking_state,
    )
    policy.reset(seed=0)
    weights = weights0.copy()
    alpha_i, alpha_f, shift = PAPER_SCHEDULES[task]
    for k in range(4):  # successive steps: the schedule advances and the weights accumulate
        obs = _random_observation(ur10, ctx.layout, rng)
        s = _critic_state(ctx.layout, obs, task, tracking_state)
        jac = ur10.jacobian(obs[ctx.layout.slices["q"]])
        command, direction = _laws_loops(list(s), list(weights), jac.tolist(), r_inverse, n)
        u = policy.act(obs)
        np.testing.assert_allclose(u, command, rtol=1e-10, atol=1e-12)  # eq. 15 / eq. 36
        alpha = alpha_i * math.tanh(shift - (k if clock == "steps" else k * DT)) + alpha_f
        gain = alpha if unit == "per_step" else alpha * DT
        weights = weights + gain * direction  # eq. 19 / eq. 38, one Euler step
        np.testing.assert_allclose(policy.internals["critic_weights"], weights, rtol=1e-10, atol=1e-12)
        assert policy.internals["learning_rate"] == pytest.approx(alpha)
        assert policy.internals["step"] == k


@pytest.mark.parametrize("task", ["reach", "track"])
def test_euler_updated_commands_with_the_new_weights(ur10, rng, task):
    ctx = _context(ur10, task)
    n = ur10.task_dim
    weights0 = rng.normal(size=QuadraticBasis(n if task == "reach" else 2 * n).size)
    policy = SNACPolicy(ctx, initial_weights=weights0, weight_update="euler_updated")  # α per second (default)
    policy.reset()
    obs = _random_observation(ur10, ctx.layout, rng)
    s = _critic_state(ctx.layout, obs, task)
    jac = ur10.jacobian(obs[:6]).tolist()
    _, direction = _laws_loops(list(s), list(weights0), jac, np.eye(6).tolist(), n)
    alpha = PAPER_SCHEDULES[task][0] * math.tanh(PAPER_SCHEDULES[task][2]) + PAPER_SCHEDULES[task][1]
    updated = weights0 + alpha * DT * direction
    command, _ = _laws_loops(list(s), list(updated), jac, np.eye(6).tolist(), n)
    np.testing.assert_allclose(policy.act(obs), command, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(policy.internals["critic_weights"], updated, rtol=1e-12)


@pytest.mark.parametrize("task", ["reach", "track"])
@pytest.mark.parametrize("unit", ["per_step", "per_second"])
def test_zoh_update_is_the_integral_along_the_held_command(ur10, rng, task, unit):
    """Ŵₖ₊₁ − Ŵₖ = h/Δt · α ∫₀^Δt ∇σ(s(τ)) G R⁻¹ Gᵀ s(τ) dτ with s(τ) = s + τ[Ju − ẋ_d; ẋ_d], by quadrature.

    h = 1 per step (α is the gain of one update), h = Δt per second (α is the continuous rate).
    """
    ctx = _context(ur10, task)
    n = ur10.task_dim
    weights0 = rng.normal(size=QuadraticBasis(n if task == "reach" else 2 * n).size)
    R = rng.uniform(0.5, 2.0, 6)
    policy = SNACPolicy(ctx, R=R, initial_weights=weights0, weight_update="zoh", learning_rate_unit=unit)
    policy.reset()
    obs = _random_observation(ur10, ctx.layout, rng)
    f = ctx.layout.unpack(obs)
    s = _critic_state(ctx.layout, obs, task)
    jac = ur10.jacobian(f.q)
    u = policy.act(obs)
    xdot_d = f.xdot_d if task == "track" else np.zeros(n)  # reach: ẋ_d = 0 is what the env sends
    rate = np.concatenate([jac @ u - f.xdot_d, xdot_d])[: len(s)]
    rinv = np.diag(1.0 / R).tolist()

    def integrand(tau):
        return _laws_loops(list(s + tau * rate), list(weights0), jac.tolist(), rinv, n)[1]

    integral, _ = quad_vec(integrand, 0.0, DT, epsabs=1e-14)
    alpha = PAPER_SCHEDULES[task][0] * math.tanh(PAPER_SCHEDULES[task][2]) + PAPER_SCHEDULES[task][1]
    h = 1.0 if unit == "per_step" else DT
    np.testing.assert_allclose(policy.internals["critic_weights"], weights0 + h * alpha / DT * integral, rtol=1e-9)


def test_seconds_clock_reads_k_as_time(ur10):
    policy = SNACPolicy(_context(ur10, "track"), schedule_clock="seconds")
    for k in (0, 7, 1250, 5000):
        assert policy.learning_rate(k) == pytest.approx(20.0 * math.tanh(10.0 - k * DT) + 70.0)
    default = SNACPolicy(_context(ur10, "reach"))  # seconds is the default clock
    assert default.schedule_clock == "seconds"
    assert default.learning_rate(1250) == pytest.approx(100 * math.tanh(50 - 10.0) + 150)
    steps = SNACPolicy(_context(ur10, "reach"), schedule_clock="steps")
    assert steps.learning_rate(0) == pytest.approx(100 * math.tanh(50) + 150)
    assert steps.learning_rate(100) == pytest.approx(100 * math.tanh(-50) + 150)


def test_internals_value_and_lyapunov(ur10, rng):
    ctx = _context(ur10, "track")
    weights0 = rng.normal(size=21)
    policy = SNACPolicy(ctx, initial_weights=weights0)
    policy.reset()
    obs = _random_observation(ur10, ctx.layout, rng)
    s = _critic_state(ctx.layout, obs, "track")
    policy.act(obs)
    internals = policy.internals
    expected_value = sum(w * s[i] * s[j] for w, (i, j) in zip(weights0, _terms(6)))
    assert internals["critic_value"] == pytest.approx(expected_value, rel=1e-12)
    assert internals["lyapunov"] == pytest.approx(0.5 * float(s @ s), rel=1e-12)
    assert internals["saturated"] is False


def test_general_dimensions_nothing_hard_coded(rng):
    """A 4-joint arm in a 2-D task space: basis sizes 3 / 10, laws still match the hand expansion."""

    class PlanarKinematics:
        n_joints, task_dim = 4, 2
        velocity_limits = np.full(4, 1e9)

        def __init__(self):
            self.matrix = rng.normal(size=(2, 4))

        def jacobian(self, q):
            return self.matrix

    kin = PlanarKinematics()
    layout = ObservationLayout(4, 2)
    for task, size in (("reach", 3), ("track", 10)):
        context = PolicyContext(kin, DT, kin.velocity_limits, layout, task)
        policy = SNACPolicy(context, initial_weights=rng.normal(size=size))
        policy.reset()
        assert policy.basis.size == size
        q = rng.normal(size=4)
        x_d, x_c = rng.normal(size=2), rng.normal(size=2)
        obs = layout.pack(q, np.zeros(4), kin.matrix @ q, x_d, rng.normal(size=2), x_c)
        s = _critic_state(layout, obs, task)
        weights = list(policy.critic_weights)
        command, direction = _laws_loops(list(s), weights, kin.matrix.tolist(), np.eye(4).tolist(), 2)
        w0 = policy.critic_weights.copy()
        u = policy.act(obs)
        assert u.shape == (4,)
        np.testing.assert_allclose(u, command, rtol=1e-10)
        alpha = 100 * math.tanh(50) + 150 if task == "reach" else 20 * math.tanh(10) + 70
        assert policy.learning_rate(0) == pytest.approx(alpha)
        np.testing.assert_allclose(policy.internals["critic_weights"], w0 + alpha * DT * direction, rtol=1e-10)


# -- limits, anti-windup, randomness, errors ---------------------------------------------------
@pytest.mark.parametrize("freeze", [True, False])
def test_commands_are_clipped_and_freeze_skips_learning(ur10, rng, freeze):
    ctx = PolicyContext(ur10, DT, ur10.velocity_limits.copy(), ObservationLayout(6, 3), "reach")
    weights0 = np.array([400.0, 0.0, 0.0, 400.0, 0.0, 400.0])  # a steep critic: the command saturates
    policy = SNACPolicy(ctx, initial_weights=weights0, freeze_when_saturated=freeze)
    policy.reset()
    obs = _random_observation(ur10, ctx.layout, rng)
    s = _critic_state(ctx.layout, obs, "reach")
    command, _ = _laws_loops(list(s), list(weights0), ur10.jacobian(obs[:6]).tolist(), np.eye(6).tolist(), 3)
    assert np.any(np.abs(command) > ur10.velocity_limits)
    u = policy.act(obs)
    np.testing.assert_array_equal(u, np.clip(command, -ur10.velocity_limits, ur10.velocity_limits))
    assert np.all(np.abs(u) <= ur10.velocity_limits)
    assert policy.internals["saturated"] is True
    unchanged = np.array_equal(policy.internals["critic_weights"], weights0)
    assert unchanged == freeze


def test_command_scale_multiplies_the_unclipped_command(ur10, rng):
    ctx = _context(ur10, "track")
    weights0 = rng.normal(size=21)
    obs = _random_observation(ur10, ctx.layout, rng)
    commands = []
    for scale in (1.0, 2.5):
        policy = SNACPolicy(ctx, initial_weights=weights0, command_scale=scale)
        policy.reset()
        commands.append(policy.act(obs))
    np.testing.assert_allclose(commands[1], 2.5 * commands[0], rtol=1e-12)
    assert SNACPolicy.effort_parameter == "command_scale"


def test_random_initial_weights_follow_the_seed(ur10):
    ctx = _context(ur10, "track")
    policy = SNACPolicy(ctx, initial_weights="uniform")
    policy.reset(seed=3)
    first = policy.critic_weights.copy()
    assert first.shape == (21,) and np.all((first >= 0) & (first < 1))
    policy.reset(seed=3)
    np.testing.assert_array_equal(policy.critic_weights, first)
    np.testing.assert_array_equal(policy.internals["critic_weights"], first)
    policy.reset(seed=4)
    assert not np.array_equal(policy.critic_weights, first)
    ranged = SNACPolicy(ctx, initial_weights="uniform", initial_weight_range=(-2.0, -1.0))
    ranged.reset(seed=3)
    assert np.all((ranged.critic_weights >= -2) & (ranged.critic_weights < -1))
    given = SNACPolicy(ctx, initial_weights=np.arange(21.0))
    given.reset(seed=9)
    np.testing.assert_array_equal(given.critic_weights, np.arange(21.0))
    legacy = SNACPolicy(ctx, initial_weights=None)  # the earlier spelling of "uniform"
    legacy.reset(seed=3)
    np.testing.assert_array_equal(legacy.critic_weights, first)


@pytest.mark.parametrize(("task", "dim", "default_scale"), [("reach", 3, 2.0), ("track", 6, 20.0)])
def test_identity_initial_weights_are_c_on_the_squared_terms(ur10, rng, task, dim, default_scale):
    """Identity Ŵ₀: c on s_i², 0 on s_i s_j (i ≠ j), so V̂₀(s) = c‖s‖²; the seed does not enter."""
    ctx = _context(ur10, task)
    for scale, expected_scale in ((None, default_scale), (7.5, 7.5)):
        policy = SNACPolicy(ctx, initial_weights="identity", initial_weight_scale=scale)
        assert policy.initial_weight_kind == "identity" and policy.initial_weight_scale == expected_scale
        expected = [expected_scale if i == j else 0.0 for i, j in _terms(dim)]
        for seed in (0, 1):
            policy.reset(seed=seed)
            np.testing.assert_array_equal(policy.critic_weights, expected)
        obs = _random_observation(ur10, ctx.layout, rng)
        s = _critic_state(ctx.layout, obs, task)
        policy.act(obs)
        assert policy.internals["critic_value"] == pytest.approx(expected_scale * float(s @ s), rel=1e-12)
    explicit = SNACPolicy(ctx, initial_weights="identity", initial_weight_scale=3.0)
    explicit.reset()
    assert explicit.critic_weights.sum() == pytest.approx(3.0 * dim)


def test_defaults_are_the_papers_reading(ur10):
    """The defaults read the paper literally where it is explicit: random Ŵ₀ ~ U(0, 1), ξ = [e; x_d],
    the continuous law without anti-windup, the paper's schedule, Q = I, R = I."""
    for task in ("reach", "track"):
        policy = SNACPolicy(_context(ur10, task))
        assert policy.learning_rate_unit == "per_second"
        assert policy.freeze_when_saturated is False
        assert policy.weight_update == "euler"
        assert policy.schedule_clock == "seconds"
        assert policy.initial_weight_kind == "uniform" and policy.initial_weight_range == (0.0, 1.0)
        assert policy.tracking_state == "paper"
        alpha_i, alpha_f, shift = PAPER_SCHEDULES[task]
        schedule = (policy.learning_rate_initial, policy.learning_rate_final, policy.schedule_shift)
        assert schedule == (alpha_i, alpha_f, shift)
        np.testing.assert_array_equal(policy.Q, np.eye(3))
        np.testing.assert_array_equal(policy.R, np.eye(6))


def test_reset_restarts_the_schedule_and_earlier_weights_are_kept(ur10, rng):
    ctx = _context(ur10, "reach")
    policy = SNACPolicy(ctx)
    policy.reset(seed=1)
    obs = _random_observation(ur10, ctx.layout, rng)
    snapshot = policy.internals["critic_weights"]
    before = snapshot.copy()
    policy.act(obs)
    policy.act(obs)
    np.testing.assert_array_equal(snapshot, before)  # updates make new arrays
    assert policy.internals["step"] == 1
    policy.reset(seed=1)
    policy.act(obs)
    assert policy.internals["step"] == 0


def test_bad_arguments_and_act_before_reset(ur10):
    ctx = _context(ur10, "reach")
    with pytest.raises(RuntimeError, match="reset"):
        SNACPolicy(ctx).act(np.zeros(ctx.layout.size))
    for kwargs in (
        {"weight_update": "rk4"},
        {"schedule_clock": "minutes"},
        {"learning_rate_unit": "per_hour"},
        {"command_scale": 0.0},
        {"R": -np.eye(6)},
        {"R": np.eye(3)},
        {"initial_weights": np.zeros(5)},
        {"initial_weight_range": (1.0, 0.0)},
        {"initial_weights": "gaussian"},
        {"initial_weight_scale": float("nan")},
    ):
        with pytest.raises(ValueError):
            SNACPolicy(ctx, **kwargs)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"initial_weight_scale": 3.0}, "initial_weight_scale is c of initial_weights='identity' and does nothing "
         "with initial_weights='uniform'; pass initial_weights='identity' with it"),
        ({"initial_weights": np.zeros(6), "initial_weight_scale": 3.0}, "does nothing with initial_weights=an array"),
        ({"initial_weights": "identity", "initial_weight_range": (0.0, 2.0)},
         "initial_weight_range is the range of initial_weights='uniform' and does nothing with initial_weights="
         "'identity'"),
    ],
)  # fmt: skip
def test_a_knob_of_another_initialisation_is_refused_not_ignored(ur10, kwargs, message):
    """A study that passed initial_weight_scale alone (docs/snac.md's, once the default became the paper's uniform
    draw) ran the uniform draw under the name of each scale, every row the same, without a word."""
    ctx = _context(ur10, "reach")
    with pytest.raises(ValueError, match=re.escape(message)):
        SNACPolicy(ctx, **kwargs)
    SNACPolicy(ctx, initial_weights="identity", initial_weight_scale=3.0)  # with its own kind: taken
    SNACPolicy(ctx, initial_weights="uniform", initial_weight_range=(0.0, 2.0))


@pytest.mark.parametrize("copier", [lambda p: pickle.loads(pickle.dumps(p)), copy.deepcopy])
def test_a_copied_policy_continues_identically(ur10, rng, copier):
    """Pickled or deep-copied mid-episode (as worker processes do), the copy acts like the original."""
    ctx = _context(ur10, "track", limit=3.0)
    policy = SNACPolicy(ctx)
    policy.reset(seed=2)
    observations = [_random_observation(ur10, ctx.layout, rng) for _ in range(6)]
    for obs in observations[:3]:
        policy.act(obs)
    twin = copier(policy)
    for obs in observations[3:]:
        np.testing.assert_array_equal(twin.act(obs), policy.act(obs))
        np.testing.assert_array_equal(twin.internals["critic_weights"], policy.internals["critic_weights"])


# -- optimality diagnostics -------------------------------------------------------------------
@pytest.mark.parametrize("task", ["reach", "track"])
@pytest.mark.parametrize("tracking_state", ["paper", "centred"])
def test_hjb_residual_of_the_critic_matches_a_hand_expansion(ur10, rng, task, tracking_state):
    """r = ∇_ξV̂ᵀ(F + Gû) + eᵀQe + ûᵀRû with F = [−ẋ_d; ẋ_d], G = [J; 0] (eqs. 7, 31), by loops."""
    ctx = _context(ur10, task)
    n = ur10.task_dim
    Q, R = _random_spd(rng, n), _random_spd(rng, 6)
    policy = SNACPolicy(ctx, Q=Q, R=R, tracking_state=tracking_state)
    size = policy.basis.size
    rows = [_random_observation(ur10, ctx.layout, rng) for _ in range(4)]
    weights = rng.normal(size=(4, size))
    fields = [ctx.layout.unpack(obs) for obs in rows]
    x_c = fields[0].x_c
    expected = []
    for f, w in zip(fields, weights):
        obs = ctx.layout.pack(f.q, f.qdot, f.x, f.x_d, f.xdot_d if task == "track" else np.zeros(n), x_c)
        g = ctx.layout.unpack(obs)
        s = _critic_state(ctx.layout, obs, task, tracking_state)
        jac = ur10.jacobian(g.q)
        command, _ = _laws_loops(list(s), list(w), jac.tolist(), np.linalg.inv(R).tolist(), n)
        grad = np.array(_basis_gradient_loops(list(s))).T @ w  # ∇_s V̂
        rate = np.concatenate([jac @ command - g.xdot_d, g.xdot_d])[: len(s)]
        expected.append(grad @ rate + g.e @ Q @ g.e + command @ R @ command)
    xdot_d = np.array([f.xdot_d if task == "track" else np.zeros(n) for f in fields])
    out = policy.critic_diagnostics(
        np.array([f.q for f in fields]),
        np.array([f.e for f in fields]),
        np.array([f.x_d for f in fields]),
        xdot_d,
        x_c,
        weights,
    )
    np.testing.assert_allclose(out["hjb_residual"], expected, rtol=1e-9)
    np.testing.assert_allclose(out["hjb_ratio"], np.array(expected) / [f.e @ Q @ f.e for f in fields], rtol=1e-9)
    assert ("critic_error" in out) == (task == "reach")


def test_the_optimal_critic_has_zero_residual_and_zero_critic_error(ur10, rng):
    from scipy.linalg import solve_continuous_are

    from snac_gym.control.optimality import matrix_to_quadratic_weights

    ctx = _context(ur10, "reach")
    Q, R = _random_spd(rng, 3), _random_spd(rng, 6)
    policy = SNACPolicy(ctx, Q=Q, R=R)
    q = rng.uniform(-np.pi, np.pi, size=(5, 6))
    optimum = [solve_continuous_are(np.zeros((3, 3)), ur10.jacobian(row), Q, R) for row in q]
    weights = np.array([matrix_to_quadratic_weights(P) for P in optimum])
    e = rng.normal(scale=0.1, size=(5, 3))
    out = policy.critic_diagnostics(q, e, np.zeros((5, 3)), np.zeros((5, 3)), np.zeros(3), weights)
    np.testing.assert_allclose(out["hjb_ratio"], 0.0, atol=1e-7)
    np.testing.assert_allclose(out["critic_error"], 0.0, atol=1e-7)
    doubled = policy.critic_diagnostics(q, e, np.zeros((5, 3)), np.zeros((5, 3)), np.zeros(3), 2 * weights)
    np.testing.assert_allclose(doubled["critic_error"], 1.0, rtol=1e-9)  # ‖2P* − P*‖/‖P*‖
    np.testing.assert_allclose(doubled["hjb_ratio"], -3.0, rtol=1e-6)  # eᵀ(Q − 4P*GP*)e / eᵀQe = −3


@pytest.mark.parametrize("task", ["reach", "track"])
def test_the_papers_snac_trajectory_does_not_depend_on_q(task):
    """Eqs. 15/19 and 36/38 contain no Q: any Q gives the same commands and weights, bit for bit."""
    from snac_gym.apps.demo import run_demo

    logs = [
        run_demo(task, "snac", None, seed=3, steps=150, policy_kwargs={"Q": Q}).log for Q in (None, [100.0, 0.01, 7.0])
    ]
    diagnostics = ["hjb_residual", "hjb_ratio", "critic_error"]  # these measure against the cost, so they do see Q
    trajectories = [log.drop(columns=[c for c in diagnostics if c in log.columns]) for log in logs]
    assert trajectories[0].equals(trajectories[1])
    assert not np.allclose(logs[0]["hjb_ratio"], logs[1]["hjb_ratio"])
