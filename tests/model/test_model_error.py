"""A wrong arm model for the controllers (``--model-error``) and ``snac-adaptive``, which identifies it.

The erroneous kinematics is checked against the true one evaluated independently (Pinocchio at
shifted angles, scaled, offset in the tool frame); the evaluator's plant against a replay of the
same commands; the identifier against the true Jacobian; the adaptive critic against the ARE
(scipy).
"""

import json
import subprocess
import sys

import numpy as np
import pandas as pd
import pinocchio as pin
import pytest
from scipy.linalg import solve_continuous_are
from snac_gym.evaluation.execution.jobs import RolloutJob, policy_context, run_job, task_kinematics
from snac_gym.evaluation.reference.optimum import ReplayPolicy
from snac_gym.evaluation.run_config import EvaluationConfig
from snac_gym.evaluation.runner import run_evaluation
from snac_gym.evaluation.samples import generate_samples

from snac_gym.control.optimality import quadratic_weights_to_matrix
from snac_gym.model.kinematics import Kinematics
from snac_gym.model.model_error import ModelError
from snac_gym.observation import ObservationLayout
from snac_gym.policies.base import PolicyContext
from snac_gym.policies.snac_adaptive import GeometricIdentifier, SNACAdaptivePolicy
from snac_gym.rollout import simulate_kinematic
from snac_gym.sampling import SampleSpace

ELBOW = "joint_offset=0,0,0.3,0,0,0"


def _true_frame(kinematics, q):
    """The tool frame through Pinocchio directly (no snac-gym batching)."""
    model, data = kinematics.model, kinematics.model.createData()
    frame = model.getFrameId(kinematics.ee_frame)
    pin.framesForwardKinematics(model, data, q)
    return data.oMf[frame]


def test_each_part_of_the_error_is_the_true_kinematics_changed_as_documented(ur10, rng):
    offsets = rng.normal(scale=0.3, size=6)
    shifted = Kinematics("ur10", model_error=ModelError(joint_offset=tuple(offsets)))
    scaled = Kinematics("ur10", model_error="link_scale=0.05")
    tool = Kinematics("ur10", model_error="tool_offset=0.01,-0.02,0.03")
    for q in rng.uniform(-2.5, 2.5, size=(5, 6)):
        np.testing.assert_allclose(shifted.forward(q), _true_frame(ur10, q + offsets).translation, atol=1e-12)
        np.testing.assert_allclose(shifted.jacobian(q), ur10.jacobian(q + offsets), atol=1e-12)
        np.testing.assert_allclose(shifted.forward_batch(q[None])[0], ur10.forward(q + offsets), atol=1e-12)
        np.testing.assert_allclose(scaled.forward(q), 1.05 * ur10.forward(q), atol=1e-12)
        frame = _true_frame(ur10, q)
        np.testing.assert_allclose(
            tool.forward(q), frame.translation + frame.rotation @ [0.01, -0.02, 0.03], atol=1e-12
        )
        # the batched chain of the wrong model agrees with its own Pinocchio evaluation
        np.testing.assert_allclose(tool.jacobian_batch(q[None])[0], tool.jacobian(q), atol=1e-12)


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("joint_offset=0,0.3", "joint_offset needs 6 values"),
        ("joint_offset=0,0,nan,0,0,0", r"joint_offset must be a finite number in \[-3.14159, 3.14159\], got nan"),
        ("link_scale=-1", r"link_scale must be a finite number in \(-1, 1\], got -1.0"),
        ("link_scale=1e6", r"link_scale must be a finite number in \(-1, 1\], got 1000000.0"),
        ("tool_offset=0,0", "tool_offset must be 3 finite numbers"),
        ("elbow=0.3", "NAME one of joint_offset, link_scale, tool_offset"),
        ("link_scale=0.1;link_scale=0.2", "link_scale is given twice"),
        ("joint_offset=a,b", "is not a comma-separated list of numbers"),
    ],
)
def test_a_bad_specification_is_refused_naming_what_is_wrong(spec, message):
    with pytest.raises(ValueError, match=message):
        ModelError.parse(spec).check_joints(6)


def test_the_cli_refuses_a_bad_specification_in_one_line(tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", "snac_gym.apps.cli", "evaluate", "--out", str(tmp_path / "run"), "--samples", "2",
         "--model-error", "joint_offset=0,0.3"],
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert done.returncode == 2
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].endswith("--model-error: joint_offset needs 6 values (one per joint), got 2")


def _samples(task, count=4):
    kinematics = Kinematics("ur10")
    return generate_samples(kinematics, SampleSpace.for_robot(kinematics), 5, task, range(count))


@pytest.mark.parametrize("controller", ["lqr", "snac-hjb", "dls"])
def test_a_zero_model_error_gives_todays_rows_bit_for_bit(controller):
    samples = _samples("track")
    common = {"task": "track", "controller": controller, "kwargs": {}, "samples": tuple(samples),
              "seeds": tuple(range(4)), "steps": 60, "dt": 1 / 125}  # fmt: skip
    today = run_job(RolloutJob(**common)).metrics
    zero = run_job(RolloutJob(**common, model_error="joint_offset=0,0,0,0,0,0;link_scale=0")).metrics
    pd.testing.assert_frame_equal(today, zero, check_exact=True)
    wrong = run_job(RolloutJob(**common, model_error=ELBOW)).metrics
    assert not np.allclose(wrong["cost"], today["cost"])  # the error does reach the controller


def test_the_plant_moves_the_same_under_a_model_error_when_the_commands_are_replayed():
    samples = _samples("reach")
    commands = np.random.default_rng(3).uniform(-0.3, 0.3, size=(4, 50, 6))
    runs = []
    for error in (None, ELBOW):
        context = policy_context("ur10", 1 / 125, "reach", error)
        runs.append(simulate_kinematic(context, lambda: ReplayPolicy(commands), samples, 50, range(4), True,
                                       plant=task_kinematics("ur10", "reach")))  # fmt: skip
    for field in ("q", "x", "errors", "commands", "final_x"):
        np.testing.assert_array_equal(getattr(runs[0], field), getattr(runs[1], field))


def test_a_run_records_its_model_error_and_the_optimum_stays_below_every_controller(tmp_path):
    config = EvaluationConfig(
        out=tmp_path / "run", controllers=("snac-hjb", "snac-adaptive", "lqr", "optimal"), samples=3,
        match_effort=False, horizons={"reach": 1.0, "track": 1.0}, cost="hjb", q_scale=4.0,
        model_error=ELBOW, progress=False, plots=False,
    )  # fmt: skip
    results = run_evaluation(config)
    assert json.loads((tmp_path / "run" / "run.json").read_text())["model_error"] == ELBOW
    assert (results["model_error"] == ELBOW).all()
    costs = results.pivot_table(index=["task", "sample"], columns="controller", values="cost")
    assert (costs.drop(columns="optimal").min(axis=1) >= costs["optimal"]).all()


def _context(kinematics, task="reach"):
    layout = ObservationLayout(kinematics.n_joints, kinematics.task_dim)
    return PolicyContext(kinematics, 1 / 125, np.full(kinematics.n_joints, 1e9), layout, task)


@pytest.mark.parametrize("model_arm", ["ur10 with joint offsets and a link scale", "ur5"])
def test_the_identifier_converges_to_the_true_jacobian_under_persistent_excitation_at_a_fixed_pose(ur10, model_arm):
    """Dither around one pose (a persistently exciting input): Ĵ at that pose → the true J (Pinocchio), from a
    model in the old error family and from another arm's model, which no family of the CLI's names."""
    if model_arm == "ur5":
        model = Kinematics("ur5")
    else:
        model = Kinematics("ur10", model_error="joint_offset=0.05,-0.1,0.3,0.1,-0.2,0.15;link_scale=0.02")
    identifier = GeometricIdentifier(model, (0.1, 0.05), 1e-4)
    rng = np.random.default_rng(11)
    q0 = np.array([0.3, -1.2, 1.4, -1.0, -1.3, 0.4])
    size = np.linalg.norm(ur10.jacobian(q0))
    errors = [np.linalg.norm(identifier.jacobians(q0[None])[0] - ur10.jacobian(q0)) / size]
    for step in range(1, 1001):
        q = q0 + rng.uniform(-0.1, 0.1, 6)
        identifier.update(q[None], ur10.forward(q)[None])
        if step in (100, 1000):
            errors.append(np.linalg.norm(identifier.jacobians(q0[None])[0] - ur10.jacobian(q0)) / size)
    assert errors[0] > 0.05  # the model starts 5 % or more off
    assert errors[2] < 3e-4 and errors[2] < errors[1] / 3  # and keeps converging
    assert identifier.residual[0] < 1e-4  # m: the model predicts the measured position to its noise σ
    assert identifier.excitation()[0] > 0


def _obs(context, plant, q, e, xdot_d=np.zeros(3)):
    x = plant.forward(q)  # measured: the plant's position
    return context.layout.pack(q, np.zeros(len(q)), x, x - e, xdot_d, x - e)


def test_without_a_model_error_the_critic_converges_to_the_are_solution(ur10, rng):
    context = _context(ur10)
    policy = SNACAdaptivePolicy(context, learning_rate=60.0, warm_start_iterations=0)
    policy.reset(seed=8)
    q = rng.uniform(-2, 2, 6)
    for _ in range(200):
        policy.act(_obs(context, ur10, q, np.zeros(3)))
    expected = solve_continuous_are(np.zeros((3, 3)), ur10.jacobian(q), np.eye(3), np.eye(6))
    np.testing.assert_allclose(quadratic_weights_to_matrix(policy.critic_weights, 3), expected, rtol=1e-8)
    np.testing.assert_allclose(policy.identifier.params, 0.0, atol=1e-12)  # nothing to correct (rounding aside)


def test_with_a_model_error_the_critic_converges_to_the_true_problems_are_solution(ur10):
    """snac-hjb's critic settles on P*(J_model); snac-adaptive's on P*(J), the true arm's."""
    model = Kinematics("ur10", model_error=ELBOW)
    context = _context(model)
    rng = np.random.default_rng(4)
    q0 = np.array([0.3, -1.2, 1.4, -1.0, -1.3, 0.4])
    policy = SNACAdaptivePolicy(context, learning_rate=60.0)
    policy.reset(seed=1)
    for _ in range(1000):
        policy.act(_obs(context, ur10, q0 + rng.uniform(-0.1, 0.1, 6), np.zeros(3)))
    for _ in range(100):
        policy.act(_obs(context, ur10, q0, np.zeros(3)))
    true_p = solve_continuous_are(np.zeros((3, 3)), ur10.jacobian(q0), np.eye(3), np.eye(6))
    model_p = solve_continuous_are(np.zeros((3, 3)), model.jacobian(q0), np.eye(3), np.eye(6))
    learnt = quadratic_weights_to_matrix(policy.critic_weights, 3)
    assert np.linalg.norm(model_p - true_p) > 0.05 * np.linalg.norm(true_p)
    # Ĵ is within ~1e-4 of J after this dither (the identifier test above), and P* follows it.
    assert np.linalg.norm(learnt - true_p) < 1e-3 * np.linalg.norm(true_p)


def test_the_demo_gives_the_wrong_model_to_the_controller_and_draws_its_correction(tmp_path):
    from snac_gym.apps.demo import run_demo

    result = run_demo("track", "snac-adaptive", tmp_path, steps=60, model_error=ELBOW)
    residual = result.log["model_residual"].to_numpy()
    assert residual[0] > 0.05  # the wrong model first misplaces the tool by centimetres (0.3 rad at the elbow)
    assert residual[-1] < 1e-3  # and predicts the measured position within 1 mm after 0.5 s
    assert (tmp_path / "track_snac-adaptive_model.png").is_file()
    assert result.log.attrs["model_error"] == ELBOW
    true_model = run_demo("track", "snac-adaptive", None, steps=60)
    assert true_model.log["model_residual"].max() < 1e-4  # PyBullet's arm matches the true model


def test_a_real_arm_refuses_a_model_error():
    from snac_gym.apps.real import run_real_episode

    with pytest.raises(ValueError, match="--connection sim only"):
        run_real_episode(connection="rtde", host="127.0.0.1", model_error=ELBOW, out_dir=None)


def test_a_controller_that_cannot_take_the_wrong_model_refuses_it():
    pytest.importorskip("mink")
    from snac_gym.policies import make_policy

    context = policy_context("ur10", 1 / 125, "reach", ELBOW)
    with pytest.raises(ValueError, match="mink builds its MuJoCo model from the URDF"):
        make_policy("mink", context)


def test_the_identifiers_model_is_the_arm_at_zero_and_its_derivatives_are_exact(ur10, rng):
    """x̂ and Ĵ at ĉ = 0 are the model's (Pinocchio); at a random ĉ, Ĵ = ∂x̂/∂θ and H = ∂x̂/∂c by central differences."""
    identifier = GeometricIdentifier(ur10, (0.1, 0.05), 1e-4)
    q = rng.uniform(-2.0, 2.0, (4, 6))
    identifier.reset(4)
    x, jacobian, _ = identifier._model(q)
    np.testing.assert_allclose(x, ur10.forward_batch(q), atol=1e-12)
    np.testing.assert_allclose(jacobian, ur10.jacobian_batch(q), atol=1e-12)
    identifier.params = rng.normal(0.0, 0.05, (4, identifier.size))
    x, jacobian, regressor = identifier._model(q)
    step, params = 1e-6, identifier.params.copy()
    for i in range(identifier.size):
        shifted = []
        for sign in (1.0, -1.0):
            identifier.params = params.copy()
            identifier.params[:, i] += sign * step
            shifted.append(identifier._model(q)[0])
        np.testing.assert_allclose(regressor[:, :, i], (shifted[0] - shifted[1]) / (2 * step), atol=1e-8)
    identifier.params = params
    for j in range(6):
        dq = np.zeros(6)
        dq[j] = step
        numeric = (identifier._model(q + dq)[0] - identifier._model(q - dq)[0]) / (2 * step)
        np.testing.assert_allclose(jacobian[:, :, j], numeric, atol=1e-8)
