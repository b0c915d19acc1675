"""Inputs the public API used to take silently (or answer with a raw exception), each refused with a message
naming the argument: the list of a robustness pass over the landed code."""

from __future__ import annotations

import json
import logging
import os
import warnings
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from snac_gym.evaluation import EvaluationConfig

import snac_gym  # noqa: F401  (registers the ids)
from snac_gym.common.validation import real_array, real_number, whole_number
from snac_gym.control.cost import trajectory_cost
from snac_gym.model.model_error import ModelError
from snac_gym.policies import make_policy

ID = "snac_gym/UR10Reach-v0"


@pytest.fixture(scope="module")
def goal_env():
    env = gym.make("snac_gym/UR10ReachGoal-v0", physics="kinematic", reward_type="sparse").unwrapped
    env.reset(seed=0)
    yield env
    env.close()


@pytest.mark.parametrize(
    ("desired", "message"),
    [
        (np.array([np.nan, 0.0, 0.0]), r"desired_goal must be finite, got NaN or inf"),
        (np.zeros(1), r"desired_goal must have shape \(\.\.\., 3\), got \(1,\)"),
        (np.zeros((3, 2)), r"desired_goal must have shape \(\.\.\., 3\), got \(3, 2\)"),
        (np.full(3, 0.5j), r"desired_goal must be real numbers, got dtype complex128"),
        (np.zeros((2, 3)), r"must have one shape, got \(3,\) and \(2, 3\)"),
    ],
    ids=["nan", "1-wide", "3x2", "complex", "batch-against-one"],
)
def test_a_goal_that_is_not_a_goal_never_scores(goal_env, desired, message):
    for method in (goal_env.compute_reward, goal_env.compute_terminated):
        with pytest.raises(ValueError, match=message):
            method(np.zeros(3), desired, {})
    # A batch of goals against a batch of achieved goals still works, element by element.
    rewards = goal_env.compute_reward(np.zeros((4, 3)), np.zeros((4, 3)), {})
    assert rewards.shape == (4,) and np.all(rewards == 0.0)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"n_substeps": 0}, r"n_substeps must be a whole number in \[1, 1000\], got 0"),
        ({"n_substeps": -3}, r"n_substeps must be a whole number in \[1, 1000\], got -3"),
        ({"n_substeps": 2.5}, r"n_substeps must be a whole number in \[1, 1000\], got 2.5"),
        ({"n_substeps": 10**9}, r"n_substeps must be a whole number in \[1, 1000\], got 1000000000"),
        ({"n_substeps": True}, r"n_substeps must be a whole number"),
        ({"dt": "0.008"}, r"dt \(s\) must be a real number in \[1e-06, 1\], got '0.008'"),
        ({"dt": True}, r"dt \(s\) must be a real number in \[1e-06, 1\], got True"),
        ({"dt": 0.5j}, r"dt \(s\) must be a real number"),
        ({"max_steps": 2.7}, r"max_steps must be a whole number in \[1, 10000000\], got 2.7"),
        ({"max_steps": 10**8}, r"max_steps must be a whole number in \[1, 10000000\]"),
        ({"dt": 1e-320}, r"dt \(s\) must be a finite number in \[1e-06, 1\], got 1e-320"),
    ],
)
@pytest.mark.parametrize("physics", ["kinematic", "pybullet"])
def test_env_timing_arguments_are_refused_on_every_engine(physics, kwargs, message):
    with pytest.raises(ValueError, match=message):
        gym.make(ID, physics=physics, **kwargs)


def test_whole_float_arguments_keep_working():
    env = gym.make(ID, physics="kinematic", n_substeps=3.0, dt=np.float32(0.008)).unwrapped
    assert env.dt == pytest.approx(0.008)
    env.close()


@pytest.mark.parametrize("action", [np.full(6, 0.5j), np.array([True] * 6), np.array(["a"] * 6)])
def test_an_action_that_is_not_real_numbers_is_refused_not_cast(action):
    env = gym.make(ID, physics="kinematic")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must be 6 joint velocities in rad/s \(real numbers\)"):
        env.step(action)
    env.close()


def test_trajectory_cost_refuses_an_empty_trajectory_and_complex_weights():
    with pytest.raises(ValueError, match=r"a trajectory cost needs at least one step, got K = 0"):
        trajectory_cost(np.zeros((0, 3)), np.zeros((0, 6)), 0.008)
    with pytest.raises(ValueError, match=r"Q must be a \(3, 3\) matrix .*dtype complex128"):
        trajectory_cost(np.zeros((2, 3)), np.zeros((2, 6)), 0.008, Q=np.eye(3) * 1j)
    with pytest.raises(ValueError, match=r"commands must be real numbers, got dtype complex128"):
        trajectory_cost(np.zeros((2, 3)), np.full((2, 6), 1j), 0.008)
    with pytest.raises(ValueError, match=r"errors must be finite, got NaN or inf at \[1, 2\]"):
        trajectory_cost(np.array([[0.0, 0, 0], [0, 0, np.nan]]), np.zeros((2, 6)), 0.008)
    with pytest.raises(ValueError, match=r"commands must be finite, got NaN or inf at \[0, 0\]"):
        trajectory_cost(np.zeros((2, 3)), np.full((2, 6), np.inf), 0.008)
    with pytest.raises(ValueError, match=r"dt must be a finite number in \(0, inf\]"):
        trajectory_cost(np.zeros((2, 3)), np.zeros((2, 6)), -1.0)
    assert float(trajectory_cost(np.ones((1, 3)), np.zeros((1, 6)), 0.5).total) == pytest.approx(1.5)


@pytest.mark.parametrize("controller", ["dls", "lqr", "snac"])
def test_act_refuses_a_nan_observation_instead_of_returning_a_nan_command(controller):
    env = gym.make(ID, physics="kinematic")
    obs, _ = env.reset(seed=0)
    policy = make_policy(controller, env.unwrapped)
    policy.reset(seed=0)
    assert np.isfinite(policy.act(obs)).all()
    bad = obs.copy()
    bad[0] = np.nan
    with pytest.raises(
        ValueError, match=rf"act needs a finite observation of shape \({obs.size},\), got float64 .* with NaN"
    ):
        policy.act(bad)
    with pytest.raises(ValueError, match=r"act needs a finite observation of shape"):
        policy.act(obs[:-1])
    env.close()


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"link_scale": 1e6}, r"model error link_scale must be a finite number in \(-1, 1\], got 1000000.0"),
        ({"link_scale": True}, r"model error link_scale must be a real number"),
        ({"tool_offset": (1e9, 0, 0)}, r"model error tool_offset \(m\) must be a finite number in \[-1, 1\]"),
        ({"joint_offset": (0, 4.0)}, r"model error joint_offset must be a finite number in \[-3.14159, 3.14159\]"),
    ],
)
def test_a_model_error_outside_what_a_wrong_model_can_be_is_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        ModelError(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"samples": True}, "samples must be a whole number, got True"),
        ({"seed": 1.5}, "seed must be a whole number, got 1.5"),
        ({"dt": "0.008"}, "dt must be a real number, got '0.008'"),
        ({"plots": 1}, "plots must be True or False, got 1"),
    ],
)
def test_evaluation_options_of_the_wrong_type_are_refused(kwargs, message):
    with pytest.raises(ValueError, match=message):
        EvaluationConfig(out=Path("unused"), **kwargs).validate()


def test_the_shared_checks():
    assert real_number("x", np.float32(0.5), 0, 1) == 0.5 and whole_number("n", 4.0, 1, 5) == 4
    for bad in (True, "1", 1j, float("nan"), float("inf")):
        with pytest.raises(ValueError, match="x must be a"):
            real_number("x", bad)
    with pytest.raises(ValueError, match=r"a must have shape \(N, 3\), got \(2, 2\)"):
        real_array("a", np.zeros((2, 2)), (None, 3))
    with pytest.raises(ValueError, match="a must be an array of real numbers"):
        real_array("a", [[1, 2], [3]])


@pytest.mark.parametrize(
    ("arguments", "message"),
    [
        (["real", "--connection", "sim", "--host", "10.0.0.1", "--dry-run"], "--host is for --connection rtde"),
        (
            ["real", "--connection", "sim", "--steps", "1000000000000", "--dry-run"],
            "--steps must be a whole number in [1, 1800000], got 1000000000000",
        ),
        (
            ["evaluate", "--seed", "-1", "--samples", "2"],
            "seed must be a whole number in [0, 4294967295] (a NumPy seed), got -1",
        ),
        (
            ["real", "--connection", "sim", "--seed", "-1", "--dry-run"],
            "--seed must be a whole number in [0, 4294967295], got -1",
        ),
        (
            ["evaluate", "--ray", "auto", "--workers", "2", "--samples", "2"],
            "--workers 2 has no effect on a Ray cluster",
        ),
        (["train-ppo", "--task", "reach", "--n-envs", "100000000"], "Invalid value for '--n-envs'"),
        (["train-ppo", "--task", "reach", "--resume", "--seed", "3"], "--seed has no effect with --resume"),
    ],
    ids=["sim-host", "real-steps", "seed", "real-seed", "ray-workers", "n-envs", "resume-seed"],
)
def test_cli_inputs_it_used_to_ignore_or_hang_on_are_refused(tmp_path, arguments, message):
    """Each before anything runs, with exit 2 (the long runs and the hang never start)."""
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    result = CliRunner().invoke(app, [*arguments, "--out", str(tmp_path / "out")], terminal_width=200)
    assert result.exit_code == 2, result.output
    assert message in " ".join(result.output.split()), result.output


def test_a_ppo_config_with_too_many_envs_is_refused():
    from snac_gym.ppo.config import ConfigError, resolve_config, validate_config

    with pytest.raises(ConfigError, match=r"vec_env.n_envs must be an integer in \[1, 1024\], got 100000000"):
        validate_config(resolve_config("reach", n_envs=100_000_000))


# -- the rest of the inputs reported as accepted, hanging or unclear -------------------------------------
def test_a_complex_action_is_refused_by_the_goal_env_and_the_vector_env():
    goal = gym.make("snac_gym/UR10ReachGoal-v0")
    goal.reset(seed=0)
    with pytest.raises(ValueError, match=r"action must be 6 joint velocities in rad/s \(real numbers\)"):
        goal.step(np.full(6, 0.5j))
    goal.close()
    vector = gym.make_vec(ID, 2, vectorization_mode="vector_entry_point")
    vector.reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # not a ComplexWarning and a cast: an error
        with pytest.raises(ValueError, match=r"actions must be an array of real numbers of shape \(2, 6\)"):
            vector.step(np.full((2, 6), 0.5j))
    vector.close()


def test_a_vector_env_of_a_billion_episodes_is_refused_before_it_allocates():
    with pytest.raises(ValueError, match=r"num_envs must be a whole number in \[1, 1048576\], got 1000000000"):
        gym.make_vec(ID, 10**9, vectorization_mode="vector_entry_point")
    with pytest.raises(ValueError, match=r"num_envs must be a whole number in \[1, 1048576\], got 2.5"):
        gym.make_vec(ID, 2.5, vectorization_mode="vector_entry_point")


def test_mujoco_refuses_a_billion_substeps_too():
    pytest.importorskip("mujoco")
    with pytest.raises(ValueError, match=r"n_substeps must be a whole number in \[1, 1000\], got 1000000000"):
        gym.make(ID, physics="mujoco", n_substeps=10**9)


@pytest.mark.parametrize(
    ("section", "key", "value", "message"),
    [
        ("env", "n_substeps", 10**9, r"env.n_substeps must be a whole number in \[1, 1000\], got 1000000000"),
        ("env", "dt", "0.008", r"env.dt must be a number > 0, got '0.008'"),
        ("env", "dt", 1e-9, r"env.dt \(s\) must be a finite number in \[1e-06, 1\], got 1e-09"),
    ],
)
def test_a_ppo_config_with_an_env_argument_out_of_range_is_refused_before_training(
    tmp_path, section, key, value, message
):
    from snac_gym.ppo.config import default_config_path, load_config
    from snac_gym.ppo.train import train_ppo

    config = load_config(default_config_path("reach"))
    config[section][key] = value
    path = tmp_path / "config.json"
    path.write_text(json.dumps(config))
    with pytest.raises(ValueError, match=message):
        train_ppo("reach", tmp_path / "out", config_path=path, log=lambda line: None)
    assert not (tmp_path / "out" / "state.json").exists()


def test_a_ppo_model_path_that_is_a_device_or_folder_is_named_as_such(tmp_path):
    from snac_gym.ppo import PolicyFileError

    env = gym.make(ID, physics="kinematic")
    for path, what in (("/dev/zero", "a device, pipe or socket"), (str(tmp_path), "a folder")):
        with pytest.raises(PolicyFileError, match=f"PPO policy file {path} is {what}, not a policy file"):
            make_policy("ppo", env.unwrapped, model_path=path)
    env.close()


@pytest.mark.parametrize("kind", ["fifo", "file"])
def test_real_refuses_an_out_that_is_a_pipe_or_a_file_before_it_connects(tmp_path, kind):
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    out = tmp_path / "out"
    os.mkfifo(out) if kind == "fifo" else out.write_text("")
    result = CliRunner().invoke(
        app, ["real", "--connection", "sim", "--out", str(out), "--steps", "5"], terminal_width=200
    )
    what = "a named pipe" if kind == "fifo" else "a file"
    assert result.exit_code == 2, result.output
    assert f"error: the output folder {out} is {what}, not a folder; choose another --out" in result.output


def test_evaluate_refuses_a_model_error_no_arm_can_have(tmp_path):
    from typer.testing import CliRunner

    from snac_gym.apps.cli import app

    result = CliRunner().invoke(
        app,
        ["evaluate", "--out", str(tmp_path / "out"), "--samples", "2", "--model-error", "link_scale=1e6"],
        terminal_width=200,
    )
    assert result.exit_code == 2, result.output
    assert "model error link_scale must be a finite number in (-1, 1], got 1000000.0" in result.output
    assert not (tmp_path / "out" / "run.json").exists()


def test_a_local_ray_instance_gets_the_workers_as_its_cpus(monkeypatch):
    """`evaluate --ray local --workers 2` used to ignore --workers: the local instance now has that many CPUs."""
    import types

    from snac_gym.evaluation.execution import executors

    calls = []
    fake = types.SimpleNamespace(is_initialized=lambda: False, init=lambda **kwargs: calls.append(kwargs))
    monkeypatch.setitem(__import__("sys").modules, "ray", fake)
    executors.RayExecutor("local", 2)
    assert calls == [
        {"num_cpus": 2, "include_dashboard": False, "log_to_driver": False, "logging_level": logging.WARNING}
    ]
