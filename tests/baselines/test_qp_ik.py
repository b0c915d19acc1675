"""The QP differential-IK controllers ``pink`` and ``mink`` (baselines/qp_ik.py) and the MuJoCo model mink runs on.

Each library's command is checked against the same QP solved independently (SciPy's bounded least squares
on the project's Jacobian, and its KKT conditions written out), and both against the joint limits on random
episodes. Skipped, with the reason, when the ``ik`` extra is not installed.
"""

from __future__ import annotations

import sys

import gymnasium as gym
import numpy as np
import pytest
from scipy.optimize import lsq_linear
from snac_gym.evaluation.execution.jobs import policy_context
from snac_gym.evaluation.samples import EvaluationSample

from snac_gym.common.extras import MissingExtraError
from snac_gym.metrics import rollout_metrics
from snac_gym.model.kinematics import Kinematics, PoseKinematics
from snac_gym.policies import make_policy
from snac_gym.references import FixedTarget
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import nominal_configuration, solve_reachable

DT = 1 / 125
#: The libraries' own Tikhonov term ε of solve_ik (their default, left as is).
EPSILON = 1e-12
LIBRARIES = {"pink": "pink", "mink": "mink"}


def _library(name: str) -> None:
    pytest.importorskip(LIBRARIES[name], reason=f"the 'ik' extra ({LIBRARIES[name]}) is not installed")
    qpsolvers = pytest.importorskip("qpsolvers", reason="the 'ik' extra (qpsolvers) is not installed")
    if "daqp" not in qpsolvers.available_solvers:
        pytest.skip("the 'ik' extra (daqp) is not installed")


@pytest.fixture(params=sorted(LIBRARIES))
def controller(request) -> str:
    _library(request.param)
    return request.param


# -- the MuJoCo model --------------------------------------------------------------------------------
@pytest.mark.parametrize("robot", ["ur3", "ur5", "ur10", "panda", "xarm7"])
def test_mujoco_site_matches_the_kinematics(robot):
    """Site position, orientation and Jacobian [jacp; jacr] equal Kinematics/PoseKinematics to 1e-9."""
    mujoco = pytest.importorskip("mujoco", reason="the 'ik' extra (mujoco) is not installed")
    from snac_gym.physics.mujoco_model import EE_SITE, build_mujoco_model

    kinematics, pose = Kinematics(robot), PoseKinematics(robot)
    model = build_mujoco_model(kinematics)
    data, site = mujoco.MjData(model), model.site(EE_SITE).id
    assert (
        model.nq == kinematics.n_joints
        and tuple(model.joint(i).name for i in range(model.njnt)) == kinematics.joint_names
    )
    np.testing.assert_array_equal(model.jnt_range[:, 0], kinematics.lower_limits)
    np.testing.assert_array_equal(model.jnt_range[:, 1], kinematics.upper_limits)
    rng = np.random.default_rng(7)
    for _ in range(20):
        q = rng.uniform(np.maximum(kinematics.lower_limits, -np.pi), np.minimum(kinematics.upper_limits, np.pi))
        data.qpos[:] = q
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        jacobian = np.zeros((6, model.nv))
        mujoco.mj_jacSite(model, data, jacobian[:3], jacobian[3:], site)
        np.testing.assert_allclose(data.site_xpos[site], kinematics.forward(q), rtol=0, atol=1e-9)
        np.testing.assert_allclose(jacobian[:3], kinematics.jacobian(q), rtol=0, atol=1e-9)
        np.testing.assert_allclose(data.site_xmat[site].reshape(3, 3), pose.placement(q).rotation, rtol=0, atol=1e-9)
        np.testing.assert_allclose(jacobian, pose.jacobian(q), rtol=0, atol=1e-9)


# -- the command is the QP's optimum ----------------------------------------------------------------
def _independent_qp(policy, kinematics, obs) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The module's QP solved with SciPy: min ‖J u − v‖² + (λ² + ε + μ)‖u‖² over the box lb ≤ u ≤ ub.

    The libraries' objective in Δq = uΔt is ½‖JΔq + αẽ‖² + ½(λ² + ε + μ)‖Δq‖², αẽ = −vΔt: the same up to
    the factor Δt²/2. J is the project's (Kinematics/PoseKinematics), not the library's.
    """
    layout = policy.layout
    q = obs[layout.slices["q"]]
    e, xdot_d = obs[layout.slices["e"]], obs[layout.slices["xdot_d"]]
    v = xdot_d - policy.gain * e
    jacobian = kinematics.jacobian(q)
    mu = policy.lm_damping * float((policy.dt * v) @ (policy.dt * v))
    regulariser = policy.damping**2 + EPSILON + mu
    m = len(q)
    lower_q, upper_q = policy._lower, policy._upper
    lb = np.maximum(-policy.velocity_limits, policy.limit_gain * (lower_q - q) / policy.dt)
    ub = np.minimum(policy.velocity_limits, policy.limit_gain * (upper_q - q) / policy.dt)
    a = np.vstack([jacobian, np.sqrt(regulariser) * np.eye(m)])
    b = np.concatenate([v, np.zeros(m)])
    u = lsq_linear(a, b, bounds=(lb, ub), method="bvls", tol=1e-15).x
    gradient = jacobian.T @ (jacobian @ u - v) + regulariser * u
    return u, (lb, ub), gradient


def _random_observations(kinematics, layout, task_dim, rng, count):
    """Random states: θ anywhere in the limits (some next to one), errors up to 0.5 m (velocity bounds
    active) or 5 mm, a random ẋ_d on half of them (the feed-forward)."""
    lower, upper = kinematics.lower_limits, kinematics.upper_limits
    for k in range(count):
        q = rng.uniform(np.maximum(lower, -np.pi), np.minimum(upper, np.pi))
        if k % 3 == 0:  # a joint 0.1-2 mrad from a position limit
            j = rng.integers(len(q))
            q[j] = upper[j] - rng.uniform(1e-4, 2e-3) if rng.random() < 0.5 else lower[j] + rng.uniform(1e-4, 2e-3)
        e = rng.normal(size=task_dim)
        e *= (0.5 if k % 2 else 5e-3) * rng.uniform(0.2, 1.0) / np.linalg.norm(e)
        xdot_d = rng.normal(scale=0.1, size=task_dim) if k % 4 < 2 else np.zeros(task_dim)
        x = np.zeros(task_dim)
        yield layout.pack(q, np.zeros_like(q), x, x - e, xdot_d, x, error=e)


@pytest.mark.parametrize(
    "robot, task, kwargs",
    [
        ("ur10", "reach", {}),
        ("ur10", "track", {"lm_damping": 0.5}),
        ("panda", "reach", {"gain": 5.0}),
        ("panda", "reach", {"gain": 5.0, "assembly": "library"}),
        ("ur10", "track", {"assembly": "library"}),
        ("panda", "pose-reach", {"damping": 0.05}),
        ("ur10", "pose-track", {"limit_gain": 0.3}),
    ],
)
def test_command_is_the_optimum_of_the_qp(controller, robot, task, kwargs, pose_tasks):
    """The library's command equals the QP solved by SciPy (BVLS) to 1e-6 relative, and meets the KKT
    conditions: zero gradient on free joints, a gradient pushing outwards at an active bound."""
    context = policy_context(robot, DT, task)
    kinematics = context.kinematics
    policy = make_policy(controller, context, **kwargs)
    rng = np.random.default_rng(3)
    active = {"velocity": 0, "position": 0}
    for obs in _random_observations(
        kinematics.position if task.startswith("pose") else kinematics, context.layout, context.layout.task_dim, rng, 18
    ):
        command = policy.act(obs)
        expected, (lb, ub), _ = _independent_qp(policy, kinematics, obs)
        scale = max(1.0, np.abs(expected).max())
        np.testing.assert_allclose(command, expected, rtol=0, atol=1e-6 * scale)
        # KKT at the library's own command (its gradient, its active set).
        jacobian = kinematics.jacobian(obs[context.layout.slices["q"]])
        v = obs[context.layout.slices["xdot_d"]] - policy.gain * obs[context.layout.slices["e"]]
        mu = policy.lm_damping * float((policy.dt * v) @ (policy.dt * v))
        gradient = jacobian.T @ (jacobian @ command - v) + (policy.damping**2 + EPSILON + mu) * command
        at_lower, at_upper = command <= lb + 1e-9 * scale, command >= ub - 1e-9 * scale
        free = ~(at_lower | at_upper)
        tolerance = 1e-6 * max(1.0, np.abs(jacobian.T @ v).max())
        assert np.all(np.abs(gradient[free]) <= tolerance)
        assert np.all(gradient[at_lower] >= -tolerance) and np.all(gradient[at_upper] <= tolerance)
        bounded = at_lower | at_upper
        active["velocity"] += int(np.any(bounded & np.isclose(np.abs(command), policy.velocity_limits)))
        active["position"] += int(np.any(bounded & ~np.isclose(np.abs(command), policy.velocity_limits)))
    assert active["velocity"] > 0 and active["position"] > 0  # both kinds of constraint were exercised


def _library_box(policy) -> tuple[np.ndarray, np.ndarray]:
    """The bounds on Δq that the library's own limit objects give at its configuration: each row of their
    ``G Δq ≤ h`` is ±(a unit row), read back into a per-joint box."""
    m = len(policy._lower)
    lower, upper = np.full(m, -np.inf), np.full(m, np.inf)
    for limit in policy._limits:
        rows = limit.compute_qp_inequalities(policy._configuration, policy.dt)
        G, h = (rows.G, rows.h) if hasattr(rows, "G") else rows
        for row, bound in zip(G, h, strict=True):
            (joint,) = np.flatnonzero(row)
            if row[joint] > 0:
                upper[joint] = min(upper[joint], bound / row[joint])
            else:
                lower[joint] = max(lower[joint], bound / row[joint])
    return lower, upper


@pytest.mark.parametrize("robot, task", [("ur10", "track"), ("panda", "reach"), ("panda", "pose-reach")])
def test_direct_assembly_is_the_librarys_solve_ik(controller, robot, task, pose_tasks):
    """The default ``assembly="direct"`` solves the library's own QP: its box is the library limits' rows
    (to 1e-15) and its command the library's ``solve_ik`` (to 1e-9), at states with active bounds."""
    context = policy_context(robot, DT, task)
    direct = make_policy(controller, context, gain=20.0)
    library = make_policy(controller, context, gain=20.0, assembly="library")
    assert direct.assembly == "direct"
    kinematics = context.kinematics.position if task.startswith("pose") else context.kinematics
    rng = np.random.default_rng(11)
    bounded = 0
    for obs in _random_observations(kinematics, context.layout, context.layout.task_dim, rng, 24):
        command, expected = direct.act(obs), library.act(obs)
        np.testing.assert_allclose(command, expected, rtol=0, atol=1e-9 * max(1.0, np.abs(expected).max()))
        q = library.measured_q(obs)
        lower, upper = _library_box(library)  # at q: the library's configuration was updated by act
        np.testing.assert_allclose(np.array(direct.box(q)), np.array([lower, upper]), rtol=1e-15, atol=1e-15)
        bounded += int(np.any(np.isclose(command * DT, lower) | np.isclose(command * DT, upper)))
    assert bounded > 0


def test_an_unknown_assembly_is_refused(controller):
    with pytest.raises(ValueError, match="assembly must be one of direct, library, got 'fast'"):
        make_policy(controller, policy_context("ur10", DT, "reach"), assembly="fast")


def test_without_active_bounds_the_command_is_dls(controller):
    """Where no bound is active the QP's minimiser is Jᵀ(JJᵀ + λ²I)⁻¹v: DLS's command with the same λ
    (on the UR10, whose ±2π position limits are far, wherever DLS's command is inside the velocity box)."""
    context = policy_context("ur10", DT, "track")
    policy, dls = make_policy(controller, context), make_policy("dls", context)
    env = gym.make("snac_gym/UR10EllipseTrack-v0", physics="kinematic")
    obs, _ = env.reset(seed=2)
    compared = 0
    for _ in range(200):
        command, reference = policy.act(obs), dls.act(obs)
        if np.all(np.abs(reference) < 0.999 * context.velocity_limits):
            np.testing.assert_allclose(command, reference, rtol=0, atol=1e-9)
            compared += 1
        obs, *_ = env.step(command)
    assert compared > 100
    env.close()


# -- limits on episodes ------------------------------------------------------------------------------
@pytest.mark.parametrize("robot", ["ur10", "panda"])
def test_random_episodes_stay_inside_the_position_and_velocity_limits(controller, robot):
    env = gym.make(f"snac_gym/{'UR10' if robot == 'ur10' else 'Panda'}Reach-v0", physics="kinematic")
    base = env.unwrapped
    policy = make_policy(controller, env, gain=20.0)  # aggressive: the velocity bounds are active
    lower, upper, limits = base.kinematics.lower_limits, base.kinematics.upper_limits, base.velocity_limits
    saturated = 0
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        policy.reset(seed=seed)
        for _ in range(150):
            u = policy.act(obs)
            assert np.all(np.abs(u) <= limits)
            saturated += int(np.any(np.isclose(np.abs(u), limits)))
            obs, *_ = env.step(u)
            q = obs[: len(u)]
            assert np.all(q >= lower) and np.all(q <= upper)
    assert saturated > 0
    env.close()


def _pushing_sample(kinematics: Kinematics) -> EvaluationSample:
    """The Panda's ready pose with the shoulder 0.12 rad from its upper limit and a target that leaning
    0.3 rad further would reach (tests/model/test_joint_limits.py: the least-norm motion crosses the limit)."""
    q0 = nominal_configuration(kinematics)
    q0[1] = kinematics.upper_limits[1] - 0.12
    beyond = q0.copy()
    beyond[1] += 0.3
    assert solve_reachable(kinematics, kinematics.forward(beyond), q0) is not None
    return EvaluationSample("reach", 0, q0, FixedTarget(kinematics.forward(beyond)))


def test_next_to_a_limit_the_qp_stays_inside_and_still_reaches(controller):
    """Where DLS unguarded crosses the limit and guarded stops short of the target, the QP stays inside its
    limits and reaches the target: the other joints take over the motion the bounded one cannot make."""
    context = policy_context("panda", DT, "reach")
    kinematics = context.kinematics
    sample = _pushing_sample(kinematics)
    rollouts = simulate_kinematic(context, lambda: make_policy(controller, context), [sample], 1500, [0])
    metrics = rollout_metrics(
        rollouts, "reach", context.velocity_limits, None, (kinematics.lower_limits, kinematics.upper_limits)
    )
    assert metrics["joint_limit_margin"].iloc[0] >= 0
    assert metrics["final_error"].iloc[0] < 1e-3


# -- the paper's tasks, the batch protocol --------------------------------------------------------
def test_paper_reach_and_track_succeed(controller):
    for env_id, check in (
        ("snac_gym/UR10Reach-v0", lambda info, errors: info["error_norm"] < 1e-3),
        ("snac_gym/UR10EllipseTrack-v0", lambda info, errors: np.mean(errors[len(errors) // 2 :]) < 5e-3),
    ):
        env = gym.make(env_id, physics="kinematic")
        policy = make_policy(controller, env)
        obs, info = env.reset(options={"q0": list(nominal_configuration(env.unwrapped.kinematics))}, seed=0)
        errors, done = [], False
        while not done:
            obs, _, terminated, truncated, info = env.step(policy.act(obs))
            errors.append(info["error_norm"])
            done = terminated or truncated
        assert check(info, errors), env_id
        env.close()


def test_act_batch_rows_equal_act(controller):
    context = policy_context("ur10", DT, "track")
    policy = make_policy(controller, context)
    rng = np.random.default_rng(5)
    batch = np.array(list(_random_observations(context.kinematics, context.layout, 3, rng, 6)))
    policy.reset_batch(list(range(len(batch))))
    np.testing.assert_array_equal(policy.act_batch(batch), np.array([policy.act(obs) for obs in batch]))


def test_gain_times_dt_above_one_is_refused(controller):
    with pytest.raises(ValueError, match="gain·dt"):
        make_policy(controller, policy_context("ur10", DT, "reach"), gain=200.0)


# -- without the extra ----------------------------------------------------------------------------
@pytest.mark.parametrize("name", sorted(LIBRARIES))
def test_missing_extra_is_one_line(name, monkeypatch):
    monkeypatch.setitem(sys.modules, LIBRARIES[name], None)  # what an uninstalled package looks like to import
    with pytest.raises(MissingExtraError) as info:
        make_policy(name, policy_context("ur10", DT, "reach"))
    assert str(info.value) == f"{name} needs the 'ik' extra: pip install -e \".[ik]\""
    assert isinstance(info.value, ValueError) and isinstance(info.value, ImportError)


def test_missing_extra_is_one_line_from_the_cli(tmp_path, monkeypatch):
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    monkeypatch.setitem(sys.modules, "mink", None)
    result = CliRunner().invoke(
        app, ["demo", "--controller", "mink", "--steps", "5", "--no-plots", "--out", str(tmp_path)]
    )
    assert result.exit_code == 2
    assert result.output.strip() == "error: mink needs the 'ik' extra: pip install -e \".[ik]\""
    evaluate = CliRunner().invoke(
        app,
        ["evaluate", "--controllers", "mink,dls", "--samples", "2", "--no-progress", "--out", str(tmp_path / "run")],
    )
    assert evaluate.exit_code == 2
    assert (
        evaluate.output.strip()
        == "error: controller 'mink' is not installed: mink needs the 'ik' extra: pip install -e \".[ik]\""
    )
