"""The evaluator on the pose tasks: the lockstep engine against the env's kinematic physics, the
pose samples CSV, and small evaluations (API and CLI) on the Panda."""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import numpy as np
import pinocchio as pin
import pytest
from snac_gym.evaluation import EvaluationConfig, run_evaluation
from snac_gym.evaluation.samples import (
    SampleFileError,
    column_names,
    generate_samples,
    read_samples_csv,
    write_samples_csv,
)
from typer.testing import CliRunner

from snac_gym.apps.cli import app
from snac_gym.model.kinematics import Kinematics, PoseKinematics
from snac_gym.policies import make_policy
from snac_gym.policies.base import PolicyContext
from snac_gym.rollout import rollout, simulate_kinematic
from snac_gym.rollout.kinematic import task_error_function
from snac_gym.sampling import SampleSpace
from snac_gym.tasks import Sample
from snac_gym.tasks.pose import (
    POSE_TASK_NAMES,
    POSE_TASKS,
    ROTVEC_COLUMNS,
    pose_errors_and_jacobians,
)

POSE_ENV_IDS = ["snac_gym/PandaPoseReach-v0", "snac_gym/PandaPoseEllipseTrack-v0"]
SMALL = {"robot": "panda", "samples": 3, "effort_samples": 0, "horizons": {"pose-reach": 0.4}, "chunk_size": 2,
         "progress": False, "plots": False}  # fmt: skip


#: The pose tasks are registered for this module only (conftest.py): the others see the paper's two.
pytestmark = pytest.mark.usefixtures("pose_tasks")


@pytest.fixture(scope="module")
def panda() -> Kinematics:
    return Kinematics("panda")


def test_pose_task_names_are_the_registered_ones():
    assert tuple(task.name for task in POSE_TASKS) == POSE_TASK_NAMES


@pytest.mark.parametrize("env_id", POSE_ENV_IDS)
@pytest.mark.parametrize("controller", ["snac", "dls"])
def test_engine_is_the_kinematic_env_episode_for_episode(env_id, controller):
    """physics="kinematic" of a pose env and simulate_kinematic: the same commands and log₃ errors."""
    env = gym.make(env_id, physics="kinematic")
    log = rollout(env, make_policy(controller, env), seed=5, steps=150)
    base = env.unwrapped
    m = base.kinematics.n_joints
    sample = Sample(base.task_name, 0, log[[f"q_{j}" for j in range(m)]].to_numpy()[0], base.reference)
    context = PolicyContext.from_env(env)
    assert context.layout.task_dim == 6
    u = log[[f"u_{j}" for j in range(m)]].to_numpy()
    e = log[[f"e_{j}" for j in range(6)]].to_numpy()
    # One policy object per sample: the env's own arithmetic, so the two agree exactly.
    single = simulate_kinematic(context, lambda: make_policy(controller, context), [sample], 150, [5], use_batch=False)
    np.testing.assert_array_equal(single.commands[0], u)
    np.testing.assert_array_equal(single.errors[0], e)
    np.testing.assert_array_equal(single.final_errors[0], log.attrs["final_e"])
    # The batch protocol sums in another order: equal to rounding.
    batch = simulate_kinematic(context, lambda: make_policy(controller, context), [sample], 150, [5])
    np.testing.assert_allclose(batch.commands[0], u, rtol=0, atol=1e-9)
    np.testing.assert_allclose(batch.final_errors[0], log.attrs["final_e"], rtol=0, atol=1e-12)


def test_engine_errors_are_the_log3_of_the_orientation_error():
    """The orientation rows are log₃(R R_dᵀ) from the placements, not a difference of rotation vectors."""
    env = gym.make("snac_gym/PandaPoseReach-v0", physics="kinematic")
    env.reset(seed=3)
    context = PolicyContext.from_env(env)
    kin: PoseKinematics = context.kinematics
    target = env.unwrapped.reference
    q0 = np.zeros(kin.n_joints) + 0.3
    sample = Sample("pose-reach", 0, q0, target)
    out = simulate_kinematic(context, lambda: make_policy("dls", context), [sample], 5, [0])
    desired = pin.exp3(target.rotation)
    for k in range(5):
        placement = kin.placement(out.q[0, k])
        np.testing.assert_allclose(out.errors[0, k, :3], placement.translation - target.position, atol=1e-14)
        np.testing.assert_allclose(out.errors[0, k, 3:], pin.log3(placement.rotation @ desired.T), atol=1e-12)
    assert not np.allclose(out.errors[0, 0, 3:], out.x[0, 0, 3:] - target.rotation, atol=1e-6)


def test_position_tasks_keep_the_plain_difference(panda):
    assert task_error_function(panda) is np.subtract
    assert task_error_function(PoseKinematics("panda")) is not np.subtract


def test_pose_samples_round_trip_through_the_csv(tmp_path, panda):
    space = SampleSpace.for_robot(panda)
    samples = [
        *generate_samples(panda, space, 4, "pose-reach", range(3)),
        *generate_samples(panda, space, 4, "pose-track", range(2)),
    ]
    path = write_samples_csv(samples, tmp_path / "pose.csv", panda.n_joints)
    header = path.read_text().splitlines()[0].split(",")
    assert header == column_names(panda.n_joints) and set(ROTVEC_COLUMNS) <= set(header)
    read = read_samples_csv(path, panda, space)
    again = [*read["pose-reach"], *read["pose-track"]]
    assert [(s.task, s.index) for s in again] == [(s.task, s.index) for s in samples]
    for original, copy in zip(samples, again, strict=True):
        np.testing.assert_array_equal(copy.q0, original.q0)
        np.testing.assert_array_equal(copy.reference.centre, original.reference.centre)
        assert copy.reference.to_dict() == original.reference.to_dict()


def test_a_bad_pose_row_is_named(tmp_path, panda):
    space = SampleSpace.for_robot(panda)
    (sample,) = generate_samples(panda, space, 0, "pose-reach", [0])
    path = write_samples_csv([sample], tmp_path / "ok.csv", panda.n_joints)
    text = path.read_text()
    bad = tmp_path / "bad.csv"
    bad.write_text(text.replace(repr(float(sample.reference.rotation[1])), "oops", 1))
    with pytest.raises(SampleFileError, match="column 'rotvec_1'.*not a number"):
        read_samples_csv(bad, panda, space)
    far = tmp_path / "far.csv"
    far.write_text(text.replace(repr(float(sample.reference.position[0])), "3.0", 1))
    with pytest.raises(SampleFileError, match="unreachable"):
        read_samples_csv(far, panda, space)


def test_a_tiny_evaluation_runs_and_reads_back_its_samples(tmp_path):
    config = EvaluationConfig(
        out=tmp_path / "run",
        tasks=("pose-reach",),
        controllers=("dls", "snac"),
        export_samples=tmp_path / "samples.csv",
        **SMALL,
    )
    results = run_evaluation(config)
    assert set(results["task"]) == {"pose-reach"} and len(results) == 2 * 3
    assert np.isfinite(results["cost"]).all() and (results["cost"] > 0).all()
    again = run_evaluation(
        dataclasses.replace(config, out=tmp_path / "again", export_samples=None, samples_file=tmp_path / "samples.csv")
    )
    columns = ["controller", "sample", "cost", "final_error", "max_abs_u"]
    assert again[columns].equals(results[columns])


def test_pose_runs_do_not_mix_with_position_tasks(tmp_path):
    with pytest.raises(ValueError, match="mix pose tasks"):
        EvaluationConfig(out=tmp_path, **{**SMALL, "tasks": ("pose-reach", "reach")}).validate()


def test_pose_error_jacobian_is_the_derivative_of_the_log3_error():
    kin = PoseKinematics("panda")
    rng = np.random.default_rng(7)
    qs = rng.uniform(-1.0, 1.0, size=(6, kin.n_joints))
    x_d = kin.forward_batch(rng.uniform(-1.0, 1.0, size=(6, kin.n_joints)))  # up to ~3 rad apart
    errors, jacobians = pose_errors_and_jacobians(kin, qs, x_d)
    np.testing.assert_array_equal(errors, [kin.task_error(x, d) for x, d in zip(kin.forward_batch(qs), x_d)])
    h = 1e-6
    for j in range(kin.n_joints):
        step = h * np.eye(kin.n_joints)[j]
        plus, minus = (
            pose_errors_and_jacobians(kin, qs + step, x_d)[0],
            pose_errors_and_jacobians(kin, qs - step, x_d)[0],
        )
        np.testing.assert_allclose(jacobians[:, :, j], (plus - minus) / (2 * h), atol=1e-7)
    # Not the controllers' J: Jlog₃ matters away from the target.
    assert np.abs(jacobians[:, 3:] - kin.jacobian_batch(qs)[:, 3:]).max() > 0.1


def test_the_optimum_of_a_pose_run_is_below_every_controller(tmp_path):
    config = EvaluationConfig(
        out=tmp_path / "opt",
        tasks=("pose-reach",),
        controllers=("dls", "rnn", "optimal"),
        **{**SMALL, "horizons": {"pose-reach": 1.0}},
    )
    results = run_evaluation(config)
    optimal = results[results["controller"] == "optimal"].set_index("sample")
    assert optimal["optimal_converged"].all()
    for name in ("dls", "rnn"):
        rows = results[results["controller"] == name].set_index("sample")
        assert (optimal["cost"] < rows["cost"]).all(), name


def test_cli_evaluates_a_pose_task(tmp_path):
    result = CliRunner().invoke(
        app,
        [
            "evaluate",
            "--out",
            str(tmp_path / "cli"),
            "--robot",
            "panda",
            "--task",
            "pose-reach",
            "--samples",
            "2",
            "--horizon",
            "pose-reach=0.2",
            "--controllers",
            "dls",
            "--no-match-effort",
            "--no-progress",
        ],
    )
    assert result.exit_code == 0, result.output
    assert "Pose regulation" in result.output
